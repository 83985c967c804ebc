"""Relative-pose refinement from ray matches (calibration.relative_pose) on synthetic scenes with
known truth: exact rays, noisy rays with outliers, rays through every camera model (past 90°
off axis), near and distant scenes for the baseline direction, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import CalibrationFailed
from calibration.geometry import invert_transform, make_transform, rot_x, rot_y, rot_z, rotation_angle
from calibration.models import CameraModel, create
from calibration.relative_pose import (
    RelativePoseOptions,
    epipolar_errors,
    refine_relative_pose,
    rig_with_relative_pose,
)
from calibration.rig import Rig
from tests.calibration.model_cases import model_cases

F64 = np.ndarray
# The rig's axes (x along the baseline, y down, z forward) seen from the left camera of a 90°
# divergent mount: the frame corrections are expressed in.
HALF = math.radians(45.0)


def divergent(left: CameraModel, right: CameraModel, angle_deg: float = 90.0, baseline: float = 0.072) -> Rig:
    h = math.radians(angle_deg) / 2.0
    return Rig(
        {"left": left, "right": right},
        {
            "left": make_transform(rot_y(-h), [-baseline / 2, 0.0, 0.0]),
            "right": make_transform(rot_y(h), [baseline / 2, 0.0, 0.0]),
        },
    )


def perturbed(
    rig: Rig, deg: tuple[float, float, float], along_baseline_m: float = 0.0, centre_m=(0, 0, 0)
) -> Rig:
    """``rig`` with the right camera turned by ``deg`` about the rig's x, y, z and moved."""
    T = rig.T_rig_cam["right"].copy()
    dR = rot_x(math.radians(deg[0])) @ rot_y(math.radians(deg[1])) @ rot_z(math.radians(deg[2]))
    T[:3, :3] = dR @ T[:3, :3]
    b = T[:3, 3] - rig.T_rig_cam["left"][:3, 3]
    T[:3, 3] += along_baseline_m * b / np.linalg.norm(b) + np.asarray(centre_m, dtype=float)
    return Rig(dict(rig.cameras), {"left": rig.T_rig_cam["left"].copy(), "right": T})


def t_right_left(rig: Rig) -> F64:
    return invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]


def room_points(rng: np.random.Generator, n: int, near: float = 0.8, far: float = 4.0) -> F64:
    """Points around the rig (forward hemisphere and beyond the sides), ``near``..``far`` m away."""
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2]) - 0.3  # mostly ahead, some behind the sides
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(near, far, (n, 1))


def rays(rig: Rig, name: str, points: F64) -> F64:
    T = rig.T_rig_cam[name]
    p = (points - T[:3, 3]) @ T[:3, :3]
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def seen_by_both(rig: Rig, points: F64, max_deg: float = 95.0) -> tuple[F64, F64]:
    fl, fr = rays(rig, "left", points), rays(rig, "right", points)
    c = math.cos(math.radians(max_deg))
    keep = (fl[:, 2] > c) & (fr[:, 2] > c)
    return fl[keep], fr[keep]


def rig_axes_in_left(rig: Rig) -> F64:
    """Columns: the rig's x, y, z in the left camera's frame."""
    return rig.T_rig_cam["left"][:3, :3].T


def rotation_error_deg(a: Rig, b: Rig) -> float:
    return math.degrees(rotation_angle(t_right_left(a)[:3, :3] @ t_right_left(b)[:3, :3].T))


def lens() -> CameraModel:
    return create("equidistant", 1024, 1024, fx=326.0, fy=326.0, cx=511.5, cy=511.5, fov_deg=190.0)


def noisy(f: F64, deg: float, rng: np.random.Generator) -> F64:
    g = f + rng.normal(0.0, math.radians(deg), f.shape)
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def test_epipolar_error_is_the_angle_off_the_epipolar_plane() -> None:
    """A right ray tilted by δ out of the epipolar plane of a distant point gives e = δ."""
    rig = divergent(lens(), lens())
    T = t_right_left(rig)
    R, t = T[:3, :3], T[:3, 3]
    rng = np.random.default_rng(3)
    X = room_points(rng, 200, 1e4, 2e4)
    fl, fr0 = seen_by_both(rig, X)
    assert np.abs(epipolar_errors(R, t, fl, fr0)).max() < 1e-9
    for delta in (1e-4, -2e-3):
        n = np.cross(t, fr0)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        fr = math.cos(delta) * fr0 + math.sin(delta) * n
        e = epipolar_errors(R, t, fl, fr)
        np.testing.assert_allclose(e, delta, rtol=1e-3)


COMBOS = [
    (0.1, 0.0, 0.0),
    (0.0, 1.0, 0.0),
    (0.0, 0.0, -1.0),
    (0.5, -0.3, 0.8),
    (-1.0, 1.0, 1.0),
    (0.1, 0.1, 0.1),
]


@pytest.mark.parametrize("deg", COMBOS)
def test_recovers_rotation_exactly_from_exact_rays(deg: tuple[float, float, float]) -> None:
    truth = divergent(lens(), lens())
    prior = perturbed(truth, deg, along_baseline_m=0.001)
    fl, fr = seen_by_both(truth, room_points(np.random.default_rng(1), 800))
    fit = refine_relative_pose(fl, fr, t_right_left(prior), rig_axes_in_left(prior))
    refined = rig_with_relative_pose(prior, "left", "right", fit.T_right_left)
    assert rotation_error_deg(refined, truth) < 1e-6
    # The correction is the perturbation undone, about the rig's axes (small-angle composition).
    np.testing.assert_allclose(-fit.rotation_deg, deg, atol=0.01)
    # Never the scale: the prior's 73 mm baseline stays.
    assert refined.baseline() == pytest.approx(prior.baseline(), abs=1e-12)
    assert fit.n_inliers == len(fl)


def test_noise_and_outliers_within_the_reported_uncertainty() -> None:
    rng = np.random.default_rng(7)
    truth = divergent(lens(), lens())
    prior = perturbed(truth, (0.5, -0.7, 0.3))
    fl, fr = seen_by_both(truth, room_points(rng, 3000))
    fl, fr = noisy(fl, 0.03, rng), noisy(fr, 0.03, rng)
    bad = rng.random(len(fr)) < 0.25
    fr[bad] = noisy(fr[rng.permutation(np.flatnonzero(bad))], 5.0, rng)  # mismatched rays
    fit = refine_relative_pose(fl, fr, t_right_left(prior), rig_axes_in_left(prior))
    refined = rig_with_relative_pose(prior, "left", "right", fit.T_right_left)
    err = rotation_error_deg(refined, truth)
    print(f"\nnoisy rays (0.03°, 25% outliers): error {err:.4f}°, reported 1σ {fit.angle_sigma_deg:.4f}°")
    assert err <= 0.02
    assert err <= 4.0 * max(fit.angle_sigma_deg, fit.rotation_sigma_deg.max())
    assert fit.sigma_deg == pytest.approx(0.03 * math.sqrt(2), rel=0.3)  # two rays' noise
    assert np.count_nonzero(fit.inliers & bad) < 0.02 * bad.sum()
    assert fit.rms_after_deg < fit.rms_before_deg / 5


def test_baseline_direction_estimated_where_the_scene_is_near() -> None:
    """A right camera moved 1 mm down (0.8° of baseline direction): observable in a room."""
    rng = np.random.default_rng(11)
    truth = perturbed(divergent(lens(), lens()), (0.0, 0.0, 0.0), centre_m=(0.0, 0.001, 0.0))
    prior = divergent(lens(), lens())
    fl, fr = seen_by_both(truth, room_points(rng, 4000, 0.5, 2.0))
    fit = refine_relative_pose(fl, fr, t_right_left(prior), rig_axes_in_left(prior))
    assert fit.direction_estimated, fit.direction_note
    refined = rig_with_relative_pose(prior, "left", "right", fit.T_right_left)
    b_true = truth.center("right") - truth.center("left")
    b_fit = refined.center("right") - refined.center("left")
    angle = math.degrees(math.acos(b_true @ b_fit / np.linalg.norm(b_true) / np.linalg.norm(b_fit)))
    assert angle < 1e-4
    assert refined.baseline() == pytest.approx(prior.baseline(), abs=1e-12)
    assert rotation_error_deg(refined, truth) < 1e-4


def test_baseline_direction_kept_for_a_distant_scene() -> None:
    rng = np.random.default_rng(12)
    truth = perturbed(divergent(lens(), lens()), (0.2, 0.4, -0.3))
    prior = divergent(lens(), lens())
    fl, fr = seen_by_both(truth, room_points(rng, 2000, 500.0, 1000.0))
    fl, fr = noisy(fl, 0.02, rng), noisy(fr, 0.02, rng)
    fit = refine_relative_pose(fl, fr, t_right_left(prior), rig_axes_in_left(prior))
    assert not fit.direction_estimated
    assert "does not constrain" in fit.direction_note
    assert fit.direction_sigma_deg.max() > RelativePoseOptions().max_direction_sigma_deg
    refined = rig_with_relative_pose(prior, "left", "right", fit.T_right_left)
    assert rotation_error_deg(refined, truth) < 0.01
    np.testing.assert_allclose(refined.center("right"), prior.center("right"), atol=1e-15)


@pytest.mark.parametrize("case", model_cases(), ids=lambda c: c.id)
def test_rays_through_every_model(case) -> None:
    """Pixels (0.1 px noise) unprojected by each model; wide lenses contribute rays past 90°."""
    rng = np.random.default_rng(5)
    model = case.model
    angle = 90.0 if case.wide else 20.0
    truth = perturbed(divergent(model, model.replace(), angle), (0.3, -0.5, 0.4))
    prior = divergent(model, model.replace(), angle)
    X = room_points(rng, 20000, 1.0, 5.0)
    rl, rr = rays(truth, "left", X), rays(truth, "right", X)
    pl, ok_l = model.project(rl)
    pr, ok_r = model.project(rr)
    ok = ok_l & ok_r
    fl, v_l = model.unproject(pl[ok] + rng.normal(0, 0.1, (ok.sum(), 2)))
    fr, v_r = model.unproject(pr[ok] + rng.normal(0, 0.1, (ok.sum(), 2)))
    keep = v_l & v_r
    fl, fr = fl[keep], fr[keep]
    assert len(fl) > 200
    if case.wide:
        assert np.degrees(np.arccos(np.minimum(fl[:, 2], fr[:, 2]))).max() > 90.0
    fit = refine_relative_pose(fl, fr, t_right_left(prior), rig_axes_in_left(prior))
    refined = rig_with_relative_pose(prior, "left", "right", fit.T_right_left)
    assert rotation_error_deg(refined, truth) < 0.02


def test_too_few_or_inconsistent_matches_fail() -> None:
    rng = np.random.default_rng(2)
    truth = divergent(lens(), lens())
    fl, fr = seen_by_both(truth, room_points(rng, 20))
    with pytest.raises(CalibrationFailed, match="not enough matches"):
        refine_relative_pose(fl, fr, t_right_left(truth))
    # Random pairs of rays agree on no rotation.
    fl = noisy(np.tile([0.0, 0.0, 1.0], (500, 1)), 40.0, rng)
    fr = noisy(np.tile([0.0, 0.0, 1.0], (500, 1)), 40.0, rng)
    with pytest.raises(CalibrationFailed, match="consistent"):
        refine_relative_pose(fl, fr, t_right_left(truth))
    with pytest.raises(ValueError, match="same shape"):
        refine_relative_pose(fl, fr[:10], t_right_left(truth))


def test_rig_with_relative_pose_moves_only_the_right_camera() -> None:
    rig = divergent(lens(), lens())
    T = make_transform(rot_z(0.01) @ t_right_left(rig)[:3, :3], t_right_left(rig)[:3, 3])
    out = rig_with_relative_pose(rig, "left", "right", T)
    np.testing.assert_array_equal(out.T_rig_cam["left"], rig.T_rig_cam["left"])
    np.testing.assert_allclose(t_right_left(out), T, atol=1e-15)
