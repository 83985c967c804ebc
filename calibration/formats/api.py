"""The three entry points: :func:`load_camera`, :func:`load_rig`, :func:`save_rig`."""

from __future__ import annotations

from pathlib import Path

from calibration.errors import CalibrationFileError, ModelError
from calibration.formats.detect import read_calibration
from calibration.formats.rig_yaml import write_rig_yaml
from calibration.models import CameraModel
from calibration.rig import Rig

__all__ = ["load_camera", "load_rig", "save_rig"]


def load_camera(path: str | Path, name: str | None = None) -> CameraModel:
    """One camera model from any supported calibration file (format detected from content).

    ``name`` picks a camera of a multi-camera file: ``left``/``right`` (also ``cam0``/``cam1``
    for Kalibr, basalt and OpenCV stereo files) or a rig.yaml camera name; default the first.
    """
    return read_calibration(path).camera(name)


def load_rig(path: str | Path) -> Rig:
    """A rig from rig.yaml (poses as stored) or from a stereo file giving the relative pose of
    the second camera (Kalibr, basalt, OpenCV stereo): cameras ``left``/``right`` in the canonical
    rig frame of :meth:`Rig.from_relative_pose`."""
    content = read_calibration(path)
    if len(content.cameras) < 2:
        raise CalibrationFileError(content.path, "holds one camera; a rig needs two")
    try:
        if content.T_rig_cam is not None:
            return Rig(dict(content.cameras), dict(content.T_rig_cam), content.pairs)
        if content.pose_error is not None:
            raise content.pose_error
        if content.T_right_left is None:
            raise CalibrationFileError(content.path, "gives no pose between its cameras")
        left, right = list(content.cameras)[:2]
        return Rig.from_relative_pose(content.cameras[left], content.cameras[right], content.T_right_left)
    except ModelError as err:
        raise CalibrationFileError(content.path, f"not a usable rig: {err}") from err


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write ``rig`` as our rig.yaml (``version: 1``), atomically, with exact float round trips."""
    write_rig_yaml(rig, path)
