"""The shopper's page on a touch screen: headless Chromium with touch emulation, fingers dispatched through the
DevTools protocol (`Input.dispatchTouchEvent`, as a touch panel delivers them), against a real daemon with the
emulated haptic device. Feeling must never draw, render or change the device's frame; a second finger cancels a
stroke; taps leave no ink; idle returns to the attract screen with the drawing and the friction frame cleared;
the catalogue switches garments."""
from __future__ import annotations

import hashlib
import shutil
import urllib.request

import numpy as np
import pytest

from tests.kiosk.bundle_factory import base_manifest, make_bundle
from tests.kiosk.daemon_fixtures import demo_build, start_daemon, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.slow]
playwright = pytest.importorskip("playwright.sync_api")

OUTLINE = [(380, 220), (900, 220), (900, 640), (380, 640), (380, 222)]  # one closed stroke
ACROSS = [(300, 430), (980, 430)]  # a slide across the garment and beyond it


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    bundle, trusted, _ = demo_build(tmp_path_factory)
    tmp = tmp_path_factory.mktemp("touch")
    other, other_trusted = make_bundle(tmp, manifest=base_manifest(garment_id="test-coat", display_name="Test coat"))
    keys = tmp / "all-trusted"
    keys.mkdir()
    for folder in (trusted, other_trusted):
        for pub in folder.glob("*.pub"):
            shutil.copy(pub, keys / f"{folder.parent.name}-{pub.name}")
    d = start_daemon([bundle, other], keys)
    yield d
    d.stop()


@pytest.fixture(scope="module")
def browser():
    with playwright.sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True)
        yield b
        b.close()


class Fingers:
    """Touch points sent the way a touch panel sends them (Chromium turns them into pointer events)."""

    def __init__(self, page):
        self.page = page
        self.cdp = page.context.new_cdp_session(page)

    def send(self, kind: str, points: dict[int, tuple[float, float]]) -> None:
        self.cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": [
            {"id": i, "x": float(x), "y": float(y)} for i, (x, y) in points.items()]})

    def tap(self, x: float, y: float) -> None:
        self.send("touchStart", {1: (x, y)})
        self.send("touchEnd", {})

    def slide(self, points, *, seconds: float = 0.4, finger: int = 1, end: bool = True) -> None:
        """Slide one finger along the polyline at a touch panel's report rate (about 60 Hz)."""
        path = _resample(points, max(2, int(seconds * 60)))
        self.send("touchStart", {finger: path[0]})
        for p in path[1:]:
            self.send("touchMove", {finger: p})
            self.page.wait_for_timeout(1000 / 60)
        if end:
            self.send("touchEnd", {})


def _resample(points, n: int) -> list[tuple[float, float]]:
    pts = np.asarray(points, float)
    seg = np.r_[0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    at = np.linspace(0, seg[-1], n)
    return list(zip(np.interp(at, seg, pts[:, 0]), np.interp(at, seg, pts[:, 1])))


def open_page(browser, url: str, errors: list):
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, device_scale_factor=1, has_touch=True)
    page = ctx.new_page()
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.evaluate("window.vtkiosk.ready")
    assert page.is_visible("#attract") and page.evaluate("window.vtkiosk.state.attract")
    fingers = Fingers(page)
    fingers.tap(640, 400)  # wakes the kiosk; leaves no ink
    page.wait_for_function("!window.vtkiosk.state.attract")
    return page, fingers


@pytest.fixture()
def touch(browser, daemon):
    errors: list[str] = []
    page, fingers = open_page(browser, daemon.server.url, errors)
    yield page, fingers
    page.context.close()
    assert not errors, errors


def js(page, expr: str):
    return page.evaluate(expr)


def wait_settled(page, finals_before: int) -> dict:
    page.wait_for_function(f"window.vtkiosk.stats.finals.length > {finals_before}", timeout=30000)
    page.wait_for_function("(() => { const m = window.vtkiosk.lastMeta;"
                           " return m.mode === 'refine' || (m.mode === 'final' && !m.refine); })()", timeout=30000)
    return js(page, "window.vtkiosk.shown")


def get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.read()


def counters(d) -> dict:
    """What the daemon did: render requests, frames, graph runs, device commits, the committed frame itself."""
    _, _, requests = d.series.requests.snapshot(route="/api/render")
    return {"render_requests": requests,
            "frames": sum(d.series.frames.value(kind=k) for k in ("preview", "final", "refine", "full")),
            "graph_runs": sum(d.series.graph_runs.value(graph=g) for g in ("full", "visual", "tactile")),
            "device_commits": d.device.state()["frames_committed"],
            "device_frame": hashlib.sha256(get(d.server.url + "api/debug/device-frame")).hexdigest()}


def canvas_digest(page) -> str:
    return js(page, "document.getElementById('stage').toDataURL()")


def draw_garment(page, fingers) -> dict:
    n = js(page, "window.vtkiosk.stats.finals.length")
    fingers.slide(OUTLINE, seconds=0.8)
    return wait_settled(page, n)


def test_a_touch_stroke_draws_then_feeling_changes_nothing(touch, daemon):
    page, fingers = touch
    texts = js(page, "window.vtkiosk.config().texts")
    assert js(page, "window.vtkiosk.state.mode") == "draw" and page.inner_text("#hint") == texts["hint_draw_empty"]
    shown = draw_garment(page, fingers)
    # Draw mode: the touch stroke drew exactly what the finger traced, and a garment was made of it.
    strokes = js(page, "window.vtkiosk.state.strokes")
    assert len(strokes) == 1 and strokes[0][0] == [380, 220] and strokes[0][-1] == [380, 222]
    assert shown["status"] == "ok" and js(page, "window.vtkiosk.stats.touches.draw") == 1
    commit = daemon.wait_commit(shown["device_frame"], 10.0)
    assert commit is not None and commit.status == "committed" and daemon.device.emulator.active_frame.any()
    # The outline closed: Feel mode, and the page says so.
    assert js(page, "window.vtkiosk.state.mode") == "feel" and page.inner_text("#hint") == texts["hint_feel"]
    assert page.inner_text("#fabric-name") == "Demo denim shorts"
    page.wait_for_timeout(300)  # any answer still on its way lands before the baseline
    before, canvas, sketch = counters(daemon), canvas_digest(page), strokes
    felt_before = daemon.usage.felt.snapshot()[2]
    feel_touches = daemon.usage.touches.value(mode="feel")

    fingers.slide(ACROSS + [(640, 300), (640, 600)], seconds=2.0, end=False)
    assert page.is_visible("#finger")  # the page shows where the finger is, nothing else
    fingers.send("touchEnd", {})
    page.wait_for_timeout(500)

    assert js(page, "window.vtkiosk.state.strokes") == sketch and canvas_digest(page) == canvas
    assert counters(daemon) == before  # no render request, no inference, no device commit, same friction frame
    assert js(page, "window.vtkiosk.stats.touches.feel") == 1 and not page.is_visible("#finger")
    # Anonymous figures: one feel touch, and the time to the first felt garment.
    assert wait_for(lambda: daemon.usage.touches.value(mode="feel") == feel_touches + 1, 5.0)
    assert wait_for(lambda: daemon.usage.felt.snapshot()[2] == felt_before + 1, 5.0)
    metrics = get(daemon.server.url + "metrics").decode()
    assert 'vtkiosk_touches_total{mode="feel"}' in metrics and "vtkiosk_first_feel_seconds_count" in metrics


def test_the_catalogue_switches_garment_and_names_the_fabric(touch, daemon):
    page, fingers = touch
    thumbs = page.eval_on_selector_all("#garments img", "els => els.map(e => [e.src, e.naturalWidth])")
    assert len(thumbs) == 2 and all(w > 0 for _, w in thumbs)  # the bundles' own reference pictures
    assert thumbs[0][0].endswith("/api/bundles/denim-shorts/visual.png")
    # With nothing drawn, picking a garment lays out its own outline: ready to feel at once.
    n = js(page, "window.vtkiosk.stats.finals.length")
    page.tap("#garments button[data-id='test-coat']")
    shown = wait_settled(page, n)
    assert shown["status"] == "ok" and js(page, "window.vtkiosk.lastMeta.plan.panels[0].bundle") == "test-coat"
    assert js(page, "window.vtkiosk.state.mode") == "feel" and page.inner_text("#fabric-name") == "Test coat"
    coat = daemon.frames.textures["main"].texture().pixels.copy()
    # The other garment: its own outline and model, another friction frame under the finger.
    n = js(page, "window.vtkiosk.stats.finals.length")
    page.tap("#garments button[data-id='denim-shorts']")
    shown = wait_settled(page, n)
    assert js(page, "window.vtkiosk.lastMeta.plan.panels[0].bundle") == "denim-shorts"
    assert page.inner_text("#fabric-name") == "Demo denim shorts"
    assert page.get_attribute("#garments button[data-id='denim-shorts']", "aria-checked") == "true"
    assert daemon.wait_commit(shown["device_frame"], 10.0).status == "committed"
    fx, fy, fw, fh = shown["friction"]
    felt = daemon.device.emulator.active_frame[fy:fy + fh, fx:fx + fw]
    np.testing.assert_array_equal(felt, daemon.frames.textures["main"].texture().pixels)
    assert felt.shape != coat.shape or not np.array_equal(felt, coat)


def test_a_pen_draws_while_a_finger_feels(touch, daemon):
    page, fingers = touch
    cdp = fingers.cdp

    def pen(kind, x, y):
        cdp.send("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left", "buttons": 1,
                                              "clickCount": 1, "pointerType": "pen"})

    n = js(page, "window.vtkiosk.stats.finals.length")
    path = _resample(OUTLINE, 40)
    pen("mousePressed", *path[0])
    for i, p in enumerate(path[1:]):
        if i == 10:
            fingers.send("touchStart", {7: (1000, 700)})  # the drawing hand's palm comes to rest
        pen("mouseMoved", *p)
        page.wait_for_timeout(16)
    pen("mouseReleased", *path[-1])
    fingers.send("touchEnd", {})
    assert wait_settled(page, n)["status"] == "ok"
    assert js(page, "window.vtkiosk.stats.cancelled") == 0 and js(page, "window.vtkiosk.stats.touches.feel") == 0
    assert js(page, "window.vtkiosk.state.penSeen") and js(page, "window.vtkiosk.state.mode") == "feel"
    assert page.inner_text("#hint") == js(page, "window.vtkiosk.config().texts.hint_pen")
    before = counters(daemon)
    fingers.slide(ACROSS, seconds=0.5)
    page.wait_for_timeout(300)
    assert counters(daemon) == before and len(js(page, "window.vtkiosk.state.strokes")) == 1


def test_idle_returns_to_the_attract_screen_with_the_drawing_and_friction_cleared(browser, tmp_path):
    bundle, trusted = make_bundle(tmp_path)
    d = start_daemon([bundle], trusted, page={"idle_timeout_s": 3.0, "attract_garment_s": 2.0})
    errors: list[str] = []
    try:
        page, fingers = open_page(browser, d.server.url, errors)
        assert wait_for(lambda: d.usage.sessions.value() == 1, 10.0)
        shown = draw_garment(page, fingers)
        assert shown["status"] == "ok"
        assert wait_for(lambda: d.device.emulator.active_frame.any(), 10.0)
        page.wait_for_function("window.vtkiosk.state.attract", timeout=30000)
        assert page.is_visible("#attract")
        assert js(page, "window.vtkiosk.state.strokes") == [] and js(page, "window.vtkiosk.state.mode") == "draw"
        page.wait_for_function("window.vtkiosk.shown.status === 'empty'", timeout=15000)
        page.wait_for_timeout(100)
        assert canvas_digest(page) == js(page, "(() => { const c = document.createElement('canvas');"
                                               " c.width = 1280; c.height = 800; return c.toDataURL(); })()")
        assert wait_for(lambda: not d.device.emulator.active_frame.any(), 10.0)  # nothing left to feel
        assert wait_for(lambda: d.usage.idle_resets.value() == 1, 10.0)
        # The attract screen draws the catalogue's reference sketch (pixels appear on its canvas).
        page.wait_for_function("(() => { const c = document.getElementById('attract-art');"
                               " return c.width > 0 && c.getContext('2d').getImageData(0, 0, c.width, c.height)"
                               ".data.some((v, i) => i % 4 === 3 && v > 0); })()", polling=500, timeout=20000)
        fingers.tap(640, 400)
        page.wait_for_function("!window.vtkiosk.state.attract")
        assert wait_for(lambda: d.usage.sessions.value() == 2, 10.0)
        page.context.close()
    finally:
        d.stop()
    assert not errors, errors
