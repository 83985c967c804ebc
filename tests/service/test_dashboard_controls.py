"""The dashboard's metres and controls in a real headless Chromium (Debian's, driven by
Playwright): the colour bar's ticks in metres, the read-out under the pointer against the rendered
truth, the point cloud drawn, stereo settings changed through PATCH /config (If-Match, a refusal's
detail, a change made meanwhile), a recording started and stopped; the token from the URL, pasted,
or missing (the controls say why they are off); Swagger UI's Authorize button."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import httpx
import numpy as np
import pytest

from tests.helpers.browser import CHROMIUM, CHROMIUM_ARGS, needs_chromium
from tests.helpers.recordings import CALM_SUPERVISOR
from tests.helpers.service import AUTH, TOKEN, LiveServer, SmallRecording, StartServer
from tests.helpers.waiting import wait_for

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300), needs_chromium]

CALM = CALM_SUPERVISOR.model_dump()  # these tests are of the page, not of camera health
WAIT_MS = 60_000  # the machine may be busy: generous, never what the test measures


@contextmanager
def browser_page(errors: list[str]) -> Iterator[Any]:
    """A page of a fresh headless Chromium; console errors and page errors go to ``errors``."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1300})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            yield page
        finally:
            browser.close()


def text_of(page: Any, element: str) -> str:
    return str(page.text_content(f"#{element}") or "")


def wait_text(page: Any, element: str, needle: str, timeout_ms: float = WAIT_MS) -> str:
    page.wait_for_function(
        f"(document.getElementById({element!r}).textContent || '').includes({needle!r})", timeout=timeout_ms
    )
    return text_of(page, element)


def true_range(live: LiveServer, recording: SmallRecording) -> np.ndarray:
    """The rendered truth as range along each left pinhole pixel's ray (z times the ray's length)."""
    v = httpx.get(live.base_url + "/calibration").json()["vpc"]
    assert v["projection"] == "pinhole"
    cols, rows = np.meshgrid(np.arange(v["width"]), np.arange(v["height"]))
    length = np.sqrt(1 + ((cols - v["cx"]) / v["fx"]) ** 2 + ((rows - v["cy"]) / v["fy"]) ** 2)
    truth: np.ndarray = recording.gt_depth * length
    return truth


def steady_pixel(live: LiveServer, truth: np.ndarray) -> tuple[int, int]:
    """A pixel whose 7×7 neighbourhood has range within 1 % of the truth on the current frame,
    the one nearest the image's centre: where the read-out has one right answer."""
    from service.client import RigClient

    with RigClient(live.base_url) as client:
        measured = client.range().range
    good = np.isfinite(measured) & (np.abs(measured / truth - 1.0) < 0.01)
    h, w = good.shape
    best, best_d = None, np.inf
    for v in range(3, h - 3):
        for u in range(3, w - 3):
            if good[v - 3 : v + 4, u - 3 : u + 4].all():
                d = (u - w / 2) ** 2 + (v - h / 2) ** 2
                if d < best_d:
                    best, best_d = (u, v), d
    assert best is not None, "no steady pixel in the frame"
    return best


def hover(page: Any, element: str, u: int, v: int) -> None:
    """The pointer on pixel (u, v) of the image ``element``."""
    # Read in one go once decoded (a refreshed src has no size until its frame decodes), and the
    # box with it, just before the move: a reason line above the images that comes and goes (a
    # loaded machine's moment of degraded) moves them.
    geometry = (
        f"(() => {{ const e = document.getElementById({element!r}); const r = e.getBoundingClientRect();"
        " return e.naturalWidth > 0 ? [e.naturalWidth, e.naturalHeight, r.x, r.y, r.width, r.height]"
        " : null; })()"
    )
    width, height, x, y, box_w, box_h = page.wait_for_function(geometry, timeout=20_000).json_value()
    # Chromium reports whole CSS pixels for the pointer: pick the whole position whose pixel, by
    # the page's floor((x - left) / width * naturalWidth), is (u, v).
    page.mouse.move(_whole_position(x, box_w / width, u), _whole_position(y, box_h / height, v))


def _whole_position(start: float, scale: float, pixel: int) -> float:
    for x in range(math.floor(start + pixel * scale), math.ceil(start + (pixel + 1) * scale) + 1):
        if math.floor((x - start) / scale) == pixel:
            return float(x)
    return start + (pixel + 0.5) * scale  # a pixel narrower than a CSS pixel: its centre


def read_at(page: Any, u: int, v: int) -> tuple[int, int, str]:
    """The pixel the read-out shows and its line, once it shows one within a pixel of (u, v) (the
    pointer lands on whole CSS pixels, and the layout may move as captions fill in): the pointer
    put there again, from outside the image, until it does."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    pattern = r"/^\((\d+), (\d+)\): range/"
    near = (
        f"(() => {{ const m = (document.getElementById('readout').textContent || '').match({pattern});"
        f" return m && Math.abs(m[1] - {u}) <= 1 && Math.abs(m[2] - {v}) <= 1; }})()"
    )
    for _ in range(12):
        page.mouse.move(0, 0)
        hover(page, "depth-img", u, v)
        try:
            page.wait_for_function(near, timeout=5_000)
        except PlaywrightTimeout:
            continue
        line = text_of(page, "readout")
        shown = re.match(r"\((\d+), (\d+)\)", line)
        assert shown is not None, line
        return int(shown.group(1)), int(shown.group(2)), line
    raise AssertionError(f"the read-out never showed a pixel near ({u}, {v}): {text_of(page, 'readout')!r}")


def test_metres_cloud_and_controls_with_the_token_from_the_url(
    start_server: StartServer, small_recording: SmallRecording
) -> None:
    live = start_server(supervisor=CALM)
    errors: list[str] = []
    patches: list[dict[str, str]] = []
    with browser_page(errors) as page:
        page.on("request", lambda r: patches.append(r.headers) if r.method == "PATCH" else None)
        page.goto(f"{live.base_url}/?token={TOKEN}")
        page.wait_for_function("document.getElementById('depth-img').naturalWidth > 0", timeout=WAIT_MS)
        # The token left the address bar (and history) for the tab's session storage.
        assert page.url == live.base_url + "/"
        assert page.evaluate("sessionStorage.getItem('rig-api-token')") == TOKEN

        # The colour bar: the server's scale, its ticks in metres, the caption saying what the colours are.
        scale = httpx.get(live.base_url + "/depth/colorbar").json()
        page.wait_for_function(
            "document.querySelectorAll('#colorbar-ticks .tick').length > 0", timeout=WAIT_MS
        )
        ticks = page.eval_on_selector_all("#colorbar-ticks .tick", "els => els.map(e => e.textContent)")
        assert ticks == [t["label"] for t in scale["ticks"]] == ["0.3 m", "0.5 m", "1 m", "2 m", "5 m", "8 m"]
        assert "linear-gradient" in page.eval_on_selector("#colorbar", "e => e.style.background")
        caption = text_of(page, "depth-scale")
        assert "0.3 m (dark red)" in caption and "8 m (dark blue)" in caption and "log" in caption
        assert "near = red" not in (page.content())
        assert wait_text(page, "pair-info", "pinhole pair 320×240").startswith(
            "pinhole pair 320×240, 90° wide"
        )

        # The read-out under the pointer: near the rendered truth at a steady pixel.
        truth = true_range(live, small_recording)
        u, v = steady_pixel(live, truth)
        u, v, line = read_at(page, u, v)  # within a pixel of the steady one: steady too
        shown = float(re.search(r"range (\d+\.\d+) m", line).group(1))  # type: ignore[union-attr]
        print(f"read-out at ({u}, {v}): {line!r}; truth {truth[v, u]:.3f} m")
        assert shown == pytest.approx(float(truth[v, u]), rel=0.02)
        assert re.search(r"confidence (0|1)\.\d\d", line)

        # The point cloud view draws the cloud.
        page.locator("#cloud").scroll_into_view_if_needed()
        page.wait_for_function(
            "Number(document.getElementById('cloud').dataset.drawn || 0) > 1000", timeout=WAIT_MS
        )
        lit = page.eval_on_selector(
            "#cloud",
            "c => { const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;"
            " for (let i = 0; i < d.length; i += 4) if (d[i] || d[i + 1] || d[i + 2]) n++; return n; }",
        )
        assert lit > 2000, lit

        # Stereo settings: enabled, applied with If-Match, in effect in /config.
        assert page.is_hidden("#auth-note") and page.is_enabled("#stereo-apply")
        page.wait_for_function("document.getElementById('ctl-median').value === '5'", timeout=WAIT_MS)
        before = httpx.get(live.base_url + "/config")
        page.select_option("#ctl-median", "3")
        page.fill("#ctl-uniqueness_ratio", "15")
        page.click("#stereo-apply")
        wait_text(page, "config-status", "in effect")
        after = httpx.get(live.base_url + "/config").json()
        assert after["stereo"]["median"] == 3 and after["stereo"]["uniqueness_ratio"] == 15.0
        assert after["revision"] == before.json()["revision"] + 1
        assert patches[-1]["if-match"] == before.headers["etag"]
        assert patches[-1]["authorization"] == f"Bearer {TOKEN}"

        # A value the matcher refuses: the server's 422 detail, nothing changed.
        page.fill("#ctl-correlation_window_size", "8")
        page.click("#stereo-apply")
        status = wait_text(page, "config-status", "refused (422)")
        assert "correlation_window_size" in status and "odd" in status, status
        assert httpx.get(live.base_url + "/config").json()["revision"] == after["revision"]

        # Changed meanwhile by someone else: 412, the form reloads the settings in effect.
        r = httpx.patch(live.base_url + "/config", json={"stereo": {"median": 0}}, headers=AUTH)
        assert r.status_code == 200
        page.fill("#ctl-correlation_window_size", "9")
        page.click("#stereo-apply")
        wait_text(page, "config-status", "changed meanwhile")
        page.wait_for_function("document.getElementById('ctl-median').value === '0'", timeout=WAIT_MS)
        assert httpx.get(live.base_url + "/config").json()["stereo"]["correlation_window_size"] == 7

        # A recording started and stopped from the page.
        page.fill("#rec-name", "from-the-dashboard")
        page.click("#rec-start")
        wait_text(page, "rec-status", "recording from-the-dashboard")
        page.wait_for_function("!document.getElementById('rec-stop').disabled", timeout=WAIT_MS)
        wait_for(
            lambda: (httpx.get(live.base_url + "/health").json()["recording"] or {}).get("pairs", 0) >= 2,
            WAIT_MS / 1000,
            "two recorded pairs",
        )
        page.click("#rec-stop")
        stopped = wait_text(page, "rec-status", "stopped from-the-dashboard")
        listed = {r["name"]: r for r in httpx.get(live.base_url + "/recordings").json()}
        rec = listed["from-the-dashboard"]
        assert not rec["active"] and rec["pairs"] >= 2
        assert f"{rec['pairs']} pairs" in stopped
    assert errors == [] or all("422" in e or "412" in e for e in errors), errors


def test_without_a_token_in_the_page_the_controls_say_why_until_one_is_pasted(
    start_server: StartServer,
) -> None:
    live = start_server(supervisor=CALM)
    errors: list[str] = []
    with browser_page(errors) as page:
        page.goto(live.base_url + "/")
        note = wait_text(page, "auth-note", "this page has no API token")
        assert "?token=" in note
        for control in ("#stereo-apply", "#ctl-median", "#rec-start", "#rec-stop"):
            assert page.is_disabled(control), control
        assert page.is_visible("#token-form")
        page.fill("#token-input", TOKEN)
        page.click("#token-form button")
        page.wait_for_function("!document.getElementById('stereo-apply').disabled", timeout=WAIT_MS)
        assert page.is_hidden("#auth-note") and page.is_hidden("#token-form")
        # A wrong token: the server's 401 detail, and the controls off again.
        page.evaluate("sessionStorage.setItem('rig-api-token', 'wrong-token-0123456789')")
        page.reload()
        page.wait_for_function("!document.getElementById('stereo-apply').disabled", timeout=WAIT_MS)
        page.click("#stereo-apply")
        assert "invalid bearer token" in wait_text(page, "config-status", "refused (401)")
        assert page.is_disabled("#stereo-apply") and page.is_visible("#token-form")
    assert all("401" in e for e in errors), errors


def test_a_service_without_a_token_has_read_only_controls_that_say_so(start_server: StartServer) -> None:
    live = start_server(api_token=None, supervisor=CALM)
    errors: list[str] = []
    with browser_page(errors) as page:
        page.goto(f"{live.base_url}/?token={TOKEN}")  # a token the service does not have changes nothing
        note = wait_text(page, "auth-note", "this service has no API token")
        assert "RIG_API_TOKEN" in note and "rig serve --demo" in note
        for control in ("#stereo-apply", "#ctl-lr_check", "#rec-name", "#rec-start"):
            assert page.is_disabled(control), control
        assert page.is_hidden("#token-form")
    assert errors == []


def test_swagger_authorize_then_try_it_out(start_server: StartServer) -> None:
    live = start_server(supervisor=CALM)
    errors: list[str] = []
    with browser_page(errors) as page:
        page.goto(live.base_url + "/docs")
        page.wait_for_selector("button.authorize", timeout=WAIT_MS)
        op = page.locator("#operations-config-patch_config_config_patch")
        op.locator(".opblock-summary").first.click()
        op.locator(".try-out__btn").click()

        def execute() -> str:
            op.locator("textarea.body-param__text").fill('{"stereo": {"median": 3}}')
            op.locator("button.execute").click()
            cell = op.locator(".live-responses-table tbody .response-col_status").first
            cell.wait_for(timeout=WAIT_MS)
            return str(cell.text_content()).strip()

        assert execute() == "401"
        page.click("button.authorize")
        page.fill(".auth-container input", TOKEN)
        page.click(".auth-btn-wrapper button.authorize")
        page.click(".auth-btn-wrapper button.btn-done")
        op.locator("button.btn-clear").click()
        assert execute() == "200"
    assert httpx.get(live.base_url + "/config").json()["stereo"]["median"] == 3
    assert all("401" in e for e in errors), errors
