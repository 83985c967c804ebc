"""The one suite every camera model passes (basalt-headers style): round trips over the whole
image, behaviour outside the domain, serialisation, and references where they exist."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from calibration.errors import ModelError
from calibration.models import MODELS, CameraModel, ScaramuzzaModel, create
from calibration.models.base import smallest_positive_root
from calibration.models.radtan import RadTan
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
    print(f"\n{case.id}: round trip over {ok.sum()} valid pixels, max error {err:.1e} px")
    assert err <= 1e-10, f"round trip error {err} px"  # measured ≤ 7.6e-12 (Mei), ~1e-13 elsewhere


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
    assert len(m.params) == len(m.param_layout)
    if not type(m).list_params:
        assert len(m.params) == len(type(m).all_param_names())
    # The rig.yaml block is plain YAML/JSON data (lists, not tuples or numpy) and survives a dump.
    text = yaml.safe_dump(d)
    assert CameraModel.from_dict(yaml.safe_load(text)) == m


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
    print(f"\nKannala-Brandt against cv2.fisheye.projectPoints: max relative difference {rel.max():.1e}")
    assert rel.max() <= 1e-13  # measured 8.5e-15


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
    diff = float(np.abs(ours - ref.reshape(-1, 2)).max())
    print(f"\npinhole + radtan against cv2.projectPoints: max difference {diff:.1e} px")
    assert diff <= 1e-12  # measured 1.1e-13 px


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


# ----- list-valued parameters (Scaramuzza's poly/invpol) -------------------------------------------
SCARA_POLY = [260.0, 0.0, -1.3e-3, 1.9e-7, -1.9e-9]
SCARA: dict[str, Any] = dict(poly=SCARA_POLY, cx=322.4, cy=237.1, c=0.9996, d=0.0011, e=-0.0007)


def test_list_parameters_flat_vector_layout() -> None:
    m = ScaramuzzaModel(640, 480, None, **SCARA)
    assert m.param_layout == (
        "poly[0]",
        "poly[1]",
        "poly[2]",
        "poly[3]",
        "poly[4]",
        "cx",
        "cy",
        "c",
        "d",
        "e",
    )
    assert np.array_equal(m.params, [*SCARA_POLY, 322.4, 237.1, 0.9996, 0.0011, -0.0007])
    d = m.to_dict()
    assert d["params"]["poly"] == SCARA["poly"] and isinstance(d["params"]["invpol"], list)
    assert m.param_dict["poly"] == tuple(SCARA_POLY)
    assert m.invpol_error_px is not None and m.invpol_error_px <= 0.01
    # A changed vector refits the derived invpol; the new model is self-consistent.
    v = m.params.copy()
    v[2] *= 1.05
    m2 = m.with_params(v)
    assert m2.poly[2] == pytest.approx(SCARA_POLY[2] * 1.05) and m2.invpol != m.invpol
    px = pixel_grid(m2, step=9)
    rays, ok = m2.unproject(px)
    back, ok2 = m2.project(rays[ok])
    assert ok2.all() and np.abs(back - px[ok]).max() <= 1e-6
    # replace() refits invpol when anything changes, keeps it for a plain copy or when given.
    assert m.replace() == m
    assert m.replace(cx=330.0).invpol != m.invpol
    assert m.replace(cx=330.0, invpol=list(m.invpol)).invpol == m.invpol
    with pytest.raises(ModelError, match="expected 10 parameters"):
        m.with_params(v[:-1])


@pytest.mark.parametrize(
    "name, params, match",
    [
        ("scaramuzza", SCARA | {"poly": "260 0 -1e-3"}, "poly must be a list"),
        ("scaramuzza", SCARA | {"poly": [260.0, "x"]}, r"poly\[1\] must be a number"),
        ("scaramuzza", SCARA | {"poly": [260.0, float("nan")]}, r"poly\[1\] must be finite"),
        ("scaramuzza", SCARA | {"poly": []}, "at least one coefficient"),
        ("scaramuzza", SCARA | {"poly": [-260.0, 0.0, 1.3e-3]}, "a0"),
        ("scaramuzza", SCARA | {"c": 0.001, "d": 1.0, "e": 1.0}, "determinant"),
        ("scaramuzza", SCARA | {"invpol": [1.0, float("inf")]}, r"invpol\[1\] must be finite"),
        ("scaramuzza", SCARA | {"cx": [1.0]}, "cx must be a number"),
        ("mei", dict(xi=-0.1, k1=0, k2=0, p1=0, p2=0, fx=300, fy=300, cx=320, cy=240), "xi"),
        ("mei", dict(xi=0.9, k1=0, k2=0, p1=0, p2=0, fx=0, fy=300, cx=320, cy=240), "fx and fy"),
        ("double_sphere", dict(fx=300, fy=300, cx=320, cy=240, xi=-1.0, alpha=0.6), "xi"),
        ("double_sphere", dict(fx=300, fy=300, cx=320, cy=240, xi=0.1, alpha=1.2), "alpha"),
        ("eucm", dict(fx=300, fy=300, cx=320, cy=240, alpha=0.6, beta=0.0), "beta"),
        ("eucm", dict(fx=300, fy=300, cx=320, cy=240, alpha=-0.1, beta=1.0), "alpha"),
    ],
)
def test_bad_omnidirectional_parameters_raise_model_error(
    name: str, params: dict[str, object], match: str
) -> None:
    with pytest.raises(ModelError, match=match):
        create(name, 640, 480, **params)


# ----- absurd magnitudes: a ModelError naming the parameter, never an overflow warning --------------
PINHOLE = dict(fx=320.0, fy=321.0, cx=319.5, cy=239.5)


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize(
    "name, width, height, params, match, param",
    [
        ("pinhole", 100_001, 480, PINHOLE, "pinhole: width must be at most 100000 px, got 100001", "width"),
        ("pinhole", 640, 1e200, PINHOLE, r"pinhole: height must be at most 100000 px, got 1e\+200", "height"),
        (
            "scaramuzza",
            1e155,
            480,
            SCARA,
            r"scaramuzza: width must be at most 100000 px, got 1e\+155",
            "width",
        ),
        ("pinhole", 640, 10**400, PINHOLE, r"height must be at most 100000 px, got ~1e\+400", "height"),
        ("pinhole", float("inf"), 480, PINHOLE, "width must be a positive integer, got inf", "width"),
        (
            "scaramuzza",
            640,
            480,
            SCARA | {"cx": 1e200},
            r"scaramuzza: distortion centre cx must be within \[-640, 1280\] .*, got 1e\+200",
            "cx",
        ),
        (
            "scaramuzza",
            640,
            480,
            SCARA | {"cy": -481.0},
            r"scaramuzza: distortion centre cy must be within \[-480, 960\] .*, got -481",
            "cy",
        ),
        ("scaramuzza", 640, 480, SCARA | {"d": 1e300}, "stretch matrix entry d must be within ±10", "d"),
        (
            "scaramuzza",
            640,
            480,
            SCARA | {"c": 1e-300, "d": 0.0},
            "determinant c - d\\*e must be at least",
            None,
        ),
        (
            "scaramuzza",
            640,
            480,
            SCARA | {"poly": [260.0, 0.0, 1e300, 1.9e-7, -1.9e-11]},  # ratio 1e300/5.7e-11 overflows
            "poly's dθ/dρ polynomial: coefficients from .* too far apart",
            "poly",
        ),
        ("scaramuzza", 640, 480, SCARA | {"poly": [260.0, 1e300]}, "poly coefficients are too large", "poly"),
        (
            "scaramuzza",
            640,
            480,
            SCARA | {"poly": [1e300, 0.0, -1e-3]},
            "poly leaves a field of only",
            "poly",
        ),
    ],
)
def test_out_of_range_parameters_raise_model_error(
    name: str, width: Any, height: Any, params: dict[str, Any], match: str, param: str | None
) -> None:
    with pytest.raises(ModelError, match=match) as info:
        create(name, width, height, **params)
    assert info.value.param == param


def test_range_limits_accept_their_bounds() -> None:
    """The bounds are inclusive, and far from real cameras: the extremes still load."""
    assert create("pinhole", 100_000, 100_000, **PINHOLE).width == 100_000
    for cx, cy in ((-640.0, -480.0), (1280.0, 960.0)):
        m = create("scaramuzza", 640, 480, **(SCARA | {"cx": cx, "cy": cy}))
        assert m.max_theta > 0.0 and np.isfinite(m.rho_max)
    m = create("scaramuzza", 640, 480, **(SCARA | {"c": 10.0, "d": -10.0, "e": 10.0}))
    assert m.max_theta > 0.0


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_smallest_positive_root_scales_instead_of_overflowing() -> None:
    # c_0 / c_2 = 1e400 overflows float64, the roots ±1e200 do not.
    assert smallest_positive_root([-1e200, 0.0, 1e-200]) == pytest.approx(1e200, rel=1e-12)
    assert smallest_positive_root([2.0, -3.0, 1.0]) == pytest.approx(1.0, rel=1e-12)
    assert smallest_positive_root([0.0, 0.0, 2.0, -3.0, 1.0]) == pytest.approx(
        1.0, rel=1e-12
    )  # s² (s-1)(s-2)
    assert smallest_positive_root([1.0, 1.0]) == math.inf
    assert smallest_positive_root([5.0, 0.0]) == math.inf
    # Roots -1e-300 and ~-1e600: no scaling holds both.
    with pytest.raises(ModelError, match=r"lens: coefficients from 1e-300 to 1e\+300 .* too far apart"):
        smallest_positive_root([1.0, 1e300, 1e-300], what="lens")
    with pytest.raises(ModelError, match="must be finite"):
        smallest_positive_root([1.0, math.inf])


# ----- iterative inversions converge to a tolerance, and say so when they cannot ------------------------
def test_mei_unprojection_beyond_the_invertible_radtan_region_is_invalid() -> None:
    """k1 = -0.45: the radial map m(1 + k1 m²) peaks at m = 1/√(3·0.45), distorted radius
    2/3·that; distorted points beyond the peak have no undistorted preimage."""
    m = create("mei", 1000, 1000, xi=0.9, k1=-0.45, k2=0, p1=0, p2=0, fx=400, fy=400, cx=500, cy=500)
    r_peak = 1 / math.sqrt(3 * 0.45)
    rd_peak = r_peak * (1 - 0.45 * r_peak**2)
    radii = np.array([0.5, 0.99, 1.01, 1.5, 3.0]) * rd_peak
    px = np.column_stack([500 + 400 * radii, np.full(radii.size, 500.0)])
    rays, ok = m.unproject(px, in_image=False)
    assert ok.tolist() == [True, True, False, False, False]
    assert np.isfinite(rays).all()
    back, ok2 = m.project(rays[ok], in_image=False)
    assert ok2.all() and np.abs(back - px[ok]).max() < 1e-6
    # The field ends at the ray of the peak (unified lift of r_peak), beyond which rays would
    # fold back onto valid pixels: the projection refuses them.
    lam = (0.9 + math.sqrt(1 + (1 - 0.81) * r_peak**2)) / (1 + r_peak**2)
    assert m.max_theta == pytest.approx(math.acos(lam - 0.9), rel=1e-12)
    beyond = np.array([[math.sin(m.max_theta + 0.01), 0.0, math.cos(m.max_theta + 0.01)]])
    assert not m.project(beyond, in_image=False)[1].any()


def test_radtan_undistortion_stops_on_tolerance_not_count() -> None:
    """Strongly distorted points need several Newton steps: cut the budget and they are reported
    unconverged instead of returned half-way; with the normal budget they converge."""
    rt = RadTan(-0.344504, 0.0984552, -0.00403995, 0.00610364)
    xd = np.linspace(0.05, 1.0, 20)
    yd = 0.4 * xd
    _, _, ok_short = rt.undistort(xd, yd, max_iter=2)
    x, y, ok = rt.undistort(xd, yd)
    assert ok.all() and not ok_short[-5:].any()
    back_x, back_y = rt.distort(x, y)
    assert np.abs(back_x - xd).max() < 1e-13 and np.abs(back_y - yd).max() < 1e-13


def test_scaramuzza_newton_polish_reports_non_convergence() -> None:
    """With a useless invpol seed and too small an iteration budget the projection says invalid
    rather than returning an unpolished pixel; with the normal budget the same seed converges."""
    m = create("scaramuzza", 640, 480, **SCARA, invpol=[1.0])
    rays, ok = m.unproject(pixel_grid(m, step=40))
    _, ok_full = m.project(rays[ok])
    assert ok_full.all()
    starved = ScaramuzzaModel(640, 480, None, **SCARA, invpol=[1.0])
    starved.MAX_ITER = 2
    _, ok_starved = starved.project(rays[ok])
    assert not ok_starved.all() and ok_starved.sum() < ok_full.sum()


def test_scaramuzza_validity_stops_where_theta_stops_increasing() -> None:
    """poly = a0 + a2 ρ²: dθ/dρ of θ(ρ) = atan2(ρ, poly(ρ)) has the sign of poly − ρ·poly' =
    a0 − a2 ρ², so with a2 > 0 the angle turns back at ρ = √(a0 / a2)."""
    a0, a2 = 300.0, 4e-3
    m = create("scaramuzza", 4000, 4000, poly=[a0, 0.0, a2], cx=2000, cy=2000, c=1, d=0, e=0)
    rho_turn = math.sqrt(a0 / a2)
    assert m.max_theta == pytest.approx(math.atan2(rho_turn, a0 + a2 * rho_turn**2), rel=1e-12)
    px = np.array([[2000 + 0.99 * rho_turn, 2000.0], [2000 + 1.01 * rho_turn, 2000.0]])
    _, ok = m.unproject(px)
    assert ok.tolist() == [True, False]


def test_mei_xi_above_one_keeps_only_the_one_to_one_cap() -> None:
    """ξ > 1: the projection centre (0, 0, -ξ) lies outside the sphere, and each line from it
    meets the sphere twice. Only the far cap Zs > -1/ξ is one-to-one; its image is the disc
    ρ² <= 1/(ξ² - 1) bounded by the tangent circle (basalt UnifiedCamera, α = ξ/(1 + ξ) > 0.5)."""
    xi, f, c = 1.6, 500.0, 1000.0
    m = create("mei", 2000, 2000, xi=xi, k1=0, k2=0, p1=0, p2=0, fx=f, fy=f, cx=c, cy=c)
    assert m.max_theta == pytest.approx(math.acos(-1 / xi), rel=1e-12)
    rho_edge = 1 / math.sqrt(xi * xi - 1)
    px = np.array([[c + f * rho_edge * 0.999, c], [c + f * rho_edge * 1.001, c]])
    _, ok = m.unproject(px)
    assert ok.tolist() == [True, False]
    # The two sphere points λ(mx, 0, 1) - (0, 0, ξ) on one line through (0, 0, -ξ) share the
    # same m: only the far one (beyond the tangent circle) is valid.
    mx = 0.5
    lam = np.roots([1 + mx * mx, -2 * xi, xi * xi - 1])  # |λ(mx, 0, 1) - (0, 0, ξ)| = 1
    pts = np.array([[s * mx, 0.0, s - xi] for s in sorted(lam)])
    px, ok = m.project(pts, in_image=False)
    assert ok.tolist() == [False, True]
    assert np.allclose(px[1], [c + f * mx, c], atol=1e-9) and pts[0, 2] < -1 / xi < pts[1, 2]
