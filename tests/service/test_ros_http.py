"""HTTP parity with ROS: ``/camera_info/{left,right,rectified}`` in ROS 2's CameraInfo layout, and
``/pointcloud?format=pcd`` read back by an independent PCD reader (pypcd4)."""

from __future__ import annotations

import io
from typing import Any

import httpx
import numpy as np
import pytest
from pypcd4 import PointCloud

from calibration import load_rig
from service.client import parse_ply
from tests.helpers.service import SMALL_SPEC, InProcessServer, SmallRecording

pytestmark = pytest.mark.timeout(120)


def get(app: InProcessServer, path: str, **params: Any) -> httpx.Response:
    return app.client.get(path, params=params)


def test_camera_info_in_ros_layout(shared_app: InProcessServer, small_recording: SmallRecording) -> None:
    rig = load_rig(small_recording.loop / "calibration.yaml")
    vpc = shared_app.runtime.pipeline.pair
    docs = {cam: get(shared_app, f"/camera_info/{cam}").json() for cam in ("left", "right")}
    for cam, doc in docs.items():
        p = rig.cameras[cam].param_dict
        assert doc["distortion_model"] == "equidistant"  # the prototype's Kannala-Brandt lenses
        assert doc["d"] == [p["k1"], p["k2"], p["k3"], p["k4"]]
        assert doc["k"] == [p["fx"], 0.0, p["cx"], 0.0, p["fy"], p["cy"], 0.0, 0.0, 1.0]
        assert (doc["width"], doc["height"]) == (rig.cameras[cam].width, rig.cameras[cam].height)
        assert doc["header"]["frame_id"] == f"rig_{cam}_optical_frame" and doc["header"]["stamp"]["sec"] > 0
        R = np.array(doc["r"]).reshape(3, 3)
        np.testing.assert_allclose(R, vpc.R_cam_rect[cam].T, atol=1e-12)  # camera → rectified
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    fx, B = vpc.camera.fx, vpc.baseline_m
    assert docs["left"]["p"][3] == 0.0 and docs["right"]["p"][3] == pytest.approx(-fx * B, rel=1e-12)
    rect = get(shared_app, "/camera_info/rectified").json()
    assert rect["distortion_model"] == "plumb_bob" and rect["d"] == [0.0] * 5
    assert rect["r"] == np.eye(3).reshape(-1).tolist() and rect["p"] == docs["left"]["p"]
    assert (rect["width"], rect["height"]) == (SMALL_SPEC.vpc.width, SMALL_SPEC.vpc.height)
    assert rect["header"]["frame_id"] == "rig_left_rect_optical_frame"
    right = get(shared_app, "/camera_info/rectified", side="right").json()
    assert right["p"] == docs["right"]["p"] and right["header"]["frame_id"] == "rig_right_rect_optical_frame"
    assert get(shared_app, "/camera_info/middle").status_code == 422
    assert get(shared_app, "/camera_info/rectified", side="up").status_code == 422


def test_pointcloud_as_pcd_equals_the_ply(shared_app: InProcessServer) -> None:
    for _ in range(30):
        ply = get(shared_app, "/pointcloud", stride=2)
        pcd = get(shared_app, "/pointcloud", stride=2, format="pcd")
        if ply.headers["X-Frame-Seq"] == pcd.headers["X-Frame-Seq"]:
            break
    else:
        raise AssertionError("no two responses of one frame")
    assert pcd.status_code == 200 and pcd.headers["content-type"] == "application/x-pcd"
    assert pcd.headers["content-disposition"].endswith('.pcd"')
    cloud = PointCloud.from_fileobj(io.BytesIO(pcd.content))
    assert cloud.fields == ("x", "y", "z", "rgb")
    arr = cloud.numpy()
    pts, cols = parse_ply(ply.content)
    assert cols is not None and len(pts) > 100
    assert np.array_equal(arr[:, :3].astype(np.float32), pts)
    assert np.array_equal(PointCloud.decode_rgb(arr[:, 3]), cols)
