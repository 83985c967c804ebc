"""Camera models, calibration file formats and calibration of fisheye cameras and rigs.

Imports only numpy, scipy and cv2: nothing here knows about streaming cameras or HTTP.
"""

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
