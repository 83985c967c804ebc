"""Camera models, calibration file formats and calibration of fisheye cameras and rigs.

Imports only numpy, scipy and cv2: nothing here knows about streaming cameras or HTTP.

The names below are imported on first use, so that ``import calibration.rig`` (what the
depth pipeline needs) does not import the calibration solvers and scipy.optimize with them.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from calibration.board_views import DroppedView
    from calibration.calibrate import CameraCalibration, calibrate_camera
    from calibration.corner_refine import RefinementReport, refine_corners_local
    from calibration.errors import CalibrationError, CalibrationFailed, CalibrationFileError, ModelError
    from calibration.formats import detect_format, load_camera, load_rig, save_rig
    from calibration.models import MODELS, CameraModel, create
    from calibration.rig import Rig
    from calibration.stereo_calibrate import StereoCalibration, calibrate_stereo
    from calibration.targets import (
        BoardSpec,
        Detection,
        board_object_points,
        detect_chessboard,
        detect_chessboard_files,
        read_corner_lists,
        read_omnidir_corners,
    )

__all__ = [
    "MODELS",
    "BoardSpec",
    "CalibrationError",
    "CalibrationFailed",
    "CalibrationFileError",
    "CameraCalibration",
    "CameraModel",
    "Detection",
    "DroppedView",
    "ModelError",
    "RefinementReport",
    "Rig",
    "StereoCalibration",
    "board_object_points",
    "calibrate_camera",
    "calibrate_stereo",
    "create",
    "detect_chessboard",
    "detect_chessboard_files",
    "detect_format",
    "load_camera",
    "load_rig",
    "read_corner_lists",
    "read_omnidir_corners",
    "refine_corners_local",
    "save_rig",
]

_LAZY = {
    "CameraCalibration": "calibration.calibrate",
    "DroppedView": "calibration.board_views",
    "calibrate_camera": "calibration.calibrate",
    "RefinementReport": "calibration.corner_refine",
    "refine_corners_local": "calibration.corner_refine",
    "CalibrationError": "calibration.errors",
    "CalibrationFailed": "calibration.errors",
    "CalibrationFileError": "calibration.errors",
    "ModelError": "calibration.errors",
    "detect_format": "calibration.formats",
    "load_camera": "calibration.formats",
    "load_rig": "calibration.formats",
    "save_rig": "calibration.formats",
    "MODELS": "calibration.models",
    "CameraModel": "calibration.models",
    "create": "calibration.models",
    "Rig": "calibration.rig",
    "StereoCalibration": "calibration.stereo_calibrate",
    "calibrate_stereo": "calibration.stereo_calibrate",
    "BoardSpec": "calibration.targets",
    "Detection": "calibration.targets",
    "board_object_points": "calibration.targets",
    "detect_chessboard": "calibration.targets",
    "detect_chessboard_files": "calibration.targets",
    "read_corner_lists": "calibration.targets",
    "read_omnidir_corners": "calibration.targets",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
