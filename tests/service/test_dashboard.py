"""The dashboard in a real headless Chromium (Debian's, driven by Playwright): it loads, its
images refresh, the footprint is drawn, the camera table has the counter table's columns, broken
frames are counted and a stopped camera shows up as unavailable; on a ring of four cameras it
shows the 360° panorama too (hidden on two cameras)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.helpers.browser import dashboard_page, needs_chromium, wait_for_image_width
from tests.helpers.recordings import CALM_SUPERVISOR
from tests.helpers.rings import ring_service_settings, write_small_ring
from tests.helpers.service import TOKEN, LiveServer, StartServer

pytestmark = [pytest.mark.browser, pytest.mark.timeout(180), needs_chromium]


def test_dashboard_live_in_chromium(start_server: StartServer, tmp_path: Path) -> None:
    # The disconnect below is reported by the camera's read; the watchdog is kept out of it (a
    # replay stalled by the busy machine would make both cameras unavailable for a moment).
    live = start_server(supervisor=CALM_SUPERVISOR.model_dump())
    console_errors: list[str] = []
    with dashboard_page(live.base_url, console_errors) as page:
        page.wait_for_function("document.getElementById('status').textContent === 'ok'", timeout=20_000)

        # Images load and refresh: the depth image's src follows new frames.
        page.wait_for_function("document.getElementById('depth-img').naturalWidth > 0", timeout=20_000)
        first = page.get_attribute("#depth-img", "src")
        page.wait_for_function(
            f"document.getElementById('depth-img').getAttribute('src') !== {first!r}", timeout=20_000
        )
        for img in ("confidence-img", "vpc-left", "vpc-right", "raw-left", "raw-right"):
            page.wait_for_function(f"document.getElementById('{img}').naturalWidth > 0", timeout=20_000)
        for img, width in (("depth-img", 320), ("confidence-img", 320), ("raw-left", 640)):
            wait_for_image_width(page, img, width)
        assert not page.is_visible("#panorama-row")  # two cameras: no panorama

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
        columns = list(dict.fromkeys(c["column"] for c in counters if c["group"] == "camera" and c["column"]))
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
    assert console_errors == []


def test_dashboard_shows_the_panorama_of_a_ring(lut_cache: Path, tmp_path: Path) -> None:
    rec = write_small_ring(tmp_path / "ring", frames=2)
    live = LiveServer(ring_service_settings(rec, tmp_path, lut_cache)).start()
    console_errors: list[str] = []
    try:
        live.wait_ready(120.0)
        info = live.client.get("/panorama/info").json()
        with dashboard_page(live.base_url, console_errors) as page:
            # Read in one go once loaded: a newer set's image may be loading (its size 0 until then).
            loaded = (
                "(() => { const e = document.getElementById('panorama-img');"
                " return e.complete && e.naturalWidth > 0 ? [e.naturalWidth, e.naturalHeight] : null; })()"
            )
            size = page.wait_for_function(loaded, timeout=30_000).json_value()
            assert page.is_visible("#panorama-row")
            assert size == [info["width"], info["height"]]
            first = page.get_attribute("#panorama-img", "src")
            assert first is not None and first.startswith("/panorama/colorized?seq=")
            page.wait_for_function(  # it follows new sets
                f"document.getElementById('panorama-img').getAttribute('src') !== {first!r}",
                timeout=30_000,
            )
            assert "360°" in (page.text_content("#panorama-row figcaption") or "")
            # The camera table has a row per camera of the ring, with its state and figures.
            page.wait_for_function(
                "document.getElementById('cam-cam4-fps') !== null"
                " && Number(document.getElementById('cam-cam4-fps').textContent) > 0",
                timeout=20_000,
            )
            rows = page.eval_on_selector_all(
                "#health-body tr", "rows => rows.map(r => [r.cells[0].textContent, r.cells[1].textContent])"
            )
            assert rows == [[f"cam{k}", "available"] for k in range(1, 5)]
            page.screenshot(path=str(tmp_path / "dashboard-ring.png"), full_page=True)
    finally:
        live.stop()
    assert console_errors == []
