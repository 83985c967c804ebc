"""The omnidirectional models against references that do not share their code: closed-form
identities between models, OpenCV, per-point scalar implementations written here straight from
the published equations, and real third-party calibrations from /work/shared/data."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from scipy.optimize import fsolve

from calibration.models import ScaramuzzaModel, create
from tests.calibration.test_models import pixel_grid
from tests.conftest import shared_file

RNG = np.random.default_rng(11)


def random_points(n: int, rng: np.random.Generator = RNG) -> np.ndarray:
    """(n, 3) points in every direction at distances 0.1..20."""
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.1, 20.0, (n, 1))


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----- closed-form identities -------------------------------------------------------------------
@pytest.mark.parametrize("alpha", [0.3, 0.5, 0.62, 0.8])
def test_ucm_three_ways(alpha: float) -> None:
    """DS with ξ = 0, EUCM with β = 1 and Mei without distortion are all the unified model:
    Mei's ξ = α/(1 − α) and focal f/(1 − α) (x / (α d + (1 − α) z) = x / ((1 − α)(z + ξ d)))."""
    f, cx, cy = 300.0, 400.5, 300.2
    ds = create("double_sphere", 800, 600, fx=f, fy=f * 1.01, cx=cx, cy=cy, xi=0.0, alpha=alpha)
    eucm = create("eucm", 800, 600, fx=f, fy=f * 1.01, cx=cx, cy=cy, alpha=alpha, beta=1.0)
    s = 1.0 - alpha
    mei = create(
        "mei", 800, 600, xi=alpha / s, k1=0, k2=0, p1=0, p2=0, fx=f / s, fy=f * 1.01 / s, cx=cx, cy=cy
    )
    pts = random_points(4000)
    results = [m.project(pts, in_image=False) for m in (ds, eucm, mei)]
    (p0, ok0), (p1, ok1), (p2, ok2) = results
    assert ok0.sum() > 1000
    assert np.array_equal(ok0, ok1) and np.array_equal(ok0, ok2)
    size = np.maximum(np.abs(p0[ok0]), 1.0)  # far from the axis pixels grow large: compare relatively
    assert (np.abs(p0[ok0] - p1[ok0]) / size).max() < 1e-12 and (
        np.abs(p0[ok0] - p2[ok0]) / size
    ).max() < 1e-12
    # Pixels over a disc 1.2 times the unprojection domain (r² <= 1/(2α − 1) when α > 0.5).
    r_px = 1.2 * f * (1.0 / math.sqrt(2 * alpha - 1) if alpha > 0.5 else 10.0)
    radius, angle = r_px * np.sqrt(RNG.uniform(0, 1, 4000)), RNG.uniform(-math.pi, math.pi, 4000)
    px = np.column_stack([cx + radius * np.cos(angle), cy + radius * np.sin(angle)])
    rays = [m.unproject(px, in_image=False) for m in (ds, eucm, mei)]
    (r0, u0), (r1, u1), (r2, u2) = rays
    assert u0.sum() > 1000
    assert np.array_equal(u0, u1) and np.array_equal(u0, u2)
    assert np.abs(r0[u0] - r1[u0]).max() < 1e-12 and np.abs(r0[u0] - r2[u0]).max() < 1e-12


def test_mei_with_xi_zero_is_opencv_pinhole_radtan() -> None:
    """ξ = 0 puts the projection centre at the sphere centre: a pinhole with the same radtan."""
    K = np.array([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]])
    D = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
    intrinsics = dict(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
    mei = create("mei", 752, 480, xi=0.0, k1=D[0], k2=D[1], p1=D[2], p2=D[3], **intrinsics)
    pts = np.column_stack([RNG.uniform(-0.6, 0.6, (3000, 2)), np.ones(3000)]) * RNG.uniform(0.5, 9, (3000, 1))
    ours, ok = mei.project(pts, in_image=False)
    assert ok.all()
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)
    assert np.abs(ours - ref.reshape(-1, 2)).max() < 1e-9
    # Unprojection against OpenCV's iterative undistortion run to convergence.
    px = pixel_grid(mei, step=16)
    rays, ok = mei.unproject(px)
    assert ok.all()
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    und = cv2.undistortPoints(px.reshape(-1, 1, 2), K, D, None, None, None, criteria).reshape(-1, 2)
    assert np.abs(rays - unit(np.column_stack([und, np.ones(len(und))]))).max() < 1e-9


# ----- per-point scalar references ------------------------------------------------------------------
def mei_project_scalar(p: dict[str, float], X: float, Y: float, Z: float) -> tuple[float, float]:
    """CamOdoCal CataCamera::spaceToPlane + OpenCV omnidir's skew, one point."""
    n = math.sqrt(X * X + Y * Y + Z * Z)
    z = Z + p["xi"] * n
    mx, my = X / z, Y / z
    r2 = mx * mx + my * my
    rad = p["k1"] * r2 + p["k2"] * r2 * r2
    dx = mx * rad + 2 * p["p1"] * mx * my + p["p2"] * (r2 + 2 * mx * mx)
    dy = my * rad + 2 * p["p2"] * mx * my + p["p1"] * (r2 + 2 * my * my)
    xd, yd = mx + dx, my + dy
    return p["fx"] * xd + p.get("s", 0.0) * yd + p["cx"], p["fy"] * yd + p["cy"]


def mei_unproject_scalar(p: dict[str, float], u: float, v: float) -> np.ndarray:
    """Undistortion by scipy's fsolve, then CataCamera::liftSphere's closed form, one pixel."""
    yd = (v - p["cy"]) / p["fy"]
    xd = (u - p["cx"] - p.get("s", 0.0) * yd) / p["fx"]

    def residual(m: np.ndarray) -> list[float]:
        # Pixel of the undistorted point minus the target, through the scalar projection.
        mx, my = m
        r2 = mx * mx + my * my
        rad = 1 + p["k1"] * r2 + p["k2"] * r2 * r2
        return [
            mx * rad + 2 * p["p1"] * mx * my + p["p2"] * (r2 + 2 * mx * mx) - xd,
            my * rad + 2 * p["p2"] * mx * my + p["p1"] * (r2 + 2 * my * my) - yd,
        ]

    (mx, my), info, _, _ = fsolve(residual, [xd, yd], xtol=1e-13, full_output=True)
    assert np.abs(info["fvec"]).max() < 1e-13, "the reference undistortion itself must converge"
    xi, r2 = p["xi"], mx * mx + my * my
    lam = (xi + math.sqrt(1 + (1 - xi * xi) * r2)) / (1 + r2)
    return np.array([lam * mx, lam * my, lam - xi])


def ds_project_scalar(p: dict[str, float], x: float, y: float, z: float) -> tuple[float, float, bool]:
    """Usenko et al. 2018, eqs. (40)-(45): projection and its validity, one point."""
    d1 = math.sqrt(x * x + y * y + z * z)
    d2 = math.sqrt(x * x + y * y + (p["xi"] * d1 + z) ** 2)
    a = p["alpha"]
    den = a * d2 + (1 - a) * (p["xi"] * d1 + z)
    w1 = a / (1 - a) if a <= 0.5 else (1 - a) / a
    w2 = (w1 + p["xi"]) / math.sqrt(2 * w1 * p["xi"] + p["xi"] ** 2 + 1)
    return p["fx"] * x / den + p["cx"], p["fy"] * y / den + p["cy"], z > -w2 * d1


def ds_unproject_scalar(p: dict[str, float], u: float, v: float) -> tuple[np.ndarray, bool]:
    """Usenko et al. 2018, eqs. (46)-(51), one pixel."""
    mx, my = (u - p["cx"]) / p["fx"], (v - p["cy"]) / p["fy"]
    r2, a, xi = mx * mx + my * my, p["alpha"], p["xi"]
    if a > 0.5 and r2 > 1 / (2 * a - 1):
        return np.zeros(3), False
    mz = (1 - a * a * r2) / (a * math.sqrt(1 - (2 * a - 1) * r2) + 1 - a)
    k = (mz * xi + math.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
    return unit(np.array([k * mx, k * my, k * mz - xi])), True


def eucm_project_scalar(p: dict[str, float], x: float, y: float, z: float) -> tuple[float, float, bool]:
    """Khomutenko et al. 2016 / Usenko et al. 2018 eqs. (25)-(29), one point."""
    a, b = p["alpha"], p["beta"]
    d = math.sqrt(b * (x * x + y * y) + z * z)
    den = a * d + (1 - a) * z
    w = a / (1 - a) if a <= 0.5 else (1 - a) / a
    return p["fx"] * x / den + p["cx"], p["fy"] * y / den + p["cy"], z > -w * d


def eucm_unproject_scalar(p: dict[str, float], u: float, v: float) -> tuple[np.ndarray, bool]:
    """Usenko et al. 2018 eqs. (30)-(35), one pixel."""
    mx, my = (u - p["cx"]) / p["fx"], (v - p["cy"]) / p["fy"]
    r2, a, b = mx * mx + my * my, p["alpha"], p["beta"]
    if a > 0.5 and r2 > 1 / (b * (2 * a - 1)):
        return np.zeros(3), False
    mz = (1 - b * a * a * r2) / (a * math.sqrt(1 - (2 * a - 1) * b * r2) + 1 - a)
    return unit(np.array([mx, my, mz])), True


MEI_PARAMS = [
    dict(xi=0.894975, k1=-0.344504, k2=0.0984552, p1=-0.00403995, p2=0.00610364)
    | dict(fx=758.355, fy=757.615, cx=646.72, cy=395.001),
    dict(xi=1.6, k1=-0.08, k2=0.01, p1=1e-4, p2=-2e-4, fx=740.2, fy=739.1, cx=641.3, cy=478.6, s=0.35),
]


@pytest.mark.parametrize("params", MEI_PARAMS, ids=["camodocal", "xi1.6-skew"])
def test_mei_matches_scalar_reference(params: dict[str, float]) -> None:
    m = create("mei", 1280, 960, **params)
    pts = random_points(400)
    px, ok = m.project(pts, in_image=False)
    assert ok.sum() > 150
    ref = np.array([mei_project_scalar(params, *p) for p in pts[ok]])
    # Near the domain limit pixels reach 1e13 (far outside any image): compare relatively.
    assert (np.abs(px[ok] - ref) / np.maximum(np.abs(ref), 1.0)).max() < 1e-12
    pix = pixel_grid(m, step=53)
    rays, ok = m.unproject(pix)
    assert ok.sum() > 150
    ref_rays = np.array([mei_unproject_scalar(params, *q) for q in pix[ok]])
    assert np.abs(rays[ok] - ref_rays).max() < 1e-9


SPHERE_CASES: list[tuple[str, dict[str, float], int, int]] = [
    ("double_sphere", dict(fx=402.5, fy=400.0, cx=505.0, cy=509.0, xi=-0.075347, alpha=0.743925), 1024, 1024),
    ("double_sphere", dict(fx=270.3, fy=269.8, cx=515.1, cy=381.7, xi=0.4, alpha=0.45), 1024, 768),
    ("eucm", dict(fx=460.76484651566468, fy=459.4051018049483, cx=365.8937161309615)
     | dict(cy=249.33499869752445, alpha=0.5903365915227143, beta=1.127468196965374), 752, 480),
    ("eucm", dict(fx=180.4, fy=180.1, cx=509.6, cy=386.2, alpha=0.42, beta=1.3), 1024, 768),
]  # fmt: skip


@pytest.mark.parametrize(
    "name, params, width, height", SPHERE_CASES, ids=["ds-basalt", "ds-a0.45", "eucm-euroc", "eucm-a0.42"]
)
def test_ds_and_eucm_match_the_paper_equations(
    name: str, params: dict[str, float], width: int, height: int
) -> None:
    m = create(name, width, height, **params)
    project = ds_project_scalar if name == "double_sphere" else eucm_project_scalar
    unproject = ds_unproject_scalar if name == "double_sphere" else eucm_unproject_scalar
    pts = random_points(600)
    px, ok = m.project(pts, in_image=False)
    ref = [project(params, *p) for p in pts]
    ref_ok = np.array([r[2] for r in ref])
    assert ok.sum() > 300 and np.array_equal(ok, ref_ok)
    assert np.abs(px[ok] - np.array([r[:2] for r in ref])[ok]).max() < 1e-9
    # Pixels over a disc 1.3 times the unprojection domain (or twice the image when unbounded).
    r2_max = 1 / (2 * params["alpha"] - 1) / params.get("beta", 1.0) if params["alpha"] > 0.5 else math.inf
    r_px = (
        1.3 * params["fx"] * math.sqrt(r2_max) if math.isfinite(r2_max) else 2.0 * math.hypot(width, height)
    )
    radius, angle = r_px * np.sqrt(RNG.uniform(0, 1, 600)), RNG.uniform(-math.pi, math.pi, 600)
    pix = np.column_stack([params["cx"] + radius * np.cos(angle), params["cy"] + radius * np.sin(angle)])
    rays, ok = m.unproject(pix, in_image=False)
    ref_rays = [unproject(params, *q) for q in pix]
    ref_ok = np.array([r[1] for r in ref_rays])
    # The paper's unprojection domain may reach slightly past the projection domain (DS): ours
    # keeps the smaller one so both directions agree; where ours says valid, the paper agrees.
    assert ok.sum() > 200 and not (ok & ~ref_ok).any()
    assert (ok == ref_ok).mean() > 0.97
    assert np.abs(rays[ok] - np.array([r[0] for r in ref_rays])[ok]).max() < 1e-12


# ----- Scaramuzza ----------------------------------------------------------------------------------
def test_scaramuzza_fitted_to_an_equidistant_lens_reproduces_it() -> None:
    """An ideal 190° equidistant lens r = f·θ is ray (u', v', ρ·cot(ρ/f)): fit that with a
    polynomial (OCamCalib form, a1 = 0) and the Scaramuzza model must project like the lens."""
    f, cx, cy = 300.0, 640.3, 479.6
    equi = create("equidistant", 1280, 960, fx=f, fy=f, cx=cx, cy=cy, fov_deg=190.0)
    rho = np.linspace(1e-9, 1.05 * f * math.radians(95.0), 3000)
    powers = np.array([0, 2, 3, 4, 5, 6, 7, 8])
    scale = rho.max()
    coef, *_ = np.linalg.lstsq((rho[:, None] / scale) ** powers, rho / np.tan(rho / f), rcond=None)
    poly = np.zeros(9)
    poly[powers] = coef / scale**powers
    scara = create("scaramuzza", 1280, 960, poly=list(poly), cx=cx, cy=cy, c=1.0, d=0.0, e=0.0, fov_deg=190.0)
    theta = np.radians(RNG.uniform(0.0, 95.0, 3000))
    phi = RNG.uniform(-math.pi, math.pi, 3000)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    pe, oke = equi.project(rays)
    ps, oks = scara.project(rays)
    assert oke.sum() > 2000 and np.array_equal(oke, oks)
    assert np.abs(pe[oke] - ps[oke]).max() < 0.01
    px = pixel_grid(equi, step=17)
    re, oke = equi.unproject(px)
    rs, oks = scara.unproject(px)
    both = oke & oks
    assert both.sum() > 0.95 * oke.sum()
    assert np.degrees(np.arccos(np.clip((re[both] * rs[both]).sum(axis=1), -1, 1))).max() < 0.01 / f * 57.3


def test_scaramuzza_unprojection_is_matlab_stretch_convention() -> None:
    """MATLAB fisheyeIntrinsics: [u; v] = StretchMatrix·[u'; v'] + centre, ray (u', v', poly(ρ))."""
    poly = [260.0, 0.0, -1.3e-3, 2e-7, -1.9e-9]
    p = dict(cx=322.4, cy=237.1, c=1.02, d=0.03, e=-0.05)
    m = create("scaramuzza", 640, 480, poly=poly, **p)
    pix = pixel_grid(m, step=23)
    rays, ok = m.unproject(pix)
    assert ok.all()
    A = np.array([[p["c"], p["d"]], [p["e"], 1.0]])
    for q, ray in zip(pix[::7], rays[::7], strict=True):
        up, vp = np.linalg.solve(A, q - [p["cx"], p["cy"]])
        rho = math.hypot(up, vp)
        z = sum(a * rho**i for i, a in enumerate(poly))
        assert np.abs(unit(np.array([up, vp, z])) - ray).max() < 1e-12
    # And forward: the pixel of a ray is A·(ρ·direction) + centre with poly(ρ)/ρ = z/r.
    back, ok = m.project(rays)
    assert ok.all() and np.abs(back - pix).max() < 1e-9


# ----- real calibrations from /work/shared/data -------------------------------------------------------
def basalt_intrinsics(rel: str) -> list[dict[str, Any]]:
    """``value0.intrinsics[i]`` and ``value0.resolution[i]`` of a basalt calibration JSON."""
    doc = json.loads(shared_file(rel).read_text())["value0"]
    return [
        {"camera_type": c["camera_type"], "params": c["intrinsics"], "size": tuple(r)}
        for c, r in zip(doc["intrinsics"], doc["resolution"], strict=True)
    ]


BASALT_FILES = [
    "vio_fisheye_calibs/basalt/euroc_ds_calib.json",
    "vio_fisheye_calibs/basalt/euroc_eucm_calib.json",
    "vio_fisheye_calibs/basalt/tumvi_512_ds_calib.json",
    "vio_fisheye_calibs/basalt/tumvi_512_eucm_calib.json",
]


@pytest.mark.parametrize("rel", BASALT_FILES, ids=lambda r: Path(r).stem)
def test_basalt_real_calibrations_round_trip(rel: str) -> None:
    """Both cameras of each basalt file, built from its JSON numbers: full-image round trip."""
    for cam in basalt_intrinsics(rel):
        name = {"ds": "double_sphere", "eucm": "eucm"}[cam["camera_type"]]
        m = create(name, *cam["size"], **cam["params"])
        px = pixel_grid(m, step=2)
        rays, ok = m.unproject(px)
        assert ok.all(), "these lenses fill their images"
        back, ok2 = m.project(rays)
        assert ok2.all() and np.abs(back - px).max() <= 1e-6
        theta = np.degrees(np.arccos(rays[:, 2])).max()
        assert (theta > 90.0) == ("tumvi" in rel), f"{rel}: max angle {theta:.1f}°"


def test_tumvi_lens_in_three_models_agrees() -> None:
    """TUM VI cam0 calibrated three times (basalt DS, basalt EUCM, Kalibr KB4 via open_vins):
    the same lens, so the models must agree to calibration noise up to 90° off axis. A wrong sign
    or convention in any of them would cost tens of pixels."""
    ds = basalt_intrinsics("vio_fisheye_calibs/basalt/tumvi_512_ds_calib.json")[0]["params"]
    eu = basalt_intrinsics("vio_fisheye_calibs/basalt/tumvi_512_eucm_calib.json")[0]["params"]
    chain = shared_file("vio_fisheye_calibs/open_vins/tum_vi/kalibr_imucam_chain.yaml").read_text()
    cam0 = yaml.safe_load(chain.split("\n", 1)[1])["cam0"]  # line 1 is OpenCV's "%YAML:1.0" header
    fx, fy, cx, cy = cam0["intrinsics"]
    k1, k2, k3, k4 = cam0["distortion_coeffs"]
    models = [
        create("double_sphere", 512, 512, **ds),
        create("eucm", 512, 512, **eu),
        create("kannala_brandt", 512, 512, fx=fx, fy=fy, cx=cx, cy=cy, k1=k1, k2=k2, k3=k3, k4=k4),
    ]
    theta = np.radians(RNG.uniform(0.0, 90.0, 2000))
    phi = RNG.uniform(-math.pi, math.pi, 2000)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    (p_ds, ok_ds), (p_eu, ok_eu), (p_kb, ok_kb) = (m.project(rays, in_image=False) for m in models)
    assert ok_ds.all() and ok_eu.all() and ok_kb.all()
    assert np.linalg.norm(p_ds - p_eu, axis=1).max() < 0.2
    assert np.linalg.norm(p_ds - p_kb, axis=1).max() < 1.5


# OCamCalib calib_results.txt: read by hand here (the file loader is written elsewhere).
OCAM_FILES = [
    "ocamcalib_matsuren/calib_results_0.txt",
    "ocamcalib_vivekmudgal/calib_results.txt",
    "ocamcalib_premnirmal/calib_results.txt",
]


def read_ocamcalib(path: Path) -> dict[str, Any]:
    """The five data lines of an OCamCalib export: pol (count first), invpol (count first),
    centre "row column" (0-based, as these files' comments say), affine c d e, "height width"."""
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    pol = [float(x) for x in rows[0][1 : 1 + int(rows[0][0])]]
    invpol = [float(x) for x in rows[1][1 : 1 + int(rows[1][0])]]
    xc, yc = map(float, rows[2])
    c, d, e = map(float, rows[3])
    height, width = map(int, rows[4])
    return dict(pol=pol, invpol=invpol, xc=xc, yc=yc, c=c, d=d, e=e, height=height, width=width)


def ocam_to_ours(o: dict[str, Any], with_invpol: bool = True) -> ScaramuzzaModel:
    """OCamCalib (x = row, y = column, z backwards; A = [[c, d], [e, 1]] on (row, col)) -> ours.

    Our frame is (y_oc, x_oc, −z_oc). In (column, row) order the stretch is [[1, e], [d, c]]
    = c·A' with A' = [[1/c, e/c], [d/c, 1]] of our form, so our (u', v') = c·(y', x'), ρ = c·ρ_oc,
    and the ray c·(y', x', −pol(ρ/c)) gives poly_i = −pol_i·c^(1−i); invpol (ρ in ψ) scales by c.
    """
    c = o["c"]
    kw: dict[str, Any] = dict(
        poly=[-a * c ** (1 - i) for i, a in enumerate(o["pol"])],
        cx=o["yc"],
        cy=o["xc"],
        c=1.0 / c,
        d=o["e"] / c,
        e=o["d"] / c,
    )
    if with_invpol:
        kw["invpol"] = [c * b for b in o["invpol"]]
    return ScaramuzzaModel(o["width"], o["height"], None, **kw)


def ocam_cam2world(o: dict[str, Any], u: float, v: float) -> np.ndarray:
    """OCamCalib's C ``cam2world`` for pixel (row v, column u), returned in our frame."""
    inv_det = 1.0 / (o["c"] - o["d"] * o["e"])
    xp = inv_det * ((v - o["xc"]) - o["d"] * (u - o["yc"]))
    yp = inv_det * (-o["e"] * (v - o["xc"]) + o["c"] * (u - o["yc"]))
    r = math.hypot(xp, yp)
    zp = sum(a * r**i for i, a in enumerate(o["pol"]))
    return unit(np.array([yp, xp, -zp]))


def ocam_world2cam(o: dict[str, Any], ray: np.ndarray) -> tuple[float, float, float]:
    """OCamCalib's C ``world2cam`` for a ray in our frame: (column, row, ρ_oc)."""
    X, Y, Z = ray[1], ray[0], -ray[2]
    norm = math.hypot(X, Y)
    theta = math.atan(Z / norm)
    rho = sum(b * theta**i for i, b in enumerate(o["invpol"]))
    x, y = X / norm * rho, Y / norm * rho
    return x * o["e"] + y + o["yc"], x * o["c"] + y * o["d"] + o["xc"], rho


@pytest.mark.parametrize("rel", OCAM_FILES, ids=lambda r: r.split("/")[0])
def test_ocamcalib_files(rel: str) -> None:
    o = read_ocamcalib(shared_file(rel))
    m = ocam_to_ours(o)
    px = pixel_grid(m, step=3)
    rays, ok = m.unproject(px)
    assert ok.all()
    back, ok2 = m.project(rays)
    assert ok2.all() and np.abs(back - px).max() <= 1e-6
    # Unprojection equals OCamCalib's own cam2world exactly: proves the frame/stretch mapping.
    sample = px[:: max(1, len(px) // 400)]
    sample_rays, _ = m.unproject(sample)
    ref = np.array([ocam_cam2world(o, *q) for q in sample])
    assert np.abs(sample_rays - ref).max() < 1e-12
    # Projection agrees with the file's invpol (world2cam) wherever that invpol was fitted: inside
    # the half-diagonal radius; premnirmal's degree-32 invpol, printed to 6 decimals, loses ~0.5 px
    # near the axis (|ψ|^32 ~ 2e6 times the rounding), so its first 10° are left out.
    radius = math.hypot(o["width"] / 2, o["height"] / 2)
    min_theta = 10.0 if "premnirmal" in rel else 0.0
    world = [ocam_world2cam(o, r) for r in sample_rays]
    theta = np.degrees(np.arccos(sample_rays[:, 2]))
    fitted = np.array([w[2] <= radius for w in world]) & (theta >= min_theta)
    assert fitted.mean() > 0.8
    err = np.linalg.norm(np.array([w[:2] for w in world]) - sample, axis=1)
    assert err[fitted].max() < 0.1, f"max {err[fitted].max():.3f} px"
    # Our own fitted invpol only seeds the Newton polish: same projection to 1e-6 px.
    refit = ocam_to_ours(o, with_invpol=False)
    assert refit.invpol != m.invpol
    p_refit, ok3 = refit.project(rays)
    assert ok3.all() and np.abs(p_refit - back).max() <= 1e-6
