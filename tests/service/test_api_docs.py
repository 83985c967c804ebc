"""``/docs`` works on a robot without internet: the page names only the service's own assets,
and a real Chromium with every request off loopback refused shows the operations. No
``/redoc`` (ReDoc's bundle fetches its logo from a CDN)."""

from __future__ import annotations

import re
from urllib.parse import urlparse

import pytest

from tests.helpers.browser import CHROMIUM, CHROMIUM_ARGS, needs_chromium
from tests.helpers.service import StartApp, StartServer


def test_docs_page_loads_everything_from_the_service(start_app: StartApp) -> None:
    live = start_app(ready=False)
    html = live.client.get("/docs").text
    urls = re.findall(r"""(?:src|href|url)\s*[=:(]\s*['"]([^'"]+)['"]""", html)
    assert urls and all(u.startswith("/") for u in urls), urls  # no CDN, no fonts from outside
    assert "/openapi.json" in urls
    for url in urls:
        r = live.client.get(url)
        assert r.status_code == 200 and len(r.content) > 100, url
    kinds = {u.rsplit(".", 1)[-1]: live.client.get(u).headers["content-type"] for u in urls}
    assert kinds["js"].startswith("text/javascript") and kinds["png"] == "image/png"
    assert live.client.get("/docs-assets/../pyproject.toml").status_code == 404
    assert live.client.get("/redoc").status_code == 404


@pytest.mark.browser
@needs_chromium
def test_docs_page_shows_the_operations_offline_in_chromium(start_server: StartServer) -> None:
    from playwright.sync_api import Route, sync_playwright

    live = start_server(ready=False)
    refused: list[str] = []
    console_errors: list[str] = []

    def loopback_only(route: Route) -> None:
        if urlparse(route.request.url).hostname == "127.0.0.1":
            route.continue_()
        else:
            refused.append(route.request.url)
            route.abort("internetdisconnected")

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            tab = browser.new_page()
            tab.on("console", lambda m: console_errors.append(m.text) if m.type == "error" else None)
            tab.route("**/*", loopback_only)
            tab.goto(live.base_url + "/docs")
            shown = tab.locator("#operations-depth-get_depth_depth_get .opblock-summary-description")
            shown.wait_for(state="visible", timeout=30_000)
            assert "Latest depth map" in shown.inner_text()
        finally:
            browser.close()
    assert refused == [] and console_errors == []
