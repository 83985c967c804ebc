"""Debian's chromium driven by Playwright, for the pages the service serves."""

from __future__ import annotations

import os

import pytest

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "needs_chromium"]

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
