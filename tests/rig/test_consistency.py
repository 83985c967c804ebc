"""The cross-pair consistency measure (rig.evaluate.consistency) on exact synthetic ranges: a
closed box room around the ring4 rig, each pair's range computed in closed form (ray against the
box's walls, not the renderer), so the measure's geometry is checked against an independent
reference, and known biases read back as what they are."""

from __future__ import annotations

import functools
import re

import numpy as np
import pytest

from calibration.geometry import make_transform, rot_x, rot_y
from calibration.models import LatLonModel
from calibration.rig import Rig
from rig.depth import latlon_range
from rig.errors import EvaluationError
from rig.evaluate.consistency import (
    ConsistencyFigures,
    Couple,
    PairRange,
    camera_pose,
    couples,
    figures_by,
    range_coverage,
    sample_range,
    transfer_range,
    view_mask,
)
from rig.field import overlap, pixel_solid_angles
from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim.presets import get_ring_preset

BOX_LO, BOX_HI = np.array([-2.5, -1.4, -3.0]), np.array([3.5, 1.1, 4.0])  # rig frame, metres
BAND = 24  # unmatched columns of the synthetic matcher


def _box_range(pair: RectifiedPair, T_world_rig: np.ndarray) -> np.ndarray:
    """Exact range (H, W) float32 along the left view's pixel rays to the box's walls."""
    cam = pair.camera
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], 1), in_image=False)
    T = T_world_rig @ pair.T_rig_rect[pair.left]
    d = rays @ T[:3, :3].T
    o = T[:3, 3]
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, (BOX_HI - o) / d, (BOX_LO - o) / d)
    return np.asarray(np.min(np.where(np.abs(d) > 1e-12, t, np.inf), axis=1), np.float32).reshape(
        cam.height, cam.width
    )


@functools.cache
def _ring() -> tuple[Rig, dict[tuple[str, str], RectifiedPair]]:
    rig = get_ring_preset("ring4").rig
    vpc = {
        p: RectifiedPairConfig(px_per_deg=2.0, left=p[0], right=p[1])
        for p in (("cam1", "cam2"), ("cam2", "cam3"))
    }
    return rig, {p: design_rectified_pair(rig, c, blind_band_px=BAND) for p, c in vpc.items()}


def _view(rig: Rig, pair: RectifiedPair) -> np.ndarray:
    """Directions both lenses see (their models, not lookup tables) left of the band."""
    cam = pair.camera
    v, u = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], 1), in_image=False)
    ok = [rig.cameras[n].project(rays @ pair.R_cam_rect[n].T)[1] for n in (pair.left, pair.right)]
    return view_mask(ok[0].reshape(v.shape), ok[1].reshape(v.shape), BAND)


def _exact(pair: RectifiedPair, rig: Rig, T_world_rig: np.ndarray | None = None) -> PairRange:
    view = _view(rig, pair)
    r = _box_range(pair, np.eye(4) if T_world_rig is None else T_world_rig)
    r[~view] = np.nan
    return PairRange(pair, r, view)


def test_exact_ranges_agree_and_the_points_reach_the_other_pair() -> None:
    rig, pairs = _ring()
    src, tgt = _exact(pairs["cam1", "cam2"], rig), _exact(pairs["cam2", "cam3"], rig)
    t = transfer_range(src, tgt, "cam2")
    f = ConsistencyFigures.of(t)
    print(f"\nexact box room, cam1|cam2 -> cam2|cam3: {f}")
    assert f.points > 2000 and f.both_share > 0.99
    # Bilinear between pixels: a wall's range is not linear in a lat-lon view's pixels (2.4e-5 measured).
    assert f.median_abs < 1e-4 and abs(f.median_signed) < 1e-4
    assert f.within_3 > 0.995 and f.median_abs_px < 1e-3
    # Every point compared lies in the direction all three lenses see (the ring's 10° band
    # about cam2's vertical plane, at the rims of cam1 and cam3).
    assert (t.r_source > 0).all() and np.isfinite(t.d_source).all()


def test_a_known_bias_reads_back() -> None:
    rig, pairs = _ring()
    src, tgt = _exact(pairs["cam1", "cam2"], rig), _exact(pairs["cam2", "cam3"], rig)
    short = PairRange(tgt.pair, (tgt.range / np.float32(1.05)).astype(np.float32), tgt.view)
    f = ConsistencyFigures.of(transfer_range(src, short, "cam2"))
    assert f.median_signed == pytest.approx(0.05, abs=2e-4)
    assert f.median_abs == pytest.approx(0.05, abs=2e-4)
    assert f.within_3 == 0.0 and f.within_10 == 1.0
    # The other way: 5 % too far reads -4.76 % (the disagreement is relative to the target).
    far = PairRange(tgt.pair, (tgt.range * np.float32(1.05)).astype(np.float32), tgt.view)
    assert ConsistencyFigures.of(transfer_range(src, far, "cam2")).median_signed == pytest.approx(
        1 / 1.05 - 1, abs=2e-4
    )


def test_a_disparity_offset_reads_back_in_pixels() -> None:
    """The target's range made from its true disparity plus 1 px (rig.depth.latlon_range, the
    pipeline's own formula) reads a disparity disagreement of -1 px, through the measure's
    projection of each range into the right view."""
    rig, pairs = _ring()
    src, tgt = _exact(pairs["cam1", "cam2"], rig), _exact(pairs["cam2", "cam3"], rig)
    cam = tgt.pair.camera
    assert isinstance(cam, LatLonModel)
    az = cam.azimuths()[None, :]
    B = tgt.pair.baseline_m
    # Invert range = B (cos α cot δ + sin α): tan δ = cos α / (r/B − sin α).
    delta = np.arctan2(np.cos(az), tgt.range / B - np.sin(az))
    shifted = latlon_range((delta * cam.fx + 1.0).astype(np.float32), cam, B)
    f = ConsistencyFigures.of(transfer_range(src, PairRange(tgt.pair, shifted, tgt.view), "cam2"))
    assert f.median_signed_px == pytest.approx(-1.0, abs=0.01)
    assert f.median_abs_px == pytest.approx(1.0, abs=0.01)
    assert f.median_signed > 0.0  # more disparity = nearer target, the source reads further


def test_pairs_calibrated_apart_meet_in_the_shared_camera() -> None:
    """The target pair designed in another rig frame (its calibration file put the rig's origin
    elsewhere): the points move through cam2's own frame, so the comparison is unchanged; had
    they gone through the rig frame they would land 0.3 m and 20° off."""
    rig, pairs = _ring()
    T = make_transform(rot_y(0.35) @ rot_x(-0.1), [0.3, 0.05, -0.2])
    moved = Rig(dict(rig.cameras), {n: T @ P for n, P in rig.T_rig_cam.items()})
    tgt_pair = design_rectified_pair(
        moved, RectifiedPairConfig(px_per_deg=2.0, left="cam2", right="cam3"), blind_band_px=BAND
    )
    assert np.allclose(camera_pose(tgt_pair, "cam2"), moved.T_rig_cam["cam2"], atol=1e-12)
    src = _exact(pairs["cam1", "cam2"], rig)
    tgt = _exact(tgt_pair, moved, np.linalg.inv(T))  # the same room, seen from the moved frame
    f = ConsistencyFigures.of(transfer_range(src, tgt, "cam2"))
    assert f.both_share > 0.99 and f.median_abs < 1e-4


def test_sample_range_interpolates_only_between_valid_pixels() -> None:
    r = np.add.outer(np.arange(4.0), 10.0 * np.arange(5.0)).astype(np.float32)  # r = v + 10 u
    pix = np.array([[1.25, 2.5], [3.9, 0.1], [-0.4, -0.4], [4.6, 1.0], [1.0, -0.6]])
    got = sample_range(r, pix)
    assert got[:3] == pytest.approx([2.5 + 12.5, 0.1 + 39.0, 0.0], abs=1e-5)  # bilinear (clamped at the edge)
    assert np.isnan(got[3:]).all()  # outside the image
    r[2, 2] = np.nan  # a hole: no bilinear across it
    near = sample_range(r, np.array([[1.4, 1.4], [1.6, 1.6], [2.6, 1.4], [3.5, 3.0]]))
    assert near[0] == pytest.approx(1.0 + 10.0)  # the nearest pixel, (1, 1)
    assert np.isnan(near[1])  # the nearest pixel is the hole itself
    assert near[2] == pytest.approx(1.0 + 30.0)  # (u, v) = (3, 1)
    assert near[3] == pytest.approx(3.0 + 35.0)  # four valid neighbours away from the hole


def test_coverage_is_the_solid_angle_share_of_the_view() -> None:
    rig, pairs = _ring()
    pr = _exact(pairs["cam1", "cam2"], rig)
    cam = pr.pair.camera
    assert isinstance(cam, LatLonModel)
    solid = pixel_solid_angles(cam)
    # Closed form per pixel: cos(azimuth) / (fx fy); the overlap's own solid angle on its grid.
    closed = np.cos(cam.azimuths())[None, :] / (cam.fx * cam.fy)
    assert np.allclose(solid, closed, rtol=1e-4)
    view_sr = float((closed * pr.view).sum())
    ov = overlap(rig, pr.pair.R_rig_rect, "cam1", "cam2", step_deg=0.25)
    assert view_sr == pytest.approx(ov.solid_angle_sr, rel=0.02)
    assert range_coverage(pr, solid) == pytest.approx(1.0)
    half = pr.range.copy()
    half[:, : cam.width // 2] = np.nan
    expect = float((closed * pr.view)[:, cam.width // 2 :].sum()) / view_sr
    assert range_coverage(PairRange(pr.pair, half, pr.view), solid) == pytest.approx(expect, rel=1e-4)
    assert not pr.view[:, :BAND].any()  # the matcher's band is left out


def test_figures_by_bins_and_empty_figures() -> None:
    rig, pairs = _ring()
    t = transfer_range(_exact(pairs["cam1", "cam2"], rig), _exact(pairs["cam2", "cam3"], rig), "cam2")
    bins = figures_by(t, t.r_target, [0.0, 2.0, 4.0, 100.0])
    assert sum(f.points for _, _, f in bins) == t.r_target.size
    assert [lo for lo, _, _ in bins] == [0.0, 2.0, 4.0]
    empty = ConsistencyFigures.of(t.select(np.zeros(t.r_target.size, dtype=bool)))
    assert empty.points == 0 and np.isnan(empty.median_abs)


def test_couples_take_the_pair_seen_from_the_shared_camera_as_target() -> None:
    ring = [("c1", "c2"), ("c2", "c3"), ("c3", "c4"), ("c4", "c1")]
    got = {(c.source, c.target, c.shared) for c in couples(ring)}
    assert got == {
        (("c1", "c2"), ("c2", "c3"), "c2"),
        (("c2", "c3"), ("c3", "c4"), "c3"),
        (("c3", "c4"), ("c4", "c1"), "c4"),
        (("c4", "c1"), ("c1", "c2"), "c1"),
    }
    assert couples([("a", "b"), ("b", "a")]) == []  # the same two cameras
    assert couples([("s", "a"), ("s", "b")]) == [Couple(("s", "a"), ("s", "b"), "s")]
    assert couples([("a", "s"), ("b", "s")]) == [Couple(("a", "s"), ("b", "s"), "s")]
    assert Couple(("c1", "c2"), ("c2", "c3"), "c2").label == "c1|c2 → c2|c3"


def test_bad_input_is_named() -> None:
    rig, pairs = _ring()
    pr = _exact(pairs["cam1", "cam2"], rig)
    with pytest.raises(EvaluationError, match="must be the rectified view's"):
        PairRange(pr.pair, pr.range[:-1], pr.view)
    with pytest.raises(EvaluationError, match=re.escape("camera 'cam3' is not in pair cam1|cam2")):
        transfer_range(pr, pr, "cam3")
