"""Depth that ROS's pinhole tools read correctly (rig.pinhole_depth) from the default lat-lon pair:
``/depth/pinhole`` is z on a plumb_bob pinhole with zero distortion (``/camera_info/pinhole_depth``),
checked as depth_image_proc would use it: against the renderer's exact depth of that pinhole, and
its cloud (x = (u − cx)·z/fx, as depth_image_proc computes it) against the range along the
lat-lon rays. In process (tests.helpers.service.in_process)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from rig.rectified import RectifiedPairConfig
from service.settings import load_settings
from tests.helpers.service import SMALL_SPEC, SmallRecording, in_process, service_overrides
from tests.helpers.waiting import wait_for

pytestmark = pytest.mark.timeout(180)


def test_the_pinhole_depth_of_the_lat_lon_pair_is_the_pinholes_exact_depth(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    doc = service_overrides(small_recording.loop, tmp_path, lut_cache)
    doc["rectified"] = RectifiedPairConfig(projection="latlon", px_per_deg=2.8).model_dump()
    # The pinhole of the recording's ground truth: 320x240, 90° about the rectified z axis.
    width, height, hfov = SMALL_SPEC.vpc.pinhole_size
    doc["pinhole_depth"] = {"width": width, "height": height, "hfov_deg": hfov}
    with in_process(load_settings(None, doc)) as server:
        client = server.client
        wait_for(lambda: client.get("/depth").status_code == 200, 60, "a depth frame")
        info = client.get("/camera_info/pinhole_depth").json()

        def same_frame() -> tuple[bytes, bytes] | None:
            a = client.get("/depth/pinhole", params={"format": "npy"})
            b = client.get("/range", params={"format": "npy"})
            same = a.headers["X-Frame-Seq"] == b.headers["X-Frame-Seq"]
            return (a.content, b.content) if same and a.headers["X-Depth-Scale"] == "1" else None

        pinhole_npy, range_npy = wait_for(same_frame, 20, "/depth/pinhole and /range of one frame")
        rng = np.load(io.BytesIO(range_npy))
        png = client.get("/depth/pinhole")
        config = client.get("/config").json()
    assert config["rectified"]["projection"] == "latlon"
    assert info["distortion_model"] == "plumb_bob" and info["d"] == [0.0] * 5
    assert (info["width"], info["height"]) == (width, height) and info["header"][
        "frame_id"
    ] == "rig_left_rect_optical_frame"
    fx, cx, fy, cy = info["k"][0], info["k"][2], info["k"][4], info["k"][5]
    assert fx == pytest.approx(width / 2.0) and fy == fx and info["r"] == [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    assert png.headers["X-Depth-Scale"] == "0.001"
    z = np.load(io.BytesIO(pinhole_npy))
    gt = small_recording.gt_depth
    assert z.shape == gt.shape == (height, width)
    both = np.isfinite(z) & np.isfinite(gt)
    # Stereo error is a disparity error (this half-size rig's disparities are a few pixels):
    # compared in pixels, with the bounds the pinhole pair's own depth meets (test_api.py).
    fb = fx * config["rectified"]["baseline_m"]
    err_px = np.abs(fb / z[both] - fb / gt[both])
    within = np.mean(err_px < 1.0)
    print(f"\npinhole depth from the lat-lon range: {100 * both.mean():.0f} % of the pixels, median "
          f"disparity error {np.median(err_px):.2f} px, {100 * within:.1f} % within 1 px")  # fmt: skip
    assert both.mean() > 0.4 and np.median(err_px) < 0.35 and within > 0.85
    # depth_image_proc's cloud from it lies at the range the lat-lon pair measured along the same
    # rays (read from /range at the lat-lon pixel each point projects to, by the formula).
    v, u = np.nonzero(np.isfinite(z))
    zz = z[v, u]
    pts = np.stack([(u - cx) * zz / fx, (v - cy) * zz / fy, zz], axis=1)
    dist = np.linalg.norm(pts, axis=1)
    ll = config["rectified"]
    lu = np.rint(ll["cx"] + ll["fx"] * np.arcsin(pts[:, 0] / dist)).astype(int)
    lv = np.rint(ll["cy"] + ll["fy"] * np.arctan2(pts[:, 1], pts[:, 2])).astype(int)
    measured = rng[lv, lu]
    ok = np.isfinite(measured)
    assert ok.mean() > 0.95 and np.median(np.abs(dist[ok] / measured[ok] - 1.0)) < 0.002
