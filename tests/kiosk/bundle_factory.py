"""Small real bundles for tests: tiny ONNX graphs with the bundle's input/output contract, written by the
exporter's real writer. The graphs compute simple functions of the sketch so outputs are checkable."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from exporter.bundle_writer import write_bundle
from exporter.keys import generate_keypair, load_private_key
from exporter.shared_weights import WEIGHTS_FILE, share_weights
from kiosk.bundle.manifest import SCHEMA_VERSION, GraphSpec, Manifest
from kiosk.contract.graph import OUTPUT_CHANNELS
from kiosk.contract.sketch import rasterize


def save_graph(path: Path, name: str, nodes: list, inputs: list, outs: list, initializer: list = ()) -> Path:
    """Check and save a test graph at the opset and IR version the kiosk's engines load."""
    model = helper.make_model(helper.make_graph(nodes, name, inputs, outs, initializer=list(initializer)),
                              opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def tiny_graph(path: Path, outputs: list[str], *, poison: bool = False) -> Path:
    """visual = tanh(concat(sketch, mask, sketch)) * mask; tactile = 0.1 * concat(sketch, -sketch) * mask."""
    dims = [1, 1, "H", "W"]
    inputs = [helper.make_tensor_value_info("sketch", TensorProto.FLOAT, dims),
              helper.make_tensor_value_info("mask", TensorProto.FLOAT, dims)]
    nodes = [helper.make_node("Constant", [], ["k"], value=helper.make_tensor("k", TensorProto.FLOAT, [], [0.1])),
             helper.make_node("Constant", [], ["z"], value=helper.make_tensor("z", TensorProto.FLOAT, [], [0.0]))]
    outs = []
    src = "sketch"
    if poison:  # 0/0 -> NaN everywhere
        nodes.append(helper.make_node("Div", ["z", "z"], ["nan"]))
        nodes.append(helper.make_node("Add", ["sketch", "nan"], ["poisoned"]))
        src = "poisoned"
    if "visual" in outputs:
        nodes += [helper.make_node("Concat", [src, "mask", src], ["v3"], axis=1),
                  helper.make_node("Tanh", ["v3"], ["vt"]),
                  helper.make_node("Mul", ["vt", "mask"], ["visual"])]
        outs.append(helper.make_tensor_value_info("visual", TensorProto.FLOAT, [1, 3, "H", "W"]))
    if "tactile" in outputs:
        nodes += [helper.make_node("Neg", [src], ["neg"]),
                  helper.make_node("Concat", [src, "neg"], ["t2"], axis=1),
                  helper.make_node("Mul", ["t2", "k"], ["t3"]),
                  helper.make_node("Mul", ["t3", "mask"], ["tactile"])]
        outs.append(helper.make_tensor_value_info("tactile", TensorProto.FLOAT, [1, 2, "H", "W"]))
    return save_graph(path, "tiny", nodes, inputs, outs)


def conv_graph(path: Path, outputs: list[str], *, poison: bool = False, seed: int = 7) -> Path:
    """A small real encoder-decoder (Conv stride 2 -> Relu -> ConvTranspose stride 2 -> Tanh, masked) with seeded
    random weights: enough arithmetic that two engines' float results differ, as they do on a real bundle."""
    rng = np.random.default_rng(seed)
    dims = [1, 1, "H", "W"]
    inputs = [helper.make_tensor_value_info("sketch", TensorProto.FLOAT, dims),
              helper.make_tensor_value_info("mask", TensorProto.FLOAT, dims)]
    inits = [numpy_helper.from_array(rng.normal(0, 0.5, (16, 2, 3, 3)).astype(np.float32), "w1"),
             numpy_helper.from_array(rng.normal(0, 0.1, (16,)).astype(np.float32), "b1")]
    nodes = []
    if poison:  # NaN added at the outputs (a Relu inside may legally map NaN to 0 in one engine and not another)
        inits.append(numpy_helper.from_array(np.array(0.0, np.float32), "z"))
        nodes.append(helper.make_node("Div", ["z", "z"], ["nan"]))
    nodes += [helper.make_node("Concat", ["sketch", "mask"], ["x"], axis=1),
              helper.make_node("Conv", ["x", "w1", "b1"], ["c1"], pads=[1, 1, 1, 1], strides=[2, 2]),
              helper.make_node("Relu", ["c1"], ["r1"])]
    outs = []
    for name in outputs:
        ch = OUTPUT_CHANNELS[name]
        inits.append(numpy_helper.from_array(rng.normal(0, 0.3, (16, ch, 4, 4)).astype(np.float32), f"w_{name}"))
        nodes += [helper.make_node("ConvTranspose", ["r1", f"w_{name}"], [f"d_{name}"], strides=[2, 2],
                                   pads=[1, 1, 1, 1]),
                  helper.make_node("Tanh", [f"d_{name}"], [f"t_{name}"])]
        if poison:
            nodes.append(helper.make_node("Add", [f"t_{name}", "nan"], [f"t_{name}_p"]))
        nodes.append(helper.make_node("Mul", [f"t_{name}_p" if poison else f"t_{name}", "mask"], [name]))
        outs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, [1, ch, "H", "W"]))
    return save_graph(path, "conv", nodes, inputs, outs, inits)


def make_assets(folder: Path) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    sketch = rasterize([[(40, 30), (280, 30), (280, 210), (40, 210), (40, 30)]], (320, 240))
    mask = np.zeros((240, 320), np.uint8)
    mask[30:211, 40:281] = 255
    visual = np.zeros((240, 320, 3), np.uint8)
    visual[mask > 0] = (40, 70, 160)
    paths = {"sketch": folder / "sketch.png", "mask": folder / "mask.png", "visual": folder / "visual.png"}
    cv2.imwrite(str(paths["sketch"]), sketch)
    cv2.imwrite(str(paths["mask"]), mask)
    cv2.imwrite(str(paths["visual"]), visual)
    return paths


def base_manifest(**overrides) -> Manifest:
    fields = dict(
        schema_version=SCHEMA_VERSION, garment_id="denim-shorts", display_name="Denim shorts",
        model_version="2026.11.21-1", method="ours", created_at="2026-11-21T00:00:00Z", exporter_version="0.1.0",
        source_run="runs/test", checkpoint_sha256="0" * 64,
        graphs={"full": GraphSpec("graphs/full.onnx", "fp32", ["visual", "tactile"], [[256, 256], [512, 512]]),
                "tactile": GraphSpec("graphs/tactile.onnx", "fp32", ["tactile"], [[256, 256]]),
                "visual": GraphSpec("graphs/visual.onnx", "fp32", ["visual"], [[256, 256]])},
        friction_scale=0.05, friction_normalization="calibrated", pixel_pitch_mm=0.3, panel_size=[1280, 800],
        assets={"sketch": "assets/sketch.png", "mask": "assets/mask.png", "visual": "assets/visual.png"},
        files={}, metrics={"visual_psnr_db": 30.5}, errors={"int8": {"friction_mae_levels": 0.4}},
        provenance={"host": "test"})
    fields.update(overrides)
    return Manifest(**fields)


def shared_manifest(**overrides) -> Manifest:
    """`base_manifest` for a bundle whose graphs share `graphs/weights.bin` (the exporter's default layout)."""
    m = base_manifest(**overrides)
    return dataclasses.replace(m, graphs={k: dataclasses.replace(g, weights=f"graphs/{WEIGHTS_FILE}")
                                          for k, g in m.graphs.items()})


def make_bundle(tmp: Path, *, name: str = "garment.vtb", key_name: str = "operator", poison: bool = False,
                sign: bool = True, manifest: Manifest | None = None, graph=tiny_graph,
                shared: bool = False, edit=None) -> tuple[Path, Path]:
    """Write a signed bundle; return (bundle path, trusted-keys folder). `shared`: the graphs (`conv_graph` unless
    `graph` is given) keep their tensors in one shared weights file, written by the exporter's own code; `edit`
    (a function of the onnx.ModelProto) then changes the shared tactile graph before it is hashed and signed."""
    keys = tmp / "keys"
    if not (keys / f"{key_name}.key").exists():
        generate_keypair(keys, key_name)
    work = tmp / f"src-{name}"
    (work / "graphs").mkdir(parents=True, exist_ok=True)
    sources = {f"assets/{k}.png": p for k, p in make_assets(work / "assets").items()}
    if shared and graph is tiny_graph:
        graph = conv_graph
    for kind, outs in (("full", ["visual", "tactile"]), ("tactile", ["tactile"]), ("visual", ["visual"])):
        sources[f"graphs/{kind}.onnx"] = graph(work / "graphs" / f"{kind}.onnx", outs, poison=poison)
    if shared:
        graphs = {rel: p for rel, p in sources.items() if rel.startswith("graphs/")}
        out_graphs, weights, _ = share_weights(graphs, work / "shared")
        if edit is not None:
            path = out_graphs["graphs/tactile.onnx"]
            model = onnx.load(str(path), load_external_data=False)
            edit(model)
            onnx.save(model, str(path))
        sources.update(out_graphs)
        sources[f"graphs/{WEIGHTS_FILE}"] = weights
        manifest = manifest or shared_manifest()
    key = load_private_key(keys / f"{key_name}.key") if sign else None
    out = tmp / name
    write_bundle(out, manifest or base_manifest(), sources, signing_key=key)
    trusted = tmp / "trusted"
    trusted.mkdir(exist_ok=True)
    (trusted / f"{key_name}.pub").write_bytes((keys / f"{key_name}.pub").read_bytes())
    return out, trusted
