"""The rectified pair in effect: what one stereo pair of the rig runs with, as one object.

:class:`PairInEffect` holds the configuration asked for, the designed pair with its lookup tables
(:class:`PairGeometry`: projection, size, field, tables, masks) and the stereo matcher with its
parameters. A :class:`rig.pipeline.DepthPipeline` owns one and is the only thing that replaces it
(:meth:`~rig.pipeline.DepthPipeline.apply`, for new stereo parameters or a corrected
calibration); everything else (the service's ``/config`` and memory budget, the rectification
monitor, ``rig process``'s ``run.json``, the ROS messages) reads it. A rig with several pairs has
one pipeline, so one :class:`PairInEffect`, per pair.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from calibration.models import LatLonModel
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.lut import Lut, percent_valid
from rig.lut_cache import CachedLut, LutCache
from rig.reach import nearest_range_m, reach_note
from rig.rectified import RectifiedCamera, RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.stereo import SeenColumns, StereoMatcher, StereoParams

__all__ = ["PairGeometry", "PairInEffect"]


@dataclass(frozen=True)
class PairGeometry:
    """What the calibration fixes for one pair: the rig, the designed rectified pair, one lookup
    table per camera (and where it came from), the masks the post-processing applies (None where
    a table sees its whole rectified view) and the columns each lens sees, which bound the
    matching (None: all of them)."""

    rig: Rig
    pair: RectifiedPair
    lut_info: dict[str, CachedLut]
    left_mask: NDArray[np.bool_] | None
    right_mask: NDArray[np.bool_] | None
    seen: SeenColumns | None = None

    @property
    def luts(self) -> dict[str, Lut]:
        return {n: info.lut for n, info in self.lut_info.items()}

    @classmethod
    def build(
        cls,
        rig: Rig,
        config: RectifiedPairConfig,
        cache: LutCache,
        blind_band_px: int = 0,
        camera: RectifiedCamera | None = None,
        luts: Mapping[str, CachedLut] | None = None,
    ) -> PairGeometry:
        """The pair of ``rig`` for ``config`` (a lat-lon field's default widened by the matcher's
        ``blind_band_px`` unmatched columns), tables from (or built into) ``cache``. ``camera``
        keeps a given rectified image grid (a corrected calibration moves the lenses' overlap,
        and with it a lat-lon field's size, which frames in flight and the finish stage share).
        ``luts``: the tables handed in instead (built once elsewhere for this calibration, e.g.
        shipped to a cluster's workers)."""
        pair = design_rectified_pair(rig, config, blind_band_px=blind_band_px)
        if camera is not None:
            pair = replace(pair, camera=camera)
        info = {
            n: _shipped(n, luts, pair)
            if luts is not None
            else cache.get(rig.cameras[n], pair.R_cam_rect[n], pair.camera)
            for n in (pair.left, pair.right)
        }
        left, right = info[pair.left].lut, info[pair.right].lut
        whole = left.valid_fraction == 1.0 and right.valid_fraction == 1.0
        return cls(
            rig,
            pair,
            info,
            None if left.valid_fraction == 1.0 else left.valid,
            None if right.valid_fraction == 1.0 else right.valid,
            None if whole else SeenColumns.of(left.valid, right.valid),
        )


def _shipped(name: str, luts: Mapping[str, CachedLut], pair: RectifiedPair) -> CachedLut:
    """Camera ``name``'s table as handed in, checked against the pair's image size."""
    info = luts.get(name)
    expected = (pair.camera.height, pair.camera.width)
    if info is None or info.lut.shape != expected:
        got = "none" if info is None else "x".join(map(str, info.lut.shape[::-1]))
        raise ConfigError(
            f"lookup table of camera {name!r}: {got} handed in for a {expected[1]}x{expected[0]} VPC"
        )
    return info


@dataclass(frozen=True)
class PairInEffect:
    """One pair's rectified pair and stereo settings in effect (see the module doc).

    ``config``: the rectified pair as configured (a lat-lon field may be left to the design);
    ``geometry``: the pair designed from it and the calibration, with its tables; ``matcher``: the
    stereo matcher of the parameters in effect; ``field_reserve_px``: the unmatched columns a
    default lat-lon field was widened by on the left (the matcher's blind band when the pipeline
    was built); ``revision``: 1 when built, one more at each change."""

    config: RectifiedPairConfig
    geometry: PairGeometry
    matcher: StereoMatcher
    field_reserve_px: int
    revision: int = 1

    @property
    def stereo(self) -> StereoParams:
        return self.matcher.params

    @property
    def pair(self) -> RectifiedPair:
        return self.geometry.pair

    @property
    def camera(self) -> RectifiedCamera:
        """The rectified projection both views share (its width and height are the images')."""
        return self.geometry.pair.camera

    @property
    def names(self) -> tuple[str, str]:
        return self.geometry.pair.left, self.geometry.pair.right

    @property
    def field_warnings(self) -> list[str]:
        """What the rectified view leaves out, one line each: for the pinhole pair the share of its
        pixels a lens does not see (an unusual view); the lat-lon field is the lenses' overlap by
        design, an explicit field wider than it is clipped (:attr:`RectifiedPair.field_note`)."""
        pair, c, v = self.pair, self.camera, self.config
        lines = [pair.field_note] if pair.field_note else []
        reach = reach_note(f"{pair.left}|{pair.right}", pair.projection, c.fx, pair.baseline_m, self.stereo)
        lines += [reach] if reach else []
        if isinstance(c, LatLonModel):
            return lines
        for name, info in self.geometry.lut_info.items():
            if info.lut.valid_fraction < 1.0:
                lines.append(
                    f"pinhole pair ({c.width}x{c.height}, hfov {v.hfov_deg:.1f}°, yaw {v.yaw_deg:.1f}°, "
                    f"pitch {v.pitch_deg:.1f}°) leaves camera '{name}''s field: only "
                    f"{percent_valid(info.lut.valid_fraction)} of its pixels are valid"
                )
        return lines

    def redesigned(self, rig: Rig) -> RectifiedPair:
        """The pair this configuration gives with ``rig`` (a corrected calibration of the same
        cameras), on the same rectified image grid (frames in flight share it)."""
        pair = design_rectified_pair(rig, self.config, blind_band_px=self.field_reserve_px)
        return replace(pair, camera=self.camera)

    def changed(
        self, *, geometry: PairGeometry | None = None, matcher: StereoMatcher | None = None
    ) -> PairInEffect:
        """The next revision, with a new geometry and/or matcher."""
        return replace(
            self,
            geometry=geometry or self.geometry,
            matcher=matcher or self.matcher,
            revision=self.revision + 1,
        )

    @property
    def nearest_range_m(self) -> float:
        """The nearest range straight ahead the matcher's search reaches (rig.reach)."""
        return nearest_range_m(self.pair.projection, self.camera.fx, self.pair.baseline_m, self.stereo)

    def as_json(self) -> dict[str, Any]:
        """What is in effect, as the service's ``/config`` and ``rig process``'s ``run.json`` show it:
        the projection and size really used (``pair``: ``vpc.json``'s fields), the configuration
        asked for and the stereo parameters."""
        return {
            "revision": self.revision,
            "pair": {**self.pair.as_json(), "left": self.pair.left, "right": self.pair.right},
            "config": self.config.model_dump(mode="json"),
            "stereo": self.stereo.model_dump(mode="json"),
            "nearest_range_m": self.nearest_range_m,
        }
