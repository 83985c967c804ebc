"""How near a pair ranges (rig.reach): the nearest range of a search against the renderer's
geometry, ``min_range_m`` widening the search to reach it, and a pair that cannot saying so."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rig.pipeline import DepthPipeline
from rig.reach import axis_disparity_px, nearest_range_m, reaching
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from tests.helpers.shots import prototype_rig


def test_the_axis_disparity_is_the_angle_between_the_rays() -> None:
    # Two rays to a point r ahead of the midpoint... of the left centre: the left ray straight
    # ahead, the right one turned by atan(B / r); a pinhole sees B·f/r.
    assert axis_disparity_px("latlon", 320.0, 0.072, 0.24) == pytest.approx(320.0 * math.atan(0.3))
    assert axis_disparity_px("pinhole", 320.0, 0.3, 1.0) == pytest.approx(96.0)
    # 96 disparities (95 px the largest): 0.24 m on the prototype's 72 mm, about 1 m on 0.3 m.
    p = StereoParams()
    assert nearest_range_m("latlon", 320.0, 0.072, p) == pytest.approx(0.072 / math.tan(95 / 320), rel=1e-9)
    assert 0.23 < nearest_range_m("latlon", 320.0, 0.072, p) < 0.25
    assert 0.95 < nearest_range_m("latlon", 320.0, 0.3, p) < 1.05


def test_min_range_widens_the_search_to_reach_it_and_never_narrows_it() -> None:
    p = StereoParams(min_range_m=0.5)
    wide = reaching(p, "latlon", 320.0, 0.3, None)
    assert wide.disparity_range % 16 == 0 and nearest_range_m("latlon", 320.0, 0.3, wide) <= 0.5
    assert (
        nearest_range_m(
            "latlon", 320.0, 0.3, wide.model_copy(update={"disparity_range": wide.disparity_range - 16})
        )
        > 0.5
    )
    # Already near enough: unchanged.
    assert reaching(StereoParams(min_range_m=5.0), "latlon", 320.0, 0.3, None).disparity_range == 96
    assert reaching(StereoParams(), "latlon", 320.0, 0.3, None) == StereoParams()
    # A pinhole pair's search stays within its width (and then says how near it reaches).
    capped = reaching(StereoParams(min_range_m=0.05, coarse_to_fine=False), "pinhole", 320.0, 0.3, 320)
    assert capped.disparity_range == 304
    # The coarse-to-fine search's unmatched band is its coarse level's (304 disparities at 1/4:
    # 80 coarse px, 320 columns): the widest whose band fits.
    c2f = reaching(StereoParams(min_range_m=0.05, coarse_to_fine=True), "pinhole", 320.0, 0.3, 320)
    assert c2f.disparity_range == 256 and c2f.blind_band_px == 256
    assert c2f.model_copy(update={"disparity_range": 272}).blind_band_px + 16 > 320


def test_a_pair_says_when_it_cannot_reach_the_range_asked_for(tmp_path: Path) -> None:
    rig = prototype_rig(0.5)  # 72 mm baseline, half resolution
    config = RectifiedPairConfig(width=160, height=120)  # fx 80 px: 96 disparities reach 6 cm
    pipe = DepthPipeline(rig, config, StereoParams(min_range_m=0.01), cache_dir=tmp_path, tune_malloc=False)
    in_effect = pipe.in_effect
    assert in_effect.stereo.blind_band_px + 16 <= 160 and in_effect.stereo.disparity_range == 144
    # The coarse-to-fine search's unmatched band rounds up: its widest that fits is narrower.
    c2f = DepthPipeline(
        rig,
        config,
        StereoParams(min_range_m=0.01, coarse_to_fine=True),
        cache_dir=tmp_path,
        tune_malloc=False,
    ).in_effect.stereo
    assert c2f.blind_band_px + 16 <= 160 and c2f.disparity_range == 128
    notes = [line for line in in_effect.field_warnings if "ranges no nearer than" in line]
    assert len(notes) == 1 and "not the 0.01 m of stereo.min_range_m" in notes[0]
    assert in_effect.as_json()["nearest_range_m"] == pytest.approx(in_effect.nearest_range_m)
    latlon = DepthPipeline(
        rig,
        RectifiedPairConfig(px_per_deg=2.8),
        StereoParams(min_range_m=0.1),
        cache_dir=tmp_path,
        tune_malloc=False,
    )
    assert latlon.in_effect.nearest_range_m <= 0.1 and not [
        line for line in latlon.in_effect.field_warnings if "ranges no nearer" in line
    ]
    # The field leaves room for the widened search's unmatched columns.
    assert latlon.in_effect.field_reserve_px == latlon.in_effect.stereo.blind_band_px
    assert np.isfinite(latlon.in_effect.nearest_range_m)
