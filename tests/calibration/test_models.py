"""The one suite every camera model passes (basalt-headers style): round trips over the whole
image, behaviour outside the domain, serialisation, and references where they exist."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.errors import ModelError
from calibration.models import MODELS, CameraModel, create
from tests.calibration.model_cases import ModelCase, model_cases

CASES = model_cases()


@pytest.fixture(params=CASES, ids=[c.id for c in CASES])
def case(request: pytest.FixtureRequest) -> ModelCase:
    return request.param


def pixel_grid(model: CameraModel, step: int = 2) -> np.ndarray:
    """Every ``step``-th pixel of the image plus the exact corners and edges, (N, 2)."""
    u = np.arange(0, model.width, step, dtype=np.float64)
    v = np.arange(0, model.height, step, dtype=np.float64)
    uu, vv = np.meshgrid(np.append(u, model.width - 1), np.append(v, model.height - 1))
    extra = np.array([[-0.5, -0.5], [model.width - 0.5, model.height - 0.5]])
    return np.vstack([np.stack([uu.ravel(), vv.ravel()], axis=1), extra])


def test_every_model_is_covered() -> None:
    assert {c.model.name for c in CASES} == set(MODELS)


def test_round_trip_every_valid_pixel(case: ModelCase) -> None:
    m = case.model
    px = pixel_grid(m)
    rays, ok = m.unproject(px)
    assert ok.mean() > 0.3, "a realistic model unprojects a good part of its image"
    assert np.allclose(np.linalg.norm(rays[ok], axis=1), 1.0, atol=1e-12)
    back, ok2 = m.project(rays[ok])
    assert ok2.all(), "every unprojected ray must project back as valid"
    err = np.abs(back - px[ok]).max()
    assert err <= 1e-6, f"round trip error {err} px"


@pytest.mark.parametrize("wide_case", [c for c in CASES if c.wide], ids=lambda c: c.id)
def test_wide_lenses_round_trip_past_90_degrees(wide_case: ModelCase) -> None:
    m = wide_case.model
    rays, ok = m.unproject(pixel_grid(m))
    theta = np.degrees(np.arccos(rays[ok, 2]))
    assert theta.max() > 90.0
    beyond = rays[ok][theta > 90.0]
    back, ok2 = m.project(beyond)
    assert ok2.all()
    rays2, ok3 = m.unproject(back)
    assert ok3.all() and np.abs(rays2 - beyond).max() < 1e-9


def test_ray_round_trip_within_field(case: ModelCase) -> None:
    m = case.model
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.0, m.max_theta, 5000)
    phi = rng.uniform(-math.pi, math.pi, 5000)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    px, ok = m.project(rays * rng.uniform(0.1, 50.0, (5000, 1)))
    assert ok.any()
    back, ok2 = m.unproject(px[ok])
    assert ok2.all()
    assert np.abs(back - rays[ok]).max() < 1e-8


def test_points_beyond_the_lens_limit_are_invalid_and_finite(case: ModelCase) -> None:
    m = case.model
    theta = np.linspace(min(m.max_theta + 1e-3, math.pi), math.pi, 50)
    phi = np.linspace(-math.pi, math.pi, theta.size)
    pts = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    pts = np.vstack([pts, [[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]])
    px, ok = m.project(pts, in_image=False)
    assert not ok.any()
    assert np.isfinite(px).all()


def test_points_outside_the_image_are_invalid(case: ModelCase) -> None:
    m = case.model
    outside = np.array(
        [[-0.51, 10.0], [m.width - 0.49, 10.0], [10.0, -0.51], [10.0, m.height - 0.49], [-1e6, 1e6]]
    )
    rays, ok = m.unproject(outside)
    assert not ok.any() and np.isfinite(rays).all()
    # A ray that lands outside the image is invalid with in_image, valid without it.
    rays_in, ok_in = m.unproject(pixel_grid(m, step=37))
    _, ok_px = m.project(rays_in[ok_in])
    assert ok_px.all()


def test_garbage_input_is_invalid_never_nan(case: ModelCase) -> None:
    m = case.model
    pts = np.array([[np.nan, 0.0, 1.0], [np.inf, 0.0, 1.0], [0.0, 0.0, np.nan]])
    px, ok = m.project(pts)
    assert not ok.any() and np.isfinite(px).all()
    rays, ok = m.unproject(np.array([[np.nan, 1.0], [1.0, np.inf]]))
    assert not ok.any() and np.isfinite(rays).all()


def test_serialisation_round_trip(case: ModelCase) -> None:
    m = case.model
    d = m.to_dict()
    again = CameraModel.from_dict(d)
    assert again == m
    assert type(m).from_dict(d) == m
    assert m.with_params(m.params) == m
    assert len(m.params) == len(type(m).all_param_names())


def test_shapes_and_single_point(case: ModelCase) -> None:
    m = case.model
    px, ok = m.project(np.array([0.01, -0.02, 1.0]))
    assert px.shape == (1, 2) and ok.shape == (1,) and ok[0]
    with pytest.raises(ModelError):
        m.project(np.zeros((3, 2)))


def test_kannala_brandt_matches_opencv_fisheye() -> None:
    p = dict(fx=285.0, fy=284.2, cx=652.3, cy=471.8, k1=0.0241, k2=-0.0153, k3=0.0047, k4=-0.00061)
    m = create("kannala_brandt", 1280, 960, **p)
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(20000, 3))
    pts[:, 2] = np.abs(pts[:, 2]) + 1e-3
    ours, _ = m.project(pts, in_image=False)
    K = np.array([[p["fx"], 0, p["cx"]], [0, p["fy"], p["cy"]], [0, 0, 1.0]])
    D = np.array([p["k1"], p["k2"], p["k3"], p["k4"]])
    ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    ref = ref.reshape(-1, 2)
    rel = np.abs(ours - ref) / np.maximum(np.abs(ref), 1.0)
    assert rel.max() <= 1e-9


def test_pinhole_radtan_matches_opencv() -> None:
    p = dict(fx=458.654, fy=457.296, cx=367.215, cy=248.375, k1=-0.2834, k2=0.07396, p1=1.9e-4, p2=1.8e-5)
    m = create("pinhole", 752, 480, **p)
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, (5000, 2)), np.ones(5000)]) * rng.uniform(0.5, 9, (5000, 1))
    ours, ok = m.project(pts, in_image=False)
    assert ok.all()
    K = np.array([[p["fx"], 0, p["cx"]], [0, p["fy"], p["cy"]], [0, 0, 1.0]])
    D = np.array([p["k1"], p["k2"], p["p1"], p["p2"]])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)
    assert np.abs(ours - ref.reshape(-1, 2)).max() < 1e-9


def test_kannala_brandt_limit_where_theta_d_stops_increasing() -> None:
    # k1 < 0 strong enough that θd(θ) peaks before 90°: beyond the peak there is no inverse.
    m = create("kannala_brandt", 1000, 1000, fx=300, fy=300, cx=500, cy=500, k1=-0.3, k2=0, k3=0, k4=0)
    peak = math.sqrt(1 / 0.9)
    assert m.max_theta == pytest.approx(peak, rel=1e-9)
    past = np.array([[math.sin(peak + 0.05), 0.0, math.cos(peak + 0.05)]])
    assert not m.project(past, in_image=False)[1].any()


def test_equidistant_is_kannala_brandt_without_distortion() -> None:
    e = create("equidistant", 800, 800, fx=250, fy=251, cx=400, cy=399)
    k = create("kannala_brandt", 800, 800, fx=250, fy=251, cx=400, cy=399, k1=0, k2=0, k3=0, k4=0)
    pts = np.random.default_rng(0).normal(size=(1000, 3))
    pe, oke = e.project(pts, in_image=False)
    pk, okk = k.project(pts, in_image=False)
    both = oke & okk
    assert both.sum() > 400 and np.allclose(pe[both], pk[both], atol=1e-9)


@pytest.mark.parametrize(
    "name, params",
    [
        ("nope", {}),
        ("pinhole", {"fx": 1.0, "fy": 1.0, "cx": 0.0}),
        ("pinhole", {"fx": -1.0, "fy": 1.0, "cx": 0.0, "cy": 0.0}),
        ("pinhole", {"fx": 1.0, "fy": 1.0, "cx": 0.0, "cy": float("nan")}),
        ("pinhole", {"fx": 1.0, "fy": 1.0, "cx": 0.0, "cy": 0.0, "bogus": 1.0}),
        ("pinhole", {"fx": "a", "fy": 1.0, "cx": 0.0, "cy": 0.0}),
    ],
)
def test_bad_parameters_raise_model_error(name: str, params: dict[str, object]) -> None:
    with pytest.raises(ModelError):
        create(name, 640, 480, **params)
    with pytest.raises(ModelError):
        create("pinhole", 0, 480, fx=1, fy=1, cx=0, cy=0)
