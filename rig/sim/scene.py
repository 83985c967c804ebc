"""Scenes of textured rectangles, and the ray casting the renderer does against them.

World frame = rig frame (docs/design.md, "Conventions": x right, y down, z forward), metres. A
:class:`TexturedRect` lies in the z = 0 plane of its own frame ``T_world_rect``, centred on its
origin, spanning ``size_m = (width along its x, height along its y)``; it is seen from both
sides. Its texture coordinates (s, t) run from the corner at local (-w/2, -h/2), so a rectangle
with the identity rotation in front of a camera with the identity rotation shows its texture
upright, unmirrored.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.geometry import is_rotation, make_transform, rot_y
from rig.errors import SimulationError
from rig.sim.textures import CheckerTexture, Texture, make_texture, texture_name

__all__ = [
    "Hits",
    "RectArrays",
    "Scene",
    "TexturedRect",
    "chessboard_corners",
    "chessboard_scene",
    "intersect_rects",
    "plane_scene",
    "rect_from_axes",
    "room_scene",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

#: Centres, x axes, y axes, normals (R, 3) each and half sizes (R, 2) of R rectangles.
RectArrays = tuple[F64, F64, F64, F64, F64]

# Hits closer than this (metres) are the ray's own origin, not a surface.
_T_MIN = 1e-9
# Bound on rays x rectangles per intersection batch (~16 MB per float64 temporary).
_BATCH_ELEMENTS = 1 << 21


@dataclass(frozen=True, eq=False)
class TexturedRect:
    """A textured rectangle (see the module docstring for its frame and texture coordinates)."""

    T_world_rect: F64
    size_m: tuple[float, float]
    texture: Texture
    name: str = ""

    def __post_init__(self) -> None:
        T = np.asarray(self.T_world_rect, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise SimulationError(f"rect {self.name!r}: T_world_rect must be a finite 4x4 matrix")
        R = T[:3, :3]
        if not is_rotation(R, tol=1e-9):
            raise SimulationError(f"rect {self.name!r}: T_world_rect is not a rigid transform")
        w, h = (float(v) for v in self.size_m)
        if not (w > 0 and h > 0 and math.isfinite(w) and math.isfinite(h)):
            raise SimulationError(f"rect {self.name!r}: size_m must be positive, got {self.size_m}")
        object.__setattr__(self, "T_world_rect", T)
        object.__setattr__(self, "size_m", (w, h))


class Hits(NamedTuple):
    """Nearest hits of N rays: ``t`` (N,) ray parameter (inf = none), ``rect_index`` (N,) index
    into ``Scene.rects`` (-1 = none), ``st`` (N, 2) texture coordinates in metres on it."""

    t: F64
    rect_index: I64
    st: F64


@dataclass(eq=False)
class Scene:
    """Rectangles plus a JSON-able description ``info`` (``kind`` and its parameters)."""

    rects: list[TexturedRect]
    info: dict[str, Any] = field(default_factory=dict)

    @functools.cached_property
    def rect_arrays(self) -> RectArrays:
        """The rectangles as arrays in the world frame (see :data:`RectArrays`)."""
        T = np.stack([r.T_world_rect for r in self.rects]) if self.rects else np.zeros((0, 4, 4))
        half = np.array([r.size_m for r in self.rects], dtype=np.float64).reshape(-1, 2) / 2.0
        return T[:, :3, 3], T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], half

    def intersect(self, origin: ArrayLike, dirs: F64) -> Hits:
        """Nearest rectangle along rays ``origin (3,) + t * dirs (N, 3)`` with t > 0."""
        return intersect_rects(self.rect_arrays, origin, dirs)


def intersect_rects(rects: RectArrays, origin: ArrayLike, dirs: F64) -> Hits:
    """Nearest of the rectangles ``rects`` (centres, x axes, y axes, normals (R, 3) each and half
    sizes (R, 2)) along rays ``origin (3,) + t * dirs (N, 3)`` with t > 0; ``rect_index`` indexes
    ``rects`` (ties go to the lower index)."""
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    n = d.shape[0]
    t_best = np.full(n, np.inf)
    idx = np.full(n, -1, dtype=np.int64)
    st = np.zeros((n, 2))
    centres, ux, uy, normal, half = rects
    r = centres.shape[0]
    if r == 0 or n == 0:
        return Hits(t_best, idx, st)
    # Per rectangle: the origin's offset along the normal and in-plane axes; one matrix
    # product then gives every ray's components along all three axes of all rectangles.
    oc = o[None, :] - centres  # (R, 3)
    num = -np.einsum("rk,rk->r", oc, normal)
    a0, b0 = np.einsum("rk,rk->r", oc, ux), np.einsum("rk,rk->r", oc, uy)
    basis = np.concatenate([normal, ux, uy]).T  # (3, 3R)
    step = max(1, _BATCH_ELEMENTS // r)
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo in range(0, n, step):
            sl = slice(lo, lo + step)
            proj = d[sl] @ basis  # (m, 3R)
            # Rays parallel to a plane give t = ±inf or nan there: rejected below.
            t = num / proj[:, :r]
            # The hit's coordinates in the rectangle's plane, from its centre.
            a = proj[:, r : 2 * r]
            a *= t
            a += a0
            b = proj[:, 2 * r :]
            b *= t
            b += b0
            hit = np.abs(a) <= half[:, 0]
            hit &= np.abs(b) <= half[:, 1]
            hit &= t > _T_MIN
            t[~hit] = np.inf
            if r == 1:
                k = np.zeros(t.shape[0], dtype=np.int64)
                t_best[sl], st[sl, 0], st[sl, 1] = t[:, 0], a[:, 0], b[:, 0]
            else:
                k = np.argmin(t, axis=1)
                rows = np.arange(k.shape[0])
                t_best[sl], st[sl, 0], st[sl, 1] = t[rows, k], a[rows, k], b[rows, k]
            idx[sl] = k
    found = np.isfinite(t_best)
    idx[~found] = -1
    # Texture coordinates run from the rectangle's corner.
    st += half[np.maximum(idx, 0)]
    st[~found] = 0.0
    return Hits(t_best, idx, st)


def rect_from_axes(
    centre: ArrayLike,
    x_axis: ArrayLike,
    y_axis: ArrayLike,
    size_m: tuple[float, float],
    texture: Texture,
    name: str = "",
) -> TexturedRect:
    """Rectangle centred at ``centre`` whose width runs along ``x_axis`` and height along
    ``y_axis`` (orthogonal directions, normalised here); its normal is x × y."""
    x = np.asarray(x_axis, dtype=np.float64)
    y = np.asarray(y_axis, dtype=np.float64)
    x, y = x / np.linalg.norm(x), y / np.linalg.norm(y)
    if abs(float(x @ y)) > 1e-9:
        raise SimulationError(f"rect {name!r}: x and y axes must be orthogonal")
    return TexturedRect(
        make_transform(np.column_stack([x, y, np.cross(x, y)]), centre), size_m, texture, name
    )


def plane_scene(
    distance_m: float,
    texture: str | int = 0,
    seed: int = 0,
    size_m: float | None = None,
    *,
    texture_px: int = 2048,
) -> Scene:
    """The paper's target: a fronto-parallel square at z = ``distance_m`` in the rig frame.

    ``size_m`` defaults to 4 × distance (126° wide seen from the rig: fills a 120° view). One
    texture tile spans the whole plane (``texture_px`` texels across), so there is no repeat
    for the matcher to confuse, and the texture subtends the same angle at every distance.
    """
    d = float(distance_m)
    if not (math.isfinite(d) and d > 0):
        raise SimulationError(f"plane distance must be a positive number of metres, got {distance_m!r}")
    size = 4.0 * d if size_m is None else float(size_m)
    if not (math.isfinite(size) and size > 0):
        raise SimulationError(f"plane size_m must be positive, got {size_m!r}")
    name = texture_name(texture)
    tex = make_texture(name, seed, size_m=size, size_px=texture_px)
    rect = TexturedRect(make_transform(np.eye(3), [0.0, 0.0, d]), (size, size), tex, "plane")
    info = {"kind": "plane", "distance_m": d, "size_m": size, "texture": name, "seed": int(seed)}
    return Scene([rect], info)


# Room: x in [-3, 3], floor 1.2 m below the rig (y down), ceiling 1.5 m above, z in [-3, 7].
_ROOM_X, _ROOM_FLOOR, _ROOM_CEIL, _ROOM_Z = 3.0, 1.2, -1.5, (-3.0, 7.0)


def _box(
    cx: float, cz: float, size: tuple[float, float, float], yaw: float, tex: Texture, name: str
) -> list[TexturedRect]:
    """Top and four sides of a box standing on the floor, yawed about the vertical."""
    sx, sy, sz = size
    R = rot_y(yaw)
    ex, ey, ez = R[:, 0], np.array([0.0, 1.0, 0.0]), R[:, 2]
    c = np.array([cx, _ROOM_FLOOR - sy / 2.0, cz])
    return [
        rect_from_axes(c - ey * sy / 2, ex, ez, (sx, sz), tex, f"{name}-top"),
        rect_from_axes(c - ez * sz / 2, ex, ey, (sx, sy), tex, f"{name}-front"),
        rect_from_axes(c + ez * sz / 2, ex, ey, (sx, sy), tex, f"{name}-back"),
        rect_from_axes(c - ex * sx / 2, ez, ey, (sz, sy), tex, f"{name}-left"),
        rect_from_axes(c + ex * sx / 2, ez, ey, (sz, sy), tex, f"{name}-right"),
    ]


def room_scene(seed: int = 0) -> Scene:
    """A closed room (floor, ceiling, four walls) with four boxes ahead of the rig, for the demo.

    The room encloses the rig on every side, so every ray of a 190° lens hits a surface. The
    seed jitters the boxes and picks the texture seeds; the rig may move within x ∈ [-1, 1],
    z ∈ [-1, 1.5] without entering a box.
    """
    rng = np.random.default_rng([int(seed), 7])
    w = 2.0 * _ROOM_X
    height = _ROOM_FLOOR - _ROOM_CEIL
    depth = _ROOM_Z[1] - _ROOM_Z[0]
    mid_y, mid_z = (_ROOM_FLOOR + _ROOM_CEIL) / 2.0, sum(_ROOM_Z) / 2.0

    def tex(
        kind: str, tile: float, dark: tuple[float, float, float], light: tuple[float, float, float]
    ) -> Texture:
        return make_texture(kind, int(rng.integers(1 << 31)), size_m=tile).tinted(dark, light)

    ex, ey, ez = np.eye(3)
    rects = [
        rect_from_axes(
            [0, _ROOM_FLOOR, mid_z],
            ex,
            ez,
            (w, depth),
            tex("checker-noise", 2.0, (20, 30, 45), (200, 225, 240)),
            "floor",
        ),
        rect_from_axes(
            [0, _ROOM_CEIL, mid_z],
            ex,
            ez,
            (w, depth),
            tex("noise", 4.0, (70, 70, 70), (250, 250, 245)),
            "ceiling",
        ),
        rect_from_axes(
            [0, mid_y, _ROOM_Z[1]],
            ex,
            ey,
            (w, height),
            tex("paper", 2.0, (40, 30, 20), (235, 245, 250)),
            "front-wall",
        ),
        rect_from_axes(
            [0, mid_y, _ROOM_Z[0]],
            ex,
            ey,
            (w, height),
            tex("noise", 2.5, (60, 20, 20), (250, 210, 190)),
            "back-wall",
        ),
        rect_from_axes(
            [-_ROOM_X, mid_y, mid_z],
            ez,
            ey,
            (depth, height),
            tex("bricks", 3.0, (20, 30, 70), (170, 190, 240)),
            "left-wall",
        ),
        rect_from_axes(
            [_ROOM_X, mid_y, mid_z],
            ez,
            ey,
            (depth, height),
            tex("bricks", 3.0, (40, 40, 40), (220, 220, 210)),
            "right-wall",
        ),
    ]
    boxes = [
        (-1.2, 3.0, (0.8, 0.9, 0.8), 20.0, ("blobs", (10, 60, 10), (150, 250, 150))),
        (1.3, 4.2, (1.0, 1.4, 0.7), -15.0, ("noise", (10, 10, 80), (140, 200, 255))),
        (0.1, 5.6, (1.6, 0.6, 0.9), 5.0, ("paper", (60, 20, 60), (250, 220, 250))),
        (-2.2, 1.6, (0.6, 1.8, 0.6), 0.0, ("blobs", (50, 50, 10), (200, 240, 240))),
    ]
    placed = []
    for i, (x, z, size, yaw, (kind, dark, light)) in enumerate(boxes):
        jx, jz = rng.uniform(-0.15, 0.15, 2)
        jyaw = float(rng.uniform(-8.0, 8.0))
        rects += _box(x + jx, z + jz, size, math.radians(yaw + jyaw), tex(kind, 1.0, dark, light), f"box{i}")
        placed.append({"x": float(x + jx), "z": float(z + jz), "size_m": list(size), "yaw_deg": yaw + jyaw})
    return Scene(rects, {"kind": "room", "seed": int(seed), "boxes": placed})


def chessboard_corners(cols: int, rows: int, square_m: float) -> F64:
    """Inner corners (cols*rows, 3) in the board frame, row-major: corner (i, j) = (j s, i s, 0).

    Board frame: origin at the first inner corner, x along a row of corners, y down the board,
    z into it (a camera with the board's rotation looks at its printed side). This is the order
    ``cv2.findChessboardCornersSB(img, (cols, rows))`` returns for an unrotated board.
    """
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.stack([j.ravel() * square_m, i.ravel() * square_m, np.zeros(cols * rows)], axis=1).astype(
        np.float64
    )


def chessboard_scene(
    cols: int, rows: int, square_m: float, T_world_board: ArrayLike, margin_squares: float = 1
) -> Scene:
    """A chessboard with ``cols × rows`` inner corners ((cols+1) × (rows+1) squares, the top-left
    one white) inside a white border of ``margin_squares`` squares, posed by ``T_world_board``
    (board frame as in :func:`chessboard_corners`). Edges are analytic: sharp at any distance.

    Use one odd and one even count (e.g. 9×6): ``cv2.findChessboardCornersSB`` then returns the
    corners in :func:`chessboard_corners` order; a board with both counts odd or both even looks
    the same turned 180° and its detected order is ambiguous."""
    if int(cols) < 2 or int(rows) < 2:
        raise SimulationError(f"chessboard needs at least 2x2 inner corners, got {cols}x{rows}")
    s = float(square_m)
    if not (math.isfinite(s) and s > 0):
        raise SimulationError(f"chessboard square_m must be positive, got {square_m!r}")
    if not (margin_squares >= 0):
        raise SimulationError(f"chessboard margin_squares must be >= 0, got {margin_squares!r}")
    T = np.asarray(T_world_board, dtype=np.float64)
    if T.shape != (4, 4):
        raise SimulationError(f"T_world_board must be 4x4, got shape {T.shape}")
    cols, rows = int(cols), int(rows)
    m = float(margin_squares) * s
    width, height = (cols + 1) * s + 2 * m, (rows + 1) * s + 2 * m
    # The rect's centre in the board frame: the board's squares start one square before corner 0.
    centre = np.array([-s - m + width / 2.0, -s - m + height / 2.0, 0.0])
    T_world_rect = T @ make_transform(np.eye(3), centre)
    tex = CheckerTexture(cols + 1, rows + 1, s, m)
    info = {
        "kind": "chessboard",
        "cols": cols,
        "rows": rows,
        "square_m": s,
        "margin_squares": float(margin_squares),
    }
    return Scene([TexturedRect(T_world_rect, (width, height), tex, "chessboard")], info)
