"""Stereo pairs of a rig of N cameras from its geometry: each camera with its neighbour by
optical-axis azimuth about the rig's up axis, where their lenses overlap (docs/ring.md).

**Up.** The normal of the plane the optical axes span (the axes' direction of least spread: the
last right-singular vector of the stacked unit axes), its sign towards the cameras' mean up
(their mean −y: our camera frames have y down). A ring's axes lie in the horizontal plane, so
its normal is the vertical even where the cameras are tilted a little; a two-camera divergent
rig's axes span the plane of its baseline and mean axis, whose normal is its −y. Where the axes
span no plane (all parallel, e.g. a forward-looking stereo pair: the second singular value below
:data:`PLANE_SPREAD` of the first), up is the cameras' mean −y itself.

**Azimuth.** The angle of an optical axis about up, from the first camera's axis (0) to 2π,
growing clockwise seen from above (forward to right, the way x points from z in our frames).

**Pairs.** Sorted by azimuth, each camera pairs with the next; for N ≥ 3 the last with the first
too (a ring), for N = 2 the one pair. Left and right follow the convention of the two-camera
rig: the baseline from the left to the right optical centre is the rectified x, so the left
camera is the one that makes the rectified y = z × x (z the mean optical axis) point down,
images upright. For cameras looking out of a ring that is the one of smaller azimuth (its
clockwise neighbour is its right); for a two-camera rig it gives today's (left, right). A
pair is kept only where the two lenses see a common direction (:func:`rig.field.overlap`).

**Explicit pairs.** A rig.yaml's ``pairs:`` (``Rig.pairs``) overrides the geometry:
:func:`stereo_pairs` is the one place a rig's pairs are chosen.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from calibration.rig import Rig, pairs_problem
from rig.errors import ConfigError
from rig.field import overlap
from rig.rectified import rectified_frame

__all__ = [
    "PLANE_SPREAD",
    "PairNames",
    "StereoPairs",
    "adjacent_pairs",
    "axis_azimuths",
    "pair_label",
    "rig_up",
    "stereo_pairs",
]

F64 = NDArray[np.float64]

#: The optical axes span a plane when their second singular value is at least this share of the
#: first (axes 6° apart or more); below, they are parallel and up is the cameras' mean −y.
PLANE_SPREAD = 0.1
# Coarse overlap check: a pair of lenses is kept when they share any direction on this grid.
_OVERLAP_STEP_DEG = 1.0

#: A stereo pair's (left, right) camera names.
PairNames = tuple[str, str]
#: The stereo pairs of a rig.
StereoPairs = list[PairNames]


def _unit(v: F64, what: str) -> F64:
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise ConfigError(f"rig: {what} is undefined")
    return v / n


def rig_up(rig: Rig) -> F64:
    """The rig's up axis (3,), unit, in the rig frame (see the module doc)."""
    cameras_up = _unit(-np.mean([rig.T_rig_cam[n][:3, 1] for n in rig.names], axis=0), "the cameras' mean up")
    axes = np.array([rig.axis(n) for n in rig.names])
    if len(axes) < 2:
        return cameras_up
    _, s, vt = np.linalg.svd(axes)
    if s[1] < PLANE_SPREAD * s[0]:
        return cameras_up
    normal: F64 = vt[2]
    return normal if float(normal @ cameras_up) >= 0.0 else -normal


def axis_azimuths(rig: Rig, up: F64 | None = None) -> dict[str, float]:
    """Each camera's optical-axis azimuth (radians in [0, 2π)) about ``up`` (default
    :func:`rig_up`), from the first camera's axis, clockwise seen from above."""
    up = rig_up(rig) if up is None else _unit(np.asarray(up, dtype=np.float64), "up")
    flat = {n: rig.axis(n) - (rig.axis(n) @ up) * up for n in rig.names}
    forward = _unit(flat[rig.names[0]], f"camera {rig.names[0]!r}'s azimuth (it looks straight up or down)")
    right = np.cross(forward, up)
    out = {n: math.atan2(float(a @ right), float(a @ forward)) % math.tau for n, a in flat.items()}
    out[rig.names[0]] = 0.0  # by definition (rounding may put it a hair below 2π)
    return out


def _oriented(rig: Rig, a: str, b: str, up: F64) -> tuple[str, str]:
    """(left, right) of neighbours ``a`` (smaller azimuth) and ``b``: the order whose rectified
    y points down; ``(a, b)`` where the rectified frame is undefined or y is level."""
    try:
        R, _ = rectified_frame(rig, a, b)
    except ConfigError:
        return a, b
    return (b, a) if float(R[:, 1] @ up) > 1e-9 else (a, b)


def _overlaps(rig: Rig, left: str, right: str) -> bool:
    try:
        R, _ = rectified_frame(rig, left, right)
        overlap(rig, R, left, right, step_deg=_OVERLAP_STEP_DEG)
    except ConfigError:
        return False
    return True


def adjacent_pairs(rig: Rig, pairs: Sequence[tuple[str, str]] | None = None) -> StereoPairs:
    """The stereo pairs of ``rig`` (see the module doc); ``pairs``, when given, overrides them
    (checked: named cameras of the rig, two different ones per pair, no pair twice).
    ConfigError for a rig of fewer than two cameras or a bad explicit list."""
    if pairs is not None:
        return _checked(rig, pairs)
    if len(rig.names) < 2:
        raise ConfigError(f"rig: stereo needs two cameras or more, the rig has {len(rig.names)}")
    up = rig_up(rig)
    azimuths = axis_azimuths(rig, up)
    order = sorted(rig.names, key=lambda n: azimuths[n])
    neighbours = list(itertools.pairwise(order))
    if len(order) >= 3:
        neighbours.append((order[-1], order[0]))
    oriented = [_oriented(rig, a, b, up) for a, b in neighbours]
    return [p for p in oriented if _overlaps(rig, *p)]


def _checked(rig: Rig, pairs: Sequence[tuple[str, str]]) -> StereoPairs:
    problem = pairs_problem(pairs, rig.names)
    if problem is not None:
        where = "pairs" if problem[0] < 0 else f"pairs[{problem[0]}]"
        raise ConfigError(f"{where}: {problem[1]}")
    return [(str(left), str(right)) for left, right in pairs]


def stereo_pairs(rig: Rig) -> StereoPairs:
    """The stereo pairs of ``rig``: its explicit ``pairs`` (rig.yaml's ``pairs:``) or, without
    them, the pairs of its geometry (:func:`adjacent_pairs`). Every consumer of a rig's pairs
    asks here."""
    return adjacent_pairs(rig, rig.pairs)


def pair_label(names: PairNames) -> str:
    """A pair's name in files, URLs and topics: ``"A-B"`` (left camera, right camera)."""
    return f"{names[0]}-{names[1]}"
