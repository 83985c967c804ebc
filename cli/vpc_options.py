"""VPC options shared by ``rig process`` and ``rig lut build``: size, FOV, look direction,
calibration loading and the LUT cache directory."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import ValidationError

from calibration import load_rig
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.settings_model import field_errors
from rig.vpc import VpcConfig

__all__ = [
    "CacheDirOption",
    "CalibrationOption",
    "PitchOption",
    "VpcHfovOption",
    "VpcSizeOption",
    "YawOption",
    "load_calibration",
    "make_vpc_config",
    "parse_size",
]

CalibrationOption = Annotated[
    Path | None,
    typer.Option(
        "--calibration",
        "-c",
        metavar="FILE",
        help="Rig calibration: rig.yaml or Kalibr camchain.yaml (cam0 = left, cam1 = right).",
    ),
]
VpcHfovOption = Annotated[
    float, typer.Option("--vpc-hfov", metavar="DEG", help="VPC horizontal field of view.")
]
VpcSizeOption = Annotated[str, typer.Option("--vpc-size", metavar="WxH", help="VPC image size.")]
YawOption = Annotated[
    float, typer.Option("--yaw", metavar="DEG", help="VPC look direction, right (+) / left (-).")
]
PitchOption = Annotated[
    float, typer.Option("--pitch", metavar="DEG", help="VPC look direction, up (+) / down (-).")
]
CacheDirOption = Annotated[
    Path | None,
    typer.Option(
        "--cache-dir",
        metavar="DIR",
        help="LUT cache directory.",
        show_default="$RIG_CACHE_DIR or the user cache",
    ),
]


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); ConfigError naming the option otherwise."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        w, h = int(parts[0]), int(parts[1])
    except ValueError:
        raise ConfigError(f"--vpc-size must look like 640x480, got {text!r}") from None
    return w, h


def make_vpc_config(size: str, hfov_deg: float, yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> VpcConfig:
    """A validated :class:`VpcConfig`; ConfigError naming the offending option."""
    w, h = parse_size(size)
    names = {"width": "--vpc-size", "height": "--vpc-size", "hfov_deg": "--vpc-hfov"}
    names |= {"yaw_deg": "--yaw", "pitch_deg": "--pitch"}
    values: dict[str, Any] = {"width": w, "height": h, "hfov_deg": hfov_deg}
    values |= {"yaw_deg": yaw_deg, "pitch_deg": pitch_deg}
    try:
        return VpcConfig(**values)
    except ValidationError as err:
        problems = [f"{names.get(f, f)}: {msg} (got {values.get(f)!r})" for f, msg in field_errors(err)]
        raise ConfigError("; ".join(problems)) from None


def load_calibration(path: Path | None, fallback: Path | None = None) -> tuple[Rig, Path]:
    """The rig from ``path`` (or ``fallback`` when no path was given)."""
    chosen = path or fallback
    if chosen is None:
        raise ConfigError("--calibration FILE is required (the recording carries no calibration.yaml)")
    rig = load_rig(chosen)
    for name in ("left", "right"):
        if name not in rig.cameras:
            raise ConfigError(f"{chosen}: rig has no camera '{name}' (cameras: {', '.join(rig.names)})")
    return rig, chosen
