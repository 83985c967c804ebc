"""The rectified pair cut out of the overlap of two fisheye cameras (the "VPC" pair,
docs/design.md, "The VPC pair"; docs/wide-pair.md).

The pair is derived from the calibrated extrinsics, not from the mount's nominal angles: x of the
rectified frame is the baseline direction, so rows align exactly even on a mount that is 87°
instead of 90° or pitched; z is the mean optical axis made orthogonal to x, y = z × x.

Two projections (``RectifiedPairConfig.projection``), both with rows that are epipolar planes:

* ``pinhole`` (the paper's virtual pinhole cameras): ``u = cx + fx·x/z``, ``v = cy + fy·y/z``.
  Its image planes must contain the baseline, so a *yaw* of the look direction cannot rotate the
  pair; it is realised as a horizontal principal-point shift (an off-axis view whose centre pixel
  looks ``yaw_deg`` to the side). *Pitch* rotates the pair about the baseline.
* ``latlon`` (mrcal's LENSMODEL_LATLON, :class:`calibration.models.LatLonModel`):
  ``u = cx + fx·asin(x/|p|)``, ``v = cy + fy·atan2(y, z)``: even angular resolution
  (``px_per_deg``) over a field of any width, by default the whole overlap of the two lenses
  (:mod:`rig.field`) plus the matcher's blind band on the left.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from calibration.geometry import make_transform, rot_x
from calibration.models import LatLonModel, PinholeModel
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.field import overlap
from rig.settings_model import SettingsModel

__all__ = [
    "DEFAULT_PROJECTION",
    "DEFAULT_PX_PER_DEG",
    "PINHOLE_DEFAULTS",
    "PROJECTIONS",
    "Projection",
    "RectifiedCamera",
    "RectifiedPair",
    "RectifiedPairConfig",
    "design_rectified_pair",
]

F64 = NDArray[np.float64]

Projection = Literal["pinhole", "latlon"]
PROJECTIONS: tuple[Projection, ...] = ("pinhole", "latlon")
#: The projection of a configuration that names none and sets none of the pinhole's own fields.
DEFAULT_PROJECTION: Projection = "latlon"
#: The rectified projections' models: the same ``project``/``unproject`` surface.
RectifiedCamera = PinholeModel | LatLonModel

#: Lat-lon resolution when ``px_per_deg`` is not set: the default pinhole's at its centre
#: (640 px over 90°: fx = 320 px/rad).
DEFAULT_PX_PER_DEG = 320.0 * math.pi / 180.0
#: The pinhole's size and field of view when a pinhole configuration leaves them out.
PINHOLE_DEFAULTS: dict[str, int | float] = {"width": 640, "height": 480, "hfov_deg": 90.0}
_PINHOLE_ONLY = tuple(PINHOLE_DEFAULTS)
_LATLON_ONLY = ("px_per_deg", "az_span_deg", "el_span_deg")


class RectifiedPairConfig(SettingsModel):
    """Projection, size, field of view and look direction of the rectified pair (degrees in
    config, docs/design.md). ``width``, ``height`` and ``hfov_deg`` are the pinhole's (defaults
    :data:`PINHOLE_DEFAULTS`, None for the lat-lon pair, whose size follows from its resolution
    and field); ``px_per_deg`` and the spans the lat-lon's. Setting one for the other projection
    is an error. Without a ``projection``, one of the pinhole's fields selects the pinhole (so a
    configuration written before the lat-lon pair keeps its meaning), else
    :data:`DEFAULT_PROJECTION`. The config file's section is ``rectified:`` (``vpc:``, its first
    name, is read too)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    projection: Projection = Field(DEFAULT_PROJECTION, description="rectified projection: pinhole or latlon")
    width: int | None = Field(None, ge=16, le=8192, description="pinhole: image width (px), default 640")
    height: int | None = Field(None, ge=16, le=8192, description="pinhole: image height (px), default 480")
    hfov_deg: float | None = Field(
        None, gt=1.0, lt=179.0, description="pinhole: horizontal field of view, default 90"
    )
    yaw_deg: float = Field(0.0, ge=-80.0, le=80.0, description="look right (+) or left (-)")
    pitch_deg: float = Field(0.0, ge=-80.0, le=80.0, description="look up (+) or down (-)")
    px_per_deg: float | None = Field(
        None,
        ge=0.5,
        le=60.0,
        description="lat-lon: pixels per degree, both axes (default DEFAULT_PX_PER_DEG)",
    )
    az_span_deg: float | None = Field(
        None, gt=1.0, lt=178.0, description="lat-lon: azimuth span about yaw_deg (default: the overlap)"
    )
    el_span_deg: float | None = Field(
        None,
        gt=1.0,
        le=360.0,
        description="lat-lon: elevation span about pitch_deg (default: the overlap)",
    )
    left: str = Field("left", description="rig camera that forms the left image")
    right: str = Field("right", description="rig camera that forms the right image")

    @model_validator(mode="before")
    @classmethod
    def _pinhole_settings_mean_the_pinhole(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        given = {k: v for k, v in data.items() if v is not None}
        if "projection" not in given and any(k in given for k in _PINHOLE_ONLY):
            given["projection"] = "pinhole"
        if given.get("projection") == "pinhole":
            given = {**PINHOLE_DEFAULTS, **given}
        return given

    @model_validator(mode="after")
    def _one_projection(self) -> RectifiedPairConfig:
        # Structured errors (their context names the fields) so that the command line can say
        # them in its options' names without coding these rules again.
        other = _PINHOLE_ONLY if self.projection == "latlon" else _LATLON_ONLY
        wrong = [name for name in other if getattr(self, name) is not None]
        if wrong:
            raise PydanticCustomError(
                "other_projection",
                "{fields} {verb} not apply to the {projection} projection",
                {
                    "fields": ", ".join(wrong),
                    "verb": "does" if len(wrong) == 1 else "do",
                    "projection": self.projection,
                },
            )
        spans = self.az_span_deg is not None or self.el_span_deg is not None
        look = [name for name in ("yaw_deg", "pitch_deg") if getattr(self, name)]
        if self.projection == "latlon" and not spans and look:
            raise PydanticCustomError(
                "look_without_field",
                "{fields} centre an explicit lat-lon field (az_span_deg, el_span_deg); "
                "the default field is the whole overlap",
                {"fields": " and ".join(look)},
            )
        return self

    @property
    def pinhole_size(self) -> tuple[int, int, float]:
        """The pinhole's (width, height, hfov_deg); ConfigError for a lat-lon configuration."""
        if self.width is None or self.height is None or self.hfov_deg is None:
            raise ConfigError(f"rectified: a {self.projection} pair has no pinhole size")
        return self.width, self.height, self.hfov_deg

    @property
    def resolution_px_per_deg(self) -> float:
        """The lat-lon resolution (``px_per_deg`` or the default)."""
        return DEFAULT_PX_PER_DEG if self.px_per_deg is None else self.px_per_deg


@dataclass(frozen=True)
class RectifiedPair:
    """A rectified pair: one projection model shared by both views, and their poses in the rig.

    ``camera`` is a :class:`PinholeModel` or a :class:`LatLonModel` (``projection`` says which).
    ``T_rig_rect[name]`` (4, 4) places each view at its fisheye camera's optical centre, both with
    the orientation ``R_rig_rect`` (the rectified frame); ``R_cam_rect[name]`` (3, 3) rotates
    rectified rays into that fisheye camera's frame, the ``R`` of
    ``p_fisheye = π_f(R · π_rect⁻¹(p_rect))``. ``field_note``: what the design changed in the
    requested field (a lat-lon field clipped to the overlap), or None.
    """

    camera: RectifiedCamera
    T_rig_rect: dict[str, F64]
    R_cam_rect: dict[str, F64]
    baseline_m: float
    left: str
    right: str
    field_note: str | None = None

    @property
    def fx(self) -> float:
        return self.camera.fx

    @property
    def projection(self) -> Projection:
        return "latlon" if isinstance(self.camera, LatLonModel) else "pinhole"

    @property
    def R_rig_rect(self) -> F64:
        """The rectified frame's axes in the rig frame (3, 3), columns x, y, z."""
        return self.T_rig_rect[self.left][:3, :3]

    def describe(self) -> str:
        """The pair as the commands name it: ``lat-lon 661x1064, 5.585 px/deg`` or ``pinhole
        640x480, hfov 90.0°`` (its projection and real size, whatever was configured)."""
        c = self.camera
        if isinstance(c, LatLonModel):
            return f"lat-lon {c.width}x{c.height}, {math.radians(c.fx):.3f} px/deg"
        return (
            f"pinhole {c.width}x{c.height}, hfov {math.degrees(2.0 * math.atan(c.width / 2.0 / c.fx)):.1f}°"
        )

    def as_json(self) -> dict[str, object]:
        """``vpc.json`` of ``rig process`` (docs/design.md): the projection, its intrinsics, the
        baseline and the left rectified frame in the rig frame."""
        c = self.camera
        return {
            "projection": self.projection,
            "width": c.width,
            "height": c.height,
            "fx": c.fx,
            "fy": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "baseline_m": self.baseline_m,
            "R_rig_vpc": self.R_rig_rect.tolist(),
        }


def pinhole_intrinsics(config: RectifiedPairConfig) -> PinholeModel:
    """Square-pixel pinhole for the config; yaw shifts the principal point (see module doc)."""
    width, height, hfov_deg = config.pinhole_size
    f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    cx = (width - 1) / 2.0 - f * math.tan(math.radians(config.yaw_deg))
    cy = (height - 1) / 2.0
    return PinholeModel(width, height, fx=f, fy=f, cx=cx, cy=cy)


def rectified_frame(rig: Rig, left: str, right: str) -> tuple[F64, float]:
    """The rectified frame's axes in the rig frame (3, 3), unpitched, and the baseline (m).

    x = baseline direction (left centre to right centre); z = mean of the two optical axes made
    orthogonal to x; y = z × x.
    """
    for name in (left, right):
        if name not in rig.cameras:
            raise ConfigError(f"vpc: rig has no camera '{name}' (cameras: {', '.join(rig.names)})")
    c_l, c_r = rig.center(left), rig.center(right)
    baseline = float(np.linalg.norm(c_r - c_l))
    if baseline <= 0.0:
        raise ConfigError("vpc: the two cameras share an optical centre; no stereo baseline")
    x = (c_r - c_l) / baseline
    look = rig.axis(left) + rig.axis(right)
    z = look - np.dot(look, x) * x
    if np.linalg.norm(z) < 1e-9:
        raise ConfigError("vpc: the mean optical axis is parallel to the baseline; no common view")
    z /= np.linalg.norm(z)
    return np.column_stack([x, np.cross(z, x), z]), baseline


def latlon_intrinsics(
    rig: Rig, R_rig_rect: F64, config: RectifiedPairConfig, blind_band_px: int = 0
) -> tuple[LatLonModel, str | None]:
    """The lat-lon view of ``config`` in the rectified frame ``R_rig_rect``, and a note when the
    requested field had to be clipped to the overlap.

    Default field: the overlap's bounds (:func:`rig.field.overlap`) widened on the left by
    ``blind_band_px`` columns, the ones the matcher leaves unmatched (its ``min_disparity +
    disparity_range``), so that every column of the overlap is matched. Explicit spans are centred
    on ``yaw_deg`` (azimuth) and ``pitch_deg`` (up: negative elevation, y points down) and clipped
    to the same bounds. The image's left edge is at the field's lowest azimuth, its top edge at
    the lowest elevation.
    """
    f = math.degrees(config.resolution_px_per_deg)  # px per radian
    view = overlap(rig, R_rig_rect, config.left, config.right)
    az_lo, az_hi, el_lo, el_hi = view.bounds()
    az_lo -= blind_band_px / f
    bounds = (az_lo, az_hi, el_lo, el_hi)
    note = None
    if config.az_span_deg is not None or config.el_span_deg is not None:
        bounds, note = _clip_field(config, bounds, view.fraction_inside)
    az_lo, az_hi, el_lo, el_hi = bounds
    width, height = math.ceil((az_hi - az_lo) * f), math.ceil((el_hi - el_lo) * f)
    if width <= blind_band_px:
        raise ConfigError(
            f"vpc: the lat-lon field is {width} px wide at {config.resolution_px_per_deg:g} px/deg, "
            f"not wider than the matcher's {blind_band_px} unmatched columns"
        )
    # Pixel centres at half a pixel inside the field's edges.
    model = LatLonModel(width, height, fx=f, fy=f, cx=-0.5 - az_lo * f, cy=-0.5 - el_lo * f)
    return model, note


def _clip_field(
    config: RectifiedPairConfig,
    bounds: tuple[float, float, float, float],
    fraction_inside: Callable[[float, float, float, float], float],
) -> tuple[tuple[float, float, float, float], str | None]:
    """The explicit spans of ``config`` clipped to ``bounds`` (radians), and the note saying so."""
    lo_az, hi_az, lo_el, hi_el = bounds
    az_c, el_c = math.radians(config.yaw_deg), -math.radians(config.pitch_deg)
    az_half = math.radians(config.az_span_deg) / 2.0 if config.az_span_deg else None
    el_half = math.radians(config.el_span_deg) / 2.0 if config.el_span_deg else None
    want = (
        az_c - az_half if az_half else lo_az,
        az_c + az_half if az_half else hi_az,
        el_c - el_half if el_half else lo_el,
        el_c + el_half if el_half else hi_el,
    )
    got = (max(want[0], lo_az), min(want[1], hi_az), max(want[2], lo_el), min(want[3], hi_el))
    if got[0] >= got[1] or got[2] >= got[3]:
        raise ConfigError(
            f"vpc: the lat-lon field {_describe(want)} lies outside the lenses' overlap {_describe(bounds)}"
        )
    if got == want:
        return want, None
    frac = fraction_inside(*want)
    note = (
        f"vpc: the lat-lon field {_describe(want)} is wider than the two lenses' overlap: clipped to "
        f"{_describe(got)} ({100.0 * frac:.0f}% of the requested field is in the overlap)"
    )
    return got, note


def _describe(b: tuple[float, float, float, float]) -> str:
    az0, az1, el0, el1 = (math.degrees(v) for v in b)
    return f"azimuth {az0:.1f}°..{az1:.1f}° × elevation {el0:.1f}°..{el1:.1f}°"


def design_rectified_pair(
    rig: Rig, config: RectifiedPairConfig | None = None, *, blind_band_px: int = 0
) -> RectifiedPair:
    """Rectified pair for ``rig`` (docs/design.md, "The VPC pair"): the frame of
    :func:`rectified_frame`, pitched about x for the pinhole; the lat-lon field of
    :func:`latlon_intrinsics` (``blind_band_px``: the matcher's unmatched columns, added to the
    default field)."""
    config = config or RectifiedPairConfig()
    R_rect, baseline = rectified_frame(rig, config.left, config.right)
    note = None
    camera: RectifiedCamera
    if config.projection == "latlon":
        R_rig_rect = R_rect
        camera, note = latlon_intrinsics(rig, R_rig_rect, config, blind_band_px)
    else:
        # Pitch up (+) turns z towards -y (y points down): rot_x(+pitch) maps z to (0, -sin, cos).
        R_rig_rect = R_rect @ rot_x(math.radians(config.pitch_deg))
        camera = pinhole_intrinsics(config)
    names = (config.left, config.right)
    T_rig_rect = {n: make_transform(R_rig_rect, rig.center(n)) for n in names}
    R_cam_rect = {n: rig.T_rig_cam[n][:3, :3].T @ R_rig_rect for n in names}
    return RectifiedPair(camera, T_rig_rect, R_cam_rect, baseline, config.left, config.right, note)
