"""What every format loader returns: named camera models plus whatever pose the file gives."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationFileError, ModelError
from calibration.formats.document import Field
from calibration.models import MODELS, CameraModel

__all__ = ["CalibrationContent", "build_model"]

F64 = NDArray[np.float64]


@dataclass
class CalibrationContent:
    """A parsed calibration file.

    ``cameras`` is ordered (the first is the default camera); ``aliases`` maps other names a
    file uses (``cam0``) to keys of ``cameras`` (``left``). Poses come either as ``T_rig_cam``
    for every camera (rig.yaml) or as ``T_right_left`` (p_second = T · p_first) for the first two.
    ``pose_error`` is raised by load_rig only: a file may describe usable cameras without a pose.
    """

    path: Path
    format: str
    cameras: dict[str, CameraModel]
    aliases: dict[str, str] = field(default_factory=dict)
    T_rig_cam: dict[str, F64] | None = None
    T_right_left: F64 | None = None
    pairs: list[tuple[str, str]] | None = None
    pose_error: CalibrationFileError | None = None

    def camera(self, name: str | None = None) -> CameraModel:
        """The camera called ``name`` (or one of its aliases); the first camera when None."""
        if name is None:
            return next(iter(self.cameras.values()))
        key = name if name in self.cameras else self.aliases.get(name)
        if key is None or key not in self.cameras:
            known = list(self.cameras) + [a for a in self.aliases if a not in self.cameras]
            raise CalibrationFileError(
                self.path, f"no camera named {name!r}; the file holds: {', '.join(known)}"
            )
        return self.cameras[key]


def build_model(
    where: Field,
    model: str,
    width: int,
    height: int,
    fields: Mapping[str, Field] | None = None,
    /,
    **params: Any,
) -> CameraModel:
    """Create a model, turning a ModelError (unknown model, bad parameter) into a file error
    naming ``where``, the field that holds the camera's parameters, or the entry of ``fields``
    (model parameter name -> field) for the parameter the error names, when the file keeps it
    elsewhere."""
    cls = MODELS.get(model)
    if cls is None:
        raise where.error(f"camera model {model!r} is not available; known: {', '.join(sorted(MODELS))}")
    try:
        return cls(width, height, params.pop("fov_deg", None), **params)
    except ModelError as err:
        at = (fields or {}).get(err.param or "", where)
        raise at.error(str(err)) from err
    except (ValueError, ArithmeticError) as err:
        # A model should say ModelError; still, bad numbers from a file must not become a traceback.
        raise where.error(f"{model}: unusable parameters ({type(err).__name__}: {err})") from err
