"""`bundle verify` probes every size a graph declares: a graph that runs at 256 px but not at the 512 px it also
declares passes the quick (install/swap) probe and fails verify, naming the size."""
from __future__ import annotations

import subprocess
import sys

import onnx
import pytest

from exporter.bundle_writer import write_bundle
from exporter.keys import generate_keypair, load_private_key
from kiosk.bundle.archive import open_bundle
from kiosk.bundle.manifest import BundleError
from kiosk.bundle.probe import probe_bundle
from kiosk.bundle.signature import load_trusted_keys
from tests.kiosk.bundle_factory import base_manifest, make_assets, tiny_graph


def _bundle(tmp_path, *, static_full: bool):
    keys = tmp_path / "keys"
    generate_keypair(keys, "op")
    work = tmp_path / "src"
    (work / "graphs").mkdir(parents=True)
    sources = {f"assets/{k}.png": p for k, p in make_assets(work / "assets").items()}
    for kind, outs in (("full", ["visual", "tactile"]), ("tactile", ["tactile"]), ("visual", ["visual"])):
        path = tiny_graph(work / "graphs" / f"{kind}.onnx", outs)
        if kind == "full" and static_full:   # fixed 256x256 inputs: any other size is refused by ONNX Runtime
            model = onnx.load(str(path))
            for value in model.graph.input:
                for dim, n in zip(value.type.tensor_type.shape.dim[2:], (256, 256)):
                    dim.ClearField("dim_param")
                    dim.dim_value = n
            onnx.save(model, str(path))
        sources[f"graphs/{kind}.onnx"] = path
    out = tmp_path / "g.vtb"
    write_bundle(out, base_manifest(), sources, signing_key=load_private_key(keys / "op.key"))
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    (trusted / "op.pub").write_bytes((keys / "op.pub").read_bytes())
    return out, trusted


def test_every_declared_size_is_probed(tmp_path):
    path, trusted = _bundle(tmp_path, static_full=False)
    b = open_bundle(path, load_trusted_keys(trusted), workdir=tmp_path / "w")
    got = {(r.graph, r.size) for r in probe_bundle(b, threads=1, every_size=True)}
    assert got == {("full", (256, 256)), ("full", (512, 512)), ("tactile", (256, 256)), ("visual", (256, 256))}
    assert {(r.graph, r.size) for r in probe_bundle(b, threads=1)} == {
        ("full", (256, 256)), ("tactile", (256, 256)), ("visual", (256, 256))}


def test_a_graph_that_fails_at_a_larger_declared_size_fails_verify(tmp_path):
    path, trusted = _bundle(tmp_path, static_full=True)
    b = open_bundle(path, load_trusted_keys(trusted), workdir=tmp_path / "w")
    probe_bundle(b, threads=1)   # the smallest size alone passes
    with pytest.raises(BundleError, match="failed on a 512x512 probe sketch"):
        probe_bundle(b, threads=1, every_size=True)
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "bundle", "verify", str(path), "--trusted-keys",
                           str(trusted), "--threads", "1"], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and "512x512" in proc.stderr and "Traceback" not in proc.stderr
    assert "probe       full     256x256" in proc.stdout
