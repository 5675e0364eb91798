"""`vtkiosk study export-page`: a visual study as one self-contained HTML file, for participants who are not at
the kiosk (the paper ran its visual study on Mechanical Turk).

Everything the page needs is inside the file: each participant code's schedule (made here, by the same generator
the kiosk uses), every (condition, garment) visual output as a PNG data URI (rendered now through the real kiosk
daemon and ONNX Runtime, exactly as the kiosk would show it), the consent text and the optional questions. The page
writes the kiosk's own study-log records (the same JSON-lines format, sequence numbers and SHA-256 checksums) into
the browser's storage as it goes, so a reload resumes the session; at the end the participant downloads the log
(and, with `--post-url`, every record is also POSTed as it is written). `vtkiosk study report --log ...` pools the
downloaded logs like several kiosks' logs: the config hash in every session record must match.
"""
from __future__ import annotations

import base64
import json
import re
import tempfile
from pathlib import Path

from kiosk.bundle.durable import atomic_write
from kiosk.contract.errors import KioskError
from kiosk.study.bundles import open_study_bundles
from kiosk.study.config import StudyConfig, load_study_config
from kiosk.study.log import FORMAT, FORMAT_VERSION, software_version
from kiosk.study.records import session_payload
from kiosk.study.schedule import SIDES, Trial, make_schedule
from kiosk.study.service import study_layout, trial_scene

HERE = Path(__file__).resolve().parent
STATIC = HERE.parent / "static"
SCREENS = ("<!-- shared screens:", "<!-- end of shared screens -->")


class WebPageError(KioskError):
    """A study that cannot be exported as a web page; the message says why."""


def _render_visuals(config: StudyConfig, bundles) -> tuple[dict, dict, tuple[int, int]]:
    """(condition|garment -> data URI, condition|garment -> rect, screen) through the real daemon."""
    from kiosk.service.daemon import KioskDaemon
    from kiosk.study.runtime import DaemonRenderer, kiosk_config_for, study_sources

    images: dict[str, str] = {}
    rects: dict[str, list[int]] = {}
    with tempfile.TemporaryDirectory(prefix="vtkiosk-page-") as tmp:
        kcfg = kiosk_config_for(config, bundles, port=0, control_socket=Path(tmp) / "export.sock", device="emulated")
        daemon = KioskDaemon(kcfg, bundle_sources=study_sources(kcfg, bundles, "visual"))
        daemon.start()
        try:
            renderer = DaemonRenderer(daemon, bundles, "visual")
            screen = renderer.screen()
            layout = study_layout(screen)
            for garment in config.garments:
                for c in config.comparisons:
                    if f"{c}|{garment}" in images:
                        continue
                    trial = Trial(0, "test", garment, c, config.reference, c, "full")
                    rendered = renderer.render(trial_scene(config, bundles, layout, trial))
                    for side in SIDES:
                        key = f"{trial.condition_on(side)}|{garment}"
                        images[key] = "data:image/png;base64," + base64.b64encode(rendered.images[side]).decode()
                        # the rectangle is kept relative to its panel: the page has the same two panels
                        rx, ry, rw, rh = rendered.placements[side]["rect"]
                        px, py, _, _ = layout.panels[side]
                        rects[key] = [rx - px, ry - py, rw, rh]
        finally:
            daemon.stop()
    return images, rects, screen


def export_page(config_path: str | Path, out: str | Path, *, participants: list[str] | None = None,
                post_url: str | None = None) -> int:
    """Write the page; return the number of participant codes it accepts."""
    config = load_study_config(config_path)
    if config.kind != "visual":
        raise WebPageError("only a visual study can run as a web page (a haptic study needs the haptic screen)")
    codes = list(participants or config.participants.codes)
    if not codes:
        raise WebPageError("give the participant codes the page accepts (--participant P01 ...), or list them in "
                           "the config's participants.codes")
    for code in codes:
        config.participants.check(code)
    if len(set(codes)) != len(codes):
        raise WebPageError("a participant code is given twice")
    if post_url is not None and not post_url.startswith(("https://", "http://127.0.0.1", "http://localhost")):
        raise WebPageError("--post-url must be an https:// address (or a loopback http:// one for testing)")
    bundles = open_study_bundles(config)
    try:
        images, rects, screen = _render_visuals(config, bundles)
        identities = bundles.identities()
    finally:
        bundles.close()
    layout = study_layout(screen)
    sessions = {}
    for code in codes:
        schedule = make_schedule(config, code, 1)
        payload = session_payload(config, schedule, identities, software=_software(),
                                  stamp={"wall": None, "mono": None, "boot_id": None})
        payload["kiosk"] = "web"
        sessions[code] = payload
    data = {
        "format": FORMAT, "version": FORMAT_VERSION, "study_id": config.id, "software": _software(),
        "question": config.question, "instructions": config.instructions, "time_limit_s": config.time_limit_s,
        "timeout_notice_s": config.timeout_notice_s, "reference": config.reference,
        "consent": None if config.consent is None else {"version": config.consent.version,
                                                        "text": config.consent.text,
                                                        "sha256": config.consent.sha256},
        "demographics": {k: list(v) for k, v in (config.demographics or {}).items()} or None,
        "sessions": sessions, "images": images, "rects": rects, "post_url": post_url,
        "layout": {"screen": list(layout.screen), "panels": layout.panels, "buttons": layout.buttons,
                   "question": list(layout.question)},
    }
    blob = json.dumps(data, separators=(",", ":")).replace("<", "\\u003c")    # no `</script>`, no `<!--`
    html = _fill((HERE / "webpage.html").read_text(), {
        "/*STYLE*/": (STATIC / "study.css").read_text(), "<!--SCREENS-->": _shared_screens(),
        "/*DATA*/": blob, "/*ABOUT*/": (STATIC / "study-about.js").read_text(),
        "/*SCRIPT*/": (HERE / "webpage.js").read_text()})
    atomic_write(Path(out), html.encode("utf-8"))
    return len(codes)


def _fill(template: str, parts: dict[str, str]) -> str:
    """One pass, so a marker inside inserted text (a consent text that quotes `/*SCRIPT*/`) stays text."""
    pattern = "|".join(re.escape(marker) for marker in parts)
    return re.sub(pattern, lambda m: parts[m.group(0)], template)


def _shared_screens() -> str:
    """The consent and optional-questions screens as the kiosk's study page has them, so the two never drift."""
    page = (STATIC / "study.html").read_text()
    start, end = page.index(SCREENS[0]), page.index(SCREENS[1])
    return page[page.index("\n", start) + 1:end]


def _software() -> str:
    return software_version() + " (web page)"
