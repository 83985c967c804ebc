"""The lat-lon (transverse equirectangular) projection against its definition: mrcal's
LENSMODEL_LATLON formula written independently, round trips, the geometry of its rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.models import MODELS, LatLonModel

# 1.8 px/deg over 100° of azimuth and 200° of elevation: rows past ±90° look backwards.
F = math.degrees(1.0) * 1.8
WIDE = LatLonModel(180, 360, fx=F, fy=F, cx=89.5, cy=179.5)


def _grid(m: LatLonModel) -> np.ndarray:
    u, v = np.meshgrid(np.arange(m.width, dtype=float), np.arange(m.height, dtype=float))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def test_projection_is_mrcal_latlon_formula() -> None:
    rng = np.random.default_rng(3)
    p = rng.normal(size=(2000, 3)) * rng.uniform(0.1, 50.0, (2000, 1))
    m = LatLonModel(4000, 4000, fx=700.0, fy=650.0, cx=1999.5, cy=2010.0)
    pix, ok = m.project(p, in_image=False)
    assert ok.all()
    # mrcal's lensmodels doc: q = (fx asin(px/|p|) + cx, fy atan(py/pz) + cy), atan taken over
    # the whole circle (the quadrant of (pz, py)).
    u = 700.0 * np.arcsin(p[:, 0] / np.linalg.norm(p, axis=1)) + 1999.5
    v = 650.0 * np.angle(p[:, 2] + 1j * p[:, 1]) + 2010.0
    assert np.abs(pix[:, 0] - u).max() < 1e-8
    assert np.abs(pix[:, 1] - v).max() < 1e-8


def test_round_trip_every_pixel_of_a_field_past_180_degrees() -> None:
    px = _grid(WIDE)
    rays, ok = WIDE.unproject(px)
    assert ok.all()
    el = np.degrees(np.arctan2(rays[:, 1], rays[:, 2]))
    assert el.min() < -99.0 and el.max() > 99.0, "the field reaches past ±90° of elevation"
    assert (rays[:, 2] < 0).any()
    back, ok2 = WIDE.project(rays)
    assert ok2.all()
    assert np.abs(back - px).max() < 1e-9


def test_rows_are_planes_through_the_x_axis_and_angles_are_even() -> None:
    rays, _ = WIDE.unproject(_grid(WIDE))
    r = rays.reshape(WIDE.height, WIDE.width, 3)
    el = WIDE.elevations()
    normal = np.stack([np.zeros_like(el), np.cos(el), -np.sin(el)], axis=1)  # of the plane of row v
    assert np.abs(np.einsum("hwk,hk->hw", r, normal)).max() < 1e-12
    # Along a row neighbours are 1/fx apart; down a column cos(azimuth)/fy.
    along = np.arccos(np.clip(np.einsum("hwk,hwk->hw", r[:, 1:], r[:, :-1]), -1, 1))
    assert np.allclose(along, 1.0 / F, rtol=1e-6)
    down = np.arccos(np.clip(np.einsum("hwk,hwk->hw", r[1:], r[:-1]), -1, 1))
    expected = np.cos(WIDE.azimuths())[None, :] / F
    assert np.allclose(down, np.broadcast_to(expected, down.shape), rtol=1e-5)


def test_poles_and_outside_are_invalid() -> None:
    m = LatLonModel(100, 100, fx=30.0, fy=30.0, cx=49.5, cy=49.5)
    _, ok = m.project([[2.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1e-9, 0.0]], in_image=False)
    assert ok.tolist() == [False, False, False, True]
    # Azimuth beyond ±90° or elevation beyond ±180° has no ray.
    u_far = 49.5 + 30.0 * (math.pi / 2 + 0.01)
    v_far = 49.5 + 30.0 * (math.pi + 0.01)
    _, ok = m.unproject([[u_far, 49.5], [49.5, v_far], [49.5, 49.5]], in_image=False)
    assert ok.tolist() == [False, False, True]


def test_project_xyz_agrees_with_project() -> None:
    rng = np.random.default_rng(5)
    p = rng.normal(size=(5000, 3))
    pix, ok = WIDE.project(p)
    u, v, ok2 = WIDE.project_xyz(p[:, 0], p[:, 1], p[:, 2])
    assert (ok == ok2).all() and ok.any() and not ok.all()
    assert np.abs(u[ok] - pix[ok, 0]).max() < 1e-12
    assert np.abs(v[ok] - pix[ok, 1]).max() < 1e-12


def test_not_a_lens_and_checks_its_parameters() -> None:
    assert "latlon" not in MODELS
    with pytest.raises(ModelError, match="positive"):
        LatLonModel(10, 10, fx=0.0, fy=1.0, cx=0.0, cy=0.0)
    d = WIDE.to_dict()
    assert d["model"] == "latlon" and LatLonModel.from_dict(d) == WIDE
