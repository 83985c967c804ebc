"""The panorama's equirectangular projection against its definition: mrcal's LENSMODEL_LONLAT
formula written independently, round trips over the whole sphere, columns as half-planes through
the vertical axis, and the poles (tests/rig/test_mrcal_reference.py checks it against mrcal)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.models import MODELS, EquirectModel

PANO = EquirectModel.whole_sphere(1.5)


def _grid(m: EquirectModel) -> np.ndarray:
    u, v = np.meshgrid(np.arange(m.width, dtype=float), np.arange(m.height, dtype=float))
    return np.stack([u.ravel(), v.ravel()], axis=1)


def test_projection_is_the_lonlat_formula() -> None:
    rng = np.random.default_rng(5)
    p = rng.normal(size=(2000, 3)) * rng.uniform(0.1, 50.0, (2000, 1))
    m = EquirectModel(4000, 2000, fx=600.0, fy=620.0, cx=1999.5, cy=1010.0)
    pix, ok = m.project(p, in_image=False)
    assert ok.all()
    # mrcal's lensmodels doc: q = (fx·lon + cx, fy·lat + cy), lon = atan2(px, pz), lat = asin(py/|p|).
    u = 600.0 * np.angle(p[:, 2] + 1j * p[:, 0]) + 1999.5
    v = 620.0 * np.arcsin(p[:, 1] / np.linalg.norm(p, axis=1)) + 1010.0
    assert np.abs(pix[:, 0] - u).max() < 1e-8
    assert np.abs(pix[:, 1] - v).max() < 1e-8


def test_the_whole_sphere_in_one_image_round_trips() -> None:
    assert (PANO.width, PANO.height) == (540, 270)
    px = _grid(PANO)
    rays, ok = PANO.unproject(px)
    assert ok.all()
    lon = np.degrees(np.arctan2(rays[:, 0], rays[:, 2]))
    lat = np.degrees(np.arcsin(rays[:, 1]))
    half = 0.5 / 1.5  # half a pixel, in degrees
    assert np.isclose(lon.min(), -180.0 + half) and np.isclose(lon.max(), 180.0 - half)
    assert np.isclose(lat.min(), -90.0 + half) and np.isclose(lat.max(), 90.0 - half)
    back, ok2 = PANO.project(rays)
    assert ok2.all()
    assert np.abs(back - px).max() < 1e-9
    assert np.allclose(np.linalg.norm(rays, axis=1), 1.0)


def test_columns_are_half_planes_through_the_vertical_and_angles_are_even() -> None:
    rays, _ = PANO.unproject(_grid(PANO))
    r = rays.reshape(PANO.height, PANO.width, 3)
    lon = (np.arange(PANO.width) - PANO.cx) / PANO.fx
    normal = np.stack([np.cos(lon), np.zeros_like(lon), -np.sin(lon)], axis=1)  # of column u's plane
    assert np.abs(np.einsum("hwk,wk->hw", r, normal)).max() < 1e-12
    down = np.arccos(np.clip(np.einsum("hwk,hwk->hw", r[1:], r[:-1]), -1, 1))
    assert np.allclose(down, 1.0 / PANO.fy, rtol=1e-6)
    along = np.arccos(np.clip(np.einsum("hwk,hwk->hw", r[:, 1:], r[:, :-1]), -1, 1))
    lat = (np.arange(PANO.height) - PANO.cy) / PANO.fy
    assert np.allclose(along, np.cos(lat)[:, None] / PANO.fx, rtol=1e-5)


def test_the_poles_are_invalid_and_it_is_no_lens() -> None:
    _, ok = PANO.project(np.array([[0.0, -2.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 0.0]]), in_image=False)
    assert not ok.any()
    assert "equirect" not in MODELS
    with pytest.raises(ModelError):
        EquirectModel(10, 10, fx=0.0, fy=1.0, cx=0.0, cy=0.0)
    assert math.isclose(EquirectModel.whole_sphere(4.0).fx * 2 * math.pi, 1440)
