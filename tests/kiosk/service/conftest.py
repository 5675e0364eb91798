"""What the kiosk page tests share: one headless chromium a test module (a launch costs about a second)."""
from __future__ import annotations

import pytest

from tests.kiosk.browser import headless_chromium


@pytest.fixture(scope="module")
def browser():
    playwright = pytest.importorskip("playwright.sync_api")
    with playwright.sync_playwright() as p:
        b = headless_chromium(p)
        yield b
        b.close()
