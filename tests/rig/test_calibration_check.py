"""The calibration checked against frames: renders of the demo room through the prototype rig
(half size, VPC 320×240) with the right calibration, the cameras swapped either way, a mount
whose right camera is pitched, and frames of another size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.rig import Rig
from rig.calibration_check import check_calibration, check_frame_sizes, matched_disparities
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from tests.helpers.shots import StereoShot, prototype_rig, room_shot

VPC = RectifiedPairConfig(width=320, height=240)
STEREO = StereoParams(disparity_range=64)


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("lut")


def pipeline(rig: Rig, cache: Path) -> DepthPipeline:
    return DepthPipeline(rig, VPC, STEREO, cache_dir=cache)


@pytest.fixture(scope="module")
def room() -> StereoShot:
    return room_shot(0, scale=0.5, vpc=VPC)


def swapped(rig: Rig) -> Rig:
    """The calibration with its two cameras' blocks exchanged (left ↔ right)."""
    return Rig(
        {"left": rig.cameras["right"], "right": rig.cameras["left"]},
        {"left": rig.T_rig_cam["right"], "right": rig.T_rig_cam["left"]},
    )


def test_the_right_calibration_passes_with_its_figures(room: StereoShot, cache: Path) -> None:
    result = check_calibration(pipeline(room.rig, cache), room.left, room.right)
    assert result.findings == []
    assert result.matches is not None and result.matches > 150
    assert result.vertical_px is not None and result.vertical_px < 0.3
    assert result.negative_share is not None and result.negative_share < 0.05
    assert result.valid_fraction is not None and result.valid_fraction > 0.6


def test_swapped_cameras_are_named_either_way(room: StereoShot, cache: Path) -> None:
    # Before: processed with exit 0 and a few per cent of valid pixels.
    frames_swapped = check_calibration(pipeline(room.rig, cache), room.right, room.left)
    calibration_swapped = check_calibration(pipeline(swapped(room.rig), cache), room.left, room.right)
    for result in (frames_swapped, calibration_swapped):
        assert [f.severity for f in result.findings] == ["error"], result.findings
        message = result.findings[0].message
        assert message.startswith("cameras left and right are swapped: with their frames exchanged")
        # As configured the views share few features (or none), on rows far apart.
        assert result.vertical_px is None or result.vertical_px > 5, result
        assert result.valid_fraction is not None and result.valid_fraction < 0.25


@pytest.mark.parametrize(("pitch_deg", "severity"), [(1.0, "warning"), (3.0, "error")])
def test_a_moved_mount_shows_as_rows_apart(cache: Path, pitch_deg: float, severity: str) -> None:
    moved = room_shot(0, scale=0.5, vpc=VPC, pitch_deg=pitch_deg)  # rendered with the right camera pitched
    result = check_calibration(pipeline(prototype_rig(0.5), cache), moved.left, moved.right)
    assert result.findings[0].severity == severity, result.findings
    assert "rows are" in result.findings[0].message and "recalibrate" in result.findings[0].message
    # Rows apart cost depth too: a low-depth warning may follow, and only when depth is low.
    for later in result.findings[1:]:
        assert later.severity == "warning" and "has depth on the first pair" in later.message
        assert result.valid_fraction is not None and result.valid_fraction < 0.25
    # fx·tan(pitch) at the VPC's fx = 160: what the pitch moves a point at the centre.
    expected = 160 * np.tan(np.radians(pitch_deg))
    assert result.vertical_px == pytest.approx(expected, rel=0.3)


@pytest.mark.parametrize(("blank", "warns"), [(0.6, False), (0.85, True)])
def test_the_valid_fraction_counts_what_both_cameras_see(cache: Path, blank: float, warns: bool) -> None:
    """The lat-lon pair with the right calibration, the top ``blank`` of both fisheye frames one grey
    (an overcast sky, a blank ceiling): no depth there whatever the calibration. The share of depth
    is counted over the directions both lookup tables cover (about 50 % of this pair's image, the
    rest cannot have depth), so 60 % blank is no warning (it was: "only 19 % of the VPC has depth");
    85 % blank still is."""
    latlon = RectifiedPairConfig(projection="latlon", px_per_deg=5.585 / 2)
    shot = room_shot(0, scale=0.5, vpc=latlon)
    pipe = DepthPipeline(shot.rig, latlon, StereoParams(), cache_dir=cache)
    left, right = shot.left.copy(), shot.right.copy()
    rows = int(blank * left.shape[0])
    left[:rows], right[:rows] = 128, 128
    frame = pipe.process(left, right)
    result = check_calibration(pipe, left, right, frame)
    seen = pipe.luts["left"].valid & pipe.luts["right"].valid
    whole = float(frame.valid.mean())
    print(
        f"blank {blank:.0%}: depth on {whole:.1%} of the image, {result.valid_fraction:.1%} of what both see"
    )
    assert 0.3 < seen.mean() < 0.7  # the part both lenses see: the share the check must count over
    assert result.valid_fraction == pytest.approx(
        np.count_nonzero(frame.valid & seen) / np.count_nonzero(seen)
    )
    low = [f.message for f in result.findings if "has depth on the first pair" in f.message]
    assert bool(low) == warns, result.findings
    assert [f.severity for f in result.findings] == (["warning"] if warns else [])
    if not warns:
        assert whole < 0.25 <= result.valid_fraction  # what the whole-image count called suspect


def test_frames_of_another_size_are_named_with_the_likely_cause() -> None:
    rig = prototype_rig(0.5)  # 640x480 cameras
    assert check_frame_sizes(rig, {"left": (640, 480), "right": (640, 480)}) == []
    half, other = check_frame_sizes(rig, {"left": (320, 240), "right": (1280, 720)}, "frames of rec/")
    assert half.severity == "error" and half.message == (
        "camera left: the frames of rec/ are 320x240 but the calibration is for 640x480: a calibration "
        "made at another resolution (the frames are ×0.5 its size)"
    )
    assert "a calibration of other cameras, or the cameras in another mode" in other.message


def test_matched_disparities_of_a_shifted_image() -> None:
    rng = np.random.default_rng(3)
    base = (rng.random((60, 80)) * 255).astype(np.uint8)
    img = np.kron(base, np.ones((4, 4), dtype=np.uint8))  # 240x320, blocky texture
    shifted = np.zeros_like(img)
    shifted[:, :-12] = img[:, 12:]  # the right view sees everything 12 px further left
    dx, dy = matched_disparities(img, shifted)
    assert dx.size > 50
    assert np.median(dx) == pytest.approx(12.0, abs=0.1) and np.median(np.abs(dy)) < 0.1
