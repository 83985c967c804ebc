"""Calibration file formats: detect by content, load cameras and rigs, save our rig.yaml.

Read: our rig.yaml, Kalibr camchain, basalt JSON, CamOdoCal YAML, OCamCalib calib_results.txt,
OpenCV FileStorage YAML/XML (mono K/D[/xi], stereo K1/D1/K2/D2/R/T). Write: rig.yaml.
Every malformed file raises :class:`calibration.errors.CalibrationFileError` naming file and field.
"""

from calibration.formats.api import load_camera, load_rig, save_rig
from calibration.formats.content import CalibrationContent
from calibration.formats.detect import FORMATS, detect_format, read_calibration
from calibration.formats.rig_yaml import RIG_YAML_VERSION, dump_rig_yaml

__all__ = [
    "FORMATS",
    "RIG_YAML_VERSION",
    "CalibrationContent",
    "detect_format",
    "dump_rig_yaml",
    "load_camera",
    "load_rig",
    "read_calibration",
    "save_rig",
]
