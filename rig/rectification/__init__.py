"""The pair stays rectified: measure the rectification error from the scene, and refine the
relative rotation from it, offline and online (docs/rectification.md)."""

from rig.rectification.matching import MatchOptions, RayMatches, match_pair
from rig.rectification.measure import VerticalDisparity, vertical_disparity
from rig.rectification.monitor import RectificationConfig, RectificationMonitor, RectificationStatus
from rig.rectification.refine import (
    RectificationRefinement,
    RefineOptions,
    collect_matches,
    refine_recording,
    refine_rig,
)
from rig.rectification.views import EpipolarViews

__all__ = [
    "EpipolarViews",
    "MatchOptions",
    "RayMatches",
    "RectificationConfig",
    "RectificationMonitor",
    "RectificationRefinement",
    "RectificationStatus",
    "RefineOptions",
    "VerticalDisparity",
    "collect_matches",
    "match_pair",
    "refine_recording",
    "refine_rig",
    "vertical_disparity",
]
