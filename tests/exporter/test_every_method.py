"""Every method in the training registry exports to a kiosk bundle that the real daemon serves: train one step at
the `tiny` preset, export fp32 at the contract's 256 grid, sign, serve, render a drawn garment (visual + friction)."""
from __future__ import annotations

import pytest

from exporter.export import ExportConfig, export_run
from exporter.keys import generate_keypair, load_private_key
from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from tests.exporter.conftest import vtk
from tests.kiosk.daemon_fixtures import render, start_daemon
from trainer.methods import METHODS

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("methods") / "data"
    proc = vtk("data", "synth", "--out", out, "--garments", 1, "--frame", "320x240", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.mark.parametrize("method", sorted(METHODS))
def test_method_exports_and_serves(method, data, tmp_path):
    run = tmp_path / "run"
    proc = vtk("train", "--data", data, "--garment", "DenimShorts", "--preset", "tiny", "--steps", 1,
               "--method", method, "--out", run)
    assert proc.returncode == 0, proc.stderr
    keys = tmp_path / "keys"
    generate_keypair(keys, "op")
    (tmp_path / "trusted").mkdir()
    (tmp_path / "trusted" / "op.pub").write_bytes((keys / "op.pub").read_bytes())
    report = export_run(run, tmp_path / "g.vtb", ExportConfig(precision="fp32", sizes=[(256, 256)]),
                        signing_key=load_private_key(keys / "op.key"), progress=lambda *_: None)
    m = report.manifest
    assert m.method == method
    two = m.branches == 2
    assert set(m.graphs) == ({"full", "tactile", "visual"} if two else {"full"})
    assert open_bundle(tmp_path / "g.vtb", load_trusted_keys(tmp_path / "trusted"), workdir=tmp_path / "w").manifest == m
    d = start_daemon([tmp_path / "g.vtb"], tmp_path / "trusted")
    try:
        status, meta, visuals = render(d, garment=m.garment_id, mode="preview")
        (pp,) = meta["plan"]["panels"]
        assert status == 200 and pp["graph"] == ("visual" if two else "full"), meta
        assert ("no separate branches" in pp["reason"]) != two
        status, meta, visuals = render(d, garment=m.garment_id, mode="refine")
        (p,) = meta["panels"]
        assert status == 200 and p["status"] == "ok" and visuals
        assert d.wait_commit(meta["device_frame"], 10.0).status == "committed"
    finally:
        d.stop()
