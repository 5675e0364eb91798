"""The kiosk page in headless Chromium (Playwright) against a real daemon serving a bundle made by our own trainer
and exporter, with the emulated haptic device: strokes drawn with the mouse produce a synthesized garment where
they were drawn, and the device commits the matching friction frame exactly under it. The touch-screen behaviour
(Draw/Feel modes, second fingers, taps, the store loop) is in test_page_touch.py."""
from __future__ import annotations


import numpy as np
import pytest

from tests.kiosk.daemon_fixtures import demo_and_coat_daemon, wait_for

pytestmark = [pytest.mark.browser, pytest.mark.slow]
pytest.importorskip("playwright.sync_api")

OUTLINE_A = [(380, 220), (900, 220), (900, 420)]          # first stroke: the outline stays open
OUTLINE_B = [(900, 420), (900, 640), (380, 640), (380, 222)]  # second stroke closes it
DETAIL = [(520, 330), (760, 330)]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = demo_and_coat_daemon(tmp_path_factory, "page")
    yield d
    d.stop()


@pytest.fixture()
def page(browser, daemon):
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, device_scale_factor=1)
    pg = ctx.new_page()
    errors = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    open_page(pg, daemon.server.url)
    yield pg
    ctx.close()
    assert not errors, errors


def open_page(page, url: str) -> None:
    """Load the page and wake it from its attract screen with a touch, as a shopper does."""
    page.goto(url)
    page.evaluate("window.vtkiosk.ready")
    assert page.is_visible("#attract")
    page.mouse.click(640, 400)
    page.wait_for_function("!window.vtkiosk.state.attract")


def draw(page, points, steps=12):
    page.mouse.move(*points[0])
    page.mouse.down()
    for a, b in zip(points, points[1:]):
        for t in np.linspace(0, 1, steps + 1)[1:]:
            page.mouse.move(a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t)
            page.wait_for_timeout(8)
    page.mouse.up()


def finals(page) -> int:
    return page.evaluate("window.vtkiosk.stats.finals.length")


def wait_final(page, before: int) -> dict:
    """Wait for the stroke end's answer and, when the daemon answered quickly, for its full-resolution refinement."""
    page.wait_for_function(f"window.vtkiosk.stats.finals.length > {before}", timeout=30000)
    page.wait_for_function("(() => { const m = window.vtkiosk.lastMeta;"
                           " return m.mode === 'refine' || (m.mode === 'final' && !m.refine); })()", timeout=30000)
    return page.evaluate("window.vtkiosk.shown")


def canvas_rgba(page, x, y) -> list[int]:
    return page.evaluate(f"Array.from(document.getElementById('stage').getContext('2d')"
                         f".getImageData({x}, {y}, 1, 1).data)")


def test_drawing_shows_the_garment_and_the_device_feels_it_underneath(page, daemon):
    n = finals(page)
    draw(page, OUTLINE_A)
    open_shown = wait_final(page, n)
    assert open_shown["status"] == "empty"  # an open outline: nothing to synthesise yet
    n = finals(page)
    draw(page, OUTLINE_B)
    shown = wait_final(page, n)
    assert shown["status"] == "ok" and shown["mode"] == "refine"
    # The outline closed into a garment: the page switched to Feel mode by itself and says so.
    texts = page.evaluate("window.vtkiosk.config().texts")
    assert page.evaluate("window.vtkiosk.state.mode") == "feel"
    assert page.inner_text("#hint") == texts["hint_feel"]
    assert page.inner_text("#fabric-name") == "Demo denim shorts" and page.is_visible("#fabric")
    assert page.evaluate("window.vtkiosk.stats.previews.length") > 0  # live preview while drawing
    assert page.evaluate("window.vtkiosk.stats.refines.length") == 1  # quick answer, then full resolution
    meta = page.evaluate("window.vtkiosk.lastMeta")
    assert meta["plan"]["panels"][0]["graph"] == "full" and meta["plan"]["panels"][0]["bundle"] == "denim-shorts"
    x, y, w, h = shown["visual"]
    # The synthesized garment is where it was drawn: its region covers the outline, and inside the outline the
    # canvas shows the model's pixels (not the page background).
    assert x <= 380 and y <= 220 and x + w >= 900 and y + h >= 640
    inside = canvas_rgba(page, 640, 520)
    assert inside[:3] != [244, 241, 234] and inside[3] == 255
    assert canvas_rgba(page, 1200, 100)[3] == 0  # outside the visual nothing is painted
    # The friction frame the emulated device committed equals the daemon's friction map at the rectangle the page
    # reported, and nothing is felt elsewhere.
    commit = daemon.wait_commit(shown["device_frame"], 10.0)
    assert commit is not None and commit.status == "committed"
    assert shown["friction"] == [max(x, 0), max(y, 0), min(x + w, 1280) - max(x, 0), min(y + h, 800) - max(y, 0)]
    fx, fy, fw, fh = shown["friction"]
    texture = daemon.frames.textures["main"].texture()
    frame = daemon.device.emulator.active_frame
    np.testing.assert_array_equal(frame[fy:fy + fh, fx:fx + fw], texture.pixels)
    outside = frame.copy()
    outside[fy:fy + fh, fx:fx + fw] = 0
    assert not outside.any() and texture.pixels.any()
    # The daemon rasterized exactly the strokes the page drew (screen pixels).
    strokes = page.evaluate("window.vtkiosk.state.strokes")
    assert len(strokes) == 2 and strokes[0][0] == [380, 220] and strokes[1][-1] == [380, 222]


def test_undo_clear_reference_and_garment_picker(page, daemon):
    n = finals(page)
    draw(page, OUTLINE_A[:2] + [(900, 640), (380, 640), (380, 222)])
    first = wait_final(page, n)
    assert first["status"] == "ok", first
    assert page.evaluate("window.vtkiosk.state.mode") == "feel"  # a mouse follows the toggle like a finger
    page.click("#mode-draw")
    assert page.inner_text("#hint") == page.evaluate("window.vtkiosk.config().texts.hint_draw")
    n = finals(page)
    draw(page, DETAIL)
    edited = wait_final(page, n)
    assert edited["status"] == "ok"
    n = finals(page)
    page.click("#undo")
    undone = wait_final(page, n)
    assert page.evaluate("window.vtkiosk.lastMeta.plan.panels[0].reason") == "all from cache"
    assert undone["visual"] == first["visual"]
    # Another garment from the picker: same drawing, the other bundle's model.
    n = finals(page)
    page.click("#garments button[data-id='test-coat']")
    other = wait_final(page, n)
    assert page.evaluate("window.vtkiosk.lastMeta.plan.panels[0].bundle") == "test-coat" and other["status"] == "ok"
    # Clear: no visual, no friction.
    n = finals(page)
    page.click("#clear")
    cleared = wait_final(page, n)
    assert cleared["status"] == "empty" and cleared["visual"] is None
    assert daemon.wait_commit(cleared["device_frame"], 10.0).status == "committed"
    assert not daemon.device.emulator.active_frame.any()
    # Start from the garment's own sketch: the reference sketch is laid out and synthesised.
    n = finals(page)
    page.click("#garments button[data-id='denim-shorts']")
    wait_final(page, n)
    page.click("#mode-draw")  # picking on an empty canvas laid the garment's outline and switched to Feel
    n = finals(page)
    page.click("#reference")
    ref = wait_final(page, n)
    meta = page.evaluate("window.vtkiosk.lastMeta")
    assert meta["panels"][0]["reference"]["rect"] and ref["status"] == "ok"
    assert wait_for(lambda: daemon.device.emulator.active_frame.any(), 10.0)


def test_a_lost_device_shows_a_notice_and_drawing_goes_on(page, daemon):
    daemon.handle_control({"op": "debug.unplug"})
    try:
        assert wait_for(lambda: not daemon.device.up, 5.0)
        n = finals(page)
        draw(page, OUTLINE_A[:2] + [(900, 640), (380, 640), (380, 222)])
        shown = wait_final(page, n)
        assert shown["status"] == "ok"  # the visual still comes
        page.wait_for_function("!document.getElementById('notice').hidden", timeout=10000)
        assert "visual only" in page.inner_text("#notice")
    finally:
        daemon.handle_control({"op": "debug.replug"})
    assert wait_for(lambda: daemon.device.up, 10.0)
    page.wait_for_function("document.getElementById('notice').hidden", timeout=10000)
