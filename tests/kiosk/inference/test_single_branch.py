"""Single-branch bundles (one network computes every channel, as the baselines do): the manifest says so, old
manifests read as two-branch, and the planner runs the full graph for either need and states the cost, through the
real daemon and ONNX Runtime."""
from __future__ import annotations

import dataclasses

import pytest
import yaml

from kiosk.bundle.manifest import BundleError, GraphSpec, dump_manifest, manifest_to_dict, parse_manifest
from tests.kiosk.bundle_factory import base_manifest, make_bundle
from tests.kiosk.daemon_fixtures import BOX, render, start_daemon

FULL_ONLY = {"full": GraphSpec("graphs/full.onnx", "fp32", ["visual", "tactile"], [[256, 256], [512, 512]])}


def _with_files(m):
    return dataclasses.replace(m, files={f: "0" * 64 for f in [g.file for g in m.graphs.values()]
                                         + list(m.assets.values())})


def test_two_branch_manifests_keep_their_bytes_and_old_ones_read_as_two_branch():
    m = _with_files(base_manifest())
    assert "branches" not in manifest_to_dict(m)["model"]   # what was signed before the field stays the same
    assert parse_manifest(dump_manifest(m)).branches == 2


def test_single_branch_round_trips_and_must_ship_only_the_full_graph():
    m = _with_files(base_manifest(branches=1, graphs=FULL_ONLY))
    data = dump_manifest(m)
    assert yaml.safe_load(data)["model"]["branches"] == 1 and parse_manifest(data) == m
    doc = yaml.safe_load(dump_manifest(_with_files(base_manifest())))
    doc["model"]["branches"] = 1
    with pytest.raises(BundleError, match="single-branch model .* only the full graph"):
        parse_manifest(yaml.safe_dump(doc).encode())
    for bad in (0, 3, True, "one"):
        doc["model"]["branches"] = bad
        with pytest.raises(BundleError, match="model.branches must be 1 or 2"):
            parse_manifest(yaml.safe_dump(doc).encode())


def test_daemon_runs_the_full_graph_for_either_need_and_says_what_it_costs(tmp_path):
    path, trusted = make_bundle(tmp_path, manifest=base_manifest(branches=1, graphs=FULL_ONLY))
    d = start_daemon([path], trusted)
    try:
        assert d.bundles["denim-shorts"].info()["branches"] == 1
        status, meta, visuals = render(d, mode="preview")   # a visual-only need
        (pp,) = meta["plan"]["panels"]
        assert status == 200 and pp["graph"] == "full" and pp["needs"] == ["visual"]
        assert "no separate branches" in pp["reason"] and visuals["main"].shape[2] == 4
        status, meta, _ = render(d, BOX + [[[350, 250], [700, 550]]], mode="refine")   # visual + tactile
        (p,) = meta["panels"]
        assert status == 200 and p["status"] == "ok" and meta["plan"]["panels"][0]["graph"] == "full"
        assert "no separate branches" not in meta["plan"]["panels"][0]["reason"]
        assert d.wait_commit(meta["device_frame"], 5.0).status == "committed"
    finally:
        d.stop()
