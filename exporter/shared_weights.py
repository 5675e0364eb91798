"""Shared weights: a bundle's graphs keep their tensors in one weights file, each distinct tensor stored once.

The full, tactile and visual graphs are cut from one generator, so most of each graph's bytes are the same tensors
(the shared encoder, and each decoder twice). Every initializer of every graph is moved into one file as ONNX
external data; tensors equal in type, shape and bytes are written once and referenced by offset and length from
every graph that holds them. The engines read the graphs unchanged (same nodes, same tensors), so outputs are
bit-identical to the embedded graphs; `exporter.export` runs both to prove it for every bundle it writes.

Tensors smaller than `MIN_EXTERNAL_BYTES` stay inside their graph: the reference would cost more bytes than it
saves (measured on the demo bundle, docs/performance.md "Bundle bytes").
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import onnx
from onnx import numpy_helper

WEIGHTS_FILE = "weights.bin"
MIN_EXTERNAL_BYTES = 64
ALIGN = 64       # each tensor starts on a 64-byte boundary: the widest SIMD load, at under 64 bytes per tensor
_TYPED_FIELDS = ("float_data", "int32_data", "string_data", "int64_data", "double_data", "uint64_data")


@dataclass
class SharingReport:
    """What sharing did: tensors moved, distinct tensors written, and bytes as embedded versus as shared."""

    tensors: int = 0
    distinct: int = 0
    embedded_bytes: int = 0     # the moved tensors' bytes summed over graphs (what the graphs carried themselves)
    weights_bytes: int = 0      # the weights file, padding included
    # tensor names that hold different bytes in different graphs (e.g. per-graph calibration): stored once each
    differing: list[str] = field(default_factory=list)

    def line(self) -> str:
        return (f"{self.tensors} tensors ({self.embedded_bytes / 1e6:.2f} MB embedded) stored as {self.distinct} "
                f"distinct in {self.weights_bytes / 1e6:.2f} MB")


def _raw(t: onnx.TensorProto) -> bytes:
    """The tensor's little-endian bytes, whichever field holds them."""
    if t.HasField("raw_data"):
        return t.raw_data
    return numpy_helper.from_array(numpy_helper.to_array(t)).raw_data


def _externalize(t: onnx.TensorProto, location: str, offset: int, length: int) -> None:
    for name in _TYPED_FIELDS + ("raw_data",):
        t.ClearField(name)
    del t.external_data[:]
    t.data_location = onnx.TensorProto.EXTERNAL
    for key, value in (("location", location), ("offset", str(offset)), ("length", str(length))):
        entry = t.external_data.add()
        entry.key, entry.value = key, value


def share_weights(graphs: dict[str, Path], out_dir: Path, *, weights_name: str = WEIGHTS_FILE,
                  min_bytes: int = MIN_EXTERNAL_BYTES) -> tuple[dict[str, Path], Path, SharingReport]:
    """Write each graph of `graphs` (name -> ONNX file with embedded tensors) to `out_dir`/<its file name>, its
    initializers of at least `min_bytes` moved into `out_dir`/`weights_name`. Returns the new graph paths, the
    weights file and a report."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    weights = out_dir / weights_name
    report = SharingReport()
    where: dict[tuple, tuple[int, int]] = {}
    by_name: dict[str, set[tuple]] = {}
    out: dict[str, Path] = {}
    pos = 0
    names = [Path(src).name for src in graphs.values()]
    if len(set(names)) < len(names) or weights_name in names:
        raise ValueError(f"graph file names must differ from each other and from {weights_name}: {names}")
    with open(weights, "wb") as f:
        for name, src in graphs.items():
            model = onnx.load(str(src))
            for t in model.graph.initializer:
                if t.data_type == onnx.TensorProto.STRING:
                    continue
                raw = _raw(t)
                if len(raw) < min_bytes:
                    continue
                key = (t.data_type, tuple(t.dims), hashlib.sha256(raw).digest())
                by_name.setdefault(t.name, set()).add(key)
                if key not in where:
                    pad = -pos % ALIGN
                    f.write(b"\0" * pad)
                    pos += pad
                    f.write(raw)
                    where[key] = (pos, len(raw))
                    pos += len(raw)
                report.tensors += 1
                report.embedded_bytes += len(raw)
                _externalize(t, weights_name, *where[key])
            dst = out_dir / Path(src).name
            if dst.resolve() == Path(src).resolve():
                raise ValueError(f"share_weights would overwrite its source {src}; give another out_dir")
            onnx.save(model, str(dst))
            out[name] = dst
    report.distinct = len(where)
    report.weights_bytes = pos
    report.differing = sorted(n for n, keys in by_name.items() if len(keys) > 1)
    return out, weights, report


def graph_bytes(path: Path) -> int:
    """The bytes one graph needs: its file plus the distinct ranges of external data it reads (what the graph
    would weigh embedding its own tensors)."""
    from kiosk.bundle.weights import external_refs

    path = Path(path)
    ranges = {(r.location, r.offset, r.length) for r in external_refs(path.read_bytes())}
    return path.stat().st_size + sum(length for _, _, length in ranges)


def embedded(path: Path, dst: Path) -> Path:
    """`path` itself if its graph embeds every tensor, else a copy at `dst` that does: tools that write the model
    to a folder of their own and read it back (ONNX Runtime's quantisation pre-processing) lose a relative
    weights file."""
    from kiosk.bundle.weights import external_refs

    if not external_refs(Path(path).read_bytes()):
        return Path(path)
    onnx.save(onnx.load(str(path)), str(dst))
    return Path(dst)
