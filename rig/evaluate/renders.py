"""Renders of the virtual environment for the evaluation: calibration boards, plane pairs with
their Reference pair, the room for the image comparison.

Only the part of a fisheye image that is used gets ray-cast: the same lens with its principal
point moved by the crop origin sees exactly the same ray at every pixel, so a crop pasted into
the full frame equals the full render pixel for pixel (vignetting included, it is per pixel; the
noise is drawn afresh). With lens effects (:mod:`rig.sim.lens_effects`) the crop is rendered
larger by the blur's reach, so its blur near the crop's edge is the full image's. Outside the
crop the frame holds the background, which nothing reads: a board's detector sees the board with
its white margin and background around it; a VPC lookup table reads only its source region (plus
the bilinear neighbours, inside the margin).

The fisheye renders take the study's lens effects (``--lens honest``: the preset's fitted lens;
``ideal``: none); a Reference view is an ideal lens on the same sensor (its noise only).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.geometry import make_transform, rot_x, rot_y, rot_z
from calibration.models import CameraModel
from calibration.rig import Rig
from rig.errors import EvaluationError
from rig.lut import Lut
from rig.rectified import RectifiedPair
from rig.sim import Scene, chessboard_corners, chessboard_scene, plane_scene, render
from rig.sim.lens_effects import LensEffects

__all__ = [
    "Box",
    "PlaneShot",
    "board_fits",
    "board_outline",
    "board_pose",
    "calibration_board_poses",
    "lut_box",
    "plane_distance",
    "render_board",
    "render_in_box",
    "render_plane_shot",
    "union_box",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

#: (x0, y0, x1, y1): pixel columns x0..x1-1 and rows y0..y1-1.
Box = tuple[int, int, int, int]

BOARD_BACKGROUND = 90
# Pixels around a sampled region: bilinear neighbours and the supersampling footprint.
_MARGIN = 3
# Rim boards stop this far inside the lens's field limit (degrees).
_RIM_CLEARANCE_DEG = 0.5


def _crop(camera: CameraModel, box: Box) -> CameraModel:
    p = camera.param_dict
    if not {"cx", "cy"} <= set(p):
        raise EvaluationError(f"cannot crop a {camera.name} camera: it has no cx, cy")
    x0, y0, x1, y1 = box
    return camera.replace(width=x1 - x0, height=y1 - y0, cx=p["cx"] - x0, cy=p["cy"] - y0)


def render_in_box(
    scene: Scene,
    camera: CameraModel,
    T_world_cam: F64,
    box: Box | None,
    *,
    supersample: int,
    noise_std: float = 0.0,
    vignetting: float = 0.0,
    seed: int = 0,
    background: int = 0,
    lens: LensEffects | None = None,
    camera_index: int = 0,
) -> U8:
    """Full-size grey image of ``camera`` with only ``box`` rendered (None: everything); ``lens``
    and ``camera_index`` as :func:`rig.sim.render` takes them."""
    kw: dict[str, Any] = {"supersample": supersample, "noise_std": noise_std, "vignetting": vignetting}
    kw |= {"seed": seed, "background": background, "lens": lens, "camera_index": camera_index}
    if box is None:
        return render(scene, camera, T_world_cam, **kw).image
    x0, y0, x1, y1 = box
    full = np.full((camera.height, camera.width), background, dtype=np.uint8)
    if x1 <= x0 or y1 <= y0:
        return full
    reach = lens.reach_px(camera_index) if lens is not None else 0
    grown = (
        max(0, x0 - reach),
        max(0, y0 - reach),
        min(camera.width, x1 + reach),
        min(camera.height, y1 + reach),
    )
    part = render(scene, _crop(camera, grown), T_world_cam, **kw).image
    full[y0:y1, x0:x1] = part[y0 - grown[1] : y1 - grown[1], x0 - grown[0] : x1 - grown[0]]
    return full


def _clip_box(xs: F64, ys: F64, width: int, height: int, margin: int) -> Box:
    return (
        max(0, math.floor(float(xs.min())) - margin),
        max(0, math.floor(float(ys.min())) - margin),
        min(width, math.ceil(float(xs.max())) + margin + 1),
        min(height, math.ceil(float(ys.max())) + margin + 1),
    )


def lut_box(lut: Lut, camera: CameraModel) -> Box:
    """The fisheye region a VPC table samples, with a margin."""
    xs, ys = (m[lut.valid].astype(np.float64) for m in (lut.map_x, lut.map_y))
    return _clip_box(xs, ys, camera.width, camera.height, _MARGIN)


def union_box(boxes: Iterable[Box]) -> Box:
    bs = list(boxes)
    return (min(b[0] for b in bs), min(b[1] for b in bs), max(b[2] for b in bs), max(b[3] for b in bs))


# ----- calibration boards ------------------------------------------------------------------------


def board_pose(
    board: tuple[int, int],
    square_m: float,
    theta_deg: float,
    phi_deg: float,
    distance_m: float,
    tilt_deg: tuple[float, float] = (0.0, 0.0),
    spin_deg: float = 0.0,
) -> F64:
    """``T_cam_board`` (4, 4) of a board whose centre is ``distance_m`` away in the direction
    ``theta_deg`` off the optical axis at azimuth ``phi_deg``, facing the camera, then tilted
    about its own x and y axes and spun about its normal."""
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    d = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    # Rotation taking the board's z (into the board) onto d (Rodrigues about z × d).
    axis = np.cross([0.0, 0.0, 1.0], d)
    s = float(np.linalg.norm(axis))
    R_face = np.eye(3)
    if s > 1e-12:
        k = axis / s
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        R_face = np.eye(3) + math.sin(th) * K + (1.0 - math.cos(th)) * K @ K
    R = (
        R_face
        @ rot_x(math.radians(tilt_deg[0]))
        @ rot_y(math.radians(tilt_deg[1]))
        @ rot_z(math.radians(spin_deg))
    )
    centre = chessboard_corners(*board, square_m).mean(axis=0)
    return make_transform(R, d * distance_m - R @ centre)


def board_outline(board: tuple[int, int], square_m: float, margin_squares: float) -> F64:
    """Points (576, 3) over the board's squares and ``margin_squares`` of its white margin."""
    cols, rows = board
    m = margin_squares * square_m
    xs = np.linspace(-square_m - m, cols * square_m + m, 24)
    ys = np.linspace(-square_m - m, rows * square_m + m, 24)
    xx, yy = np.meshgrid(xs, ys)
    return np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], axis=1)


def board_fits(lens: CameraModel, T: F64, outline: F64, max_deg: float) -> bool:
    """Whether every point of ``outline`` (board frame) posed at ``T`` (``T_cam_board``) is in
    ``lens``'s image and within ``max_deg`` of its axis."""
    p = outline @ T[:3, :3].T + T[:3, 3]
    _, ok = lens.project(p)
    angle = np.degrees(np.arccos(np.clip(p[:, 2] / np.linalg.norm(p, axis=1), -1.0, 1.0)))
    return bool(ok.all() and angle.max() <= max_deg)


def calibration_board_poses(
    lens: CameraModel,
    n_views: int,
    rng: np.random.Generator,
    board: tuple[int, int] = (9, 6),
    square_m: float = 0.05,
) -> list[F64]:
    """``n_views`` board poses covering the whole image circle of ``lens``: a sixth near the
    centre (strongly tilted), a third at mid field, the rest at the rim, pushed outwards until
    the squares plus half a square of margin reach the lens's field limit (less
    :data:`_RIM_CLEARANCE_DEG`) or the image edge, so their outer corners sit past 90° off axis
    on a lens wider than 180°."""
    if n_views < 6:
        raise EvaluationError(f"calibration needs at least 6 board views, got {n_views}")
    near, far = 10.0 * square_m, 16.0 * square_m  # the board spans ~55° near, ~35° at the rim
    outline = board_outline(board, square_m, 0.0)
    limit = math.degrees(lens.max_theta) - _RIM_CLEARANCE_DEG
    n_centre = max(2, n_views // 6)
    n_mid = max(2, n_views // 3)
    n_rim = n_views - n_centre - n_mid
    poses: list[F64] = []
    for i in range(n_centre):
        tilt = (float(rng.uniform(-35, 35)), float(rng.uniform(-35, 35)))
        spin = float(rng.uniform(-45, 45))
        poses.append(board_pose(board, square_m, 5.0, 360.0 * i / n_centre, near, tilt, spin))

    def outermost(phi: float, distance: float, tilt: tuple[float, float], spin: float) -> float:
        lo, hi = 0.0, limit
        for _ in range(18):  # bisection on the centre's angle: the board fits at lo
            mid = 0.5 * (lo + hi)
            T = board_pose(board, square_m, mid, phi, distance, tilt, spin)
            lo, hi = (mid, hi) if board_fits(lens, T, outline, limit) else (lo, mid)
        return lo

    for i in range(n_mid + n_rim):
        rim = i >= n_mid
        j = i - n_mid if rim else i
        phi = 360.0 * j / (n_rim if rim else n_mid) + (0.0 if rim else 180.0 / n_mid)
        tilt = (float(rng.uniform(-20, 20)), float(rng.uniform(-20, 20)))
        spin = float(rng.uniform(-45, 45))
        distance = far if rim else near
        top = outermost(phi, distance, tilt, spin)
        poses.append(board_pose(board, square_m, top if rim else 0.5 * top, phi, distance, tilt, spin))
    return poses


def render_board(
    lens: CameraModel,
    T_cam_board: F64,
    board: tuple[int, int],
    square_m: float,
    supersample: int,
    *,
    effects: LensEffects | None = None,
    camera_index: int = 0,
    seed: int = 0,
) -> U8:
    """Grey image of the board (one square of white margin) seen by ``lens`` on a uniform
    background, through the lens ``effects`` of the rig's ``camera_index``-th camera (noise
    seeded by ``seed``); only the board's bounding box is ray-cast."""
    scene = chessboard_scene(*board, square_m, T_cam_board)
    p = board_outline(board, square_m, 1.0) @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    pix, ok = lens.project(p, in_image=False)
    if not ok.any():
        return np.full((lens.height, lens.width), BOARD_BACKGROUND, dtype=np.uint8)
    # Past the lens's field the margin has no image: the valid outline bounds what is seen.
    box = _clip_box(pix[ok, 0], pix[ok, 1], lens.width, lens.height, 2 * _MARGIN)
    return render_in_box(
        scene, lens, np.eye(4), box, supersample=supersample, background=BOARD_BACKGROUND, lens=effects,
        camera_index=camera_index, seed=seed,
    )  # fmt: skip


# ----- plane pairs ------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlaneShot:
    """The paper's target at ``k`` baselines (nominal; ``distance_m`` is where it really is, see
    :func:`plane_distance`): the fisheye pair (only the region the VPC tables read is rendered),
    the Reference pair (ideal pinholes at the VPC poses) and the exact depth (H, W) of the left
    VPC (z in its frame, NaN where no surface)."""

    k: float
    texture: str
    distance_m: float
    left: U8
    right: U8
    ref_left: U8
    ref_right: U8
    depth_true: F32


def plane_distance(pair: RectifiedPair, k: float, phase_px: float) -> float:
    """Distance (m) of the plane at ``k`` baselines moved so its disparity is ``fx/k + phase_px``.

    At whole-pixel disparities (fx/k is one for many k: fx = 320 and k = 2, 4, 5, 8, …) the
    Reference's right image is the left one shifted by whole pixels, which any matcher gets
    exactly right; a sub-pixel phase (|phase| < 0.5 px, stratified over the textures) makes the
    curves average over where the true disparity falls between pixels, as in a real scene."""
    return pair.fx * pair.baseline_m / (pair.fx / k + phase_px)


def render_plane_shot(
    rig: Rig,
    pair: RectifiedPair,
    k: float,
    texture: str,
    boxes: dict[str, Box],
    *,
    phase_px: float,
    seed: int,
    supersample: int,
    noise_std: float,
    vignetting: float,
    lens: LensEffects | None = None,
) -> PlaneShot:
    """Render the plane ``k`` baselines ahead of ``rig`` with ``texture``. The fisheye views get
    the ``lens`` effects and the simple sensor model's ``noise_std`` and ``vignetting``; the
    Reference views the same sensor noise but no lens effects. ``boxes`` per camera name: the
    fisheye regions to render; ``phase_px``: sub-pixel disparity offset (:func:`plane_distance`)."""
    distance = plane_distance(pair, k, phase_px)
    scene = plane_scene(distance, texture, seed)
    seeds = np.random.SeedSequence([seed, round(k * 1000), sum(map(ord, texture))]).generate_state(4)
    fish = {
        name: render_in_box(
            scene, rig.cameras[name], rig.T_rig_cam[name], boxes[name], supersample=supersample,
            noise_std=noise_std, vignetting=vignetting, seed=int(seeds[i]), lens=lens,
            camera_index=list(rig.cameras).index(name),
        )
        for i, name in enumerate((pair.left, pair.right))
    }  # fmt: skip
    sensor = lens.sensor_only() if lens is not None else None
    refs = {
        name: render(scene, pair.camera, pair.T_rig_rect[name], supersample=supersample,
                     noise_std=noise_std, seed=int(seeds[2 + i]), lens=sensor)
        for i, name in enumerate((pair.left, pair.right))
    }  # fmt: skip
    return PlaneShot(
        k=k,
        texture=texture,
        distance_m=distance,
        left=fish[pair.left],
        right=fish[pair.right],
        ref_left=refs[pair.left].image,
        ref_right=refs[pair.right].image,
        depth_true=refs[pair.left].depth,
    )
