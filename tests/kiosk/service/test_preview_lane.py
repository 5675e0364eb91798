"""Previews and refinements do not starve each other: with a preview lane a preview is answered while the main
loop is busy (held with the kiosk's own fault injection, standing in for a long refinement); with one loop it
waits for it. Real daemon, real bundle, real HTTP on loopback."""
from __future__ import annotations

import threading

import pytest

from kiosk.service.jobs import JobQueue
from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import render, start_daemon, wait_for


@pytest.fixture()
def bundle(tmp_path):
    return make_bundle(tmp_path)


def _in_thread(fn) -> tuple[threading.Thread, dict]:
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("answer", fn()))
    t.start()
    return t, out


def test_a_preview_is_answered_while_the_main_loop_is_busy(bundle):
    path, trusted = bundle
    d = start_daemon([path], trusted, inference={"preview_threads": 1})
    try:
        assert d.preview_loop is not None
        d.loop.hang.set()  # the main loop holds still, as during a long refinement
        final, answer = _in_thread(lambda: render(d, mode="final"))
        assert wait_for(lambda: len(d.jobs) == 1, 5.0)
        status, meta, visuals = render(d, mode="preview")
        assert status == 200 and meta["mode"] == "preview" and visuals
        assert "answer" not in answer and len(d.jobs) == 1  # the stroke end still waits for the main loop
        d.loop.hang.clear()
        final.join(30)
        assert answer["answer"][0] == 200 and answer["answer"][1]["mode"] == "final"
        lb = d.bundles["denim-shorts"]
        assert {k for k in lb._sessions if k[1] == "preview"} == {("visual", "preview")}  # only what previews run
        assert {"inference", "preview"} <= set(d.health._checks)  # a hung preview loop fails health too
    finally:
        d.loop.hang.clear()
        d.stop()


def test_with_one_loop_a_preview_waits_for_the_running_job(bundle):
    path, trusted = bundle
    d = start_daemon([path], trusted, inference={"preview_threads": 0})
    try:
        assert d.preview_loop is None
        d.loop.hang.set()
        preview, answer = _in_thread(lambda: render(d, mode="preview"))
        assert wait_for(lambda: len(d.jobs) == 1, 5.0)
        assert "answer" not in answer  # queued behind the held loop
        d.loop.hang.clear()
        preview.join(30)
        assert answer["answer"][0] == 200 and answer["answer"][1]["mode"] == "preview"
        assert {lane for (_, lane) in d.bundles["denim-shorts"]._sessions} == {"main"}
    finally:
        d.loop.hang.clear()
        d.stop()


def test_each_lane_takes_only_its_jobs():
    from kiosk.service.api import RenderRequest
    from kiosk.inference.scene import Panel, Scene

    q = JobQueue()
    scene = Scene((Panel("p", (0, 0, 10, 10), "g"),), (10, 10))
    threads = []
    for mode in ("refine", "preview", "final"):
        t = threading.Thread(target=lambda m=mode: _swallow(q, RenderRequest(scene, {}, m, f"c-{m}")))
        t.start()
        threads.append(t)
    assert wait_for(lambda: len(q) == 3, 5.0)
    assert q.take(0.01, "preview").request.mode == "preview"
    assert q.take(0.01, "preview") is None
    assert q.take(0.01, "main").request.mode in ("refine", "final")
    assert q.take(0.01, None) is not None and len(q) == 0
    for t in threads:
        t.join(1)  # the submitters time out (nobody answers them); nothing else to wait for


def _swallow(q: JobQueue, req) -> None:
    from kiosk.service.jobs import BusyError

    try:
        q.submit(req, 0.0, 0.5)
    except BusyError:
        pass
