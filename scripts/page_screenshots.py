"""Screenshots of the shopper's page for docs/img: the attract screen, drawing, and feeling beside the friction
frame the emulated device committed (`GET /api/debug/device-frame`).

    .venv/bin/python scripts/page_screenshots.py --bundle out/demo/bundles/<key>/demo.vtb \\
        --trusted-keys out/demo/trusted-keys --out docs/img

A real daemon on 127.0.0.1 with the emulated haptic device and headless Chromium (touch emulation; fingers sent
through the DevTools protocol as a touch panel sends them). PNGs are quantized to 256 colours to stay small.
"""
from __future__ import annotations

import argparse
import base64
import io
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from kiosk.service.config import config_from_mapping  # noqa: E402
from kiosk.service.daemon import KioskDaemon  # noqa: E402

VIEW = (1280, 800)
# A pair of shorts drawn with one finger (screen px), and a pocket line drawn later.
OUTLINE = [(470, 190), (810, 190), (850, 620), (680, 620), (640, 360), (600, 620), (430, 620), (470, 190)]
POCKET = [(500, 250), (520, 300), (560, 330), (610, 345)]


def compact_png(png: bytes, out: Path, width: int) -> None:
    img = Image.open(io.BytesIO(png)).convert("RGB")
    img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(out, optimize=True)
    print(f"wrote {out} ({out.stat().st_size // 1024} KiB)")


class Fingers:
    def __init__(self, page):
        self.page, self.cdp = page, page.context.new_cdp_session(page)

    def send(self, kind, points):
        self.cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": [
            {"id": i, "x": float(x), "y": float(y)} for i, (x, y) in points.items()]})

    def slide(self, points, seconds, end=True):
        pts = np.asarray(points, float)
        seg = np.r_[0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
        at = np.linspace(0, seg[-1], max(2, int(seconds * 60)))
        path = list(zip(np.interp(at, seg, pts[:, 0]), np.interp(at, seg, pts[:, 1])))
        self.send("touchStart", {1: path[0]})
        for p in path[1:]:
            self.send("touchMove", {1: p})
            self.page.wait_for_timeout(16)
        if end:
            self.send("touchEnd", {})


def settle(page, finals: int) -> None:
    page.wait_for_function(f"window.vtkiosk.stats.finals.length > {finals}", timeout=60000)
    page.wait_for_function("(() => { const m = window.vtkiosk.lastMeta;"
                           " return m.mode === 'refine' || (m.mode === 'final' && !m.refine); })()", timeout=60000)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", type=Path, action="append", required=True)
    ap.add_argument("--trusted-keys", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("docs/img"))
    ap.add_argument("--width", type=int, default=960, help="width of the saved PNGs (px)")
    args = ap.parse_args(argv)
    from playwright.sync_api import sync_playwright

    args.out.mkdir(parents=True, exist_ok=True)
    state = Path(tempfile.mkdtemp(prefix="vtkiosk-shots-"))
    cfg = config_from_mapping({"server": {"port": 0}, "bundles": [str(b) for b in args.bundle],
                               "store": {"trusted_keys": str(args.trusted_keys)}, "state_dir": str(state),
                               "device": {"type": "emulated"}, "page": {"attract_garment_s": 6.0}})
    d = KioskDaemon(cfg)
    d.start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True)
            ctx = browser.new_context(viewport=dict(zip(("width", "height"), VIEW)), device_scale_factor=1,
                                      has_touch=True)
            page = ctx.new_page()
            page.goto(d.server.url)
            page.evaluate("window.vtkiosk.ready")
            page.wait_for_timeout(4300)  # the attract screen filling in its first garment
            compact_png(page.screenshot(), args.out / "kiosk-attract.png", args.width)

            fingers = Fingers(page)
            fingers.send("touchStart", {1: (640, 400)})
            fingers.send("touchEnd", {})
            page.wait_for_function("!window.vtkiosk.state.attract")
            n = page.evaluate("window.vtkiosk.stats.finals.length")
            fingers.slide(OUTLINE, 1.5)
            settle(page, n)
            page.tap("#mode-draw")
            fingers.slide(POCKET, 0.5, end=False)  # the finger still down: the preview follows it
            page.wait_for_timeout(600)
            compact_png(page.screenshot(), args.out / "kiosk-drawing.png", args.width)
            n = page.evaluate("window.vtkiosk.stats.finals.length")
            fingers.send("touchEnd", {})
            settle(page, n)

            page.tap("#mode-feel")
            page.wait_for_timeout(4500)  # the toast fades
            frame = page.evaluate("window.vtkiosk.shown.device_frame")
            d.wait_commit(frame, 10.0)
            fingers.slide([(560, 300), (700, 420), (620, 470)], 1.0, end=False)
            page.wait_for_timeout(200)
            shot = page.screenshot()
            with urllib.request.urlopen(d.server.url + "api/debug/device-frame", timeout=10) as r:
                device = r.read()
            fingers.send("touchEnd", {})
            side = ctx.new_page()
            side.set_viewport_size({"width": 2 * VIEW[0] + 60, "height": VIEW[1] + 90})
            side.set_content(_side_by_side(shot, device))
            compact_png(side.screenshot(), args.out / "kiosk-feeling.png", 2 * args.width)
            browser.close()
    finally:
        d.stop()
        time.sleep(0.1)
    return 0


def _side_by_side(page_png: bytes, device_png: bytes) -> str:
    def url(b: bytes) -> str:
        return "data:image/png;base64," + base64.b64encode(b).decode()

    cap = "font: 26px system-ui, sans-serif; color: #333; margin: 0 0 10px 0"
    return (f"<body style='margin: 20px; background: #fff; display: flex; gap: 20px'>"
            f"<figure style='margin: 0'><p style='{cap}'>The page (Feel mode, a finger on the garment)</p>"
            f"<img src='{url(page_png)}' style='display: block; outline: 1px solid #999'></figure>"
            f"<figure style='margin: 0'><p style='{cap}'>The friction frame committed on the haptic screen "
            f"(GET /api/debug/device-frame)</p>"
            f"<img src='{url(device_png)}' style='display: block; outline: 1px solid #999'></figure></body>")


if __name__ == "__main__":
    raise SystemExit(main())
