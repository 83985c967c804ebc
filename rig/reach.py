"""How near a pair ranges: the disparity search against the baseline (docs/stereo.md, "Reach").

A pair matches disparities ``min_disparity … min_disparity + disparity_range − 1``; the largest is
its nearest range. Straight ahead (perpendicular to the baseline, where disparity is largest) a
point at range ``r`` has the disparity

    lat-lon pair:  d = fx · atan(B / r)      (fx in px per radian: the angle between the rays)
    pinhole pair:  d = fx · B / r

so 96 disparities at 320 px/rad reach 0.24 m on the prototype's 72 mm baseline and ~1 m on a
0.3 m one. ``stereo.min_range_m`` asks for a nearest range instead: the search is widened to
reach it (never narrowed below ``disparity_range``), as far as the rectified view's width allows,
and where it cannot the pair says how near it reaches (:func:`reach_note`).
"""

from __future__ import annotations

import math

from rig.stereo import StereoParams

__all__ = ["axis_disparity_px", "nearest_range_m", "reach_note", "reaching"]

# Columns a pinhole pair keeps to match beyond its search (the matcher's blind band).
_MIN_MATCH_COLUMNS = 16


def axis_disparity_px(projection: str, fx: float, baseline_m: float, range_m: float) -> float:
    """The disparity (px) of a point ``range_m`` straight ahead (see the module doc)."""
    if projection == "latlon":
        return fx * math.atan2(baseline_m, range_m)
    return fx * baseline_m / range_m


def nearest_range_m(projection: str, fx: float, baseline_m: float, params: StereoParams) -> float:
    """The nearest range straight ahead that ``params``' search matches (m; inf: none)."""
    d = params.min_disparity + params.disparity_range - 1
    if d <= 0:
        return math.inf
    if projection == "latlon":
        return baseline_m / math.tan(min(d / fx, math.pi / 2 - 1e-9))
    return fx * baseline_m / d


def reaching(
    params: StereoParams, projection: str, fx: float, baseline_m: float, width: int | None = None
) -> StereoParams:
    """``params`` with the search widened to reach ``params.min_range_m`` (unchanged without
    one); a pinhole pair's unmatched band (:attr:`StereoParams.blind_band_px`) stays
    ``_MIN_MATCH_COLUMNS`` narrower than its ``width``."""
    if params.min_range_m is None:
        return params
    need = math.ceil(axis_disparity_px(projection, fx, baseline_m, params.min_range_m)) + 1
    span = 16 * math.ceil(max(need - params.min_disparity, 16) / 16)
    if width is not None:
        # The unmatched band (the coarse-to-fine search's rounds the range up) leaves room.
        while span > 16 and _with_range(params, span).blind_band_px > width - _MIN_MATCH_COLUMNS:
            span -= 16
    return _with_range(params, max(params.disparity_range, span))


def _with_range(params: StereoParams, span: int) -> StereoParams:
    return params.model_copy(update={"disparity_range": span})


def reach_note(name: str, projection: str, fx: float, baseline_m: float, params: StereoParams) -> str | None:
    """A line saying that pair ``name`` cannot reach ``params.min_range_m``, or None."""
    asked = params.min_range_m
    if asked is None:
        return None
    nearest = nearest_range_m(projection, fx, baseline_m, params)
    if nearest <= asked * (1 + 1e-9):
        return None
    return (
        f"stereo: pair {name} ranges no nearer than {nearest:.2f} m ({params.disparity_range} disparities "
        f"at {fx:.0f} px/rad, baseline {baseline_m:.3f} m), not the {asked:g} m of stereo.min_range_m: "
        "nearer surfaces get no range (a finer pair or a wider image reaches nearer)"
    )
