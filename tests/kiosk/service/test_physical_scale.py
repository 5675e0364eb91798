"""The analytic case through the whole kiosk: a bundle whose model draws a sinusoidal height of known period at its
own pitch; the daemon plans (physical scale), runs the real ONNX graph, maps friction, and the emulated device
commits the frame. The period a finger meets on the panel is the true one, in mm.

Friction follows the squared slope (paper Sec. 4.4), so a height h = a sin(2 pi x / P) is felt as a ridge on each
flank: friction period P / 2 exactly (cos^2). That is the period checked, in mm on the panel.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from onnx import TensorProto, helper

from exporter.bundle_writer import write_bundle
from exporter.keys import generate_keypair, load_private_key
from kiosk.bench.felt import dominant_period_px
from tests.kiosk.bundle_factory import base_manifest, make_assets, save_graph
from tests.kiosk.daemon_fixtures import http, render, start_daemon

PERIOD_PX = 12          # height period in model pixels
BUNDLE_PITCH = 0.3      # mm per model pixel
SLOPE = 0.1             # slope amplitude
GARMENT = [[[440, 250], [840, 250], [840, 550], [440, 550], [440, 250]]]  # fits the bundle's 512 px at 0.3 mm/px


def sinusoid_graph(path, outputs):
    """tactile = (SLOPE cos(2 pi col / PERIOD_PX), 0) * mask: the slopes of a height sinusoid along x."""
    dims = [1, 1, "H", "W"]
    inputs = [helper.make_tensor_value_info("sketch", TensorProto.FLOAT, dims),
              helper.make_tensor_value_info("mask", TensorProto.FLOAT, dims)]
    c = lambda name, v, t=TensorProto.FLOAT, shape=(): helper.make_node(  # noqa: E731
        "Constant", [], [name], value=helper.make_tensor(name, t, list(shape), v if isinstance(v, list) else [v]))
    nodes = [c("k", 2 * math.pi / PERIOD_PX), c("amp", SLOPE), c("zero", 0.0), c("i3", 3, TensorProto.INT64),
             c("i0", 0, TensorProto.INT64), c("i1", 1, TensorProto.INT64),
             c("shape4", [1, 1, 1, -1], TensorProto.INT64, (4,)),
             helper.make_node("Shape", ["sketch"], ["shp"]),
             helper.make_node("Gather", ["shp", "i3"], ["w"], axis=0),
             helper.make_node("Range", ["i0", "w", "i1"], ["cols"]),
             helper.make_node("Cast", ["cols"], ["colsf"], to=TensorProto.FLOAT),
             helper.make_node("Mul", ["colsf", "k"], ["phase"]),
             helper.make_node("Cos", ["phase"], ["cosv"]),
             helper.make_node("Mul", ["cosv", "amp"], ["row"]),
             helper.make_node("Reshape", ["row", "shape4"], ["row4"]),
             helper.make_node("Mul", ["row4", "mask"], ["gx"]),
             helper.make_node("Mul", ["mask", "zero"], ["gy"])]
    outs = []
    if "visual" in outputs:
        nodes += [helper.make_node("Concat", ["sketch", "mask", "sketch"], ["v3"], axis=1),
                  helper.make_node("Tanh", ["v3"], ["vt"]),
                  helper.make_node("Mul", ["vt", "mask"], ["visual"])]
        outs.append(helper.make_tensor_value_info("visual", TensorProto.FLOAT, [1, 3, "H", "W"]))
    if "tactile" in outputs:
        nodes.append(helper.make_node("Concat", ["gx", "gy"], ["tactile"], axis=1))
        outs.append(helper.make_tensor_value_info("tactile", TensorProto.FLOAT, [1, 2, "H", "W"]))
    return save_graph(path, "sinusoid", nodes, inputs, outs)


@pytest.fixture()
def sinusoid_bundle(tmp_path):
    keys = tmp_path / "keys"
    generate_keypair(keys, "operator")
    work = tmp_path / "src"
    (work / "graphs").mkdir(parents=True)
    sources = {f"assets/{k}.png": p for k, p in make_assets(work / "assets").items()}
    for kind, outs in (("full", ["visual", "tactile"]), ("tactile", ["tactile"]), ("visual", ["visual"])):
        sources[f"graphs/{kind}.onnx"] = sinusoid_graph(work / "graphs" / f"{kind}.onnx", outs)
    out = tmp_path / "sinusoid.vtb"
    write_bundle(out, base_manifest(pixel_pitch_mm=BUNDLE_PITCH), sources,
                 signing_key=load_private_key(keys / "operator.key"))
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    (trusted / "operator.pub").write_bytes((keys / "operator.pub").read_bytes())
    return out, trusted


@pytest.mark.parametrize("panel", [
    {"model": "tanvastouch-10.1"},                                                     # 0.170 mm/px
    {"model": None, "width_mm": 384.0, "height_mm": 240.0, "width_px": 1280, "height_px": 800},  # 0.300 mm/px
])
def test_sinusoid_is_felt_at_its_true_period(sinusoid_bundle, panel):
    path, trusted = sinusoid_bundle
    d = start_daemon([path], trusted, panel=panel, inference={"refine": False})
    try:
        pitch = d.config.panel.pitch_mm
        status, meta, _ = render(d, GARMENT)
        assert status == 200
        assert d.wait_commit(meta["device_frame"], 10.0).status == "committed"
        x, y, w, h = meta["panels"][0]["friction"]["rect"]
        frame = d.device.emulator.active_frame[y:y + h, x:x + w].astype(np.float64)
        inner = frame[h // 4:3 * h // 4, w // 4:3 * w // 4]  # plain cloth, away from the outline
        felt_mm = dominant_period_px(inner) * pitch
        assert felt_mm == pytest.approx(PERIOD_PX * BUNDLE_PITCH / 2, rel=0.03)
        # Both pitches are reported where an operator looks.
        code, body, _ = http(d.server.url + "healthz")
        scale = json.loads(body)["scale"]
        assert scale["panel"]["pitch_mm"] == pytest.approx(pitch, abs=1e-4)
        assert scale["bundles"]["denim-shorts"]["pixel_pitch_mm"] == BUNDLE_PITCH
    finally:
        d.stop()
