"""Rectified-pair options shared by ``rig process``, ``rig lut build`` and ``rig sim``: the
projection, the pinhole's size and field of view, the lat-lon resolution and field, the look
direction; calibration loading and the LUT cache directory. Options not given are left to
:class:`rig.rectified.RectifiedPairConfig`'s defaults (see docs/wide-pair.md)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from rig.errors import ConfigError

if TYPE_CHECKING:  # the libraries load when an option is used, not for --help
    from calibration.rig import Rig
    from rig.rectified import RectifiedPairConfig

__all__ = [
    "CacheDirOption",
    "CalibrationOption",
    "FieldOption",
    "PinholeHfovOption",
    "PinholeSizeOption",
    "PitchOption",
    "ProjectionOption",
    "PxPerDegOption",
    "YawOption",
    "load_calibration",
    "make_pair_config",
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
ProjectionOption = Annotated[
    str | None,
    typer.Option(
        "--projection",
        metavar="NAME",
        help="Rectified projection: pinhole or latlon.",
        show_default="latlon; pinhole with --vpc-size or --vpc-hfov",
    ),
]
PinholeHfovOption = Annotated[
    float | None,
    typer.Option("--vpc-hfov", metavar="DEG", help="Pinhole: horizontal field of view.", show_default="90"),
]
PinholeSizeOption = Annotated[
    str | None, typer.Option("--vpc-size", metavar="WxH", help="Pinhole: image size.", show_default="640x480")
]
PxPerDegOption = Annotated[
    float | None,
    typer.Option(
        "--px-per-deg", metavar="PPD", help="Lat-lon: pixels per degree.", show_default="5.585 (320 px/rad)"
    ),
]
FieldOption = Annotated[
    str | None,
    typer.Option(
        "--field",
        metavar="AZxEL",
        help="Lat-lon: azimuth x elevation span in degrees, centred on --yaw/--pitch.",
        show_default="the lenses' overlap and the matcher's unmatched columns",
    ),
]
YawOption = Annotated[
    float | None,
    typer.Option("--yaw", metavar="DEG", help="Look direction, right (+) / left (-).", show_default="0"),
]
PitchOption = Annotated[
    float | None,
    typer.Option("--pitch", metavar="DEG", help="Look direction, up (+) / down (-).", show_default="0"),
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


def _two_numbers(text: str, kind: type[int] | type[float], option: str, example: str) -> tuple[Any, Any]:
    """``"AxB"`` (or ``A×B``) as two numbers of ``kind``; ConfigError naming ``option`` otherwise."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        return kind(parts[0]), kind(parts[1])
    except ValueError:
        raise ConfigError(f"{option} must look like {example}, got {text!r}") from None


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); ConfigError naming --vpc-size otherwise."""
    w, h = _two_numbers(text, int, "--vpc-size", "640x480")
    return int(w), int(h)


def _parse_field(text: str) -> tuple[float, float]:
    """``"100x180"`` -> (100.0, 180.0) degrees; ConfigError naming --field otherwise."""
    az, el = _two_numbers(text, float, "--field", "100x180 (azimuth x elevation, degrees)")
    return float(az), float(el)


_OPTION_OF = {
    "projection": "--projection",
    "width": "--vpc-size",
    "height": "--vpc-size",
    "hfov_deg": "--vpc-hfov",
    "yaw_deg": "--yaw",
    "pitch_deg": "--pitch",
    "px_per_deg": "--px-per-deg",
    "az_span_deg": "--field",
    "el_span_deg": "--field",
}


def make_pair_config(
    size: str | None = None,
    hfov_deg: float | None = None,
    yaw_deg: float | None = None,
    pitch_deg: float | None = None,
    *,
    projection: str | None = None,
    px_per_deg: float | None = None,
    field: str | None = None,
) -> RectifiedPairConfig:
    """A validated :class:`RectifiedPairConfig` of the options given (None: not given); its rules
    (which options go with which projection) are the model's, said here in the options' names:
    ConfigError naming the offending option."""
    from pydantic import ValidationError

    from rig.rectified import PROJECTIONS, RectifiedPairConfig

    values: dict[str, Any] = {}
    if projection is not None:
        if projection not in PROJECTIONS:
            raise ConfigError(f"--projection must be one of {', '.join(PROJECTIONS)}, got {projection!r}")
        values["projection"] = projection
    if size is not None:
        values["width"], values["height"] = parse_size(size)
    if field is not None:
        values["az_span_deg"], values["el_span_deg"] = _parse_field(field)
    given = {"hfov_deg": hfov_deg, "yaw_deg": yaw_deg, "pitch_deg": pitch_deg, "px_per_deg": px_per_deg}
    values |= {k: v for k, v in given.items() if v is not None}
    try:
        return RectifiedPairConfig(**values)
    except ValidationError as err:
        raise ConfigError("; ".join(_in_options(e, values) for e in err.errors(include_url=False))) from None


def _options(fields: str, joiner: str = " and ") -> str:
    """``"width, hfov_deg"`` -> ``"--vpc-size and --vpc-hfov"``."""
    names = dict.fromkeys(
        _OPTION_OF.get(f.strip(), f.strip()) for f in fields.replace(" and ", ",").split(",")
    )
    return joiner.join(names)


def _in_options(error: Any, values: dict[str, Any]) -> str:
    """One of the model's errors in the options' names."""
    kind, ctx = error["type"], error.get("ctx") or {}
    if kind == "other_projection":
        other = "pinhole" if ctx["projection"] == "latlon" else "latlon"
        return f"{_options(ctx['fields'])} apply to --projection {other}, not {ctx['projection']}"
    if kind == "look_without_field":
        return (
            f"{_options(ctx['fields'])} centre an explicit lat-lon --field; without one the field is the "
            "whole overlap of the two lenses"
        )
    field = str(error["loc"][0]) if error["loc"] else ""
    got = f" (got {values[field]!r})" if field in values else ""
    return f"{_OPTION_OF.get(field, field or 'rectified')}: {error['msg'].removeprefix('Value error, ')}{got}"


def load_calibration(
    path: Path | None, fallback: Path | None = None, *, rings: bool = False
) -> tuple[Rig, Path]:
    """The rig from ``path`` (or ``fallback`` when no path was given): a two-camera rig with
    cameras ``left`` and ``right``, or with ``rings`` (a command that works on every pair of a rig)
    also a rig of more than two cameras."""
    chosen = path or fallback
    if chosen is None:
        raise ConfigError("--calibration FILE is required (the recording carries no calibration.yaml)")
    from calibration import load_rig

    rig = load_rig(chosen)
    if len(rig.names) > 2:
        if rings:
            return rig, chosen
        raise ConfigError(
            f"{chosen}: field 'cameras': a rig of {len(rig.names)} cameras ({', '.join(rig.names)}); this "
            "command works on a two-camera rig (left and right)"
        )
    for name in ("left", "right"):
        if name not in rig.cameras:
            raise ConfigError(f"{chosen}: rig has no camera '{name}' (cameras: {', '.join(rig.names)})")
    return rig, chosen
