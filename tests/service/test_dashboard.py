"""The dashboard in a real headless Chromium (Debian's, driven by Playwright): it loads, its
images refresh, the footprint is drawn, the camera table has the counter table's columns, broken
frames are counted and a stopped camera shows up as unavailable."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.helpers.browser import CHROMIUM, CHROMIUM_ARGS, needs_chromium
from tests.helpers.service import TOKEN, StartServer

pytestmark = [pytest.mark.browser, pytest.mark.timeout(180), needs_chromium]


def test_dashboard_live_in_chromium(start_server: StartServer, tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    live = start_server()
    console_errors: list[str] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1100})
            page.on("console", lambda m: console_errors.append(m.text) if m.type == "error" else None)
            page.goto(live.base_url + "/")
            page.wait_for_function("document.getElementById('status').textContent === 'ok'", timeout=20_000)

            # Images load and refresh: the depth image's src follows new frames.
            page.wait_for_function("document.getElementById('depth-img').naturalWidth > 0", timeout=20_000)
            first = page.get_attribute("#depth-img", "src")
            page.wait_for_function(
                f"document.getElementById('depth-img').getAttribute('src') !== {first!r}", timeout=20_000
            )
            for img in ("confidence-img", "vpc-left", "vpc-right", "raw-left", "raw-right"):
                page.wait_for_function(f"document.getElementById('{img}').naturalWidth > 0", timeout=20_000)
            assert page.eval_on_selector("#depth-img", "e => e.naturalWidth") == 320
            assert page.eval_on_selector("#confidence-img", "e => e.naturalWidth") == 320
            assert page.eval_on_selector("#raw-left", "e => e.naturalWidth") == 640

            # The VPC footprint is drawn on the fisheye overlay (canvas at the fisheye's size).
            page.wait_for_function("document.getElementById('overlay-left').width === 640", timeout=20_000)
            drawn = page.eval_on_selector(
                "#overlay-left",
                "c => { const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
                " let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++; return n; }",
            )
            assert drawn > 500
            assert page.text_content("#cam-left-state") == "available"
            assert float(page.text_content("#fps") or "0") > 0

            # The camera table's figure columns are the counter table's (GET /counters), in its order.
            counters = httpx.get(live.base_url + "/counters").json()
            columns = list(
                dict.fromkeys(c["column"] for c in counters if c["group"] == "camera" and c["column"])
            )
            page.wait_for_function("document.getElementById('cam-left-fps') !== null", timeout=20_000)
            headers = page.eval_on_selector_all("#health-head th", "els => els.map(e => e.textContent)")
            assert headers == ["camera", "state", "reason", *columns]
            assert {"fps", "dropped", "broken"} <= set(columns)
            title = page.get_attribute("#col-broken", "title") or ""
            assert title.startswith("frames_corrupt + frames_undecodable\nframes_corrupt: frames the camera")
            page.wait_for_function(
                "Number(document.getElementById('cam-left-fps').textContent) > 0", timeout=20_000
            )
            assert re.fullmatch(r"\d+\.\d", page.text_content("#cam-left-fps") or "")  # digits: 1
            assert re.fullmatch(r"\d+", page.text_content("#cam-left-dropped") or "")
            page.screenshot(path=str(tmp_path / "dashboard-ok.png"), full_page=True)

            def inject_until(camera: str, fault: dict[str, Any], element: str, text: str) -> None:
                """Inject ``fault`` over the API and wait until the page shows ``text`` there."""
                r = httpx.post(
                    f"{live.base_url}/cameras/{camera}/faults",
                    json={"fault": fault},
                    headers={"Authorization": f"Bearer {TOKEN}"},
                )
                assert r.status_code == 202
                page.wait_for_function(
                    f"document.getElementById({element!r}).textContent === {text!r}", timeout=20_000
                )

            # Three broken frames from the right camera: counted in its row. At the test's 10 fps they
            # are 0.3 s without a good frame, which the 0.3 s watchdog may call a stall; either way
            # the camera is available again once good frames flow.
            assert page.text_content("#cam-right-broken") == "0"
            inject_until("right", {"kind": "corrupt", "count": 3}, "cam-right-broken", "3")
            page.wait_for_function(
                "document.getElementById('cam-right-state').textContent === 'available'", timeout=20_000
            )

            # Stop the left camera: the page says so, with the reason.
            inject_until("left", {"kind": "disconnect", "duration_s": 120}, "cam-left-state", "unavailable")
            assert "disconnected" in (page.text_content("#cam-left-reason") or "")
            assert page.is_visible("#banner-left") and not page.is_visible("#banner-right")
            assert page.text_content("#cam-right-state") == "available"
            assert page.text_content("#status") == "degraded"
            shot = tmp_path / "dashboard-left-camera-down.png"
            page.screenshot(path=str(shot), full_page=True)
            assert shot.stat().st_size > 10_000
            print(f"dashboard screenshots: {tmp_path}")
        finally:
            browser.close()
    assert console_errors == []
