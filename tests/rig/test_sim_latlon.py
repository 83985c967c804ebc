"""Ground truth of the rectified views in ``rig sim``: range per rectified pixel for both
projections, against ray-plane intersections worked out here, and the lat-lon Reference pair's
rows matching through that range."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.models import LatLonModel
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.sim import get_preset, plane_scene, render, simulate_recording
from rig.sim.render import render_range

LATLON = RectifiedPairConfig(projection="latlon", px_per_deg=1.5)


def test_render_range_is_the_ray_plane_distance_and_renders_distance() -> None:
    cam = LatLonModel(120, 150, fx=60.0, fy=60.0, cx=59.5, cy=74.5)  # ±57° az, ±72° el
    scene = plane_scene(2.0, "paper", 0, size_m=40.0)
    rng, has_ray = render_range(scene, cam, np.eye(4))
    assert has_ray.all()
    v, u = np.mgrid[0:150, 0:120].astype(np.float64)
    rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], 1))
    expected = (2.0 / rays[:, 2]).reshape(150, 120)  # plane z = 2 along unit rays
    assert np.allclose(rng, expected, rtol=1e-6)
    assert np.array_equal(render(scene, cam, np.eye(4), supersample=1).distance, rng)


def test_latlon_recording_has_range_and_a_reference_pair_whose_rows_match(tmp_path: Path) -> None:
    preset = get_preset("paper-sim").scaled(0.25)
    k = 4.0
    out = simulate_recording(
        preset, "plane", tmp_path / "rec", distances=(k,), supersample=3, noise_std=0.0, vpc=LATLON,
        blind_band_px=16, texture="paper", reference=True,
    )  # fmt: skip
    doc = json.loads((out / "ground_truth" / "scene.json").read_text())
    assert doc["version"] == 2 and "depth" not in doc
    assert doc["vpc"]["projection"] == "latlon" and doc["vpc"]["blind_band_px"] == 16
    assert doc["vpc"]["px_per_deg"] == 1.5
    frame = doc["frames"][0]
    assert "depth" not in frame and not (out / "ground_truth" / "depth").exists()
    rng = np.load(out / frame["range"])
    pair = design_rectified_pair(preset.rig, LATLON, blind_band_px=16)
    cam = pair.camera
    assert isinstance(cam, LatLonModel) and rng.shape == (cam.height, cam.width)
    assert doc["vpc"]["width"] == cam.width and doc["vpc"]["cx"] == pytest.approx(cam.cx)
    # The plane z = k·B of the rig frame, along each left pixel's ray (rig frame: R_rig_rect·ray).
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], 1))
    z_rig = (rays @ pair.R_rig_rect.T)[:, 2].reshape(cam.height, cam.width)
    origin_z = pair.T_rig_rect["left"][2, 3]
    on_plane = np.isfinite(rng)
    assert on_plane.mean() > 0.3
    expected = (k * 0.2 - origin_z) / z_rig
    assert np.allclose(rng[on_plane], expected[on_plane], rtol=1e-5)
    # Rows match: sampling the right Reference image at each left pixel's true match (its point
    # projected into the right view) gives the left image back.
    left = cv2.imread(str(out / frame["reference"]["left"]), cv2.IMREAD_UNCHANGED).astype(np.float32)
    right = cv2.imread(str(out / frame["reference"]["right"]), cv2.IMREAD_UNCHANGED).astype(np.float32)
    inside = on_plane & cv2.erode((left > 0).astype(np.uint8), np.ones((7, 7))).astype(bool)

    def mismatch(baseline: float) -> float:
        pts = rays * np.nan_to_num(rng.reshape(-1, 1), nan=1.0) - [baseline, 0.0, 0.0]
        match, _ = cam.project(pts, in_image=False)
        assert np.abs(match[:, 1] - v.ravel()).max() < 1e-6
        mx = match[:, 0].reshape(cam.height, cam.width).astype(np.float32)
        warped = cv2.remap(right, mx, v.astype(np.float32), cv2.INTER_LINEAR)
        sel = inside & (mx > 3) & (mx < cam.width - 4) & (warped > 0)
        assert sel.sum() > 500
        return float(np.median(np.abs(warped[sel] - left[sel])))

    # Grey levels at 1.5 px/deg (texture below the pixel size aliases): the true match against
    # no shift at all.
    assert mismatch(pair.baseline_m) < 4.0 < 10.0 < mismatch(0.0)


def test_pinhole_range_is_depth_along_the_ray(tmp_path: Path) -> None:
    preset = get_preset("paper-sim").scaled(0.25)
    vpc = RectifiedPairConfig(width=160, height=120)
    out = simulate_recording(preset, "plane", tmp_path / "p", distances=(5.0,), supersample=1, vpc=vpc)
    doc = json.loads((out / "ground_truth" / "scene.json").read_text())
    frame = doc["frames"][0]
    depth, rng = np.load(out / frame["depth"]), np.load(out / frame["range"])
    f = 80.0 / math.tan(math.radians(45.0))
    v, u = np.mgrid[0:120, 0:160].astype(np.float64)
    length = np.sqrt(1 + ((u - 79.5) / f) ** 2 + ((v - 59.5) / f) ** 2)
    assert np.allclose(rng, depth * length, rtol=1e-6)
