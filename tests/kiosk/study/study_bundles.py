"""Real, tiny study bundles: per (condition, garment) a signed bundle whose tactile graph is a known gain times the
sketch, so each condition's friction map is different and predictable. Built with the exporter's real writer and
the shared test assets (tests/kiosk/bundle_factory.py); graphs are real ONNX models run by ONNX Runtime."""
from __future__ import annotations

from pathlib import Path

from onnx import TensorProto, helper

from exporter.bundle_writer import write_bundle
from exporter.keys import generate_keypair, load_private_key
from tests.kiosk.bundle_factory import base_manifest, make_assets, save_graph

GAINS = {"ours": 0.10, "pix2pix": 0.04, "pix2pixhd": 0.06, "gaugan": 0.05, "abl": 0.08, "ours-no-gan": 0.09,
         "ours-no-rec": 0.07}


def gain_graph(path: Path, outputs: list[str], gain: float) -> Path:
    """visual = tanh(10 * gain * concat(sketch, mask, sketch)) * mask (so each condition's visual output differs too:
    the visual study can tell them apart); tactile = gain * concat(mask, -mask): one constant slope over the whole
    garment, so each condition is one friction level everywhere under it (a sign change at the sketch's lines would
    be felt as a groove: the friction map interpolates slopes, not levels)."""
    dims = [1, 1, "H", "W"]
    inputs = [helper.make_tensor_value_info("sketch", TensorProto.FLOAT, dims),
              helper.make_tensor_value_info("mask", TensorProto.FLOAT, dims)]
    nodes = [helper.make_node("Constant", [], ["k"], value=helper.make_tensor("k", TensorProto.FLOAT, [], [gain]))]
    outs = []
    if "visual" in outputs:
        nodes += [helper.make_node("Constant", [], ["kv"],
                                   value=helper.make_tensor("kv", TensorProto.FLOAT, [], [10 * gain])),
                  helper.make_node("Concat", ["sketch", "mask", "sketch"], ["v3"], axis=1),
                  helper.make_node("Mul", ["v3", "kv"], ["v4"]),
                  helper.make_node("Tanh", ["v4"], ["vt"]), helper.make_node("Mul", ["vt", "mask"], ["visual"])]
        outs.append(helper.make_tensor_value_info("visual", TensorProto.FLOAT, [1, 3, "H", "W"]))
    if "tactile" in outputs:
        nodes += [helper.make_node("Neg", ["mask"], ["neg"]),
                  helper.make_node("Concat", ["mask", "neg"], ["t2"], axis=1),
                  helper.make_node("Mul", ["t2", "k"], ["t3"]), helper.make_node("Mul", ["t3", "mask"], ["tactile"])]
        outs.append(helper.make_tensor_value_info("tactile", TensorProto.FLOAT, [1, 2, "H", "W"]))
    return save_graph(path, "gain", nodes, inputs, outs)


def make_study_bundles(root: Path, conditions: list[str], garments: list[str], *,
                       drop_asset: tuple[str, str, str] | None = None, single_branch: tuple[str, ...] = ()) -> Path:
    """Write root/bundles/<condition>/<garment>.vtb for every pair; return the trusted-keys folder.

    drop_asset=(condition, garment, asset) leaves that reference asset out of that one bundle (a bad-input test).
    single_branch: conditions whose bundles carry only the full graph (model.branches 1), like the paper's baselines.
    """
    keys = root / "keys"
    if not (keys / "operator.key").exists():
        generate_keypair(keys, "operator")
    key = load_private_key(keys / "operator.key")
    trusted = root / "trusted"
    trusted.mkdir(exist_ok=True)
    (trusted / "operator.pub").write_bytes((keys / "operator.pub").read_bytes())
    work = root / "src"
    assets = {f"assets/{k}.png": p for k, p in make_assets(work / "assets").items()}
    for cond in conditions:
        gdir = work / cond
        gdir.mkdir(parents=True, exist_ok=True)
        graphs = {f"graphs/{kind}.onnx": gain_graph(gdir / f"{kind}.onnx", outs, GAINS[cond])
                  for kind, outs in (("full", ["visual", "tactile"]), ("tactile", ["tactile"]),
                                     ("visual", ["visual"]))}
        for garment in garments:
            names = {"sketch": "assets/sketch.png", "mask": "assets/mask.png", "visual": "assets/visual.png"}
            sources = {**graphs, **assets}
            extra = {}
            if cond in single_branch:
                sources = {k: v for k, v in sources.items() if not k.startswith("graphs/") or k.endswith("full.onnx")}
                extra = {"branches": 1, "graphs": {"full": base_manifest().graphs["full"]}}
            if drop_asset is not None and drop_asset[:2] == (cond, garment):
                del names[drop_asset[2]]
                del sources[f"assets/{drop_asset[2]}.png"]
            manifest = base_manifest(garment_id=garment, display_name=garment, method=cond,
                                     model_version=f"2026.1-{cond}", assets=names, **extra)
            out = root / "bundles" / cond / f"{garment}.vtb"
            out.parent.mkdir(parents=True, exist_ok=True)
            write_bundle(out, manifest, sources, signing_key=key)
    return trusted
