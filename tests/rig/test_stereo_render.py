"""Subpixel refinement measured on the virtual environment: plain SGBM vs ours, and the
coarse-to-fine search's own parabola and ours after it.

Prototype lenses (scaled to 640×480), a textured plane at distances chosen so the true
disparity has fractional parts .1 … .75, VPC 320×240 / 90° (fx = 160), noise-free renders (the
pixel-locking claim is about noise-free fractional disparities). RMS over the central 50 % box.
Run with ``pytest -s`` to see the table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from tests.helpers.shots import central_box, plane_shot, prototype_rig

VPC = RectifiedPairConfig(width=320, height=240)
TRUE_DISPARITIES = (12.1, 16.25, 20.4, 24.5, 28.6, 33.75)  # fx·B/Z with fx = 160 px
#: Measured disparity RMS (px) at those disparities (docs/stereo.md's table).
PLAIN_RMS = (0.069, 0.156, 0.226, 0.236, 0.264, 0.213)
OURS_RMS = (0.028, 0.031, 0.037, 0.034, 0.044, 0.038)
C2F_PARABOLA_RMS = (0.066, 0.105, 0.115, 0.115, 0.126, 0.102)
C2F_OURS_RMS = (0.028, 0.031, 0.037, 0.027, 0.042, 0.038)


def test_subpixel_refinement_beats_plain_sgbm_at_every_fractional_distance(lut_cache: Path) -> None:
    pipe = DepthPipeline(prototype_rig(0.5), VPC, cache_dir=lut_cache)
    fx = pipe.pair.fx
    exact = {"disparity_range": 64, "coarse_to_fine": False}
    variants = {
        "plain SGBM": StereoParams(**exact, subpixel=False, median=0),
        "ours": StereoParams(**exact, subpixel=True, median=0),
        "ours+median5": StereoParams(**exact),
        # The coarse-to-fine search: its parabola through the block costs, then ours after it.
        "c2f parabola": StereoParams(disparity_range=64, subpixel=False, median=0, coarse_to_fine=True),
        "c2f + ours": StereoParams(disparity_range=64, median=0, coarse_to_fine=True),
    }
    rows = []
    for d in TRUE_DISPARITIES:
        k = fx / d  # distance in baselines
        shot = plane_shot(k, scale=0.5, vpc=VPC)
        box = central_box(shot.depth.shape)
        truth = shot.disparity[box]
        assert np.allclose(truth, d, rtol=1e-4), "the plane is fronto-parallel: one disparity"
        rms = {}
        for name, params in variants.items():
            pipe.apply(stereo=params)
            frame = pipe.process(shot.left, shot.right)
            err = frame.disparity[box] - truth
            assert np.isfinite(err).mean() > 0.98
            rms[name] = float(np.sqrt(np.nanmean(err**2)))
        rows.append((d, k, rms))
    print("\nDisparity RMS (px), prototype plane, VPC 320x240 fx=160, noise-free, central 50% box")
    print(f"{'true d':>8} {'Z/B':>6} " + " ".join(f"{n:>13}" for n in variants))
    for d, k, rms in rows:
        print(f"{d:8.2f} {k:6.2f} " + " ".join(f"{rms[n]:13.3f}" for n in variants))
    plain = np.array([r[2]["plain SGBM"] for r in rows])
    ours = np.array([r[2]["ours"] for r in rows])
    assert (ours < plain).all(), "ours must beat plain SGBM at every distance"
    assert ours.max() < 0.06
    assert plain.mean() > 0.12, "plain SGBM's pixel locking should show here"
    assert ours.mean() < plain.mean() / 3
    assert tuple(plain) == pytest.approx(PLAIN_RMS, rel=0.15, abs=0.002)
    assert tuple(ours) == pytest.approx(OURS_RMS, rel=0.15, abs=0.002)
    # The coarse-to-fine search's own parabola locks less than SGBM's, and the same refinement
    # after it is as accurate as after SGBM.
    parabola = np.array([r[2]["c2f parabola"] for r in rows])
    after = np.array([r[2]["c2f + ours"] for r in rows])
    assert parabola.mean() < plain.mean() and parabola.max() < 0.15
    assert after.max() < 0.06 and after.mean() < ours.mean() * 1.2
    assert tuple(parabola) == pytest.approx(C2F_PARABOLA_RMS, rel=0.15, abs=0.002)
    assert tuple(after) == pytest.approx(C2F_OURS_RMS, rel=0.15, abs=0.002)
