"""A calibrated rig: named camera models and their poses in the rig frame (docs/design.md)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.errors import ModelError
from calibration.geometry import invert_transform, is_rotation
from calibration.models import CameraModel

__all__ = ["MAX_TRANSLATION", "Rig", "pairs_problem", "translation_problem"]

F64 = NDArray[np.float64]

# Largest translation component accepted in a pose: far beyond any stereo rig in any unit files use
# (metres; OpenCV stereo files keep their calibration's, often mm), far enough from float64's range
# that baselines and the rig frame built from them cannot overflow (a 1e200 entry would).
MAX_TRANSLATION = 1e6


def translation_problem(t: F64) -> str | None:
    """What is wrong with the translation ``t`` (3,) of a pose, or None: an entry beyond
    ±MAX_TRANSLATION. (File readers name the field; the rig's checks say which pose.)"""
    if np.abs(t).max() <= MAX_TRANSLATION:
        return None
    return (
        f"translation {[float(f'{x:.6g}') for x in t]} is beyond ±{MAX_TRANSLATION:g} "
        "(a stereo rig's cameras are centimetres apart)"
    )


def pairs_problem(pairs: Sequence[Sequence[str]], cameras: Sequence[str]) -> tuple[int, str] | None:
    """What is wrong with an explicit list of stereo pairs (each ``[left, right]`` of ``cameras``),
    as (index of the entry at fault, message), or None. (File readers name the field.)"""
    if not pairs:
        return -1, "the list is empty"
    seen: set[tuple[str, str]] = set()
    for i, pair in enumerate(pairs):
        if len(pair) != 2:
            return i, f"a pair names two cameras, got {list(pair)!r}"
        left, right = pair
        for name in (left, right):
            if name not in cameras:
                return i, f"the rig has no camera {name!r} (cameras: {', '.join(cameras)})"
        if left == right:
            return i, f"camera {left!r} cannot pair with itself"
        if (left, right) in seen:
            return i, f"{left}|{right} is listed twice"
        seen.add((left, right))
    return None


def _check_translation(t: F64, what: str) -> None:
    """ModelError naming ``what`` unless the translation ``t`` (3,) is in range."""
    problem = translation_problem(t)
    if problem is not None:
        raise ModelError(f"{what} {problem}")


@dataclass
class Rig:
    """``cameras[name]`` is a model; ``T_rig_cam[name]`` (4, 4) maps camera points into the rig;
    ``pairs``, when given, the stereo pairs ``(left, right)`` (None: from the geometry,
    ``rig.ring.adjacent_pairs``)."""

    cameras: dict[str, CameraModel]
    T_rig_cam: dict[str, F64] = field(default_factory=dict)
    pairs: list[tuple[str, str]] | None = None

    def __post_init__(self) -> None:
        if set(self.cameras) != set(self.T_rig_cam):
            raise ModelError(f"rig cameras {sorted(self.cameras)} and poses {sorted(self.T_rig_cam)} differ")
        for name, T in self.T_rig_cam.items():
            T = np.asarray(T, dtype=np.float64)
            if T.shape != (4, 4) or not np.isfinite(T).all():
                raise ModelError(f"T_rig_cam of camera '{name}' must be a finite 4x4 matrix")
            if not is_rotation(T[:3, :3]):
                raise ModelError(f"T_rig_cam of camera '{name}' is not a rigid transform")
            if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
                raise ModelError(f"T_rig_cam of camera '{name}' must end with row [0, 0, 0, 1]")
            _check_translation(T[:3, 3], f"T_rig_cam of camera '{name}':")
            self.T_rig_cam[name] = T
        if self.pairs is not None:
            problem = pairs_problem(self.pairs, list(self.cameras))
            if problem is not None:
                where = "pairs" if problem[0] < 0 else f"pairs[{problem[0]}]"
                raise ModelError(f"{where}: {problem[1]}")
            self.pairs = [(str(a), str(b)) for a, b in self.pairs]

    @property
    def names(self) -> list[str]:
        return list(self.cameras)

    def center(self, name: str) -> F64:
        """Optical centre of camera ``name`` in the rig frame (3,)."""
        return self.T_rig_cam[name][:3, 3].copy()

    def axis(self, name: str) -> F64:
        """Optical axis (unit z of the camera) in the rig frame (3,)."""
        return self.T_rig_cam[name][:3, 2].copy()

    def baseline(self, a: str = "left", b: str = "right") -> float:
        """Distance between the optical centres of two cameras (metres)."""
        return float(np.linalg.norm(self.center(b) - self.center(a)))

    def to_dict(self) -> dict[str, Any]:
        """The rig.yaml document (docs/design.md, "rig.yaml")."""
        cams: dict[str, Any] = {}
        for name, model in self.cameras.items():
            entry = model.to_dict()
            entry["T_rig_cam"] = [[float(x) for x in row] for row in self.T_rig_cam[name]]
            cams[name] = entry
        doc: dict[str, Any] = {"cameras": cams}
        if self.pairs is not None:
            doc["pairs"] = [[a, b] for a, b in self.pairs]
        return doc

    @classmethod
    def from_relative_pose(
        cls,
        left_model: CameraModel,
        right_model: CameraModel,
        T_right_left: ArrayLike,
        names: tuple[str, str] = ("left", "right"),
    ) -> Rig:
        """A two-camera rig from the pose of the right camera relative to the left
        (``p_right = T_right_left · p_left``, (4, 4)), in the canonical rig frame (docs/design.md,
        "Conventions"): origin at the midpoint of the optical centres, x along the baseline (left -> right),
        z = the mean of the two optical axes made orthogonal to x, y = z × x.

        Raises ModelError if the pose is not rigid, the centres coincide or the mean axis is
        parallel to the baseline (no forward direction to define).
        """
        if names[0] == names[1]:
            raise ModelError(f"the two cameras need different names, got {names[0]!r} twice")
        T = np.asarray(T_right_left, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ModelError("T_right_left must be a finite 4x4 matrix")
        R, t = T[:3, :3], T[:3, 3]
        if not is_rotation(R):
            raise ModelError("T_right_left is not a rigid transform")
        _check_translation(t, "T_right_left:")
        # Everything below is expressed in the left camera's frame.
        center_right = -R.T @ t
        baseline = float(np.linalg.norm(center_right))
        if baseline <= 1e-12:
            raise ModelError("the two optical centres coincide: no baseline to define the rig frame")
        x = center_right / baseline
        mean_axis = np.array([0.0, 0.0, 1.0]) + R.T[:, 2]
        z = mean_axis - (mean_axis @ x) * x
        z_norm = float(np.linalg.norm(z))
        if z_norm <= 1e-9:
            raise ModelError("the mean optical axis is parallel to the baseline: no forward direction")
        z /= z_norm
        y = np.cross(z, x)
        T_left_rig = np.eye(4)
        T_left_rig[:3, :3] = np.column_stack([x, y, z])
        T_left_rig[:3, 3] = center_right / 2.0
        T_rig_left = invert_transform(T_left_rig)
        T_rig_right = T_rig_left @ invert_transform(T)
        left, right = names
        return cls({left: left_model, right: right_model}, {left: T_rig_left, right: T_rig_right})

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Rig:
        """Inverse of :meth:`to_dict`; raises ModelError naming the camera and field."""
        cams = d.get("cameras") if isinstance(d, Mapping) else None
        if not isinstance(cams, Mapping) or not cams:
            raise ModelError("field 'cameras' must be a non-empty mapping")
        cameras: dict[str, CameraModel] = {}
        poses: dict[str, F64] = {}
        for name, entry in cams.items():
            if not isinstance(entry, Mapping):
                raise ModelError(f"cameras.{name} must be a mapping")
            try:
                cameras[str(name)] = CameraModel.from_dict(entry)
            except ModelError as err:
                raise ModelError(f"cameras.{name}: {err}") from err
            if "T_rig_cam" not in entry:
                raise ModelError(f"cameras.{name}: missing field 'T_rig_cam'")
            try:
                poses[str(name)] = np.asarray(entry["T_rig_cam"], dtype=np.float64)
            except (TypeError, ValueError) as err:
                raise ModelError(f"cameras.{name}.T_rig_cam must be a 4x4 matrix of numbers") from err
        return cls(cameras, poses, _pairs_field(d.get("pairs")))


def _pairs_field(value: Any) -> list[tuple[str, str]] | None:
    """The ``pairs`` field of a rig document (None when absent); ModelError naming the entry."""
    if value is None:
        return None
    if not isinstance(value, list | tuple):
        raise ModelError("field 'pairs' must be a list of [left, right] camera names")
    out = []
    for i, pair in enumerate(value):
        if not isinstance(pair, list | tuple) or len(pair) != 2 or not all(isinstance(n, str) for n in pair):
            raise ModelError(f"pairs[{i}]: a pair is [left, right], two camera names; got {pair!r}")
        out.append((pair[0], pair[1]))
    return out
