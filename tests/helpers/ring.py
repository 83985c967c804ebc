"""The real ring of ``../shared/data/ring_sweepnet_indoor`` (SweepNet's ``real_indoor_sample``):
four ~220° fisheyes about 92° apart on a horizontal ring, 0.3 m baselines, three synchronised
frames. Reading the dataset's files (its ``.mat`` too) is a test and bench concern, never the
product's: the product reads the ``rig.yaml`` this module writes.

What each file gives, and in which conventions:

- ``ocamN.txt``: OCamCalib ``calib_results.txt``, read by our own reader
  (:mod:`calibration.formats.ocamcalib`), which turns OCamCalib's frame (x along rows, y along
  columns, z backwards) into ours (OpenCV: x right, y down, z forward).
- ``poses.txt``: per camera a rotation vector (3) and a translation (3, millimetres) with
  ``P_rig = R·P_cam + t``; camera 1 is the rig frame. The camera frame of these poses is ours,
  not OCamCalib's: SweepNet's own ``cam2world``/``world2cam_fast`` return and take
  ``(y_oc, x_oc, −z_oc)`` (columns, rows, forward). The images agree: every camera is upright
  (the floor at the bottom), and rotation vectors about y (down) turn the cameras about the
  vertical, camera 2 to camera 1's right. The decisive check is that every adjacent pair's
  features land on the same rows of its rectified views (``tests/rig/test_ring_real.py``).
- ``intrinsic_extrinsic.mat``: the same models and poses as MATLAB structs, and each camera's
  ``invisible_mask``: the pixels past SweepNet's field limit, 112.9° off the axis (a 225.8° field).
  It sets each model's ``fov_deg`` here; the scene itself ends near 108° (the lens barrel's dark
  rim lies between).
"""

from __future__ import annotations

import functools
import math
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import scipy.io
from numpy.typing import NDArray

from calibration.formats import load_camera, save_rig
from calibration.geometry import make_transform
from calibration.models import CameraModel
from calibration.rig import Rig
from rig.recording import RecordingWriter

__all__ = [
    "RING_CAMERAS",
    "RING_DIR",
    "RealRing",
    "load_ring",
    "ring_fov_deg",
    "write_ring",
    "write_ring_recording",
]

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]

#: The folder under the shared data root.
RING_DIR = "ring_sweepnet_indoor"
#: Camera names, in the dataset's order (its adjacent pairs: 1|2, 2|3, 3|4, 4|1).
RING_CAMERAS = ("cam1", "cam2", "cam3", "cam4")
_FRAMES = ("00001.png", "00002.png", "00003.png")
# Every 2nd pixel of the invisible mask finds the field limit to a few hundredths of a degree.
_MASK_STRIDE = 2


@dataclass(frozen=True)
class RealRing:
    """The ring's rig (cameras :data:`RING_CAMERAS`, poses in metres, camera 1 = rig frame) and
    its frames: ``frames[i][name]`` is frame i of camera ``name``, gray (1532, 1600) uint8."""

    root: Path
    rig: Rig
    frames: tuple[dict[str, U8], ...]


def _poses_txt(path: Path) -> list[F64]:
    """T_rig_cam (4, 4) of each line ``rx ry rz tx ty tz`` (rotation vector, millimetres)."""
    rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if rows.shape != (len(RING_CAMERAS), 6):
        raise ValueError(f"{path}: expected {len(RING_CAMERAS)} rows of 6 numbers, got {rows.shape}")
    return [make_transform(cv2.Rodrigues(r[:3])[0], r[3:] / 1000.0) for r in rows]


def _mat(root: Path) -> dict[str, Any]:
    out: dict[str, Any] = scipy.io.loadmat(
        root / "intrinsic_extrinsic.mat", squeeze_me=True, struct_as_record=False
    )
    return out


def ring_fov_deg(model: CameraModel, invisible_mask: NDArray[np.bool_]) -> float:
    """The field of view (degrees, twice the largest angle off the axis) of the pixels the
    dataset's ``invisible_mask`` (H, W) leaves visible, through ``model``."""
    v, u = np.nonzero(~invisible_mask[::_MASK_STRIDE, ::_MASK_STRIDE])
    rays, ok = model.unproject(np.stack([u, v], axis=1).astype(np.float64) * _MASK_STRIDE)
    theta = np.degrees(np.arccos(np.clip(rays[ok, 2], -1.0, 1.0)))
    return 2.0 * float(theta.max())


@functools.lru_cache(maxsize=2)
def load_ring(root: Path) -> RealRing:
    """The ring under ``root`` (the dataset's folder; see the module doc). The poses of
    ``poses.txt`` must equal the ``.mat``'s."""
    mat = _mat(root)
    ocams = np.atleast_1d(mat["ocams"])
    mat_poses = np.asarray(mat["poses"], dtype=np.float64)
    poses = _poses_txt(root / "poses.txt")
    cameras: dict[str, CameraModel] = {}
    T_rig_cam: dict[str, F64] = {}
    for i, name in enumerate(RING_CAMERAS):
        if not np.allclose(mat_poses[:, i], _pose_vector(poses[i]), atol=1e-3):
            raise ValueError(f"{root}: poses.txt and the .mat disagree on camera {i + 1}")
        model = load_camera(root / f"ocam{i + 1}.txt")
        mask = np.asarray(ocams[i].invisible_mask, dtype=bool)
        fov = math.floor(ring_fov_deg(model, mask) * 100.0) / 100.0
        # Naming invpol keeps the file's (replace would refit a derived parameter).
        cameras[name] = model.replace(fov_deg=fov, invpol=model.param_dict["invpol"])
        T_rig_cam[name] = poses[i]
    frames = tuple({name: _gray(root / name / f) for name in RING_CAMERAS} for f in _FRAMES)
    return RealRing(root, Rig(cameras, T_rig_cam), frames)


def _pose_vector(T: F64) -> F64:
    """(rotation vector, translation mm) (6,) of T_rig_cam, the .mat's column layout."""
    rvec = cv2.Rodrigues(np.ascontiguousarray(T[:3, :3]))[0].ravel()
    return np.concatenate([rvec, T[:3, 3] * 1000.0])


def _gray(path: Path) -> U8:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"{path}: missing or unreadable")
    return np.asarray(img, dtype=np.uint8)


def write_ring(ring: RealRing, out: Path) -> Path:
    """``out/rig.yaml`` (our format) and ``out/camN/0000K.png`` copies of the frames; returns the
    rig.yaml's path."""
    out.mkdir(parents=True, exist_ok=True)
    for name in RING_CAMERAS:
        (out / name).mkdir(exist_ok=True)
        for f in _FRAMES:
            shutil.copyfile(ring.root / name / f, out / name / f)
    path = out / "rig.yaml"
    save_rig(ring.rig, path)
    return path


#: The frame period the ring's recording is given (the dataset has no timestamps; 30 fps).
RING_PERIOD_NS = 33_333_333


def write_ring_recording(ring: RealRing, out: Path) -> Path:
    """The ring as an N-camera recording directory (docs/design.md): ``camN/00000K.png`` the
    dataset's frames byte for byte, one set per frame on a 30 fps grid (the dataset's frames are
    synchronised), and the ``rig.yaml`` of :func:`write_ring` as its ``calibration.yaml``."""
    with RecordingWriter(out, meta={"source": str(ring.root)}, cameras=RING_CAMERAS) as writer:
        for seq, f in enumerate(_FRAMES):
            frames = [(ring.root / name / f).read_bytes() for name in RING_CAMERAS]
            writer.write_set(seq, [seq * RING_PERIOD_NS] * len(frames), frames, ext=".png")
    save_rig(ring.rig, out / "calibration.yaml")
    return out
