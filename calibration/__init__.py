"""Camera models, calibration file formats and calibration of fisheye cameras and rigs.

Imports only numpy, scipy and cv2: nothing here knows about streaming cameras or HTTP.
"""

from calibration.errors import CalibrationError, CalibrationFailed, CalibrationFileError, ModelError
from calibration.formats import detect_format, load_camera, load_rig, save_rig
from calibration.models import MODELS, CameraModel, create
from calibration.rig import Rig

__all__ = [
    "MODELS",
    "CalibrationError",
    "CalibrationFailed",
    "CalibrationFileError",
    "CameraModel",
    "ModelError",
    "Rig",
    "create",
    "detect_format",
    "load_camera",
    "load_rig",
    "save_rig",
]
