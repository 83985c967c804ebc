"""The service on the lat-lon pair (``rectified.projection: latlon``), against the renderer's exact
range: ``/range``, ``/depth``, ``/pointcloud``, ``/calibration``, the client, the OpenAPI
document and the dashboard in Chromium; and ``/range`` of the pinhole pair."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from rig.sim import room_scene
from rig.sim.render import render_range
from service.client import RigClient
from service.settings import load_settings
from tests.helpers.browser import dashboard_page, needs_chromium, wait_for_image_width
from tests.helpers.recordings import CALM_SUPERVISOR
from tests.helpers.service import LiveServer, SmallRecording, StartApp, service_overrides
from tests.helpers.waiting import wait_for

WIDE = {"projection": "latlon", "px_per_deg": 2.0}


@pytest.fixture(scope="module")
def wide_server(
    small_recording: SmallRecording, lut_cache: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[LiveServer]:
    # Of the wide pair, not of camera health: a replay stalled by the busy machine stays available.
    calm = CALM_SUPERVISOR.model_dump()
    doc = service_overrides(small_recording.loop, tmp_path_factory.mktemp("wide"), lut_cache, supervisor=calm)
    doc["rectified"] = WIDE
    live = LiveServer(load_settings(None, doc)).start()
    live.wait_ready()
    yield live
    live.stop()


def _truth(small_recording: SmallRecording, live: LiveServer) -> np.ndarray:
    """The renderer's exact range through the service's left lat-lon view at the recording's pose."""
    scene_doc = json.loads((small_recording.render / "ground_truth" / "scene.json").read_text())
    pair = live.runtime.pipeline.pair
    T_world_rig = np.array(scene_doc["frames"][0]["T_world_rig"])
    truth, _ = render_range(
        room_scene(scene_doc["frames"][0]["seed"]), pair.camera, T_world_rig @ pair.T_rig_rect["left"]
    )
    return truth


def test_range_of_the_lat_lon_pair_is_the_truth(
    wide_server: LiveServer, small_recording: SmallRecording
) -> None:
    base = wide_server.base_url
    npy, png = httpx.get(base + "/range", params={"format": "npy"}), httpx.get(base + "/range")
    assert npy.status_code == 200 and png.status_code == 200, (npy.text, png.text)
    assert npy.headers["X-Range-Scale"] == "1" and png.headers["X-Range-Scale"] == "0.001"
    cam = wide_server.runtime.pipeline.pair.camera
    truth = _truth(small_recording, wide_server)
    rng = np.load(io.BytesIO(npy.content))
    mm = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert rng.dtype == np.float32 and rng.shape == (cam.height, cam.width)
    assert mm.dtype == np.uint16 and mm.shape == rng.shape
    from_png = np.where(mm > 0, mm * 1e-3, np.nan)
    # Each a frame of the replay (3 noisy pairs of one pose, rendered without supersampling):
    # half-size lenses at 2 px/deg put 2/3 of the range within 5 % (measured: median 2.5 %).
    for values in (rng, from_png):
        ok = np.isfinite(values) & np.isfinite(truth)
        err = np.abs(values[ok] / truth[ok] - 1.0)
        assert ok.mean() > 0.4
        assert np.median(err) < 0.035 and np.mean(err < 0.05) > 0.6
    # The lat-lon pair's /depth is its range (z is no depth past 90° off the forward axis).
    result = wide_server.runtime.store.latest
    assert result is not None and result.frame.depth is result.frame.range
    bodies = wide_server.runtime.frame_bodies
    assert bodies["depth_npy"](result) == bodies["range_npy"](result)


def test_lat_lon_calibration_point_cloud_client_and_openapi(wide_server: LiveServer) -> None:
    base = wide_server.base_url
    cal = httpx.get(base + "/calibration").json()
    vpc = cal["vpc"]
    pair = wide_server.runtime.pipeline.pair
    assert vpc["projection"] == "latlon" and vpc["px_per_deg"] == 2.0 and vpc["hfov_deg"] is None
    assert (vpc["width"], vpc["height"]) == (pair.camera.width, pair.camera.height)
    assert np.allclose(vpc["R_rig_vpc"], pair.R_rig_rect)
    for name in ("left", "right"):
        assert len(cal["cameras"][name]["footprint"]) > 100  # the overlap outlined in each fisheye
    # ROS's CameraInfo of the rectified view names the projection (no pinhole tool misprojects it).
    info = httpx.get(base + "/camera_info/rectified").json()
    c = pair.camera
    assert info["distortion_model"] == "latlon" and info["d"] == []
    assert info["k"] == [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0]
    with RigClient(base) as client:
        r = client.range()
        png = client.range(format="png")
        cloud = client.pointcloud(stride=1)
    assert r.range.shape == (pair.camera.height, pair.camera.width) and r.scale == 1.0
    assert png.scale == 0.001 and np.isnan(png.range).mean() == pytest.approx(
        np.isnan(r.range).mean(), abs=0.05
    )
    # Every point at its pixel's range from the left centre (of the cloud's own frame: its seq).
    assert cloud.points.shape[0] > 0.3 * r.range.size
    dist = np.linalg.norm(cloud.points - pair.T_rig_rect["left"][:3, 3], axis=1)
    assert 0.3 < np.median(dist) < 10.0  # inside the room
    paths = httpx.get(base + "/openapi.json").json()["paths"]
    doc = paths["/range"]["get"]["responses"]["200"]
    assert "X-Range-Scale" in doc["headers"] and "along each pixel's ray" in doc["description"]
    assert "lat-lon pair" in paths["/depth"]["get"]["responses"]["200"]["description"]


def test_pinhole_range_is_depth_along_the_ray(start_app: StartApp) -> None:
    live = start_app()
    r = live.client.get("/range?format=npy")
    assert r.status_code == 200 and r.headers["X-Range-Scale"] == "1"
    result = live.runtime.store.latest
    assert result is not None
    rng, depth = np.load(io.BytesIO(live.runtime.frame_bodies["range_npy"](result))), result.frame.depth
    cam = live.runtime.pipeline.pair.camera
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    length = np.sqrt(1 + ((u - cam.cx) / cam.fx) ** 2 + ((v - cam.cy) / cam.fy) ** 2)
    ok = np.isfinite(depth)
    assert ok.mean() > 0.3 and np.array_equal(np.isfinite(rng), ok)
    assert np.allclose(rng[ok], depth[ok] * length[ok], rtol=1e-6)


@pytest.mark.browser
@pytest.mark.timeout(180)
@needs_chromium
def test_dashboard_shows_the_wide_pair(wide_server: LiveServer, tmp_path: Path) -> None:
    cam = wide_server.runtime.pipeline.pair.camera
    errors: list[str] = []
    with dashboard_page(wide_server.base_url, errors) as page:
        page.wait_for_function("document.body.classList.contains('wide')", timeout=20_000)
        wait_for_image_width(page, "depth-img", cam.width)
        assert "range along each ray" in (page.text_content("#depth-what") or "")
        assert "lat-lon pair" in (page.text_content("#pair-info") or "")
        # The tall images are 45 % of the window's height, or less where four of them (and the
        # colour bar) would not fit side by side in the window's width (12em for the gaps, the
        # colour bar and its labels); in their own aspect, all in one row.
        # All four are measured in one evaluation, so in one layout: a reason line that comes and
        # goes above the row (a loaded machine's moment of degraded) moves the row between two.
        images = ("#depth-img", "#confidence-img", "#vpc-left", "#vpc-right")
        for img in images:
            page.wait_for_function(f"document.querySelector('{img}').naturalWidth > 0", timeout=20_000)
        boxes = page.evaluate(
            "sels => sels.map(s => { const e = document.querySelector(s);"
            " return [e.clientWidth, e.clientHeight, e.getBoundingClientRect().top]; })",
            list(images),
        )
        expected_h = min(0.45 * 1100, (1400 - 12 * 16) / 4 / (cam.width / cam.height))
        for img, (w, h, _) in zip(images, boxes, strict=True):
            assert abs(h - expected_h) <= 1 and abs(w / h - cam.width / cam.height) < 0.02, (img, w, h)
        tops = [top for _, _, top in boxes]
        assert max(tops) - min(tops) < 1, (tops, cam.width, cam.height)
        page.wait_for_function("document.getElementById('overlay-left').width > 0", timeout=20_000)
        drawn = page.eval_on_selector(
            "#overlay-left",
            "c => { const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
            " let n = 0; for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++; return n; }",
        )
        assert drawn > 500, "the overlap is outlined on the fisheye"
        # The status the service reports (a loaded machine may make it degraded for a while).
        wait_for(
            lambda: page.text_content("#status") == wide_server.runtime.health().status,
            20,
            "the dashboard's status to be the service's",
        )
        page.screenshot(path=str(tmp_path / "dashboard-wide.png"), full_page=True)
        print(f"wide-pair dashboard screenshot: {tmp_path / 'dashboard-wide.png'}")
    assert errors == []
