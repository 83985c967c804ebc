"""Debian's chromium driven by Playwright, for the pages the service serves."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from playwright.sync_api import Page

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "dashboard_page", "needs_chromium", "wait_for_image_width"]

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


def wait_for_image_width(page: Page, element_id: str, width: int, timeout_ms: float = 20_000) -> None:
    """Until the ``<img>`` ``element_id`` shows an image ``width`` pixels wide (a timeout error
    otherwise). Waited for, not read once: an image whose src the page just refreshed has no size
    until the new frame decodes, and a loaded machine can be caught between the two."""
    page.wait_for_function(
        f"document.getElementById('{element_id}').naturalWidth === {width}", timeout=timeout_ms
    )
