"""The project's one browser for page tests: Debian's chromium, headless under Playwright (nothing is downloaded)."""
from __future__ import annotations

CHROMIUM = "/usr/bin/chromium"


def headless_chromium(pw, **launch):
    """`pw` is a started `playwright.sync_api` Playwright; returns its launched Browser."""
    return pw.chromium.launch(executable_path=CHROMIUM, headless=True, **launch)
