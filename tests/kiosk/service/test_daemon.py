"""The kiosk daemon end to end: real bundles, real ONNX Runtime, real HTTP, the emulated haptic device.

Friction lands under the visual; cached sketches cost no inference; non-finite outputs, a hung loop and a lost
device degrade the kiosk (last good frame kept, counted, a notice shown) and it recovers; reload swaps or keeps.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from kiosk.ops.control import send_control
from kiosk.service.daemon import KioskDaemon
from kiosk.contract.haptics import friction_map
from kiosk.bundle.manifest import BundleError
from kiosk.inference.scene import Panel, Scene, SketchInput
from tests.kiosk.bundle_factory import base_manifest, make_bundle
from tests.kiosk.daemon_fixtures import BOX, daemon_config, http, render, settle, start_daemon, wait_for

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture()
def bundle(tmp_path):
    return make_bundle(tmp_path)


@pytest.fixture()
def daemon(bundle):
    path, trusted = bundle
    d = start_daemon([path], trusted)
    yield d
    d.stop()


def device_frame(d: KioskDaemon) -> np.ndarray:
    return d.device.emulator.active_frame


def test_friction_lands_exactly_under_the_visual(daemon):
    # The stroke end is answered quickly at the preview resolution, then refined at full resolution.
    status, meta, visuals = render(daemon)
    assert status == 200 and meta["mode"] == "final" and meta["refine"] and meta["plan"]["quick"]
    # Physical scale: the 532x432 px region at 0.170 mm/px (default panel) over the bundle's 0.3 mm/px is 301x245
    # model pixels, rounded up to the graph's 512x256; the quick answer fits 256x256 at a lower scale.
    assert visuals["main"].shape == (256, 256, 4) and meta["plan"]["panels"][0]["refine_grid"] == [512, 256]
    # At 256x256 the texture would be felt 1.19x coarser than the fabric: the quick answer shows the garment and
    # leaves its friction to the refinement (inference.quick_tactile: at-scale); the device is not touched.
    quick = meta["plan"]["panels"][0]
    assert quick["deferred"] == ["tactile"] and quick["graph"] == "visual" and meta["device_frame"] is None
    assert not device_frame(daemon).any()
    status, meta, visuals = render(daemon, mode="refine")
    assert status == 200 and not meta["refine"]
    (p,) = meta["panels"]
    assert p["status"] == "ok" and meta["plan"]["panels"][0]["graph"] == "full"
    x, y, w, h = p["visual"]["rect"]
    assert p["friction"]["rect"] == [x, y, w, h]  # fully on screen: the same rectangle
    assert visuals["main"].shape == (256, 512, 4)
    commit = daemon.wait_commit(meta["device_frame"], 5.0)
    assert commit.status == "committed" and commit.at >= meta["received_at"]
    frame = device_frame(daemon)
    # The factory's tactile graph is 0.1 * (s, -s) * mask at the grid: recompute the friction map independently
    # from the plan's network input and compare with what the device holds at the reported rectangle.
    plan = daemon.planner.plan(Scene((Panel("main", (0, 0, 1280, 800), "denim-shorts"),), (1280, 800)),
                               {"main": SketchInput(tuple(np.asarray(s, float) for s in BOX))}, daemon.bundles)
    inputs = plan.panels[0].inputs
    g = 0.1 * inputs.sketch[0, 0] * inputs.mask[0, 0]
    want = friction_map(g, -g, 0.05, size=(w, h))
    np.testing.assert_array_equal(frame[y:y + h, x:x + w], want)
    assert want.max() > 100  # the outline is felt
    outside = frame.copy()
    outside[y:y + h, x:x + w] = 0
    assert not outside.any()  # nothing anywhere else
    # The visual's alpha is the object mask: opaque inside the outline, transparent outside.
    alpha = visuals["main"][..., 3]
    assert alpha[128, 256] == 255 and alpha[2, 2] == 0


def test_quick_tactile_always_sends_the_quick_answers_friction_at_its_coarser_scale(bundle):
    path, trusted = bundle
    d = start_daemon([path], trusted, inference={"quick_tactile": "always"})
    try:
        status, meta, _ = render(d)
        quick = meta["plan"]["panels"][0]
        assert meta["refine"] and quick["deferred"] == [] and quick["graph"] == "full"
        assert quick["felt_ratio"] == pytest.approx(1.19, abs=0.01)
        assert d.wait_commit(meta["device_frame"], 5.0).status == "committed" and device_frame(d).any()
    finally:
        d.stop()


def test_a_deferring_quick_answer_keeps_the_garments_friction_but_never_anothers(tmp_path):
    a, trusted = make_bundle(tmp_path, name="a.vtb")
    b, _ = make_bundle(tmp_path, name="b.vtb", manifest=base_manifest(garment_id="knit-jacket",
                                                                      display_name="Knit jacket"))
    d = start_daemon([a, b], trusted)
    try:
        status, meta, _ = settle(d)  # denim: quick visual, then the refinement's friction
        assert d.wait_commit(meta["device_frame"], 5.0).status == "committed"
        denim = device_frame(d).copy()
        assert denim.any()
        # an edit of the same garment: the quick answer defers, the device keeps the denim frame untouched
        status, meta, _ = render(d, BOX + [[[400, 300], [600, 500]]])
        assert meta["plan"]["panels"][0]["deferred"] == ["tactile"] and meta["device_frame"] is None
        np.testing.assert_array_equal(device_frame(d), denim)
        # another garment on the same panel: its quick answer defers too, but denim's friction must not stay under
        # the knit's picture: natural friction until the knit's refinement arrives
        status, meta, _ = render(d, garment="knit-jacket")
        assert meta["plan"]["panels"][0]["deferred"] == ["tactile"] and meta["device_frame"] is not None
        assert d.wait_commit(meta["device_frame"], 5.0).status == "committed" and not device_frame(d).any()
        status, meta, _ = render(d, garment="knit-jacket", mode="refine")
        assert d.wait_commit(meta["device_frame"], 5.0).status == "committed" and device_frame(d).any()
    finally:
        d.stop()


def test_without_refinement_a_stroke_end_is_answered_at_full_resolution(bundle):
    path, trusted = bundle
    d = start_daemon([path], trusted, inference={"refine": False})
    try:
        status, meta, visuals = render(d)
        assert not meta["refine"] and not meta["plan"]["quick"] and visuals["main"].shape == (256, 512, 4)
    finally:
        d.stop()


def test_a_new_request_supersedes_queued_previews_and_refinements(daemon):
    import threading

    daemon.handle_control({"op": "debug.hang", "on": True})  # hold the loop so requests queue up
    answers, threads = {}, []

    def send(name, mode, client="test", strokes=BOX):
        def go():
            answers[name] = render(daemon, strokes, mode=mode, client=client)
        t = threading.Thread(target=go)
        t.start()
        threads.append(t)

    try:
        send("other", "preview", client="another-page")  # another client's preview is not touched
        send("preview", "preview")
        assert wait_for(lambda: len(daemon.jobs) == 2, 5.0)
        send("refine", "refine")  # replaces the queued preview of the same client
        assert wait_for(lambda: "preview" in answers and len(daemon.jobs) == 2, 5.0)
        send("final", "final", strokes=BOX + [[[400, 300], [600, 500]]])  # replaces the queued refinement
        assert wait_for(lambda: "refine" in answers and len(daemon.jobs) == 2, 5.0)
    finally:
        daemon.handle_control({"op": "debug.hang", "on": False})
    for t in threads:
        t.join(10)
    assert answers["preview"][1] == {"superseded": True} == answers["refine"][1]
    assert answers["final"][0] == 200 and answers["final"][1]["mode"] == "final"
    assert answers["other"][0] == 200 and answers["other"][1]["mode"] == "preview"


def test_unchanged_sketch_costs_no_inference_and_undo_hits_the_cache(daemon):
    runs = daemon.series.graph_runs
    total = lambda: sum(runs.value(graph=g) for g in ("full", "visual", "tactile"))  # noqa: E731
    settle(daemon)  # quick visual, then the refinement's full graph
    before = total()
    status, meta, _ = settle(daemon)
    assert meta["plan"]["panels"][0]["graph"] == "none" and meta["plan"]["panels"][0]["reused"] == ["visual",
                                                                                                      "tactile"]
    assert meta["plan"]["computed_pixels"] == 0 and total() == before
    settle(daemon, BOX + [[[400, 300], [600, 500]]])  # a new stroke: computed, quick and refined
    assert total() == before + 2
    status, meta, _ = settle(daemon)  # undo: back to the cached sketch
    assert meta["plan"]["panels"][0]["reason"] == "all from cache" and total() == before + 2
    assert http(daemon.server.url + "api/plan")[0] == 200


def test_preview_is_visual_only_and_leaves_the_device_alone(daemon):
    status, meta, _ = settle(daemon)
    daemon.wait_commit(meta["device_frame"], 5.0)
    committed = len(daemon.device.emulator.committed)
    status, meta, visuals = render(daemon, BOX + [[[350, 250], [700, 550]]], mode="preview")
    assert status == 200 and meta["preview"] and meta["device_frame"] is None
    assert meta["plan"]["panels"][0]["graph"] == "visual" and visuals["main"].shape == (256, 256, 4)
    time.sleep(0.2)
    assert len(daemon.device.emulator.committed) == committed


def test_clearing_the_canvas_clears_the_friction(daemon):
    status, meta, _ = settle(daemon)
    daemon.wait_commit(meta["device_frame"], 5.0)
    assert device_frame(daemon).any()
    status, meta, visuals = render(daemon, [])
    assert meta["panels"][0]["status"] == "empty" and not visuals
    assert daemon.wait_commit(meta["device_frame"], 5.0).status == "committed"
    assert not device_frame(daemon).any()


def test_nonfinite_outputs_keep_the_last_good_frame(daemon):
    status, meta, _ = settle(daemon)
    daemon.wait_commit(meta["device_frame"], 5.0)
    good = device_frame(daemon).copy()
    assert daemon.handle_control({"op": "debug.nonfinite", "on": True})["nonfinite"]
    status, meta, visuals = render(daemon, BOX + [[[400, 300], [600, 500]]])
    assert status == 200 and meta["panels"][0]["status"] == "kept" and not visuals
    assert "last good" in meta["panels"][0]["notice"] and any("last good" in n for n in meta["notices"])
    assert daemon.series.inference_errors.value(reason="nonfinite") == 1
    time.sleep(0.2)
    np.testing.assert_array_equal(device_frame(daemon), good)  # the finger still feels the last good frame
    daemon.handle_control({"op": "debug.nonfinite", "on": False})
    status, meta, visuals = render(daemon, BOX + [[[400, 300], [600, 500]]])
    assert meta["panels"][0]["status"] == "ok" and not meta["notices"]
    assert "vtkiosk_inference_errors_total" in http(daemon.server.url + "metrics")[1].decode()


def test_a_poisoned_bundle_never_reaches_screen_or_device(tmp_path):
    good, trusted = make_bundle(tmp_path, name="good.vtb")
    bad, _ = make_bundle(tmp_path, name="bad.vtb", poison=True,
                         manifest=base_manifest(garment_id="poison-coat", display_name="Poison coat"))
    d = start_daemon([good], trusted)  # the probe refuses a NaN bundle: start with the good one, add it raw
    try:
        from kiosk.bundle.archive import open_bundle
        from kiosk.inference.engine import LoadedBundle
        from kiosk.bundle.signature import load_trusted_keys

        lb = LoadedBundle(open_bundle(bad, load_trusted_keys(trusted), workdir=tmp_path / "w"))
        d.bundle_set.serving = {**d.bundle_set.serving, lb.garment_id: lb}
        status, meta, visuals = settle(d, garment="poison-coat")
        assert meta["panels"][0]["status"] == "kept" and not visuals and meta["device_frame"] is not None
        time.sleep(0.2)
        assert not device_frame(d).any()
        # both answers to the stroke end refused it: the quick one's visual, the refinement's full graph
        assert d.series.inference_errors.value(reason="nonfinite") == 2
    finally:
        d.stop()


def test_device_loss_degrades_to_visual_only_and_recovers(daemon):
    status, meta, _ = settle(daemon)
    daemon.wait_commit(meta["device_frame"], 5.0)
    daemon.handle_control({"op": "debug.unplug"})
    assert wait_for(lambda: not daemon.device.up, 5.0)
    edit = BOX + [[[400, 300], [600, 500]]]
    status, meta, visuals = settle(daemon, edit)  # the refinement's friction frame meets the unplugged link
    assert status == 200 and meta["panels"][0]["status"] == "ok" and "main" in visuals  # still drawing
    assert any("visual only" in n for n in meta["notices"])
    # the output thread sends the friction frame on its own; under load it may not have tried yet, and a replug
    # before it tries would let the frame through without ever meeting the down link
    c = daemon.wait_commit(meta["device_frame"], 10.0)
    assert c is not None and c.status == "failed", c
    assert not daemon.health.run().checks["device"].ok
    assert json.loads(http(daemon.server.url + "api/status")[1])["degraded"]
    assert http(daemon.server.url + "healthz")[0] == 503
    daemon.handle_control({"op": "debug.replug"})
    assert wait_for(lambda: daemon.device.up, 10.0)
    want = daemon.frames.textures["main"].texture()
    x, y, w, h = want.rect
    assert wait_for(lambda: np.array_equal(device_frame(daemon)[y:y + h, x:x + w], want.pixels), 5.0)
    assert not daemon.notices()
    assert wait_for(lambda: daemon.health.run().checks["device"].ok, 5.0)
    assert daemon.series.device_errors.value(kind="link") >= 1


def test_a_hung_inference_loop_fails_health_and_recovers(tmp_path, bundle):
    path, trusted = bundle
    d = start_daemon([path], trusted, server={"request_timeout_s": 0.5})
    try:
        assert wait_for(lambda: d.health.run().ok, 5.0)
        d.handle_control({"op": "debug.hang", "on": True})
        status, body, _ = render(d)
        assert status == 503 and "did not answer" in body["error"]
        assert wait_for(lambda: not d.health.run().checks["inference"].ok, 5.0)
        d.handle_control({"op": "debug.hang", "on": False})
        assert wait_for(lambda: d.health.run().checks["inference"].ok, 5.0)
        assert render(d)[0] == 200
    finally:
        d.stop()


def test_fault_injection_is_off_unless_configured(tmp_path, bundle):
    path, trusted = bundle
    d = KioskDaemon(daemon_config([path], trusted, debug={"fault_injection": False}))
    with pytest.raises(Exception, match="fault injection is off"):
        d.handle_control({"op": "debug.hang"})


def test_reload_swaps_a_new_version_and_keeps_the_old_on_failure(tmp_path):
    target = tmp_path / "serve" / "garment.vtb"
    target.parent.mkdir()
    v1, trusted = make_bundle(tmp_path, name="v1.vtb")
    v2, _ = make_bundle(tmp_path, name="v2.vtb", manifest=base_manifest(model_version="v2"))
    bad, _ = make_bundle(tmp_path, name="bad.vtb", poison=True, manifest=base_manifest(model_version="v3"))
    unsigned, _ = make_bundle(tmp_path, name="unsigned.vtb", sign=False, manifest=base_manifest(model_version="v4"))
    shutil.copy(v1, target)
    sock = tmp_path / "control.sock"
    d = start_daemon([target], trusted, control={"socket": str(sock)})
    try:
        old_key = d.bundles["denim-shorts"].key
        assert "v1" not in old_key and render(d)[0] == 200
        assert send_control(sock, {"op": "reload"})["unchanged"][0]["garment"] == "denim-shorts"
        shutil.copy(v2, target)
        reply = send_control(sock, {"op": "reload"})
        assert reply["ok"] and reply["swapped"][0]["replaced"] == old_key and "@v2#" in reply["serving"]["denim-shorts"]
        assert render(d)[0] == 200
        for broken, reason in ((bad, "non-finite"), (unsigned, "not signed")):
            shutil.copy(broken, target)
            reply = send_control(sock, {"op": "reload"})
            assert not reply["ok"] and reason in reply["error"], reply
            assert "@v2#" in d.bundles["denim-shorts"].key  # the old one stays
            assert render(d)[0] == 200
        assert d.series.reloads.value(result="kept") + d.series.reloads.value(result="failed") == 2
        status = send_control(sock, {"op": "status"})
        assert status["ok"] and "denim-shorts" in status["bundles"] and "torch_imported" in status
    finally:
        d.stop()


def test_reload_during_rendering_never_stalls_the_page(tmp_path):
    """Renders keep answering while bundles are swapped back and forth."""
    target = tmp_path / "g.vtb"
    v1, trusted = make_bundle(tmp_path, name="v1.vtb")
    v2, _ = make_bundle(tmp_path, name="v2.vtb", manifest=base_manifest(model_version="v2"))
    shutil.copy(v1, target)
    d = start_daemon([target], trusted)
    try:
        import threading

        errors, stop = [], threading.Event()

        def draw():
            i = 0
            while not stop.is_set():
                i += 1
                status, meta, _ = render(d, BOX + [[[400, 300 + i % 50], [600, 500]]])
                if status != 200 or meta["panels"][0]["status"] != "ok":
                    errors.append((status, meta))

        t = threading.Thread(target=draw)
        t.start()
        for src in (v2, v1, v2):
            shutil.copy(src, target)
            assert d.reload()["swapped"]
        stop.set()
        t.join()
        assert not errors
    finally:
        d.stop()


def test_no_loadable_bundle_is_a_clear_start_error(tmp_path):
    v1, trusted = make_bundle(tmp_path, sign=False)
    d = KioskDaemon(daemon_config([v1], trusted))
    with pytest.raises(BundleError, match="no bundle could be loaded.*not signed"):
        d.start()
    assert not d.server._httpd  # nothing left listening


def test_study_hooks(daemon):
    daemon.add_control_handler("study.", lambda req: {"echo": req["op"]})
    assert daemon.handle_control({"op": "study.next"}) == {"echo": "study.next"}
    from kiosk.ops.health import CheckResult

    daemon.add_health_check("study", lambda: CheckResult(True, "fine"))
    assert daemon.health.run().checks["study"].ok
    from kiosk.service.server import Response

    daemon.server.route("GET", "/api/study/", lambda req: Response.json({"study": req.path}))
    assert json.loads(http(daemon.server.url + "api/study/trial")[1]) == {"study": "/api/study/trial"}
    # A study trial: reference visuals, model tactile on two half panels, put on the device through show().
    panels = tuple(Panel(s, (0 if s == "left" else 640, 0, 640, 800), "denim-shorts", visual="reference",
                         sketch="reference", half=s) for s in ("left", "right"))
    runs = daemon.series.graph_runs.value(graph="visual") + daemon.series.graph_runs.value(graph="full")
    result = daemon.show(Scene(panels, (1280, 800)))
    assert [p.plan.graph for p in result.panels] == ["tactile", "tactile"]
    assert daemon.series.graph_runs.value(graph="visual") + daemon.series.graph_runs.value(graph="full") == runs
    assert daemon.wait_commit(result.device_frame, 5.0).status == "committed"
    left, right = (p.friction.texture() for p in result.panels)
    assert left.rect[0] + left.rect[2] <= 640 <= right.rect[0]  # each texture stays in its panel
    frame = device_frame(daemon)
    for t in (left, right):
        x, y, w, h = t.rect
        np.testing.assert_array_equal(frame[y:y + h, x:x + w], t.pixels)


def test_serve_command_runs_without_torch_reloads_on_sighup_and_stops_on_sigterm(tmp_path):
    path, trusted = make_bundle(tmp_path)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen([sys.executable, "-m", "vtkiosk", "serve", "--bundle", str(path), "--trusted-keys",
                             str(trusted), "--device", "emulated", "--port", "0"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert "kiosk serving denim-shorts at http://127.0.0.1:" in line, proc.stderr.read()
        url = line.split(" at ")[1].strip()
        status = json.loads(http(url + "api/status")[1])
        assert status["torch_imported"] is False and status["bundles"]["denim-shorts"]
        proc.send_signal(signal.SIGHUP)
        assert wait_for(lambda: json.loads(http(url + "api/status")[1])["last_reload"]["unchanged"], 10.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_serve_command_config_errors_are_one_line(tmp_path):
    cfg = tmp_path / "kiosk.yaml"
    cfg.write_text("bundles: [a.vtb]\nserver: {host: 0.0.0.0}\n")
    proc = subprocess.run([sys.executable, "-m", "vtkiosk", "serve", "--config", str(cfg)], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "not a loopback address" in proc.stderr
