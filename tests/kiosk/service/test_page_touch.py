"""The shopper's page on a touch screen: headless Chromium with touch emulation, fingers dispatched through the
DevTools protocol (`Input.dispatchTouchEvent`, as a touch panel delivers them), against a real daemon with the
emulated haptic device. Feeling must never draw, render or change the device's frame; a second finger cancels a
stroke; taps leave no ink; a tap on a button right after a flick still presses it; idle returns to the attract screen
with the drawing and the friction frame cleared; the catalogue switches garments; the hint says what a touch does.

Every wait is on the page's or the daemon's state, never a fixed sleep (the machine may be loaded); the only timed
pauses pace the fingers at a touch panel's report rate."""
from __future__ import annotations

import hashlib
import urllib.request
from dataclasses import dataclass

import numpy as np
import pytest

from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import demo_and_coat_daemon, start_daemon, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.slow]
pytest.importorskip("playwright.sync_api")

OUTLINE = [(380, 220), (900, 220), (900, 640), (380, 640), (380, 222)]  # one closed stroke
ACROSS = [(300, 430), (980, 430)]  # a slide across the garment and beyond it


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = demo_and_coat_daemon(tmp_path_factory, "touch")
    yield d
    d.stop()


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

    def tap_on(self, selector: str) -> None:
        """A finger's tap on an element's centre, sent on this session (no actionability wait in between)."""
        box = self.page.locator(selector).bounding_box()
        self.tap(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)

    def pace(self) -> None:
        """One touch panel report interval (about 60 Hz): input pacing, not a wait for the page."""
        self.page.wait_for_timeout(1000 / 60)

    def slide(self, points, *, seconds: float = 0.4, finger: int = 1, end: bool = True) -> None:
        """Slide one finger along the polyline at a touch panel's report rate. It is lifted while still moving
        (a flick), as a quick stroke or a feeling slide ends."""
        path = _resample(points, max(2, int(seconds * 60)))
        self.send("touchStart", {finger: path[0]})
        for p in path[1:]:
            self.send("touchMove", {finger: p})
            self.pace()
        if end:
            self.send("touchEnd", {})


def _resample(points, n: int) -> list[tuple[float, float]]:
    pts = np.asarray(points, float)
    seg = np.r_[0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    at = np.linspace(0, seg[-1], n)
    return list(zip(np.interp(at, seg, pts[:, 0]), np.interp(at, seg, pts[:, 1])))


@dataclass
class Screen:
    """One shopper's page on a daemon, and the daemon's render count when it opened (this page is the daemon's only
    client while it is open)."""

    page: object
    fingers: Fingers
    daemon: object
    requests0: int

    def quiet_counters(self) -> dict:
        """The daemon's counters once it is done with everything this page asked for: no render in flight, the last
        answer's friction frame committed, and every render request counted (the server counts one after writing
        its answer, so the page can hold an answer before the count moves)."""
        self.page.wait_for_function("window.vtkiosk.stats.inFlight === 0", timeout=30000)
        shown = js(self.page, "window.vtkiosk.shown")
        if shown and shown["device_frame"] is not None:
            assert self.daemon.wait_commit(shown["device_frame"], 10.0) is not None
        want = self.requests0 + js(self.page, "window.vtkiosk.stats.requests")
        assert wait_for(lambda: render_requests(self.daemon) == want, 10.0), (render_requests(self.daemon), want)
        return counters(self.daemon)


def open_page(browser, daemon, errors: list) -> Screen:
    requests0 = render_requests(daemon)
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, device_scale_factor=1, has_touch=True)
    page = ctx.new_page()
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(daemon.server.url)
    page.evaluate("window.vtkiosk.ready")
    assert page.is_visible("#attract") and page.evaluate("window.vtkiosk.state.attract")
    fingers = Fingers(page)
    fingers.tap(640, 400)  # wakes the kiosk; leaves no ink
    page.wait_for_function("!window.vtkiosk.state.attract")
    return Screen(page, fingers, daemon, requests0)


@pytest.fixture()
def touch(browser, daemon):
    errors: list[str] = []
    screen = open_page(browser, daemon, errors)
    yield screen
    screen.quiet_counters()  # the next page's count starts from here
    screen.page.context.close()
    assert not errors, errors


def js(page, expr: str):
    return page.evaluate(expr)


def wait_settled(page, finals_before: int) -> dict:
    """A full answer newer than `finals_before` is shown and no render is in flight (the refinement the page asks
    for after a quick answer included), so what is shown answers the page's last request."""
    page.wait_for_function(f"window.vtkiosk.stats.finals.length > {finals_before}"
                           " && window.vtkiosk.stats.inFlight === 0", timeout=30000)
    return js(page, "window.vtkiosk.shown")


def wait_fingers_up(page) -> None:
    """Every pointer's "up" has reached the page (it forgets a pointer only there)."""
    page.wait_for_function("window.vtkiosk.state.pointers.size === 0 && !window.vtkiosk.state.blocked")


def get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.read()


def render_requests(d) -> int:
    return d.series.requests.snapshot(route="/api/render")[2]


def counters(d) -> dict:
    """What the daemon did: render requests, frames, graph runs, device commits, the committed frame itself."""
    return {"render_requests": render_requests(d),
            "frames": sum(d.series.frames.value(kind=k) for k in ("preview", "final", "refine", "full")),
            "graph_runs": sum(d.series.graph_runs.value(graph=g) for g in ("full", "visual", "tactile")),
            "device_commits": d.device.state()["frames_committed"],
            "device_frame": hashlib.sha256(get(d.server.url + "api/debug/device-frame")).hexdigest()}


def canvas_digest(page) -> str:
    return js(page, "document.getElementById('stage').toDataURL()")


BLANK_STAGE = ("(() => { const s = document.getElementById('stage'), c = document.createElement('canvas');"
               " c.width = s.width; c.height = s.height; return s.toDataURL() === c.toDataURL(); })()")


def draw_garment(page, fingers) -> dict:
    n = js(page, "window.vtkiosk.stats.finals.length")
    fingers.slide(OUTLINE, seconds=0.8)
    return wait_settled(page, n)


def test_a_touch_stroke_draws_then_feeling_changes_nothing(touch, daemon):
    page, fingers = touch.page, touch.fingers
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
    before, canvas, sketch = touch.quiet_counters(), canvas_digest(page), strokes
    requests = js(page, "window.vtkiosk.stats.requests")
    felt_before = daemon.usage.felt.snapshot()[2]
    feel_touches = daemon.usage.touches.value(mode="feel")

    fingers.slide(ACROSS + [(640, 300), (640, 600)], seconds=2.0, end=False)
    page.wait_for_selector("#finger", state="visible")  # the page shows where the finger is, nothing else
    fingers.send("touchEnd", {})
    wait_fingers_up(page)
    page.wait_for_selector("#finger", state="hidden")

    # The page sent nothing (it would have sent a render from the slide's moves or its "up", both handled now).
    assert js(page, "window.vtkiosk.stats.requests") == requests and js(page, "window.vtkiosk.stats.inFlight") == 0
    assert js(page, "window.vtkiosk.state.strokes") == sketch and canvas_digest(page) == canvas
    assert touch.quiet_counters() == before  # no render request, no inference, no device commit, same friction frame
    assert js(page, "window.vtkiosk.stats.touches.feel") == 1
    # Anonymous figures: one feel touch, and the time to the first felt garment.
    assert wait_for(lambda: daemon.usage.touches.value(mode="feel") == feel_touches + 1, 5.0)
    assert wait_for(lambda: daemon.usage.felt.snapshot()[2] == felt_before + 1, 5.0)
    metrics = get(daemon.server.url + "metrics").decode()
    assert 'vtkiosk_touches_total{mode="feel"}' in metrics and "vtkiosk_first_feel_seconds_count" in metrics


def test_a_second_finger_cancels_the_stroke_and_taps_leave_no_ink(touch, daemon):
    page, fingers = touch.page, touch.fingers
    blank = canvas_digest(page)
    requests0 = js(page, "window.vtkiosk.stats.requests")
    finals0 = js(page, "window.vtkiosk.stats.finals.length")
    # A tap: no dot, no request.
    fingers.tap(500, 300)
    fingers.tap(700, 500)
    page.wait_for_function("window.vtkiosk.stats.taps === 2")
    wait_fingers_up(page)
    assert js(page, "window.vtkiosk.state.strokes") == [] and js(page, "window.vtkiosk.state.current") is None
    assert canvas_digest(page) == blank and js(page, "window.vtkiosk.stats.requests") == requests0
    # A stroke under way, then a second finger (a palm, a pinch): the stroke is dropped, and neither finger
    # draws until both are up.
    fingers.slide([(400, 250), (800, 250)], seconds=0.3, end=False)
    page.wait_for_function("window.vtkiosk.state.current && window.vtkiosk.state.current.length > 5")
    fingers.send("touchStart", {1: (800, 250), 2: (600, 600)})
    page.wait_for_function("window.vtkiosk.stats.cancelled === 1 && window.vtkiosk.state.blocked")
    for k in range(1, 11):
        fingers.send("touchMove", {1: (800, 250 + 30 * k), 2: (600 - 20 * k, 600)})
        fingers.pace()
    fingers.send("touchEnd", {})
    wait_fingers_up(page)
    assert js(page, "window.vtkiosk.stats.cancelled") == 1
    assert js(page, "window.vtkiosk.stats.touches.draw") == 3  # the taps and the dropped stroke, not the 2nd finger
    assert js(page, "window.vtkiosk.state.strokes") == [] and js(page, "window.vtkiosk.state.current") is None
    page.wait_for_function("window.vtkiosk.stats.inFlight === 0")  # previews of the dropped stroke, if any, came
    assert js(page, "window.vtkiosk.stats.finals.length") == finals0  # the dropped stroke was never rendered
    assert js(page, "window.vtkiosk.state.visual") is None  # a preview of it, if one came, is gone
    assert canvas_digest(page) == blank
    # Drawing goes on afterwards, one stroke at a time; Undo and Clear work per stroke.
    n = js(page, "window.vtkiosk.stats.finals.length")
    fingers.slide([(400, 250), (800, 250)], seconds=0.3)
    wait_settled(page, n)
    n = js(page, "window.vtkiosk.stats.finals.length")
    fingers.slide([(800, 250), (800, 600)], seconds=0.3)
    wait_settled(page, n)
    assert len(js(page, "window.vtkiosk.state.strokes")) == 2
    n = js(page, "window.vtkiosk.stats.finals.length")
    page.tap("#undo")
    wait_settled(page, n)
    strokes = js(page, "window.vtkiosk.state.strokes")
    assert len(strokes) == 1 and strokes[0][0] == [400, 250]
    n = js(page, "window.vtkiosk.stats.finals.length")
    page.tap("#clear")
    assert wait_settled(page, n)["status"] == "empty" and js(page, "window.vtkiosk.state.strokes") == []
    page.wait_for_function(BLANK_STAGE)
    assert page.inner_text("#hint") == js(page, "window.vtkiosk.config().texts.hint_draw_empty")


def test_a_tap_right_after_a_flick_still_presses_the_button(touch, daemon):
    """A stroke or a feeling slide ends with the finger still moving; Chromium drops the click of a tap that lands
    while such a flick coasts. The page's buttons act on the release, so the tap counts."""
    page, fingers = touch.page, touch.fingers
    for k in range(4):
        fingers.slide([(400, 300 + 40 * k), (900, 300 + 40 * k)], seconds=0.25)
        fingers.tap_on("#undo")  # at once: the flick is still coasting
        wait_fingers_up(page)
        page.wait_for_function("window.vtkiosk.stats.inFlight === 0")
        assert js(page, "window.vtkiosk.stats.touches.draw") == k + 1
        assert js(page, "window.vtkiosk.state.strokes") == [], f"round {k}: Undo did not act"
    for k in range(3):
        fingers.tap_on("#mode-feel")
        page.wait_for_function("window.vtkiosk.state.mode === 'feel'")
        fingers.slide(ACROSS, seconds=0.25)
        fingers.tap_on("#mode-draw")
        wait_fingers_up(page)
        assert js(page, "window.vtkiosk.state.mode") == "draw", f"round {k}: Draw did not act"
    assert js(page, "window.vtkiosk.stats.touches.feel") == 3
    # A keyboard (or assistive technology) still presses a button: a click with no pointer behind it.
    fingers.slide([(400, 300), (900, 300)], seconds=0.25)
    page.wait_for_function("window.vtkiosk.state.strokes.length === 1")
    page.focus("#undo")
    page.keyboard.press("Enter")
    page.wait_for_function("window.vtkiosk.state.strokes.length === 0")


def test_the_catalogue_switches_garment_and_names_the_fabric(touch, daemon):
    page, fingers = touch.page, touch.fingers
    thumbs = page.eval_on_selector_all("#garments img", "els => els.map(e => [e.src, e.naturalWidth])")
    assert len(thumbs) == 2 and all(w > 0 for _, w in thumbs)  # the bundles' own reference pictures
    assert thumbs[0][0].endswith("/api/bundles/denim-shorts/visual.png")
    # With nothing drawn, picking a garment lays out its own outline: ready to feel at once.
    n = js(page, "window.vtkiosk.stats.finals.length")
    page.tap("#garments button[data-id='test-coat']")
    shown = wait_settled(page, n)
    assert shown["status"] == "ok" and js(page, "window.vtkiosk.lastMeta.plan.panels[0].bundle") == "test-coat"
    assert js(page, "window.vtkiosk.state.mode") == "feel" and page.inner_text("#fabric-name") == "Test coat"
    assert page.inner_text("#hint") == js(page, "window.vtkiosk.config().texts.hint_feel")
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


def test_the_hint_says_what_a_touch_does(touch, daemon):
    """Feel with nothing to feel says so, and a touch there does nothing; Draw with a garment says a finger draws."""
    page, fingers = touch.page, touch.fingers
    texts = js(page, "window.vtkiosk.config().texts")
    page.tap("#mode-feel")
    page.wait_for_function("window.vtkiosk.state.mode === 'feel'")
    assert page.inner_text("#hint") == texts["hint_feel_empty"] and page.is_hidden("#fabric")
    requests = js(page, "window.vtkiosk.stats.requests")
    fingers.slide(ACROSS, seconds=0.3)
    wait_fingers_up(page)
    assert js(page, "window.vtkiosk.state.strokes") == [] and js(page, "window.vtkiosk.stats.requests") == requests
    page.tap("#mode-draw")
    page.wait_for_function("window.vtkiosk.state.mode === 'draw'")
    assert page.inner_text("#hint") == texts["hint_draw_empty"]
    draw_garment(page, fingers)
    assert page.inner_text("#hint") == texts["hint_feel"] and page.is_visible("#fabric")
    page.tap("#mode-draw")
    page.wait_for_function("window.vtkiosk.state.mode === 'draw'")
    assert page.inner_text("#hint") == texts["hint_draw"] and page.is_hidden("#fabric")


def test_a_pen_draws_while_a_finger_feels(touch, daemon):
    page, fingers = touch.page, touch.fingers
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
        fingers.pace()
    pen("mouseReleased", *path[-1])
    fingers.send("touchEnd", {})
    assert wait_settled(page, n)["status"] == "ok"
    assert js(page, "window.vtkiosk.stats.cancelled") == 0 and js(page, "window.vtkiosk.stats.touches.feel") == 0
    assert js(page, "window.vtkiosk.state.penSeen") and js(page, "window.vtkiosk.state.mode") == "feel"
    assert page.inner_text("#hint") == js(page, "window.vtkiosk.config().texts.hint_pen")
    before, requests = touch.quiet_counters(), js(page, "window.vtkiosk.stats.requests")
    fingers.slide(ACROSS, seconds=0.5)
    page.wait_for_function("window.vtkiosk.stats.touches.feel === 1")
    wait_fingers_up(page)
    assert js(page, "window.vtkiosk.stats.requests") == requests
    assert touch.quiet_counters() == before and len(js(page, "window.vtkiosk.state.strokes")) == 1
    # With the pen about, Draw still means a finger draws too: the pen's hint ("a finger feels") would be wrong.
    page.tap("#mode-draw")
    page.wait_for_function("window.vtkiosk.state.mode === 'draw'")
    assert page.inner_text("#hint") == js(page, "window.vtkiosk.config().texts.hint_draw")
    n = js(page, "window.vtkiosk.stats.finals.length")
    fingers.slide([(500, 300), (800, 500)], seconds=0.3)
    wait_settled(page, n)
    assert len(js(page, "window.vtkiosk.state.strokes")) == 2
    assert js(page, "window.vtkiosk.stats.touches.draw") == 2  # the pen's stroke, then the finger's


def test_idle_returns_to_the_attract_screen_with_the_drawing_and_friction_cleared(browser, tmp_path):
    bundle, trusted = make_bundle(tmp_path)
    d = start_daemon([bundle], trusted, page={"idle_timeout_s": 8.0, "attract_garment_s": 2.0})
    errors: list[str] = []
    try:
        screen = open_page(browser, d, errors)
        page, fingers = screen.page, screen.fingers
        shown = draw_garment(page, fingers)  # at once: the idle clock runs from the waking tap
        assert shown["status"] == "ok"
        assert wait_for(lambda: d.usage.sessions.value() == 1, 10.0)
        assert wait_for(lambda: d.device.emulator.active_frame.any(), 10.0)
        page.wait_for_function("window.vtkiosk.state.attract", timeout=30000)
        assert page.is_visible("#attract")
        assert js(page, "window.vtkiosk.state.strokes") == [] and js(page, "window.vtkiosk.state.mode") == "draw"
        page.wait_for_function("window.vtkiosk.shown.status === 'empty' && window.vtkiosk.stats.inFlight === 0",
                               timeout=15000)
        page.wait_for_function(BLANK_STAGE)
        assert wait_for(lambda: not d.device.emulator.active_frame.any(), 10.0)  # nothing left to feel
        assert wait_for(lambda: d.usage.idle_resets.value() == 1, 10.0)
        # The attract screen draws the catalogue's reference sketch (pixels appear on its canvas).
        page.wait_for_function("(() => { const c = document.getElementById('attract-art');"
                               " return c.width > 0 && c.getContext('2d').getImageData(0, 0, c.width, c.height)"
                               ".data.some((v, i) => i % 4 === 3 && v > 0); })()", polling=500, timeout=20000)
        fingers.tap(640, 400)
        page.wait_for_function("!window.vtkiosk.state.attract")
        assert page.inner_text("#hint") == js(page, "window.vtkiosk.config().texts.hint_draw_empty")
        assert wait_for(lambda: d.usage.sessions.value() == 2, 10.0)
        page.context.close()
    finally:
        d.stop()
    assert not errors, errors
