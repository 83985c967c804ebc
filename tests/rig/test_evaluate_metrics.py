"""The evaluation's metric code against hand-computed cases and closed-form identities."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.geometry import make_transform, rot_x, rot_y
from calibration.models import PinholeModel
from rig.errors import ConfigError, EvaluationError
from rig.evaluate.agreement import check_claims, mean_ratio
from rig.evaluate.config import make_config, stereo_for
from rig.evaluate.depth_quality import REFERENCE, TRUE_LENS, CurvePoint, DepthSample, average_curves
from rig.evaluate.metrics import (
    Plane,
    PlaneStats,
    disparity_stats,
    fit_quadratic,
    image_difference,
    loglog_slope,
    plane_depth_stats,
    plane_in_frame,
    sample_indices,
    theory_sigma_z,
    vicinity_mask,
)
from rig.rectified import RectifiedPairConfig


def test_vicinity_mask_keeps_points_within_the_tolerance_of_the_plane() -> None:
    z2 = Plane(np.array([0.0, 0.0, 1.0]), 2.0)
    pts = np.array([[0.3, -1.0, 1.95], [5.0, 2.0, 2.05], [0.0, 0.0, 2.3], [0.0, 0.0, 1.7]])
    assert vicinity_mask(pts, z2, 0.1).tolist() == [True, True, False, False]
    # A tilted plane x + y = 2 (unit normal (1, 1, 0)/√2, offset √2): distances 0 and √2.
    tilted = Plane(np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0), math.sqrt(2.0))
    far = np.array([[1.0, 1.0, 5.0], [2.0, 2.0, 0.0]])
    assert vicinity_mask(far, tilted, 1.0).tolist() == [True, False]
    assert vicinity_mask(far, tilted, 1.5).tolist() == [True, True]


def test_plane_in_frame_maps_the_plane_points_into_the_frame() -> None:
    T = make_transform(rot_y(0.4) @ rot_x(-0.2), [0.3, -0.1, 0.7])
    plane = plane_in_frame(T, [0.0, 0.0, 2.0], 3.0)  # world z = 3, normal given unnormalised
    # Points of the world plane, expressed in the frame: p_frame = T⁻¹ p_world.
    rng = np.random.default_rng(1)
    world = np.column_stack([rng.uniform(-2, 2, 20), rng.uniform(-2, 2, 20), np.full(20, 3.0)])
    frame = (world - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(frame @ plane.normal, plane.offset, atol=1e-12)
    assert np.linalg.norm(plane.normal) == pytest.approx(1.0)
    # Identity rotation, frame 1 m forward: the plane is 2 m ahead of it.
    shifted = plane_in_frame(make_transform(np.eye(3), [0, 0, 1.0]), [0, 0, 1], 3.0)
    assert shifted.offset == pytest.approx(2.0) and shifted.normal.tolist() == [0.0, 0.0, 1.0]


def test_sample_indices_are_distinct_seeded_and_capped_at_the_population() -> None:
    a = sample_indices(5000, 1000, np.random.default_rng(7))
    b = sample_indices(5000, 1000, np.random.default_rng(7))
    assert a.shape == (1000,) and np.unique(a).shape == (1000,)
    assert a.min() >= 0 and a.max() < 5000
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, sample_indices(5000, 1000, np.random.default_rng(8)))
    small = sample_indices(300, 1000, np.random.default_rng(0))
    assert sorted(small.tolist()) == list(range(300))  # all of them, each once
    with pytest.raises(EvaluationError):
        sample_indices(-1, 10, np.random.default_rng(0))


def _camera(w: int = 5, h: int = 4) -> PinholeModel:
    return PinholeModel(w, h, fx=2.0, fy=2.0, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0)


def test_plane_depth_stats_by_hand() -> None:
    cam = _camera()
    truth = np.full((4, 5), 2.0, dtype=np.float32)
    truth[0, 0] = np.nan  # a pixel that sees no surface
    errors = np.array(
        [
            0.01,
            -0.01,
            0.03,
            0.0,
            -0.02,
            0.05,
            0.01,
            -0.04,
            0.02,
            0.0,
            0.01,
            -0.01,
            0.0,
            0.02,
            -0.03,
            0.04,
            0.0,
        ],
        dtype=np.float64,
    )
    depth = np.full((4, 5), np.nan, dtype=np.float32)
    flat = depth.reshape(-1)
    flat[1:18] = 2.0 + errors  # 17 good pixels (the first has no truth: skipped below)
    flat[18] = 5.0  # a gross mismatch, 3 m off the plane: outside 10 % of 2 m
    # flat[19] stays NaN (no depth)
    plane = Plane(np.array([0.0, 0.0, 1.0]), 2.0)
    stats = plane_depth_stats(depth, truth, cam, plane, np.random.default_rng(0), baseline_m=0.1)
    # Expected from the error list itself (float32 storage of the depths: 1e-6 tolerance).
    assert stats.n_points == 17
    assert stats.valid_frac == pytest.approx(17 / 19)
    assert stats.rms_m == pytest.approx(math.sqrt(np.mean(errors**2)), abs=2e-6)
    assert stats.std_m == pytest.approx(np.std(errors), abs=2e-6)
    assert stats.mean_m == pytest.approx(np.mean(errors), abs=2e-6)
    fb = 2.0 * 0.1
    d_err = fb / (2.0 + errors) - fb / 2.0
    assert stats.disparity_rms_px == pytest.approx(math.sqrt(np.mean(d_err**2)), rel=1e-4)
    # A looser vicinity (200 %) keeps the gross point: its 3 m error dominates the RMS.
    loose = plane_depth_stats(
        depth, truth, cam, plane, np.random.default_rng(0), baseline_m=0.1, vicinity_frac=2.0
    )
    assert loose.n_points == 18 and loose.rms_m == pytest.approx(
        math.sqrt((np.sum(errors**2) + 9.0) / 18), rel=1e-5
    )


def test_plane_depth_stats_samples_the_requested_number_of_points() -> None:
    cam = _camera(60, 40)
    truth = np.full((40, 60), 3.0, dtype=np.float32)
    # ±0.02 m checkerboard of errors: every subset of any size has RMS exactly 0.02.
    sign = np.where((np.indices((40, 60)).sum(axis=0) % 2) == 0, 1.0, -1.0)
    depth = (truth + 0.02 * sign).astype(np.float32)
    stats = plane_depth_stats(
        depth, truth, cam, Plane(np.array([0.0, 0.0, 1.0]), 3.0), np.random.default_rng(3), baseline_m=0.2,
        samples=100,
    )  # fmt: skip
    assert stats.n_points == 2400 and stats.valid_frac == 1.0
    assert stats.rms_m == pytest.approx(0.02, abs=1e-6)
    # 100 of 2400 random ±e: the mean is not exactly 0, and std² + mean² = RMS².
    assert stats.std_m**2 + stats.mean_m**2 == pytest.approx(stats.rms_m**2, rel=1e-9)
    empty = plane_depth_stats(
        np.full((40, 60), np.nan, np.float32), truth, cam, Plane(np.array([0.0, 0.0, 1.0]), 3.0),
        np.random.default_rng(0), baseline_m=0.2,
    )  # fmt: skip
    assert empty.n_points == 0 and empty.valid_frac == 0.0 and math.isnan(empty.rms_m)
    with pytest.raises(EvaluationError):
        plane_depth_stats(depth[:10], truth, cam, Plane(np.array([0.0, 0.0, 1.0]), 3.0),
                          np.random.default_rng(0), baseline_m=0.2)  # fmt: skip


def test_disparity_stats_by_hand() -> None:
    truth = np.full((2, 2), 10.0, dtype=np.float32)
    est = np.array([[10.5, 9.8], [12.0, np.nan]], dtype=np.float32)
    s = disparity_stats(est, truth)
    assert s.rms_px == pytest.approx(math.sqrt((0.25 + 0.04 + 4.0) / 3), rel=1e-6)
    assert s.rms_inlier_px == pytest.approx(math.sqrt((0.25 + 0.04) / 2), rel=1e-5)
    assert s.bad1_frac == pytest.approx(1 / 3) and s.valid_frac == pytest.approx(3 / 4)
    none = disparity_stats(np.full((2, 2), np.nan, np.float32), truth)
    assert none.valid_frac == 0.0 and math.isnan(none.rms_px)


def test_quadratic_fit_recovers_exact_coefficients_and_needs_three_distances() -> None:
    k = np.arange(2.0, 21.0)
    y = 0.001 * k**2 - 0.002 * k + 0.05
    a2, a1, a0 = fit_quadratic(k, y) or (math.nan,) * 3
    assert (a2, a1, a0) == pytest.approx((0.001, -0.002, 0.05), abs=1e-12)
    y_nan = y.copy()
    y_nan[3] = np.nan  # ignored, not propagated
    assert fit_quadratic(k, y_nan) == pytest.approx((0.001, -0.002, 0.05), abs=1e-12)
    assert fit_quadratic([2.0, 3.0], [1.0, 2.0]) is None
    assert fit_quadratic([2.0, 2.0, 3.0], [1.0, 1.0, 2.0]) is None  # two distinct k only


def test_loglog_slope_of_power_laws() -> None:
    k = np.array([2.0, 5.0, 10.0, 20.0])
    assert loglog_slope(k, 3.0 * k**2) == pytest.approx(2.0)
    assert loglog_slope(k, 0.5 * k**1.5) == pytest.approx(1.5)
    assert math.isnan(loglog_slope([2.0], [1.0]))


def test_theory_curve_is_the_first_order_propagation_of_a_disparity_error() -> None:
    # Hand value: Z = 2 m, σd = 0.1 px, fx = 320 px, B = 0.2 m -> 4 * 0.1 / 64 = 6.25 mm.
    assert float(theory_sigma_z(2.0, 0.1, 320.0, 0.2)) == pytest.approx(0.00625)
    # Against the exact depth change of a small disparity step through Z = fx·B/d.
    fx, B, sd = 320.0, 0.2, 1e-4
    z = np.array([0.4, 1.0, 2.0, 4.0])
    d = fx * B / z
    central = (fx * B / (d - sd) - fx * B / (d + sd)) / 2.0
    np.testing.assert_allclose(theory_sigma_z(z, sd, fx, B), central, rtol=1e-6)
    # Monotonic and quadratic in Z.
    s = theory_sigma_z(z, 0.05, fx, B)
    assert np.all(np.diff(s) > 0) and s[3] / s[1] == pytest.approx(16.0)


def test_image_difference_whole_and_central_by_hand() -> None:
    ref = np.zeros((4, 4), dtype=np.uint8)
    img = np.array([[10, 0, 0, 0], [0, 4, 2, 0], [0, 0, 6, 0], [0, 0, 0, 200]], dtype=np.uint8)
    valid = np.ones((4, 4), dtype=bool)
    valid[3, 3] = False  # not mapped into the lens: ignored
    whole, central, diff = image_difference(img, ref, valid)
    assert whole == pytest.approx((10 + 4 + 2 + 6) / 15)
    assert central == pytest.approx((4 + 2 + 0 + 6) / 4)  # rows 1-2, columns 1-2
    assert diff[3, 3] == 0 and diff[0, 0] == 10
    # Differences are absolute, in both directions.
    assert image_difference(ref, img, valid)[0] == pytest.approx(whole)
    with pytest.raises(EvaluationError):
        image_difference(img, ref[:2], valid)


def _curve(values: list[float], ks: tuple[float, ...] = (2.0, 5.0, 10.0)) -> list[CurvePoint]:
    return [
        CurvePoint(k=k, rms_m=v, std_m=v / 2, mean_m=v * 0.8, valid_frac=0.9, disparity_rms_px=0.1, n=3)
        for k, v in zip(ks, values, strict=True)
    ]


def test_average_curves_means_textures_and_fits_over_k() -> None:
    def stats(rms: float) -> PlaneStats:
        return PlaneStats(rms, rms / 2, -rms / 4, 0.8, 500, 0.1)

    samples = [
        DepthSample(REFERENCE, k, tex, stats(r * k**2))
        for k in (2.0, 4.0, 8.0)
        for tex, r in (("a", 0.001), ("b", 0.003))
    ]
    curves, fits = average_curves(samples)
    ref = curves[REFERENCE]
    assert [p.k for p in ref] == [2.0, 4.0, 8.0]
    assert [p.rms_m for p in ref] == pytest.approx([0.002 * k**2 for k in (2.0, 4.0, 8.0)])
    assert all(p.n == 2 and p.valid_frac == pytest.approx(0.8) for p in ref)
    assert [p.mean_m for p in ref] == pytest.approx([-0.0005 * k**2 for k in (2.0, 4.0, 8.0)])
    assert fits[REFERENCE] == pytest.approx((0.002, 0.0, 0.0), abs=1e-12)
    assert [p.fit_rms_m for p in ref] == pytest.approx([p.rms_m for p in ref])


def test_claims_follow_the_numbers() -> None:
    ref = _curve([0.001, 0.006, 0.025])
    good = {
        REFERENCE: ref,
        TRUE_LENS: _curve([0.0011, 0.0066, 0.027]),
        "kannala_brandt": _curve([0.0011, 0.0065, 0.0275]),
        "mei": _curve([0.002, 0.012, 0.05]),
        "scaramuzza": _curve([0.004, 0.024, 0.1]),
    }
    assert mean_ratio(good["mei"], ref) == pytest.approx(2.0)
    claims = check_claims(
        {"kannala_brandt": 0.099, "mei": 0.102 * 1.1, "scaramuzza": 0.121 * 1.1},
        {TRUE_LENS: 3.0, "kannala_brandt": 3.1, "mei": 3.3, "scaramuzza": 4.0},
        good,
    )
    assert [c.verdict for c in claims] == ["agrees"] * len(claims)
    # Reverse the depth ordering and make the calibration a tie: the verdicts turn.
    bad = dict(good, mei=_curve([0.001, 0.006, 0.025]), scaramuzza=_curve([0.0011, 0.0062, 0.026]))
    flipped = check_claims({"kannala_brandt": 0.1, "mei": 0.101, "scaramuzza": 0.1}, {TRUE_LENS: 3.0}, bad)
    verdict = {c.paper: c.verdict for c in flipped}
    assert verdict["reprojection RMS KB 0.099 ≈ Mei 0.102 < Scaramuzza 0.121 px"] == "differs"
    assert verdict["Mei is substantially worse than Kannala-Brandt"] == "differs"
    assert verdict["Scaramuzza is the worst of KB, Mei and Scaramuzza"] == "differs"
    assert verdict["Scaramuzza differs more from the Reference than Mei, KB, atan"] == "not measured"
    linear = {REFERENCE: _curve([0.002, 0.005, 0.01]), "kannala_brandt": _curve([0.002, 0.005, 0.01])}
    growth = next(c for c in check_claims({}, {}, linear) if "quadratically" in c.paper)
    assert growth.verdict == "differs"


def test_disparity_range_reaches_the_nearest_plane() -> None:
    vpc = RectifiedPairConfig(projection="pinhole")  # fx = 320
    assert stereo_for(vpc, 2.0).disparity_range == 176  # 160 px * 1.1 -> 176
    assert stereo_for(vpc, 10.0).disparity_range == 48  # 32 * 1.1 = 35.2 -> 48
    assert stereo_for(RectifiedPairConfig(width=320, height=240), 3.0).disparity_range == 64
    with pytest.raises(ConfigError, match="too many"):
        stereo_for(RectifiedPairConfig(width=128, height=96), 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"preset": "nope"}, "unknown preset"),
        ({"models": ["kannala_brandt", "fisheye9"]}, "fisheye9"),
        ({"models": [" "]}, "at least one"),
        ({"textures": 0}, "textures"),
        ({"textures": 6}, "textures"),
        ({"distances": [0.5, 3.0]}, "between 1 and 200"),
        ({"distances": [math.inf]}, "between 1 and 200"),
        ({"distances": []}, "at least one"),
        ({"seed": -1}, "seed"),
    ],
)
def test_make_config_rejects_bad_values(kwargs: dict[str, object], match: str) -> None:
    args = {"preset": "paper-sim", **kwargs}
    preset = str(args.pop("preset"))
    with pytest.raises(ConfigError, match=match):
        make_config(preset, **args)  # type: ignore[arg-type]


def test_make_config_defaults() -> None:
    full = make_config("paper-sim")
    assert full.distances == tuple(float(k) for k in range(2, 21)) and len(full.textures) == 3
    assert (
        full.calibration_views >= 20
        and full.vpc == RectifiedPairConfig(projection="pinhole")
        and full.scale == 1.0
    )
    quick = make_config("prototype", quick=True, distances=[10, 4, 4])
    assert quick.distances == (4.0, 10.0) and quick.scale == 0.5 and len(quick.textures) == 2
    assert len(full.models) == 6 and "kannala_brandt" in full.models
