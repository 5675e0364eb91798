"""The planner decides what runs; the daemon carries it out and never chooses a graph of its own. A cached output
that the plan reuses but that left the cache before the frame ran sends the frame back to the planner; if it is
gone again, the panel keeps its last good result with a notice instead of silently running another graph."""
from __future__ import annotations

import pytest

from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import render, start_daemon


@pytest.fixture()
def daemon(tmp_path):
    path, trusted = make_bundle(tmp_path)
    d = start_daemon([path], trusted, inference={"refine": False})
    yield d
    d.stop()


def test_the_graph_that_runs_is_the_planned_one(daemon):
    runs = daemon.series.graph_runs
    status, meta, _ = render(daemon)
    assert status == 200 and meta["plan"]["panels"][0]["graph"] == "full" and runs.value(graph="full") == 1
    # Unchanged sketch: the plan reuses both outputs and runs nothing; the daemon runs nothing either.
    status, meta, _ = render(daemon)
    p = meta["plan"]["panels"][0]
    assert (p["graph"], sorted(p["reused"])) == ("none", ["tactile", "visual"])
    assert sum(runs.value(graph=g) for g in ("full", "visual", "tactile")) == 1


def test_a_vanished_cache_entry_goes_back_to_the_planner_not_to_a_second_decision(daemon):
    runs = daemon.series.graph_runs
    assert render(daemon)[0] == 200
    # The cache claims to hold everything while holding nothing: what a reload emptying it mid-frame looks like.
    daemon.cache.clear()
    daemon.planner.cached = lambda key, modality: True
    status, meta, _ = render(daemon)
    (panel,) = meta["panels"]
    assert status == 200 and panel["status"] == "kept" and panel["notice"]
    assert sum(runs.value(graph=g) for g in ("full", "visual", "tactile")) == 1  # no graph the plan did not name
    daemon.planner.cached = daemon.cache.has
    status, meta, _ = render(daemon)
    assert meta["panels"][0]["status"] == "ok" and meta["plan"]["panels"][0]["graph"] == "full"
