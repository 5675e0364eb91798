"""Where a bundle's bytes go: each graph file, the shared weights file, the reference assets, and what the same
graphs would weigh embedding their own tensors (the layout before shared weights), for the benchmark's summary."""
from __future__ import annotations

from kiosk.bundle.archive import Bundle

from exporter.shared_weights import graph_bytes


def bundle_layout(bundle: Bundle) -> dict:
    """Byte counts of an opened bundle (JSON-ready)."""
    m = bundle.manifest
    weights = sorted({g.weights for g in m.graphs.values() if g.weights})
    return {"graph_bytes": {k: bundle.graph_path(k).stat().st_size for k in m.graphs},
            "weights_bytes": {w: bundle.path(w).stat().st_size for w in weights},
            "asset_bytes": sum(bundle.path(a).stat().st_size for a in m.assets.values()),
            "embedded_graph_bytes": sum(graph_bytes(bundle.graph_path(k)) for k in m.graphs)}


def bundle_line(b: dict) -> str:
    """One line: the archive's bytes and what they hold."""
    parts = [f"{k} graph {v / 1e6:.2f} MB" for k, v in b["graph_bytes"].items()]
    parts += [f"shared weights {v / 1e6:.2f} MB" for v in b.get("weights_bytes", {}).values()]
    parts.append(f"assets {b.get('asset_bytes', 0) / 1e6:.2f} MB")
    line = f"bundle: {b['bytes'] / 1e6:.2f} MB ({', '.join(parts)})"
    if b.get("weights_bytes"):
        line += (f"; its graphs would take {b['embedded_graph_bytes'] / 1e6:.2f} MB embedding their own weights, "
                 f"here {(sum(b['graph_bytes'].values()) + sum(b['weights_bytes'].values())) / 1e6:.2f} MB")
    return line
