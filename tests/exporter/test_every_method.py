"""Every method in the training registry exports to a kiosk bundle that the real daemon serves: export fp32 at the
contract's 256 grid, sign, verify, serve, render a drawn garment (visual + friction) and see the device commit it.

Training is shared per generator family: the first registered method of each generator class (ours, pix2pix,
pix2pixhd, gaugan) is trained one step, so a trained checkpoint of every architecture exports; every other method
exports the checkpoint the trainer writes for it before its first step (its own method name, generator class and
config). That every method trains is tests/trainer/test_loop.py's job; here only the export and serving path is.
"""
from __future__ import annotations

import pytest

from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from tests.kiosk.daemon_fixtures import render, start_daemon
from tests.tiny_models import keypair, synthetic_set, tiny_bundle, tiny_run
from trainer.methods import METHODS, get_method

pytestmark = pytest.mark.slow


def family_head(method: str) -> str:
    """The first registered method with this method's generator class."""
    cls = get_method(method).generator_class
    return next(m for m in METHODS if get_method(m).generator_class == cls)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("methods")
    (garment,) = synthetic_set(root / "data", 1)
    signing_key, trusted = keypair(root)
    return root, garment, signing_key, trusted


def test_every_generator_family_has_a_trained_head():
    heads = {family_head(m) for m in METHODS}
    assert {"ours", "pix2pix", "pix2pixhd", "gaugan"} <= heads
    assert len(heads) == len({get_method(m).generator_class for m in METHODS})


@pytest.mark.parametrize("method", sorted(METHODS))
def test_method_exports_and_serves(method, site, tmp_path):
    root, garment, signing_key, trusted = site
    trained = family_head(method) == method
    run = tiny_run(garment, method, tmp_path / "run", steps=1 if trained else 0)
    m = tiny_bundle(run, tmp_path / "g.vtb", signing_key).manifest
    assert m.method == method and m.garment_id == "denim-shorts"
    two = m.branches == 2
    assert set(m.graphs) == ({"full", "tactile", "visual"} if two else {"full"})
    assert open_bundle(tmp_path / "g.vtb", load_trusted_keys(trusted), workdir=tmp_path / "w").manifest == m
    d = start_daemon([tmp_path / "g.vtb"], trusted)
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
