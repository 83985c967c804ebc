"""The vergence from the floor on renders (:func:`rig.floor_refine.refine_floor`): the
half-size prototype recorded in the demo room (floor 1.2 m below the rig, two frames, through
its honest lens: ``rig sim``'s default) with the right camera turned about the rig's y, the
nominal calibration refined from them through today's pair (the lat-lon pair, whose view reaches
the floor). Run with -s for the figures quoted in docs/rectification.md."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from rig.errors import ConfigError, RectificationError
from rig.floor_refine import FloorRefinement, recording_frames, refine_floor
from rig.recording import Recording
from tests.rig.rectification_renders import nominal_rig, perturbed, render_room

pytestmark = pytest.mark.slow  # ≈20 s: five renders of the room and their refinements

U8 = NDArray[np.uint8]
HEIGHT_M = 1.2  # the room's floor below the rig's origin (rig.sim.scene)


@functools.lru_cache(maxsize=4)
def turned_frames(root: Path, vergence_deg: float) -> list[tuple[U8, U8]]:
    """The room recorded by the prototype whose right camera is turned ``vergence_deg`` about the
    rig's y (the pair's rectified y)."""
    truth = perturbed(nominal_rig(), (0.0, vergence_deg, 0.0))
    return recording_frames(
        Recording(render_room(root / f"turn{vergence_deg:+.2f}", frames=2, truth=truth)), 2
    )


@pytest.fixture(scope="module")
def renders(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("floor-renders")


def describe(label: str, r: FloorRefinement) -> None:
    print(f"\n{label}:\n  " + "\n  ".join(r.summary()))


@pytest.mark.parametrize("vergence_deg", [0.3, -0.3])
def test_a_turned_right_camera_is_found_and_the_floor_put_right(renders: Path, vergence_deg: float) -> None:
    r = refine_floor(nominal_rig(), turned_frames(renders, vergence_deg), HEIGHT_M)
    describe(f"honest lens, right camera turned {vergence_deg:+.1f} deg about y", r)
    # Measured: +0.308 / -0.281 (0.01° of bias towards +, as the correct rig shows below).
    assert r.correction_deg == pytest.approx([vergence_deg, 0.0], abs=0.025)
    assert r.applied and r.reason is None
    assert r.rig is r.rig_after
    fb, fa = r.floor_before, r.floor_after
    # Before: the floor's range 8-10 % off, its disparity ≈1 px off, and it looks tilted by ≈5°
    # (to the floor, vergence and a pitch of the rig look alike).
    assert fb.range_error > 0.07 and fb.residual_px > 0.9 and abs(fb.plane.tilt_deg[0]) > 4.5
    assert fa.range_error < 0.012 and abs(fa.range_bias) < 0.002 and fa.residual_px < 0.13
    assert np.abs(fa.plane.tilt_deg).max() < 0.1 and fa.height_m == pytest.approx(HEIGHT_M, abs=0.002)
    assert fa.flatness_px <= fb.flatness_px
    vb, va = r.vertical_before.p50_px, r.vertical_after.p50_px
    assert vb is not None and va is not None and va < vb


def test_a_correct_rig_is_left_nearly_alone(renders: Path) -> None:
    r = refine_floor(nominal_rig(), turned_frames(renders, 0.0), HEIGHT_M)
    describe("honest lens, correct rig", r)
    # Measured: 0.011° about y, 0.009° about z: the render's bias, ≈0.06 disparity px.
    assert r.angle_deg < 0.02
    assert abs(r.floor_after.range_error - r.floor_before.range_error) < 0.001
    assert r.floor_before.range_error < 0.012


def test_a_wrong_height_is_turned_about_the_look_direction_and_refused(renders: Path) -> None:
    """A height 5 cm too large is fitted as a turn about z (the limit of the method), which
    rows apart show: the vertical disparity gate refuses it."""
    r = refine_floor(nominal_rig(), turned_frames(renders, 0.0), HEIGHT_M + 0.05)
    describe("honest lens, correct rig, height told 1.25 m", r)
    assert r.correction_deg[1] < -0.08
    assert not r.applied and r.reason is not None and "vertical disparity" in r.reason
    assert r.rig is r.rig_before


def test_no_floor_and_bad_heights_are_errors(renders: Path) -> None:
    frames = turned_frames(renders, 0.0)
    with pytest.raises(
        RectificationError, match=r"no floor in view: \d+ pixels below the horizon near a floor 0.300 m"
    ):
        refine_floor(nominal_rig(), frames, 0.3)
    with pytest.raises(RectificationError, match=r"no floor in view: .* a floor 5\.000 m down"):
        refine_floor(nominal_rig(), frames, 5.0)
    for bad in (0.0, -1.2, float("nan")):
        with pytest.raises(ConfigError, match=r"floor height must be a number of metres in \[0.01, 100\]"):
            refine_floor(nominal_rig(), frames, bad)
