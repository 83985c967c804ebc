"""Debian's chromium driven by Playwright, for the pages the service serves."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from playwright.sync_api import Page

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "dashboard_page", "needs_chromium"]

CHROMIUM = os.environ.get("RIG_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]

#: A test that drives the browser skips, saying why, where chromium is missing (fails in CI:
#: tests/helpers/inputs.py).
needs_chromium = pytest.mark.needs_tool(CHROMIUM, "Debian's chromium: apt-get install chromium; .ci/run does")


@contextlib.contextmanager
def dashboard_page(base_url: str, console_errors: list[str]) -> Iterator[Page]:
    """A 1400x1100 page of chromium opened at ``base_url``'s dashboard, the messages of its
    console's errors appended to ``console_errors``; the browser closed at the end."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1100})
            page.on("console", lambda m: console_errors.append(m.text) if m.type == "error" else None)
            page.goto(base_url + "/")
            yield page
        finally:
            browser.close()
