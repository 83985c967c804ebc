"""Extrinsics of a camera pair, including the 90°-divergent mount, against exact truth (rendered
and projected boards with known mount poses) and against ``cv2.fisheye.stereoCalibrate``."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from calibration.errors import CalibrationFailed
from calibration.geometry import invert_transform, rotation_angle
from calibration.models import CameraModel, create
from calibration.stereo_calibrate import average_transforms, calibrate_stereo
from calibration.targets import board_object_points, detect_chessboard, read_corner_lists
from rig.sim import divergent_rig
from tests.calibration.calibration_renders import BOARD, board_pose, render_board, true_corners, true_lenses
from tests.conftest import shared_file

X = board_object_points(*BOARD, 0.05)
LENSES = true_lenses(480)
JY = "opencv_fisheye_calib3_stereo_JY"

# Boards in the rig frame (z forward, between the two optical axes), 0.45 m away: the ~106°
# overlap wedge of two 196° lenses 90° apart. Near the wedge's sides one camera sees corners
# past 90° off its axis.
WEDGE = [
    board_pose(th, ph, 0.45, tilt, spin)
    for th, ph, tilt, spin in [
        (0, 0, (0, 0), 0), (20, 0, (15, 0), 10), (20, 180, (0, 15), -10), (25, 90, (0, -20), 20),
        (25, 270, (20, 0), 30), (30, 30, (0, 0), -20), (30, 150, (0, 0), 15), (15, 220, (-15, 10), 5),
        (35, 0, (0, 30), 0), (35, 180, (0, -30), 0), (10, 45, (30, 0), 45), (10, 135, (-30, 0), -45),
        (30, 300, (20, 20), 0), (30, 240, (-20, 20), 0), (40, 10, (0, 0), 90), (40, 170, (0, 0), -90),
    ]
]  # fmt: skip


def views_of(
    lens: CameraModel, angle_deg: float, pitch_deg: float, render: bool
) -> tuple[list[np.ndarray | None], list[np.ndarray | None], np.ndarray]:
    """Corners of the wedge boards in each camera of a divergent rig (None where a camera does
    not see the whole board), exact or detected in renders, and the true T_right_left."""
    rig = divergent_rig(lens, lens, 0.072, angle_deg, pitch_deg)
    left, right = [], []
    for T_rig_board in WEDGE:
        for name, out in (("left", left), ("right", right)):
            T = invert_transform(rig.T_rig_cam[name]) @ T_rig_board
            _, ok = lens.project(X @ T[:3, :3].T + T[:3, 3])
            if not ok.all():
                out.append(None)
            elif render:
                out.append(detect_chessboard(render_board(lens, T), BOARD))
            else:
                out.append(true_corners(lens, T)[0])
    return left, right, invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres)."""
    E = invert_transform(T_true) @ T_est
    return math.degrees(rotation_angle(E[:3, :3])), float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))


def common_count(left: list[np.ndarray | None], right: list[np.ndarray | None]) -> int:
    return sum(a is not None and b is not None for a, b in zip(left, right, strict=True))


@pytest.mark.parametrize(("model", "angle", "pitch"), [("kannala_brandt", 90, 0), ("double_sphere", 87, 2)])
def test_divergent_pair_exact_from_no_guess(model: str, angle: float, pitch: float) -> None:
    left, right, T_true = views_of(LENSES[model], angle, pitch, render=False)
    assert common_count(left, right) >= 8
    result = calibrate_stereo(model, [X] * len(WEDGE), left, right, (480, 480))
    rot, trans = pose_errors(result.T_right_left, T_true)
    assert rot < 1e-6 and trans < 1e-9
    assert result.rms < 1e-6
    # Corners past 90° off axis were used, not dropped.
    assert max(result.max_angle_deg.values()) > 90.0 and result.dropped == []
    # The rig frame reproduces the relative pose and the baseline.
    rig = result.rig
    T_rl = invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]
    np.testing.assert_allclose(T_rl, result.T_right_left, atol=1e-12)
    assert rig.baseline() == pytest.approx(0.072, abs=1e-9)
    assert math.degrees(math.acos(rig.axis("left") @ rig.axis("right"))) == pytest.approx(
        math.degrees(math.acos(math.cos(math.radians(angle)) * math.cos(math.radians(pitch)))), abs=1e-6
    )


def test_corners_numbered_the_other_way_round_are_recognised() -> None:
    left, right, T_true = views_of(LENSES["kannala_brandt"], 90, 0, render=False)
    flipped = [
        i for i, (a, b) in enumerate(zip(left, right, strict=True)) if a is not None and b is not None
    ][:3]
    for i in flipped:
        right[i] = right[i][::-1].copy()  # type: ignore[index]
    lens = LENSES["kannala_brandt"]
    result = calibrate_stereo("kannala_brandt", [X] * len(WEDGE), left, right, (480, 480),
                              left_initial=lens, right_initial=lens, fix_intrinsics=True)  # fmt: skip
    rot, trans = pose_errors(result.T_right_left, T_true)
    assert rot < 1e-6 and trans < 1e-9 and result.rms < 1e-6
    assert result.dropped == []


def test_too_few_common_views_is_one_clear_error() -> None:
    left, right, _ = views_of(LENSES["kannala_brandt"], 90, 0, render=False)
    both = [i for i, (a, b) in enumerate(zip(left, right, strict=True)) if a is not None and b is not None]
    for i in both[2:]:
        right[i] = None
    lens = LENSES["kannala_brandt"]
    with pytest.raises(CalibrationFailed, match=r"only 2 view\(s\) with the board seen by both cameras"):
        calibrate_stereo("kannala_brandt", [X] * len(WEDGE), left, right, (480, 480),
                         left_initial=lens, right_initial=lens, fix_intrinsics=True)  # fmt: skip


def test_average_transforms_is_the_rotation_mean() -> None:
    rng = np.random.default_rng(3)
    R0 = cv2.Rodrigues(np.array([0.3, -0.2, 1.1]))[0]
    Ts = []
    for _ in range(50):
        T = np.eye(4)
        T[:3, :3] = R0 @ cv2.Rodrigues(rng.normal(0, 0.01, 3))[0]
        T[:3, 3] = np.array([0.1, 0.0, 0.0]) + rng.normal(0, 0.001, 3)
        Ts.append(T)
    mean = average_transforms(Ts)
    assert math.degrees(rotation_angle(mean[:3, :3].T @ R0)) < 0.2
    np.testing.assert_allclose(mean[:3, :3] @ mean[:3, :3].T, np.eye(3), atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize(("angle", "pitch"), [(90, 0), (87, 2)])
def test_divergent_pair_on_renders(angle: float, pitch: float) -> None:
    """Relative pose from rendered boards with the lenses known: the issue's 0.05° / 0.5 mm."""
    lens = LENSES["kannala_brandt"]
    left, right, T_true = views_of(lens, angle, pitch, render=True)
    assert common_count(left, right) >= 8
    result = calibrate_stereo("kannala_brandt", [X] * len(WEDGE), left, right, (480, 480),
                              left_initial=lens, right_initial=lens, fix_intrinsics=True)  # fmt: skip
    rot, trans = pose_errors(result.T_right_left, T_true)
    assert rot <= 0.05 and trans <= 0.5e-3, (rot, trans)
    assert result.rms < 0.1
    assert max(result.max_angle_deg.values()) > 90.0
    # The reported uncertainty is of the size of the actual error (not 10x off either way).
    assert trans < 5 * result.translation_std_m and result.translation_std_m < 1e-3


@pytest.mark.slow
def test_divergent_pair_on_renders_from_no_guess() -> None:
    """Intrinsics and extrinsics together from the same renders, no guess at all. The rotation
    is then limited by how well ~10 views pin each principal point (~0.1 px ≈ 0.05°)."""
    lens = LENSES["kannala_brandt"]
    left, right, T_true = views_of(lens, 87, 2, render=True)
    result = calibrate_stereo("kannala_brandt", [X] * len(WEDGE), left, right, (480, 480))
    rot, trans = pose_errors(result.T_right_left, T_true)
    assert rot <= 0.15 and trans <= 1e-3, (rot, trans)
    assert result.rms < 0.1


def _jy() -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    obj = read_corner_lists(shared_file(f"{JY}/object.xml"), 3)
    return (
        obj,
        read_corner_lists(shared_file(f"{JY}/left.xml"), 2),
        read_corner_lists(shared_file(f"{JY}/right.xml"), 2),
    )


def _kb(K: np.ndarray, D: np.ndarray) -> CameraModel:
    k = D.ravel()
    return create("kannala_brandt", 1280, 800, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2],
                  k1=k[0], k2=k[1], k3=k[2], k4=k[3])  # fmt: skip


@pytest.mark.parametrize("fix_intrinsics", [True, False])
def test_agrees_with_opencv_fisheye_stereo_calibrate(fix_intrinsics: bool) -> None:
    """Same corners, same objective (reprojection error of both cameras over board poses, R, T
    and, without FIX_INTRINSIC, both intrinsics): both must reach the same minimum. The
    tolerances are those of the solvers' stopping rules (relative cost change ~1e-12), far
    below the pose's own uncertainty (~0.02°, ~0.07 mm here)."""
    obj, left, right = _jy()
    o = [x.reshape(1, -1, 3) for x in obj]
    lp = [x.reshape(1, -1, 2) for x in left]
    rp = [x.reshape(1, -1, 2) for x in right]
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    _, K1, D1, _, _ = cv2.fisheye.calibrate(o, lp, (1280, 800), None, None, flags=flags, criteria=crit)
    _, K2, D2, _, _ = cv2.fisheye.calibrate(o, rp, (1280, 800), None, None, flags=flags, criteria=crit)
    stereo_flags = flags | (cv2.CALIB_FIX_INTRINSIC if fix_intrinsics else 0)
    out = cv2.fisheye.stereoCalibrate(
        o, lp, rp, K1, D1, K2, D2, (1280, 800), flags=stereo_flags, criteria=crit
    )
    cv_rms, R, T = out[0], out[5], out[6]
    T_cv = np.eye(4)
    T_cv[:3, :3], T_cv[:3, 3] = R, T.ravel()
    kw = (
        {"left_initial": _kb(K1, D1), "right_initial": _kb(K2, D2), "fix_intrinsics": True}
        if fix_intrinsics
        else {}
    )
    ours = calibrate_stereo("kannala_brandt", obj, left, right, (1280, 800), **kw)  # type: ignore[arg-type]
    rot, trans = pose_errors(ours.T_right_left, T_cv)
    assert rot < 1e-4 and trans < 1e-6, (rot, trans)
    assert ours.rms <= cv_rms + 1e-4
    assert ours.baseline_m == pytest.approx(float(np.linalg.norm(T)), rel=1e-5)
    assert len(ours.common_views) == 34
