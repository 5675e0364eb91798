"""The bundle manifest: a typed schema, a strict YAML parser and the canonical serialisation.

The exporter writes what this module reads (it calls `dump_manifest`), so the two can never drift. Parsing is
strict because a manifest arrives from outside the kiosk: YAML aliases, tags and any type beyond plain scalars,
lists and mappings are refused, unknown keys are refused, nesting is bounded, and every field is type-checked.

`model.version` follows the grammar and ordering of `kiosk.bundle.version` (e.g. "2026.11.21-1" < "2026.11.22-1",
"1.9" < "1.10"): the store refuses to install or activate a version below a garment's newest installed one.
The exporter writes `model.source_run` without the build machine's paths (a path relative to the runs folder, or
`sha256:<hex>` of the run's location when it lies outside it); older bundles with an absolute path still load.
Schema 2 adds `graphs.<kind>.weights`: the graphs keep their tensors in one shared, hashed weights file beside them
(`kiosk.bundle.weights` checks what each graph reads from it); schema-1 bundles, whose graphs embed their tensors,
still load.
"""
from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field
from typing import Any

import yaml

from kiosk.bundle.version import VersionError, parse_version
from kiosk.contract.errors import InputError, KioskError
from kiosk.contract.graph import GRAPH_KINDS, GRAPH_OUTPUTS
from kiosk.contract.haptics import NORMALIZATIONS, check_constants

SCHEMA_VERSION = 2            # the newest this kiosk reads; version 2 adds a graph's shared `weights` file
SCHEMA_VERSIONS = (1, 2)
EMBEDDED_SCHEMA = 1           # what a bundle whose graphs embed their weights is written as (older kiosks read it)
MAX_MANIFEST_BYTES = 1 << 20
MAX_DEPTH = 12   # the schema nests 4 deep (graphs.<kind>.sizes[i]); room to spare, far from Python's recursion limit
PRECISIONS = ("fp32", "fp16", "int8")
_ID_RE = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")
_SHA_RE = re.compile(r"^[0-9a-f]{64}$")
PATH_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*(/[A-Za-z0-9][A-Za-z0-9._-]*)*$")


class BundleError(KioskError):
    """A bundle that cannot be trusted or used; the message says which check failed."""


@dataclass(frozen=True)
class GraphSpec:
    """One ONNX graph: which outputs it computes, at which precision, for which input sizes (width, height)."""

    file: str
    precision: str
    outputs: list[str]
    sizes: list[list[int]]
    # The bundle file (beside `file`) holding the tensors the graph stores as ONNX external data, shared by the
    # bundle's graphs; None when the graph embeds its own (schema 1).
    weights: str | None = None


@dataclass(frozen=True)
class Manifest:
    schema_version: int
    garment_id: str
    display_name: str
    model_version: str
    method: str
    created_at: str
    exporter_version: str
    source_run: str
    checkpoint_sha256: str
    graphs: dict[str, GraphSpec]
    friction_scale: float
    friction_normalization: str
    pixel_pitch_mm: float
    panel_size: list[int]
    assets: dict[str, str]
    files: dict[str, str]
    metrics: dict[str, float] = field(default_factory=dict)
    errors: dict[str, dict[str, float]] = field(default_factory=dict)
    provenance: dict[str, str] = field(default_factory=dict)
    # The friction mapping's constants beyond `friction_scale` (the `perceptual` mapping's); empty for bundles
    # written before they existed, which keep their mapping's behaviour (calibrated or quantile).
    friction_constants: dict[str, float] = field(default_factory=dict)
    # 2: separate visual and tactile branches (a one-modality graph is cheaper than `full`). 1: one network computes
    # every channel (the baselines), so the bundle ships only `full` and any need costs the whole network. Bundles
    # written before the field existed are two-branch.
    branches: int = 2

    def graph(self, kind: str) -> GraphSpec:
        if kind not in self.graphs:
            raise BundleError(f"bundle {self.garment_id} has no {kind!r} graph (has: {', '.join(self.graphs)})")
        return self.graphs[kind]


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses aliases/anchors and explicit tags: a manifest is plain data."""

    def compose_node(self, parent, index):  # type: ignore[override]
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > MAX_DEPTH:
                raise BundleError(f"manifest nests deeper than {MAX_DEPTH} levels (line "
                                  f"{self.peek_event().start_mark.line + 1}); a manifest is shallow plain data")
            return self._compose_checked(parent, index)
        finally:
            self._depth -= 1

    def _compose_checked(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise BundleError(f"manifest uses a YAML alias at line {event.start_mark.line + 1}; aliases are "
                              "not allowed")
        event = self.peek_event()
        anchor = getattr(event, "anchor", None)
        if anchor is not None:
            raise BundleError(f"manifest defines a YAML anchor at line {event.start_mark.line + 1}; anchors are "
                              "not allowed")
        tag = getattr(event, "tag", None)
        if tag is not None and getattr(event, "implicit", (True,)) in (False, (False, False)) and \
                not tag.startswith("tag:yaml.org,2002:"):
            raise BundleError(f"manifest uses the YAML tag {tag!r}; tags are not allowed")
        return super().compose_node(parent, index)


def _need(cond: bool, msg: str) -> None:
    if not cond:
        raise BundleError(f"manifest: {msg}")


def _str(d: dict, key: str, pattern: re.Pattern | None = None, where: str = "") -> str:
    v = d.get(key)
    _need(isinstance(v, str) and 0 < len(v) <= 512, f"{where}{key} must be a non-empty string")
    if pattern is not None:
        _need(bool(pattern.match(v)), f"{where}{key} {v!r} has an invalid form")
    return v


def _num(d: dict, key: str, where: str = "", positive: bool = False) -> float:
    v = d.get(key)
    _need(isinstance(v, (int, float)) and not isinstance(v, bool), f"{where}{key} must be a number")
    v = float(v)
    _need(v == v and abs(v) != float("inf"), f"{where}{key} must be finite")
    if positive:
        _need(v > 0, f"{where}{key} must be positive")
    return v


def _size(v: Any, what: str) -> list[int]:
    _need(isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool)
                                                      and 1 <= x <= 16384 for x in v),
          f"{what} must be [width, height] with integers from 1 to 16384")
    return [int(v[0]), int(v[1])]


def _mapping(d: dict, key: str, where: str = "") -> dict:
    v = d.get(key)
    _need(isinstance(v, dict), f"{where}{key} must be a mapping")
    return v


def _only_keys(d: dict, allowed: set[str], where: str) -> None:
    extra = sorted(set(d) - allowed, key=str)
    _need(not extra, f"unknown key(s) in {where}: {', '.join(map(str, extra))}")


def _flat_numbers(d: Any, where: str) -> dict[str, float]:
    _need(isinstance(d, dict), f"{where} must be a mapping")
    out = {}
    for k, v in d.items():
        _need(isinstance(k, str), f"{where} keys must be strings")
        out[k] = _num(d, k, f"{where}.")
    return out


def manifest_from_dict(doc: Any) -> Manifest:
    """Validate a parsed manifest document; raise BundleError naming the first problem."""
    _need(isinstance(doc, dict), "top level must be a mapping")
    version = doc.get("schema_version")
    _need(isinstance(version, int) and not isinstance(version, bool), "schema_version must be an integer")
    if version not in SCHEMA_VERSIONS:
        raise BundleError(f"manifest schema version {version} is not supported by this kiosk (it reads versions "
                          f"{', '.join(map(str, SCHEMA_VERSIONS))}); update the kiosk software or re-export the "
                          "bundle")
    _only_keys(doc, {"schema_version", "garment", "model", "created_at", "exporter_version", "graphs", "haptics",
                     "panel", "assets", "files", "metrics", "errors", "provenance"}, "manifest")
    garment = _mapping(doc, "garment")
    _only_keys(garment, {"id", "display_name"}, "garment")
    model = _mapping(doc, "model")
    _only_keys(model, {"version", "method", "source_run", "checkpoint_sha256", "branches"}, "model")
    branches = model.get("branches", 2)
    _need(branches in (1, 2) and not isinstance(branches, bool), "model.branches must be 1 or 2")
    try:
        parse_version(model.get("version"))
    except VersionError as exc:
        raise BundleError(f"manifest: model.{exc}") from None
    source_run = _str(model, "source_run", where="model.")   # bundles exported before 0.2 carry absolute paths
    graphs_doc = _mapping(doc, "graphs")
    _need(bool(graphs_doc), "graphs must name at least one graph")
    graphs: dict[str, GraphSpec] = {}
    for kind, spec in graphs_doc.items():
        _need(kind in GRAPH_KINDS, f"unknown graph kind {kind!r} (known: {', '.join(GRAPH_KINDS)})")
        _need(isinstance(spec, dict), f"graphs.{kind} must be a mapping")
        _only_keys(spec, {"file", "precision", "outputs", "sizes"} | ({"weights"} if version >= 2 else set()),
                   f"graphs.{kind}")
        precision = _str(spec, "precision", where=f"graphs.{kind}.")
        _need(precision in PRECISIONS, f"graphs.{kind}.precision must be one of {', '.join(PRECISIONS)}")
        outputs = spec.get("outputs")
        _need(outputs == GRAPH_OUTPUTS[kind], f"graphs.{kind}.outputs must be {GRAPH_OUTPUTS[kind]}")
        sizes = spec.get("sizes")
        _need(isinstance(sizes, list) and 0 < len(sizes) <= 32, f"graphs.{kind}.sizes must be a non-empty list")
        file = _str(spec, "file", PATH_RE, f"graphs.{kind}.")
        weights = _str(spec, "weights", PATH_RE, f"graphs.{kind}.") if "weights" in spec else None
        _need(weights is None or weights.rpartition("/")[0] == file.rpartition("/")[0],
              f"graphs.{kind}.weights must sit in the same folder as its graph ({file})")
        graphs[kind] = GraphSpec(file, precision, list(outputs),
                                 [_size(s, f"graphs.{kind}.sizes entry") for s in sizes], weights)
    _need(branches == 2 or set(graphs) == {"full"},
          "a single-branch model (model.branches 1) ships only the full graph")
    haptics = _mapping(doc, "haptics")
    _only_keys(haptics, {"friction_scale", "normalization", "pixel_pitch_mm", "constants"}, "haptics")
    normalization = _str(haptics, "normalization", where="haptics.")
    _need(normalization in NORMALIZATIONS, f"haptics.normalization must be one of {', '.join(NORMALIZATIONS)}")
    constants = _flat_numbers(haptics.get("constants", {}), "haptics.constants")
    try:
        check_constants(normalization, constants)
    except InputError as exc:
        raise BundleError(f"manifest: haptics.constants: {exc}") from None
    panel = _mapping(doc, "panel")
    _only_keys(panel, {"size"}, "panel")
    assets = _mapping(doc, "assets")
    _only_keys(assets, {"sketch", "mask", "visual"}, "assets")
    for k in assets:
        _str(assets, k, PATH_RE, "assets.")
    files = _mapping(doc, "files")
    for k, v in files.items():
        _need(isinstance(k, str) and bool(PATH_RE.match(k)), f"files: invalid path {k!r}")
        _need(isinstance(v, str) and bool(_SHA_RE.match(v)), f"files.{k} must be a lowercase SHA-256 hex digest")
    for spec in graphs.values():
        _need(spec.file in files, f"graph file {spec.file} is not listed in files")
        _need(spec.weights is None or spec.weights in files, f"weights file {spec.weights} is not listed in files")
    graph_files = {g.file for g in graphs.values()}
    for spec in graphs.values():
        _need(spec.weights not in graph_files and spec.weights not in assets.values(),
              f"weights file {spec.weights} is also a graph or an asset")
    for path in assets.values():
        _need(path in files, f"asset {path} is not listed in files")
    errors_doc = doc.get("errors", {})
    _need(isinstance(errors_doc, dict), "errors must be a mapping")
    provenance = doc.get("provenance", {})
    _need(isinstance(provenance, dict) and all(isinstance(k, str) and isinstance(v, str)
                                               for k, v in provenance.items()),
          "provenance must map strings to strings")
    return Manifest(
        schema_version=version,
        garment_id=_str(garment, "id", _ID_RE, "garment."),
        display_name=_str(garment, "display_name", where="garment."),
        model_version=_str(model, "version", where="model."),
        method=_str(model, "method", where="model."),
        created_at=_str(doc, "created_at"),
        exporter_version=_str(doc, "exporter_version"),
        source_run=source_run,
        checkpoint_sha256=_str(model, "checkpoint_sha256", _SHA_RE, "model."),
        graphs=graphs,
        friction_scale=_num(haptics, "friction_scale", "haptics.", positive=True),
        friction_normalization=normalization,
        pixel_pitch_mm=_num(haptics, "pixel_pitch_mm", "haptics.", positive=True),
        panel_size=_size(panel.get("size"), "panel.size"),
        assets=dict(assets),
        files=dict(files),
        metrics=_flat_numbers(doc.get("metrics", {}), "metrics"),
        errors={str(k): _flat_numbers(v, f"errors.{k}") for k, v in errors_doc.items()},
        provenance=dict(provenance),
        friction_constants=constants,
        branches=int(branches),
    )


def parse_manifest(data: bytes) -> Manifest:
    """Strictly parse manifest bytes (UTF-8 YAML)."""
    if len(data) > MAX_MANIFEST_BYTES:
        raise BundleError(f"manifest is {len(data)} bytes; the limit is {MAX_MANIFEST_BYTES}")
    try:
        text = data.decode("utf-8")
        doc = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - _StrictLoader is a SafeLoader
    except UnicodeDecodeError as exc:
        raise BundleError("manifest is not UTF-8 text") from exc
    except yaml.YAMLError as exc:
        raise BundleError(f"manifest is not valid YAML: {' '.join(str(exc).split())}") from None
    except RecursionError:
        raise BundleError("manifest nests too deeply to be a manifest") from None
    except ValueError as exc:   # e.g. an integer of thousands of digits
        raise BundleError(f"manifest holds a value YAML cannot read ({' '.join(str(exc).split())[:120]})") from None
    return manifest_from_dict(doc)


def _graph_dict(g: GraphSpec) -> dict:
    d = asdict(g)
    if g.weights is None:   # absent for embedded-weight graphs, so their canonical bytes stay what was signed
        del d["weights"]
    return d


def manifest_to_dict(m: Manifest) -> dict:
    """The document form of a manifest, in a stable key order (what `dump_manifest` writes)."""
    haptics: dict[str, Any] = {"friction_scale": m.friction_scale, "normalization": m.friction_normalization,
                               "pixel_pitch_mm": m.pixel_pitch_mm}
    if m.friction_constants:  # absent in bundles that have none, so their canonical bytes stay what was signed
        haptics["constants"] = dict(sorted(m.friction_constants.items()))
    model: dict[str, Any] = {"version": m.model_version, "method": m.method, "source_run": m.source_run,
                             "checkpoint_sha256": m.checkpoint_sha256}
    if m.branches != 2:   # absent for two-branch models, so their canonical bytes stay what was signed
        model["branches"] = m.branches
    return {
        "schema_version": m.schema_version,
        "garment": {"id": m.garment_id, "display_name": m.display_name},
        "model": model,
        "created_at": m.created_at,
        "exporter_version": m.exporter_version,
        "graphs": {k: _graph_dict(g) for k, g in m.graphs.items()},
        "haptics": haptics,
        "panel": {"size": list(m.panel_size)},
        "assets": dict(m.assets),
        "metrics": dict(m.metrics),
        "errors": {k: dict(v) for k, v in m.errors.items()},
        "provenance": dict(m.provenance),
        "files": dict(sorted(m.files.items())),
    }


def dump_manifest(m: Manifest) -> bytes:
    """Canonical manifest bytes: the exact bytes that are hashed and signed."""
    text = yaml.safe_dump(manifest_to_dict(m), sort_keys=False, allow_unicode=True, default_flow_style=None)
    data = text.encode("utf-8")
    # A round trip must give back the same manifest: catches values YAML cannot carry faithfully.
    if parse_manifest(data) != m:
        raise BundleError("manifest does not survive a YAML round trip (non-finite numbers or odd strings?)")
    return data
