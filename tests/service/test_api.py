"""Read-only endpoints of the service (the app in process) replaying a rendered room: headers,
formats, depth against the renderer's ground truth, point cloud geometry, calibration, metrics."""

from __future__ import annotations

import io
from typing import Any

import cv2
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from calibration import load_rig
from calibration.geometry import invert_transform, transform_points
from rig.rectified import design_rectified_pair
from service.client import parse_ply
from tests.helpers.service import SMALL_SPEC, InProcessServer, SmallRecording, same_frame
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.timeout(120)


def test_depth_headers_and_formats(shared_app: InProcessServer) -> None:
    r = shared_app.client.get("/depth")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert int(r.headers["X-Frame-Seq"]) >= 0 and int(r.headers["X-Timestamp-Ns"]) > 0
    # The frame's age, arrival to published, under its name and its first name.
    assert float(r.headers["X-Age-Ms"]) >= 0 and r.headers["X-Latency-Ms"] == r.headers["X-Age-Ms"]
    assert r.headers["X-Depth-Scale"] == "0.001"
    png = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and png.shape == (SMALL_SPEC.vpc.height, SMALL_SPEC.vpc.width)
    r = shared_app.client.get("/depth", params={"format": "npy"})
    assert r.headers["content-type"] == "application/x-npy" and r.headers["X-Depth-Scale"] == "1"
    arr = np.load(io.BytesIO(r.content), allow_pickle=False)
    assert arr.dtype == np.float32 and arr.shape == png.shape
    assert np.isnan(arr).any() and np.isfinite(arr).any()


def test_png_and_npy_agree(shared_app: InProcessServer) -> None:
    with shared_app.rig_client() as c:
        npy, png = same_frame(lambda: c.depth("npy"), lambda: c.depth("png"))
    ok = np.isfinite(npy.depth)
    fits = np.zeros_like(ok)
    fits[ok] = npy.depth[ok] <= 65.5345  # beyond 65.535 m a 16-bit mm PNG says "invalid"
    assert fits.any() and np.array_equal(fits, np.isfinite(png.depth)), npy.depth[ok & ~fits]
    assert np.abs(png.depth[fits] - npy.depth[fits]).max() <= 0.0005 + 1e-6  # rounding to 1 mm


def test_depth_matches_ground_truth(shared_app: InProcessServer, small_recording: SmallRecording) -> None:
    with shared_app.rig_client() as c:
        d = c.depth("npy").depth
        cal = c.calibration()
    gt = small_recording.gt_depth
    fb = cal.vpc.fx * cal.baseline_m
    both = np.isfinite(d) & np.isfinite(gt)
    assert both.mean() > 0.4  # most of the matchable view has depth
    # Stereo error is a disparity error: compare in pixels, where it is uniform over depth.
    err_px = np.abs(fb / d[both] - fb / gt[both])
    assert np.median(err_px) < 0.35
    assert np.mean(err_px < 1.0) > 0.85


def test_disparity_formats_and_relation_to_depth(shared_app: InProcessServer) -> None:
    with shared_app.rig_client() as c:
        disp, depth = same_frame(lambda: c.disparity("npy"), lambda: c.depth("npy"))
        cal = c.calibration()
        png = c.disparity("png")
    ok = np.isfinite(depth.depth)
    # depth = fx·B/d (docs/design.md), independently of how the server computed it.
    np.testing.assert_allclose(depth.depth[ok], cal.vpc.fx * cal.baseline_m / disp.disparity[ok], rtol=1e-5)
    valid_png = np.isfinite(png.disparity)
    assert valid_png.any() and np.all(png.disparity[valid_png] * 16 == np.rint(png.disparity[valid_png] * 16))


def test_confidence_is_aligned_with_depth_and_ranks_its_errors(
    shared_app: InProcessServer, small_recording: SmallRecording
) -> None:
    with shared_app.rig_client() as c:
        conf, depth = same_frame(lambda: c.confidence("npy"), lambda: c.depth("npy"))
        png, npy = same_frame(lambda: c.confidence("png"), lambda: c.confidence("npy"))
        cal = c.calibration()
    r = shared_app.client.get("/confidence")
    assert r.headers["content-type"] == "image/png" and float(
        r.headers["X-Confidence-Scale"]
    ) == pytest.approx(1 / 255)
    c_map, d = conf.confidence, depth.depth
    assert c_map.dtype == np.float32 and c_map.shape == d.shape and np.isfinite(c_map).all()
    assert c_map.min() >= 0.0 and c_map.max() <= 1.0
    valid = np.isfinite(d)
    assert np.all(c_map[~valid] == 0.0)  # no confidence without depth
    assert np.mean(c_map[valid] > 0.0) > 0.9
    # The PNG is the same map in 1/255 steps.
    assert np.abs(png.confidence - npy.confidence).max() <= 0.5 / 255 + 1e-6
    assert png.confidence.max() <= 1.0
    # It ranks the errors: against the render's ground truth, the more confident half of the
    # pixels has the smaller disparity error.
    fb = cal.vpc.fx * cal.baseline_m
    gt = small_recording.gt_depth
    both = valid & np.isfinite(gt)
    err = np.abs(fb / d[both] - fb / gt[both])
    high = c_map[both] >= np.median(c_map[both])
    assert np.mean(err[high]) < 0.8 * np.mean(err[~high])


def test_frames_raw_and_vpc(shared_app: InProcessServer, small_recording: SmallRecording) -> None:
    rig = load_rig(small_recording.loop / "calibration.yaml")
    with shared_app.rig_client() as c:
        for cam in ("left", "right"):
            raw = c.frames(cam, "raw")
            assert raw.image.shape[:2] == (rig.cameras[cam].height, rig.cameras[cam].width)
            vpc = c.frames(cam, "vpc")
            assert vpc.image.shape[:2] == (SMALL_SPEC.vpc.height, SMALL_SPEC.vpc.width)
            assert vpc.image.std() > 10  # a textured room, not a blank image
    r = shared_app.client.get("/frames/left", params={"view": "raw"})
    assert r.headers["content-type"] == "image/jpeg" and r.content[:2] == b"\xff\xd8"
    assert r.headers["X-Camera"] == "left" and int(r.headers["X-Frame-Seq"]) >= 0


def test_colorized_depth_is_a_jpeg_of_the_vpc_size(shared_app: InProcessServer) -> None:
    with shared_app.rig_client() as c:
        img = c.depth_colorized().image
    assert img.shape == (SMALL_SPEC.vpc.height, SMALL_SPEC.vpc.width, 3)


def test_pointcloud_geometry(shared_app: InProcessServer) -> None:
    stride = 4
    with shared_app.rig_client() as c:
        cloud, depth = same_frame(lambda: c.pointcloud(stride), lambda: c.depth("npy"))
        cal = c.calibration()
    r = shared_app.client.get("/pointcloud", params={"stride": stride})
    assert r.headers["content-type"] == "application/x-ply" and r.content.startswith(b"ply\n")
    pts, cols = parse_ply(r.content)
    assert cols is not None and pts.shape[1] == 3
    # Back into the left VPC frame: every point projects onto the stride grid with z = depth there.
    T_rig_rect = np.array(cal.vpc.T_rig_vpc["left"])
    p = transform_points(invert_transform(T_rig_rect), cloud.points.astype(np.float64))
    u = cal.vpc.fx * p[:, 0] / p[:, 2] + cal.vpc.cx
    v = cal.vpc.fy * p[:, 1] / p[:, 2] + cal.vpc.cy
    ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
    assert np.abs(u - ui).max() < 1e-2 and np.abs(v - vi).max() < 1e-2
    assert np.all(ui % stride == 0) and np.all(vi % stride == 0)
    np.testing.assert_allclose(p[:, 2], depth.depth[vi, ui], rtol=1e-5)
    expected_n = int(np.isfinite(depth.depth[::stride, ::stride]).sum())
    assert cloud.points.shape[0] == expected_n


def test_calibration_matches_the_rig_file(
    shared_app: InProcessServer, small_recording: SmallRecording
) -> None:
    rig = load_rig(small_recording.loop / "calibration.yaml")
    pair = design_rectified_pair(rig, SMALL_SPEC.vpc)
    with shared_app.rig_client() as c:
        cal = c.calibration()
    assert cal.baseline_m == pytest.approx(rig.baseline())
    assert (cal.vpc.width, cal.vpc.height) == (320, 240)
    assert cal.vpc.fx == pytest.approx(pair.camera.fx)
    for name in ("left", "right"):
        cam = cal.cameras[name]
        assert cam.model == rig.cameras[name].name
        np.testing.assert_allclose(cam.T_rig_cam, rig.T_rig_cam[name])
        fp = np.array(cam.footprint)
        # The footprint traces the VPC border inside the fisheye image.
        assert len(fp) > 100
        assert fp[:, 0].min() >= 0 and fp[:, 0].max() <= cam.width and fp[:, 1].max() <= cam.height
    assert cal.depth_scale_m == 0.001


def test_config_hides_the_token(shared_app: InProcessServer) -> None:
    r = shared_app.client.get("/config")
    assert r.status_code == 200
    doc = r.json()
    assert doc["server"]["api_token_set"] is True and "api_token" not in doc["server"]
    assert "test-token" not in r.text
    assert doc["stereo"]["disparity_range"] == 64 and doc["vpc"]["width"] == 320
    assert doc["cameras"]["left"]["kind"] == "file"


def test_health_ok_and_contract_fields(shared_app: InProcessServer) -> None:
    # A camera thread starved on a loaded machine turns /health degraded for a second, and a
    # server just started has no frame rate yet; the contract is about the steady state.
    def steady() -> dict[str, Any] | None:
        r = shared_app.client.get("/health")
        h: dict[str, Any] = r.json()
        return h if r.status_code == 200 and h["status"] == "ok" and h["worker"]["fps"] > 0 else None

    h = wait_for(steady, 20, "/health ok with frames flowing")
    for cam in ("left", "right"):
        c = h["cameras"][cam]
        assert c["connected"] is True and c["state"] == "available"
        for key in ("fps", "frames_dropped", "last_frame_age_ms"):
            assert key in c
    for key in ("fps", "latency_ms"):
        assert key in h["worker"]
    assert "skew_ms" in h["pairing"]
    assert h["worker"]["fps"] > 0 and h["worker"]["processing_ms"] > 0
    # latency_ms is processing_ms under its first name, not the frame's age (age_ms).
    assert h["worker"]["latency_ms"] == h["worker"]["processing_ms"]
    assert set(h["host"]) >= {"cpu_temp_c", "load_avg", "disk_free_bytes"}
    assert h["host"]["disk_free_bytes"] > 0


def test_probes(shared_app: InProcessServer) -> None:
    assert shared_app.client.get("/livez").json()["status"] == "ok"
    r = shared_app.client.get("/readyz")
    assert r.status_code == 200 and r.json()["status"] == "ready"


def metric_values(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_metrics(shared_app: InProcessServer) -> None:
    # Camera rates need two frames in their window: right after the first depth frame they are 0.
    right_fps = ("rig_camera_fps", (("camera", "right"),))
    wait_for(
        lambda: metric_values(shared_app.client.get("/metrics").text)[right_fps] > 0,
        10.0,
        "camera fps",
    )
    r = shared_app.client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    m = metric_values(r.text)
    assert m[("rig_camera_connected", (("camera", "left"),))] == 1.0
    assert m[("rig_camera_fps", (("camera", "right"),))] > 0
    assert ("rig_camera_frames_dropped_total", (("camera", "left"),)) in m
    assert ("rig_camera_reconnects_total", (("camera", "left"),)) in m
    assert m[("rig_worker_fps", ())] > 0
    assert m[("rig_worker_frames_total", ())] >= 1
    assert m[("rig_stage_seconds_count", (("stage", "match"),))] >= 1
    assert m[("rig_stage_latency_ms", (("stage", "total"),))] > 0
    assert ("rig_pairing_skew_ms", (("quantile", "0.5"),)) in m
    # Memory: the process's RSS, and what its allocators hold in use (a leak shows there).
    assert m[("process_resident_memory_bytes", ())] > 50e6
    assert 1e6 < m[("rig_malloc_in_use_bytes", ())] < m[("process_resident_memory_bytes", ())]
    assert m[("rig_malloc_free_bytes", ())] >= 0
    assert m[("rig_python_allocated_blocks", ())] > 10_000


def test_errors_are_json_with_the_right_status(shared_app: InProcessServer) -> None:
    client = shared_app.client
    cases = [
        ("/frames/middle", {}, 404),
        ("/frames/left", {"view": "thermal"}, 422),
        ("/depth", {"format": "bmp"}, 422),
        ("/pointcloud", {"stride": 0}, 422),
        ("/pointcloud", {"stride": "x"}, 422),
        ("/no-such-endpoint", {}, 404),
    ]
    for path, params, status in cases:
        r = client.get(path, params=params)
        assert r.status_code == status, path
        assert r.headers["content-type"] == "application/json" and "detail" in r.json()
    r = client.delete("/depth")
    assert r.status_code == 405 and "detail" in r.json() and r.headers["allow"] == "GET, HEAD"
    # Methods are separate routes; Allow still lists every method of the path (HEAD with GET).
    assert client.put("/config").headers["allow"] == "GET, HEAD, PATCH"
    assert client.delete("/recordings").headers["allow"] == "GET, HEAD, POST"


def test_cors_off_by_default(shared_app: InProcessServer) -> None:
    r = shared_app.client.get("/health", headers={"Origin": "http://evil.test"})
    assert "access-control-allow-origin" not in r.headers
    pre = shared_app.client.options(
        "/config",
        headers={"Origin": "http://evil.test", "Access-Control-Request-Method": "PATCH"},
    )
    assert "access-control-allow-origin" not in pre.headers


def test_openapi_lists_every_endpoint(shared_app: InProcessServer) -> None:
    spec = shared_app.client.get("/openapi.json").json()
    paths = set(spec["paths"])
    assert paths >= {
        "/health", "/livez", "/readyz", "/depth", "/disparity", "/confidence", "/depth/colorized",
        "/frames/{camera}", "/pointcloud", "/calibration", "/config", "/recordings",
        "/recordings/{name}/stop", "/stream.mjpg", "/metrics", "/",
    }  # fmt: skip
    depth = spec["paths"]["/depth"]["get"]["responses"]["200"]
    assert set(depth["content"]) == {"image/png", "application/x-npy"}
    assert {"X-Frame-Seq", "X-Timestamp-Ns", "X-Depth-Scale"} <= set(depth["headers"])


def test_dashboard_page_and_assets(shared_app: InProcessServer) -> None:
    r = shared_app.client.get("/")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    for element in (
        'id="depth-img"',
        'id="vpc-left"',
        'id="raw-right"',
        'id="health-body"',
        "/dashboard/app.js",
    ):
        assert element in r.text
    js = shared_app.client.get("/dashboard/app.js")
    assert js.status_code == 200 and "javascript" in js.headers["content-type"] and "/health" in js.text
    assert shared_app.client.get("/dashboard/../settings.py").status_code == 404
