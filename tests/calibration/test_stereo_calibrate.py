"""Extrinsics of a camera pair, including the 90°-divergent mount, against exact truth (rendered
and projected boards with known mount poses) and against ``cv2.fisheye.stereoCalibrate``.

Rendered pairs are 480x480, 4x4 supersampled; the right lens is a second copy of the left's
make (``twin_lens``), so intrinsics cannot be swapped unnoticed."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from calibration.calibrate import calibrate_camera
from calibration.errors import CalibrationFailed
from calibration.geometry import invert_transform, rotation_angle
from calibration.models import CameraModel, create
from calibration.stereo_calibrate import StereoCalibration, average_transforms, calibrate_stereo
from calibration.targets import board_object_points, detect_chessboard, read_corner_lists
from rig.sim import divergent_rig
from tests.conftest import shared_file
from tests.helpers.boards import (
    BOARD,
    FINE_SUPERSAMPLE,
    board_pose,
    circle_views,
    image_difference,
    render_board,
    true_corners,
    true_lenses,
    twin_lens,
)

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
    lens: CameraModel, angle_deg: float, pitch_deg: float
) -> tuple[list[np.ndarray | None], list[np.ndarray | None], np.ndarray]:
    """Exact corners of the wedge boards in each camera of a divergent rig (None where a camera
    does not see the whole board) and the true T_right_left."""
    rig = divergent_rig(lens, lens, 0.072, angle_deg, pitch_deg)
    left: list[np.ndarray | None] = []
    right: list[np.ndarray | None] = []
    for T_rig_board in WEDGE:
        for name, out in (("left", left), ("right", right)):
            T = invert_transform(rig.T_rig_cam[name]) @ T_rig_board
            _, ok = lens.project(X @ T[:3, :3].T + T[:3, 3])
            out.append(true_corners(lens, T)[0] if ok.all() else None)
    return left, right, invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres)."""
    E = invert_transform(T_true) @ T_est
    return math.degrees(rotation_angle(E[:3, :3])), float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))


def common_count(left: list[np.ndarray | None], right: list[np.ndarray | None]) -> int:
    return sum(a is not None and b is not None for a, b in zip(left, right, strict=True))


@pytest.mark.parametrize(("model", "angle", "pitch"), [("kannala_brandt", 90, 0), ("double_sphere", 87, 2)])
def test_divergent_pair_exact_from_no_guess(model: str, angle: float, pitch: float) -> None:
    left, right, T_true = views_of(LENSES[model], angle, pitch)
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
    left, right, T_true = views_of(LENSES["kannala_brandt"], 90, 0)
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
    left, right, _ = views_of(LENSES["kannala_brandt"], 90, 0)
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


@dataclass(frozen=True)
class RenderedPair:
    """The wedge boards rendered (4x4 supersampled) in both cameras of a divergent rig whose
    right lens is another copy of the left's make: images (None where a camera does not see the
    whole board), SB detections, and the true T_right_left."""

    images: dict[str, list[np.ndarray | None]]
    corners: dict[str, list[np.ndarray | None]]
    T_true: np.ndarray


PAIR_LENSES = {"left": LENSES["kannala_brandt"], "right": twin_lens(LENSES["kannala_brandt"])}


@functools.cache
def rendered_pair(angle_deg: float, pitch_deg: float) -> RenderedPair:
    rig = divergent_rig(PAIR_LENSES["left"], PAIR_LENSES["right"], 0.072, angle_deg, pitch_deg)
    images: dict[str, list[np.ndarray | None]] = {"left": [], "right": []}
    for T_rig_board in WEDGE:
        for name, lens in PAIR_LENSES.items():
            T = invert_transform(rig.T_rig_cam[name]) @ T_rig_board
            _, ok = lens.project(X @ T[:3, :3].T + T[:3, 3])
            images[name].append(render_board(lens, T, supersample=FINE_SUPERSAMPLE) if ok.all() else None)
    corners = {
        n: [None if im is None else detect_chessboard(im, BOARD) for im in ims] for n, ims in images.items()
    }
    return RenderedPair(images, corners, invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"])


@functools.cache
def own_intrinsics(name: str) -> CameraModel:
    """A camera's lens as a user gets it: calibrated (with corner refinement) from chessboard
    images taken with that camera alone over its whole field (13 views, no true values)."""
    lens = PAIR_LENSES[name]
    images = [render_board(lens, T, supersample=FINE_SUPERSAMPLE) for T in circle_views()]
    found = [detect_chessboard(im, BOARD) for im in images]
    return calibrate_camera("kannala_brandt", [X] * len(images), found, (480, 480), images=images).camera


def _stereo(pair: RenderedPair, refine: bool, **kw: object) -> tuple[float, float, StereoCalibration]:
    images = {n: pair.images[n] if refine else None for n in ("left", "right")}
    result = calibrate_stereo(
        "kannala_brandt", [X] * len(WEDGE), pair.corners["left"], pair.corners["right"], (480, 480),
        left_images=images["left"], right_images=images["right"], **kw,  # type: ignore[arg-type]
    )  # fmt: skip
    rot, trans = pose_errors(result.T_right_left, pair.T_true)
    return rot, trans, result


MOUNTS = [(90, 0), (87, 2)]
#: Measured (docs/calibration.md, corner refinement table), per mount: rotation error (°) and translation
#: error (mm) from the detector's corners, refined with the lenses fixed, and refined jointly.
OWN_INTRINSICS = {
    (90, 0): ((0.0287, 0.313), (0.0110, 0.170), (0.0044, 0.024)),
    (87, 2): ((0.0303, 0.237), (0.0117, 0.164), (0.0052, 0.039)),
}


@pytest.mark.slow
@pytest.mark.parametrize(("angle", "pitch"), MOUNTS)
def test_divergent_pair_with_intrinsics_from_each_cameras_own_images(angle: float, pitch: float) -> None:
    """0.05° / 0.5 mm, as a user gets there: each camera's lens calibrated from its
    own images, then the pair from the wedge images (corners refined with those lenses), the
    lenses held fixed or refined jointly."""
    pair = rendered_pair(angle, pitch)
    assert sum(a is not None and b is not None for a, b in zip(*pair.corners.values(), strict=True)) >= 8
    lenses = {n: own_intrinsics(n) for n in ("left", "right")}
    for n, lens in lenses.items():
        assert image_difference(PAIR_LENSES[n], lens)[0] <= 0.1
    given = {"left_initial": lenses["left"], "right_initial": lenses["right"]}
    raw_rot, raw_trans, _ = _stereo(pair, False, fix_intrinsics=True, **given)
    rot, trans, fixed = _stereo(pair, True, fix_intrinsics=True, **given)
    joint_rot, joint_trans, joint = _stereo(pair, True, **given)
    print(
        f"\n{angle}°/{pitch}°, own intrinsics: detector corners {raw_rot:.4f}° {raw_trans * 1e3:.3f} mm; "
        f"refined, lenses fixed {rot:.4f}° {trans * 1e3:.3f} mm; refined jointly {joint_rot:.4f}° "
        f"{joint_trans * 1e3:.3f} mm"
    )
    assert rot <= 0.05 and trans <= 0.5e-3
    assert joint_rot <= 0.05 and joint_trans <= 0.5e-3
    measured = [(r, t * 1e3) for r, t in ((raw_rot, raw_trans), (rot, trans), (joint_rot, joint_trans))]
    for got, want in zip(measured, OWN_INTRINSICS[(angle, pitch)], strict=True):
        assert got == pytest.approx(want, rel=0.3)
    for result in (fixed, joint):
        assert result.rms < 0.03 and max(result.max_angle_deg.values()) > 90.0
        assert all(r is not None and r.rms_after < r.rms_before for r in result.refinement.values())
    assert fixed.cameras["left"] == lenses["left"]  # held, not re-estimated


@pytest.mark.slow
@pytest.mark.parametrize(("angle", "pitch"), MOUNTS)
def test_divergent_pair_on_renders_with_the_true_lenses(angle: float, pitch: float) -> None:
    """The relative pose alone (true lenses given and held): what the corners allow."""
    pair = rendered_pair(angle, pitch)
    kw = {"left_initial": PAIR_LENSES["left"], "right_initial": PAIR_LENSES["right"], "fix_intrinsics": True}
    raw_rot, raw_trans, _ = _stereo(pair, False, **kw)
    rot, trans, result = _stereo(pair, True, **kw)
    print(f"\n{angle}°/{pitch}°, true lenses: detector corners {raw_rot:.4f}° {raw_trans * 1e3:.3f} mm; "
          f"refined {rot:.4f}° {trans * 1e3:.3f} mm")  # fmt: skip
    assert rot <= 0.02 and trans <= 0.1e-3 and rot < raw_rot
    assert result.rms < 0.03
    # The reported uncertainty is of the size of the actual error (not 10x off either way).
    assert trans < 5 * result.translation_std_m and result.translation_std_m < 0.2e-3


@pytest.mark.slow
def test_divergent_pair_on_renders_from_no_guess() -> None:
    """Lenses and pose together from the wedge images alone (what `rig calibrate stereo` does
    without intrinsics files), corners refined with each camera's lens as it is found."""
    pair = rendered_pair(87, 2)
    raw_rot, raw_trans, _ = _stereo(pair, False)
    rot, trans, result = _stereo(pair, True)
    print(f"\n87°/2°, no guess: detector corners {raw_rot:.4f}° {raw_trans * 1e3:.3f} mm; "
          f"refined {rot:.4f}° {trans * 1e3:.3f} mm")  # fmt: skip
    assert rot <= 0.05 and trans <= 0.5e-3, (rot, trans)
    assert result.rms < 0.03
    assert all(m is not None and m.refinement is not None for m in result.mono.values())


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
    and, without FIX_INTRINSIC, both intrinsics): both must reach the same minimum, to within
    the solvers' stopping rules (relative cost change ~1e-12), far below the pose's own
    uncertainty (~0.02°, ~0.07 mm here)."""
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
    print(f"\nfix_intrinsics={fix_intrinsics}: R differs by {rot:.1e}°, T by {trans:.1e} m; "
          f"RMS ours {ours.rms:.4f}, OpenCV {cv_rms:.4f} px")  # fmt: skip
    assert rot < 5e-8 and trans < 4e-10, (rot, trans)  # measured ≤ 5.4e-9° and ≤ 4.0e-11 m
    assert abs(ours.rms - cv_rms) <= 1e-6
    assert ours.baseline_m == pytest.approx(float(np.linalg.norm(T)), rel=1e-5)
    assert len(ours.common_views) == 34
