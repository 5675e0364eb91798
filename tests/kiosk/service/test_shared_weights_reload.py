"""A serving kiosk moves from a bundle whose graphs embed their weights to one whose graphs share a weights file,
and keeps serving the good one when a reload offers a bundle whose graph reads outside its own weights file."""
from __future__ import annotations

import shutil

from kiosk.bundle.manifest import EMBEDDED_SCHEMA
from tests.kiosk.bundle_factory import base_manifest, conv_graph, make_bundle, shared_manifest
from tests.kiosk.daemon_fixtures import render, start_daemon


def _outside(model):
    t = next(t for t in model.graph.initializer if t.name == "w1")
    next(e for e in t.external_data if e.key == "location").value = "../manifest.yaml"


def test_reload_from_embedded_to_shared_weights_and_refusal_of_a_hostile_reference(tmp_path):
    target = tmp_path / "serve" / "garment.vtb"
    target.parent.mkdir()
    old, trusted = make_bundle(tmp_path, name="old.vtb", graph=conv_graph,
                               manifest=base_manifest(schema_version=EMBEDDED_SCHEMA))
    new, _ = make_bundle(tmp_path, name="new.vtb", shared=True, manifest=shared_manifest(model_version="v2"))
    hostile, _ = make_bundle(tmp_path, name="hostile.vtb", shared=True, edit=_outside,
                             manifest=shared_manifest(model_version="v3"))
    shutil.copy(old, target)
    # the conv graphs' speed is not under test here: a generous budget keeps the probe about loading and answering
    d = start_daemon([target], trusted, inference={"latency_budget_ms": 60000.0})
    try:
        status, meta, _ = render(d)
        assert status == 200 and meta["panels"][0]["status"] == "ok"
        shutil.copy(new, target)
        reply = d.reload()
        assert reply["swapped"] and "@v2#" in d.bundles["denim-shorts"].key
        status, meta, _ = render(d)
        assert status == 200 and meta["panels"][0]["status"] == "ok"
        shutil.copy(hostile, target)
        reply = d.reload()
        assert not reply["swapped"] and "may read only its bundle's weights file" in str(reply), reply
        assert "@v2#" in d.bundles["denim-shorts"].key   # the good one stays
        assert render(d)[0] == 200
    finally:
        d.stop()
