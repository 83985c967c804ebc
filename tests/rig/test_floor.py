"""The floor model of :mod:`rig.floor` on exact synthetic rays (no renderer, no matcher): a floor
at a known height seen by the prototype's pair, the right camera's rays turned by a known
rotation, and the fits finding it again; what the floor cannot see (a turn about the baseline)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rig.errors import RectificationError
from rig.floor import (
    HEIGHT,
    FloorGeometry,
    FloorOptions,
    FloorSamples,
    fit_floor,
    fit_plane,
    floor_height,
    floor_params,
    floor_residuals,
)
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ring import rig_up
from rig.sim import get_preset

HEIGHT_M = 1.2


def _floor(
    turn_deg: tuple[float, float, float], noise_px: float = 0.0, wall_m: float | None = None
) -> tuple[FloorGeometry, FloorSamples]:
    """Rays of a floor ``HEIGHT_M`` below the prototype: the left rays over the lower half of the
    view, the right rays to the same floor points as a right camera turned by ``turn_deg``
    (about the rig's x, y, z) would report them through the nominal calibration. With
    ``wall_m`` the same rays see a wall that far ahead instead (no floor)."""
    rig = get_preset("prototype").rig
    pair = design_rectified_pair(rig, RectifiedPairConfig())
    geo = FloorGeometry.of(pair, rig_up(rig))
    rng = np.random.default_rng(0)
    az = rng.uniform(np.radians(-50), np.radians(50), 20000)
    el = rng.uniform(np.radians(12), np.radians(95), az.size)
    rect = np.stack([np.sin(az), np.cos(az) * np.sin(el), np.cos(az) * np.cos(el)], axis=1)
    a = rect @ pair.R_rig_rect.T
    t = (-HEIGHT_M - geo.c_left @ geo.up) / (a @ geo.up)
    if wall_m is not None:
        t = (wall_m - geo.c_left @ geo.z) / (a @ geo.z)
    u = geo.c_left + t[:, None] * a - geo.c_right
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    # The true right camera is the nominal one turned by R: what it sees along u, the nominal
    # calibration reports as R⁻¹·u.
    q = Rotation.from_rotvec(np.radians(turn_deg)).inv().apply(u)
    if noise_px:
        q = Rotation.from_rotvec(rng.normal(0, noise_px / geo.fx, (az.size, 3))).apply(q)
    cells = (np.degrees(az) // 3).astype(np.int64) * 1000 + (np.degrees(el) // 3).astype(np.int64)
    s = FloorSamples(a, q, t, np.zeros((az.size, 2)), np.zeros(az.size, dtype=np.intp), cells)
    return geo, s


def _in_rectified(geo: FloorGeometry, turn_deg: tuple[float, float, float]) -> list[float]:
    """The turn's components about the pair's rectified y and z (degrees)."""
    return [float(np.dot(turn_deg, geo.y)), float(np.dot(turn_deg, geo.z))]


@pytest.mark.parametrize("turn", [(0.0, 0.3, 0.0), (0.0, -0.5, 0.2), (0.0, 0.0, -0.4)])
def test_the_turn_about_the_rectified_y_and_z_is_found_exactly(turn: tuple[float, float, float]) -> None:
    geo, s = _floor(turn)
    assert np.median(np.abs(floor_residuals(geo, s, floor_params(HEIGHT_M)))) * geo.fx > 0.5
    fit = fit_floor(geo, s, HEIGHT_M, FloorOptions())
    # The fit is the camera's turn itself (turning the calibration's camera by it gives the true
    # one), in the pair's rectified axes.
    assert fit.omega_deg == pytest.approx(_in_rectified(geo, turn), abs=2e-4)
    assert fit.inliers.all() and fit.residual_px < 1e-3


def test_the_floor_does_not_see_a_turn_about_the_baseline() -> None:
    """A turn about the baseline moves no azimuth: the floor is exactly where it should be, the
    fit leaves it alone (it has no such parameter: the vertical disparity observes it), and it
    does not disturb the vergence found beside it beyond second order."""
    geo, s = _floor((0.5, 0.0, 0.0))
    assert np.max(np.abs(floor_residuals(geo, s, floor_params(HEIGHT_M)))) * geo.fx < 1e-6
    assert np.abs(fit_floor(geo, s, HEIGHT_M, FloorOptions()).omega_deg).max() < 1e-6
    geo, s = _floor((0.5, 0.3, 0.2))
    fit = fit_floor(geo, s, HEIGHT_M, FloorOptions())
    assert fit.omega_deg == pytest.approx(_in_rectified(geo, (0.5, 0.3, 0.2)), abs=2e-3)
    assert fit.residual_px < 1e-3


def test_a_wrong_height_is_read_as_a_turn_about_the_look_direction() -> None:
    """The limit of the method: a floor nearer than told has larger disparities, growing with
    the depression like a turn about z does; the fit cannot tell them apart to first order, so
    the height must be known. 0.2 m short of 1.2 m reads as ≈0.6° about z (the model then
    fits worse: ≈0.3 px), the vergence barely moves."""
    geo, s = _floor((0.0, 0.0, 0.0))
    fit = fit_floor(geo, s, HEIGHT_M - 0.2, FloorOptions())
    print(f"\nsynthetic, height 0.2 m short: turn {fit.omega_deg} deg, residual {fit.residual_px:.3f} px")
    assert fit.omega_deg[1] == pytest.approx(0.6, abs=0.05)
    assert abs(fit.omega_deg[0]) < 0.05
    assert 0.2 < fit.residual_px < 0.4


def test_noise_and_its_uncertainty() -> None:
    """0.3 px of noise on every ray: the turn is found to within three of its 1σ."""
    geo, s = _floor((0.0, 0.2, 0.1), noise_px=0.3)
    fit = fit_floor(geo, s, HEIGHT_M, FloorOptions())
    err = fit.omega_deg - _in_rectified(geo, (0.0, 0.2, 0.1))
    print(f"\nsynthetic, 0.3 px noise: error {err} deg, 1σ {fit.omega_sigma_deg} deg")
    assert np.all(np.abs(err) < 3 * fit.omega_sigma_deg)
    assert np.all(fit.omega_sigma_deg < 0.005)


def test_the_plane_as_the_rays_show_it() -> None:
    """Without a turn the plane fit finds the floor's height and no tilt; its own height search
    finds it with no height given."""
    geo, s = _floor((0.0, 0.0, 0.0))
    plane = fit_plane(geo, s, 1.0, FloorOptions())
    assert plane.params[HEIGHT] == pytest.approx(HEIGHT_M, abs=1e-6)
    assert np.abs(plane.tilt_deg).max() < 1e-4 and plane.residual_px < 1e-3
    assert floor_height(geo, s, FloorOptions()).params[HEIGHT] == pytest.approx(HEIGHT_M, abs=1e-6)


def test_no_floor_is_an_error_naming_it() -> None:
    geo, s = _floor((0.0, 0.0, 0.0))
    with pytest.raises(RectificationError, match="no floor in view: 100 pixels below the horizon"):
        fit_floor(geo, s.select(np.arange(len(s)) < 100), HEIGHT_M, FloorOptions())


def test_a_wall_is_no_floor() -> None:
    """Rays that see a wall 3 m ahead, not the floor: about half of them can be bent onto the
    floor, but only by a turn of a few degrees, more than the candidates' window allows."""
    geo, s = _floor((0.0, 0.0, 0.0), wall_m=3.0)
    s = s.select(s.range > 0)
    with pytest.raises(
        RectificationError, match=r"no floor in view: the pixels agree only after a [\d.]+° turn"
    ):
        fit_floor(geo, s, HEIGHT_M, FloorOptions())
