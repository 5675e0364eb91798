"""Shared weights: check a graph's ONNX external-data references before any engine opens the graph.

A bundle whose graphs share one weights file (the exporter's default since 0.3) has graphs whose initializers say
"my bytes are at offset O, length L of file F". ONNX Runtime and OpenVINO follow F relative to the graph, and ONNX
Runtime even reads a magic location as a memory address, so a signed-but-wrong or crafted graph could make an engine
read any file the kiosk can. The kiosk therefore reads every tensor's external-data entry itself (a small protobuf
walk over the parts of an ONNX model that can hold tensors, without the `onnx` package, which the runtime does not
ship) and refuses the bundle unless each one names the bundle's own weights file, in range, with the length the
tensor's shape and type need. The weights file's bytes are covered by the manifest's SHA-256 like every file.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from kiosk.bundle.manifest import BundleError

MAX_DEPTH = 24          # subgraph nesting (If/Loop bodies); our graphs have none, real models a few
_NUMBER_RE = re.compile(r"^[0-9]{1,19}$")
_EXTERNAL = 1           # TensorProto.DataLocation.EXTERNAL
# TensorProto.DataType -> bytes per element (the fixed-size numeric types an engine can read from a file)
ELEMENT_BYTES = {1: 4, 2: 1, 3: 1, 4: 2, 5: 2, 6: 4, 7: 8, 9: 1, 10: 2, 11: 8, 12: 4, 13: 8, 14: 8, 15: 16, 16: 2,
                 17: 1, 18: 1, 19: 1, 20: 1}
_KEYS = ("location", "offset", "length")

# Where tensors live in an ONNX model: message -> {field number: (kind of the field's message)}.
_SCHEMA: dict[str, dict[int, str]] = {
    "model": {7: "graph", 20: "training", 25: "function"},
    "training": {1: "graph", 2: "graph"},
    "graph": {1: "node", 5: "tensor", 15: "sparse"},
    "function": {7: "node", 11: "attribute"},
    "node": {5: "attribute"},
    "attribute": {5: "tensor", 6: "graph", 10: "tensor", 11: "graph", 22: "sparse", 23: "sparse"},
    "sparse": {1: "tensor", 2: "tensor"},
}


@dataclass(frozen=True)
class ExternalRef:
    """One tensor's external-data entry as the engines will read it."""

    tensor: str
    location: str
    offset: int
    length: int
    nbytes: int | None   # what its shape and type need (None: a type whose size the kiosk does not know)


class _Malformed(Exception):
    pass


def _varint(buf: memoryview, pos: int, end: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= end or shift > 63:
            raise _Malformed("truncated or overlong varint")
        b = buf[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, pos
        shift += 7


def _fields(buf: memoryview, start: int, end: int):
    """(field number, wire type, value) of one message; a length-delimited value is its (start, end)."""
    pos = start
    while pos < end:
        key, pos = _varint(buf, pos, end)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise _Malformed("field number 0")
        if wire == 0:
            value, pos = _varint(buf, pos, end)
        elif wire == 1:
            value, pos = None, pos + 8
        elif wire == 5:
            value, pos = None, pos + 4
        elif wire == 2:
            n, pos = _varint(buf, pos, end)
            value, pos = (pos, pos + n), pos + n
        else:
            raise _Malformed(f"wire type {wire}")
        if pos > end:
            raise _Malformed("a field runs past its message")
        yield number, wire, value


def _text(buf: memoryview, span: tuple[int, int]) -> str:
    try:
        return bytes(buf[span[0]:span[1]]).decode("utf-8")
    except UnicodeDecodeError:
        raise _Malformed("a string is not UTF-8") from None


def _tensor(buf: memoryview, start: int, end: int) -> ExternalRef | None:
    dims: list[int] = []
    dtype, name, location, has_raw, entries = 0, "", 0, False, {}
    for number, wire, value in _fields(buf, start, end):
        if number == 1 and wire == 0:
            dims.append(value)
        elif number == 1 and wire == 2:     # packed dims
            pos, stop = value
            while pos < stop:
                d, pos = _varint(buf, pos, stop)
                dims.append(d)
        elif number == 2 and wire == 0:
            dtype = value
        elif number == 8 and wire == 2:
            name = _text(buf, value)
        elif number == 9 and wire == 2:
            has_raw = value[1] > value[0]
        elif number == 14 and wire == 0:
            location = value
        elif number == 13 and wire == 2:
            key = val = ""
            for n, w, v in _fields(buf, *value):
                if n == 1 and w == 2:
                    key = _text(buf, v)
                elif n == 2 and w == 2:
                    val = _text(buf, v)
            if key in entries:
                raise BundleError(f"tensor {name or '?'} states external-data key {key!r} twice")
            entries[key] = val
    if location != _EXTERNAL and not entries:
        return None
    label = name or "(unnamed)"
    if location != _EXTERNAL:
        raise BundleError(f"tensor {label} carries external-data entries but is not marked external")
    if has_raw:
        raise BundleError(f"tensor {label} is marked external but also holds its bytes inline")
    unknown = sorted(set(entries) - set(_KEYS))
    if unknown:
        raise BundleError(f"tensor {label} has external-data key(s) {', '.join(map(repr, unknown))}; a bundle "
                          f"uses only {', '.join(_KEYS)}")
    missing = [k for k in _KEYS if k not in entries]
    if missing:
        raise BundleError(f"tensor {label}'s external data does not state its {' and '.join(missing)}")
    for k in ("offset", "length"):
        if not _NUMBER_RE.match(entries[k]):
            raise BundleError(f"tensor {label}'s external-data {k} {entries[k][:40]!r} is not a plain decimal number")
    nbytes = None
    if dtype in ELEMENT_BYTES and all(d < (1 << 40) for d in dims):
        nbytes = ELEMENT_BYTES[dtype]
        for d in dims:
            nbytes *= d
    return ExternalRef(label, entries["location"], int(entries["offset"]), int(entries["length"]), nbytes)


def _walk(buf: memoryview, kind: str, start: int, end: int, depth: int, out: list[ExternalRef]) -> None:
    if depth > MAX_DEPTH:
        raise BundleError(f"graph nests subgraphs deeper than {MAX_DEPTH} levels")
    if kind == "tensor":
        ref = _tensor(buf, start, end)
        if ref is not None:
            out.append(ref)
        return
    inner = _SCHEMA[kind]
    for number, wire, value in _fields(buf, start, end):
        if wire == 2 and number in inner:
            _walk(buf, inner[number], value[0], value[1], depth + 1, out)


def external_refs(data: bytes) -> list[ExternalRef]:
    """Every external-data reference in a serialized ONNX model, wherever a tensor can sit (initializers, sparse
    initializers, Constant and other tensor attributes, subgraphs, functions, training graphs). Raises
    BundleError on bytes that are not a well-formed model or on an entry that is malformed in itself."""
    buf = memoryview(data)
    out: list[ExternalRef] = []
    try:
        _walk(buf, "model", 0, len(buf), 0, out)
    except _Malformed as exc:
        raise BundleError(f"not a well-formed ONNX model ({exc})") from None
    return out


def check_graph_weights(graph: Path, weights: Path | None, *, graph_name: str, weights_name: str | None) -> int:
    """Refuse `graph` unless each external-data reference in it lies inside `weights` (its bundle's weights file,
    which sits in the graph's folder) with the byte length its tensor needs. `weights` None: the graph must embed
    all its tensors (the layout before shared weights). Returns the number of references checked."""
    refs = external_refs(Path(graph).read_bytes())
    if not refs:
        return 0
    if weights is None:
        raise BundleError(f"graph {graph_name} reads tensor {refs[0].tensor} from an external file "
                          f"({refs[0].location[:80]!r}), but the manifest names no weights file for it")
    size = Path(weights).stat().st_size
    own = Path(weights).name
    for ref in refs:
        if ref.location != own:
            raise BundleError(f"graph {graph_name} reads tensor {ref.tensor} from {ref.location[:80]!r}; a graph may "
                              f"read only its bundle's weights file {weights_name} (as {own!r})")
        if ref.offset + ref.length > size:
            raise BundleError(f"graph {graph_name}'s tensor {ref.tensor} lies at bytes {ref.offset}..."
                              f"{ref.offset + ref.length} of {weights_name}, which has {size} bytes")
        if ref.nbytes is None:
            raise BundleError(f"graph {graph_name}'s tensor {ref.tensor} has a type the kiosk cannot size; only "
                              "fixed-size numeric tensors may be external")
        if ref.length != ref.nbytes:
            raise BundleError(f"graph {graph_name}'s tensor {ref.tensor} states {ref.length} bytes of external "
                              f"data; its shape and type need {ref.nbytes}")
    return len(refs)
