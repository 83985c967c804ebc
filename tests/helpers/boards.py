"""Rendered calibration targets with known truth, for the calibration tests and the
``rig calibrate`` command's.

Boards are rendered by the virtual environment through the true lens, as ``rig evaluate``
renders them (``rig.evaluate.renders.render_board``: only the board's bounding box is ray-cast,
pixel for pixel the full render).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.geometry import invert_transform
from calibration.models import CameraModel, create
from calibration.targets import detect_chessboard
from rig.evaluate.renders import board_pose as evaluate_board_pose
from rig.evaluate.renders import render_board as evaluate_render_board
from rig.sim import chessboard_corners
from tests.helpers.shared import once_per_run

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

BOARD = (9, 6)  # inner corners; odd x even, so the detected order is unambiguous
# Supersampling of renders behind accuracy claims: 4x4 rays per pixel (16 coverage levels per
# edge pixel). At 2x2 the renders' own edge staircase is ~0.04 px of corner error; at 4x4 the
# refined corners are ~0.02 px from the truth (at 8x8, ~0.01 px).
FINE_SUPERSAMPLE = 4


def true_lenses(size: int = 480) -> dict[str, CameraModel]:
    """One realistic lens per model at ``size`` x ``size`` (all but pinhole see ~196°).

    Scaramuzza's stretch has e = 0: calibration holds e (a gauge: see calibration.calibrate)."""
    s = size / 480.0
    c = size / 2.0 - 0.5
    f = 137.0 * s
    return {
        "kannala_brandt": create(
            "kannala_brandt", size, size, fx=f, fy=f * 1.002, cx=c + 1.3, cy=c - 0.8,
            k1=0.02, k2=-0.01, k3=0.003, k4=-0.0005, fov_deg=196.0,
        ),
        "equidistant": create("equidistant", size, size, fx=f * 1.01, fy=f * 1.012, cx=c + 1.3, cy=c - 0.8,
                              fov_deg=196.0),
        "mei": create(
            "mei", size, size, xi=1.1, k1=-0.05, k2=0.01, p1=2e-4, p2=-1e-4,
            fx=226.0 * s, fy=226.5 * s, cx=c - 1.1, cy=c + 0.7, fov_deg=196.0,
        ),
        "double_sphere": create(
            "double_sphere", size, size, fx=118.0 * s, fy=118.3 * s, cx=c + 0.6, cy=c - 1.2,
            xi=-0.18, alpha=0.59, fov_deg=196.0,
        ),
        "eucm": create(
            "eucm", size, size, fx=134.0 * s, fy=134.2 * s, cx=c - 0.9, cy=c + 1.0,
            alpha=0.6, beta=1.1, fov_deg=196.0,
        ),
        "scaramuzza": create(
            "scaramuzza", size, size, poly=(f, 0.0, -1.0 / (3.0 * f), 0.0, -1.0 / (45.0 * f**3)),
            cx=c + 0.9, cy=c - 0.6, c=1.001, d=0.0004, e=0.0, fov_deg=196.0,
        ),
        "pinhole": create(
            "pinhole", size, size, fx=200.0 * s, fy=200.5 * s, cx=c + 1.0, cy=c - 0.5,
            k1=-0.08, k2=0.01, p1=3e-4, p2=-2e-4,
        ),
    }  # fmt: skip


def board_pose(
    theta_deg: float,
    phi_deg: float,
    distance_m: float,
    tilt_deg: tuple[float, float] = (0.0, 0.0),
    spin_deg: float = 0.0,
    square_m: float = 0.05,
) -> F64:
    """``T_cam_board`` of the :data:`BOARD` (see :func:`rig.evaluate.renders.board_pose`)."""
    return evaluate_board_pose(BOARD, square_m, theta_deg, phi_deg, distance_m, tilt_deg, spin_deg)


def circle_views(rim_theta_deg: float = 72.0, distance_m: float = 0.6) -> list[F64]:
    """Board poses covering a wide lens's whole image circle: two tilted central views, three
    at 35°, eight around the rim (their far corners past 90° off axis)."""
    poses = [
        board_pose(0, 0, distance_m, (20, 0), 5),
        board_pose(0, 0, distance_m, (-10, -30), 40),
        board_pose(35, 200, distance_m, (0, -25), 20),
        board_pose(35, 20, distance_m, (25, 0), -15),
        board_pose(35, 110, distance_m, (0, 0), 60),
    ]
    poses += [board_pose(rim_theta_deg + (k % 3) * 2, k * 45, distance_m, (0, 0), 17 * k) for k in range(8)]
    return poses


def pinhole_views(distance_m: float = 0.7) -> list[F64]:
    """Board poses for a ~100° pinhole: tilted centre views and a ring of eight at 22°."""
    poses = [
        board_pose(0, 0, distance_m, (25, 0), 5),
        board_pose(0, 0, distance_m, (-10, -30), 40),
        board_pose(0, 0, distance_m + 0.2, (0, 20), -20),
        board_pose(0, 0, distance_m - 0.1, (-30, 15), 70),
    ]
    poses += [board_pose(22, k * 45, distance_m, ((-1) ** k * 20, 10), 10 * k) for k in range(8)]
    return poses


def pinhole_full_views(distance_m: float = 0.7) -> list[F64]:
    """:func:`pinhole_views` plus boards reaching the image's edges and corners (~56° off axis)
    and strongly tilted ones, so the whole image is observed and the principal point pinned."""

    def ring(theta: float, phis: Sequence[float], tilt: float, dist: float, spin: float = 0.0) -> list[F64]:
        # Tilted about the board's own axis perpendicular to its direction from the image centre.
        out = []
        for ph in phis:
            s, c = math.sin(math.radians(ph)), math.cos(math.radians(ph))
            out.append(board_pose(theta, ph, dist, (tilt * s, -tilt * c), ph + spin))
        return out

    return (
        pinhole_views(distance_m)
        + ring(42, (45, 135, 225, 315), 20, distance_m)
        + ring(34, (0, 90, 180, 270), 20, distance_m)
        + ring(25, (0, 90, 180, 270), -45, distance_m - 0.1)
        + ring(25, (45, 135, 225, 315), -45, distance_m - 0.1, 30)
    )


def twin_lens(lens: CameraModel) -> CameraModel:
    """Another lens of the same make: principal point 2.1/1.4 px away, focal length 1 % shorter
    (where the model has fx, fy)."""
    p = lens.param_dict
    change: dict[str, float] = {"cx": p["cx"] - 2.1, "cy": p["cy"] + 1.4}
    if "fx" in p:
        change |= {"fx": p["fx"] * 0.99, "fy": p["fy"] * 0.992}
    return lens.replace(**change)


def render_board(camera: CameraModel, T_cam_board: F64, square_m: float = 0.05, supersample: int = 2) -> U8:
    """8-bit grey image of the :data:`BOARD` through ``camera`` (``T_cam_board`` in the camera
    frame), on the evaluation's background (only the board's bounding box is ray-cast)."""
    return evaluate_render_board(camera, T_cam_board, BOARD, square_m, supersample)


def true_corners(camera: CameraModel, T_cam_board: F64, square_m: float = 0.05) -> tuple[F64, F64]:
    """Exact pixels (N, 2) of the inner corners and their angles off axis (N,) in degrees."""
    X = chessboard_corners(*BOARD, square_m)
    p = X @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    pix, _ = camera.project(p, in_image=False)
    angle = np.degrees(np.arccos(np.clip(p[:, 2] / np.linalg.norm(p, axis=1), -1.0, 1.0)))
    return pix, angle


def lens_difference(a: CameraModel, b: CameraModel, max_angle_deg: float) -> tuple[float, float]:
    """RMS and max pixel distance between two lenses' projections of the same rays, over a
    polar grid of directions up to ``max_angle_deg`` off axis."""
    th = np.radians(np.linspace(0.0, max_angle_deg, 40))
    ph = np.linspace(0.0, 2 * math.pi, 36, endpoint=False)
    tt, pp = np.meshgrid(th, ph)
    rays = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], axis=-1).reshape(-1, 3)
    pa, oka = a.project(rays, in_image=False)
    pb, okb = b.project(rays, in_image=False)
    ok = oka & okb
    e = np.linalg.norm(pa[ok] - pb[ok], axis=1)
    return float(np.sqrt(np.mean(e**2))), float(e.max())


def image_difference(true: CameraModel, est: CameraModel, step_px: float = 4.0) -> tuple[float, float, float]:
    """RMS and max pixel distance between where ``est`` and ``true`` image the rays of a dense
    grid of the true lens's valid pixels (its whole image circle, or the whole image), and the
    largest angle (deg) off axis of those rays."""
    u = np.arange(0.0, true.width, step_px)
    v = np.arange(0.0, true.height, step_px)
    uu, vv = np.meshgrid(u, v)
    px = np.stack([uu.ravel(), vv.ravel()], axis=1)
    rays, ok = true.unproject(px)
    back, ok_est = est.project(rays[ok], in_image=False)
    if not ok_est.all():
        return math.inf, math.inf, 0.0
    e = np.linalg.norm(back - px[ok], axis=1)
    angle = float(np.degrees(np.arccos(np.clip(rays[ok, 2], -1.0, 1.0))).max())
    return float(np.sqrt(np.mean(e**2))), float(e.max()), angle


def radial_errors(camera: CameraModel, found: F64, truth: F64) -> tuple[F64, F64]:
    """Corner errors found − truth (N,) in px and their components (N,) along the direction away
    from the principal point / distortion centre (negative = pulled inwards)."""
    p = camera.param_dict
    out = truth - np.array([p["cx"], p["cy"]])
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
    d = found - truth
    return np.linalg.norm(d, axis=1), np.sum(d * out, axis=1)


@dataclass(frozen=True)
class RenderedViews:
    """Fine renders of a model's true lens over its field: images, SB detections (None where
    the board was not found), exact corners and their angles off axis (deg), per view."""

    lens: CameraModel
    poses: list[F64]
    images: list[NDArray[np.uint8]]
    detections: list[F64 | None]
    truth: list[F64]
    angles: list[F64]


@functools.cache
@once_per_run
def rendered_views(name: str, size: int = 480) -> RenderedViews:
    """:class:`RenderedViews` of ``true_lenses(size)[name]``: :func:`circle_views` for the wide
    lenses, :func:`pinhole_full_views` for the pinhole; rendered once per test run."""
    lens = true_lenses(size)[name]
    poses = pinhole_full_views() if name == "pinhole" else circle_views()
    images = [render_board(lens, T, supersample=FINE_SUPERSAMPLE) for T in poses]
    truth = [true_corners(lens, T) for T in poses]
    return RenderedViews(
        lens,
        poses,
        images,
        [detect_chessboard(im, BOARD) for im in images],
        [t[0] for t in truth],
        [t[1] for t in truth],
    )


def camera_pose_in_world(T_world_cam: F64, T_world_board: F64) -> F64:
    """``T_cam_board`` from world poses of a camera and a board."""
    return invert_transform(T_world_cam) @ T_world_board


def spread(values: Sequence[float]) -> float:
    return float(np.max(values) - np.min(values))
