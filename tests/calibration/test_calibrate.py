"""Intrinsic calibration: every model from no guess, against OpenCV, on real data.

References are independent of the code under test: exact projections of known board poses
through a known lens, OpenCV's own ``cv2.fisheye.calibrate`` on the same corners, and the
statistics of repeated noisy calibrations.
"""

from __future__ import annotations

import glob
import re

import cv2
import numpy as np
import pytest

from calibration.calibrate import calibrate_camera
from calibration.errors import CalibrationError, CalibrationFailed
from calibration.models import CameraModel, create
from calibration.targets import (
    board_object_points,
    detect_chessboard_files,
    read_corner_lists,
    read_omnidir_corners,
)
from tests.conftest import shared_file
from tests.helpers.boards import (
    BOARD,
    circle_views,
    lens_difference,
    pinhole_views,
    true_corners,
    true_lenses,
)

SQUARE = 0.05
X = board_object_points(*BOARD, SQUARE)
LENSES = true_lenses(480)
JY = "opencv_fisheye_calib3_stereo_JY"


def exact_views(camera: CameraModel, poses: list[np.ndarray]) -> tuple[list[np.ndarray], float]:
    """Exact corner pixels for each pose (all inside the image) and the largest angle (deg)."""
    views, top = [], 0.0
    for T in poses:
        pix, angle = true_corners(camera, T, SQUARE)
        _, ok = camera.project(X @ T[:3, :3].T + T[:3, 3])
        assert ok.all(), "test geometry: every corner must be imaged"
        views.append(pix)
        top = max(top, float(angle.max()))
    return views, top


@pytest.mark.parametrize("name", sorted(LENSES))
def test_recovers_every_model_exactly_from_no_guess(name: str) -> None:
    lens = LENSES[name]
    poses = pinhole_views() if name == "pinhole" else circle_views()
    views, top = exact_views(lens, poses)
    result = calibrate_camera(name, [X] * len(views), views, (lens.width, lens.height))
    assert result.dropped == [] and len(result.views) == len(views)
    assert result.rms < 1e-6
    # The lens itself, not just the residual: projections agree over the observed field.
    _, worst = lens_difference(lens, result.camera, top)
    assert worst < 1e-5, f"{name}: lens differs by up to {worst} px"
    if name != "pinhole":
        assert top > 95.0 and result.max_angle_deg > 95.0  # corners past 90° off axis were used


@pytest.mark.parametrize(
    ("true", "fitted", "rms_limit"),
    [
        ("equidistant", "kannala_brandt", 1e-6),  # KB contains the equidistant lens (k = 0)
        ("double_sphere", "kannala_brandt", 0.01),
        ("kannala_brandt", "eucm", 0.1),
        ("kannala_brandt", "scaramuzza", 0.1),
        ("kannala_brandt", "mei", 0.1),
    ],
)
def test_cross_fitted_models_reach_low_rms(true: str, fitted: str, rms_limit: float) -> None:
    views, _ = exact_views(LENSES[true], circle_views())
    result = calibrate_camera(fitted, [X] * len(views), views, (480, 480))
    assert result.camera.name == fitted
    assert result.rms < rms_limit
    assert len(result.views) == len(views)


def test_pinhole_drops_views_it_cannot_image() -> None:
    views, top = exact_views(LENSES["kannala_brandt"], circle_views())
    assert top > 90
    result = calibrate_camera("pinhole", [X] * len(views), views, (480, 480))
    # Every view with a corner at or past 90° off axis is out of the pinhole's reach.
    beyond = [
        i
        for i, T in enumerate(circle_views())
        if true_corners(LENSES["kannala_brandt"], T, SQUARE)[1].max() >= 90
    ]
    assert beyond and {d.index for d in result.dropped} >= set(beyond)
    assert all("outside the pinhole model's field" in d.reason for d in result.dropped)
    assert result.rms < 0.5 and len(result.views) >= 3


def test_bad_views_are_dropped_and_reported() -> None:
    lens = LENSES["equidistant"]
    views, _ = exact_views(lens, circle_views())
    rng = np.random.default_rng(1)
    image_points: list[np.ndarray | None] = list(views)
    image_points[2] = rng.uniform(0, 480, size=(len(X), 2))  # a wrong detection
    image_points[4] = None  # board not found
    few = np.full((len(X), 2), np.nan)
    few[:4] = views[5][:4]
    image_points[5] = few  # only 4 corners
    partial = views[6].copy()
    partial[10:20] = np.nan  # partly detected: still usable
    image_points[6] = partial
    names = [f"img{i}.png" for i in range(len(views))]
    result = calibrate_camera("equidistant", [X] * len(views), image_points, (480, 480), view_names=names)
    dropped = {d.index: d for d in result.dropped}
    assert set(dropped) == {2, 4, 5}
    assert dropped[4].reason == "no corners detected" and dropped[4].name == "img4.png"
    assert "only 4 corners" in dropped[5].reason
    assert 6 in result.views and len(result.image_points[result.views.index(6)]) == len(X) - 10
    assert result.rms < 1e-6
    assert lens_difference(lens, result.camera, 90.0)[1] < 1e-5


def test_too_few_views_is_one_clear_error() -> None:
    views, _ = exact_views(LENSES["kannala_brandt"], circle_views()[:2])
    with pytest.raises(CalibrationFailed, match=r"only 2 usable view\(s\), need at least 3"):
        calibrate_camera("kannala_brandt", [X, X], views, (480, 480))
    with pytest.raises(CalibrationFailed, match="view 1: no corners detected"):
        calibrate_camera("kannala_brandt", [X, X, X], [views[0], None, None], (480, 480))


def test_rejects_bad_arguments() -> None:
    views, _ = exact_views(LENSES["kannala_brandt"], circle_views()[:3])
    with pytest.raises(CalibrationError, match="unknown camera model 'fisheye'"):
        calibrate_camera("fisheye", [X] * 3, views, (480, 480))
    with pytest.raises(CalibrationError, match="3 object point sets but 2 image point sets"):
        calibrate_camera("kannala_brandt", [X] * 3, views[:2], (480, 480))
    with pytest.raises(CalibrationError, match="view 0: 53 image points but 54 object points"):
        calibrate_camera("kannala_brandt", [X] * 3, [views[0][:-1], *views[1:]], (480, 480))
    with pytest.raises(CalibrationError, match="initial guess is for 640x480 images"):
        calibrate_camera(
            "kannala_brandt", [X] * 3, views, (480, 480), initial=LENSES["pinhole"].replace(width=640)
        )
    with pytest.raises(CalibrationError, match="cannot fix unknown parameter"):
        calibrate_camera("kannala_brandt", [X] * 3, views, (480, 480), fix=("k9",))


def test_initial_guess_of_another_model_and_fixed_parameters() -> None:
    lens = LENSES["kannala_brandt"]
    views, _ = exact_views(lens, circle_views())
    guess = create("equidistant", 480, 480, fx=120.0, fy=120.0, cx=235.0, cy=245.0)
    result = calibrate_camera("kannala_brandt", [X] * len(views), views, (480, 480), initial=guess)
    assert result.rms < 1e-6
    # Holding k4 at a wrong value (0) leaves a residual, and k4 stays exactly there.
    held = calibrate_camera(
        "kannala_brandt", [X] * len(views), views, (480, 480), initial=lens.replace(k4=0.0), fix=("k4",)
    )
    assert held.camera.param_dict["k4"] == 0.0 and "k4" not in held.param_std
    assert held.rms > 1e-3


def test_parameter_std_matches_the_scatter_of_repeated_calibrations() -> None:
    """σ from the Jacobian at the optimum against Monte-Carlo: the spread of the estimates
    over independent noise draws (an independent estimate of the same quantity)."""
    lens = LENSES["equidistant"]
    views, _ = exact_views(lens, circle_views())
    rng = np.random.default_rng(7)
    estimates, predicted = [], []
    for _ in range(16):
        noisy = [v + rng.normal(0.0, 0.3, v.shape) for v in views]
        res = calibrate_camera("equidistant", [X] * len(views), noisy, (480, 480), initial=lens)
        estimates.append([res.camera.param_dict[k] for k in ("fx", "cx")])
        predicted.append([res.param_std[k] for k in ("fx", "cx")])
        assert 0.3 < res.rms < 0.55  # sqrt(2) * 0.3 px expected
    spread = np.std(estimates, axis=0, ddof=1)
    ratio = spread / np.mean(predicted, axis=0)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio


def _opencv_rms(obj: list[np.ndarray], img: list[np.ndarray], K: np.ndarray, D: np.ndarray, rv, tv) -> float:  # type: ignore[no-untyped-def]
    sq, n = 0.0, 0
    for X_, u, r, t in zip(obj, img, rv, tv, strict=True):
        proj, _ = cv2.fisheye.projectPoints(X_.reshape(-1, 1, 3), r, t, K, D)
        sq += float(np.sum((proj.reshape(-1, 2) - u) ** 2))
        n += len(u)
    return float(np.sqrt(sq / n))


@pytest.mark.parametrize("side", ["left", "right"])
def test_kannala_brandt_matches_opencv_fisheye_on_its_own_data(side: str) -> None:
    obj = read_corner_lists(shared_file(f"{JY}/object.xml"), 3)
    img = read_corner_lists(shared_file(f"{JY}/{side}.xml"), 2)
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    _, K, D, rv, tv = cv2.fisheye.calibrate(
        [o.reshape(1, -1, 3) for o in obj], [u.reshape(1, -1, 2) for u in img], (1280, 800), None, None,
        flags=flags, criteria=criteria,
    )  # fmt: skip
    cv_rms = _opencv_rms(obj, img, K, D, rv, tv)
    ours = calibrate_camera("kannala_brandt", obj, img, (1280, 800))
    p = ours.camera.param_dict
    focal_centre = max(
        abs(ours_v - cv_v) / abs(cv_v)
        for ours_v, cv_v in ((p["fx"], K[0, 0]), (p["fy"], K[1, 1]), (p["cx"], K[0, 2]), (p["cy"], K[1, 2]))
    )
    distortion = max(abs(p[f"k{i + 1}"] - D.ravel()[i]) for i in range(4))
    print(
        f"\n{side}: RMS ours {ours.rms:.4f} px, OpenCV {cv_rms:.4f} px; fx, fy, cx, cy agree to "
        f"{focal_centre:.1e} (relative), k1..k4 to {distortion:.1e}"
    )
    assert focal_centre <= 1e-9 and distortion <= 6e-8  # measured ≤ 1.2e-10 and ≤ 5.8e-9
    assert abs(ours.rms - cv_rms) <= 1e-6
    # Our RMS is computed independently of the solver's bookkeeping too.
    assert ours.rms == pytest.approx(
        float(np.sqrt(np.mean(np.concatenate(ours.residuals) ** 2) * 2)), rel=1e-9
    )


def test_mei_on_the_omnidir_tutorial_corners() -> None:
    data = read_omnidir_corners(shared_file("opencv_contrib_omnidir/omni_calib_data.xml"))
    result = calibrate_camera("mei", data.object_points, data.image_points["imagePoints"], (1280, 960))
    assert result.converged and result.dropped == [] and len(result.views) == 15
    # No published reference: a sane lens (ξ of a real wide lens, centre near the image centre)
    # and a sub-pixel RMS, better than a radial-only model on the same corners.
    p = result.camera.param_dict
    assert 0.5 < p["xi"] < 2.0 and abs(p["cx"] - 640) < 40 and abs(p["cy"] - 480) < 60
    assert result.rms < 1.0
    radial = calibrate_camera(
        "kannala_brandt", data.object_points, data.image_points["imagePoints"], (1280, 960)
    )
    assert result.rms < radial.rms
    assert result.max_angle_deg > 90


@pytest.mark.slow
@pytest.mark.parametrize("side", ["left", "right"])
def test_real_fisheye_images_calibrate_from_no_guess(side: str) -> None:
    """OpenCV needs an intrinsic guess on these real images; we do not."""
    folder = shared_file("fisheye_stereo_sourishg/imgs")
    paths = sorted(
        glob.glob(str(folder / f"{side}*.jpg")), key=lambda p: int(re.findall(r"(\d+)\.jpg$", p)[0])
    )
    assert len(paths) == 29
    dets = detect_chessboard_files(paths, (9, 6))
    found = [d for d in dets if d.ok]
    assert len(found) >= 20
    obj = board_object_points(9, 6, 0.02423)
    ours = calibrate_camera("kannala_brandt", [obj] * len(dets), [d.corners for d in dets], (960, 600))
    assert ours.converged and ours.rms < 0.5
    # OpenCV given a reasonable guess (f = 300 px, centre of the image) on the same corners.
    guess = np.array([[300.0, 0, 479.5], [0, 300.0, 299.5], [0, 0, 1]])
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    cv_rms, K, _, _, _ = cv2.fisheye.calibrate(
        [obj.reshape(1, -1, 3)] * len(found), [d.corners.reshape(1, -1, 2) for d in found], (960, 600),
        guess, np.zeros(4), flags=flags, criteria=criteria,
    )  # fmt: skip
    # OpenCV without a guess: an assertion, or a fit far from the lens (docs/calibration.md's "nonsense").
    try:
        bare = cv2.fisheye.calibrate(
            [obj.reshape(1, -1, 3)] * len(found), [d.corners.reshape(1, -1, 2) for d in found], (960, 600),
            None, None, flags=flags & ~cv2.CALIB_USE_INTRINSIC_GUESS, criteria=criteria,
        )  # fmt: skip
        no_guess = f"RMS {bare[0]:.3g} px, fx {bare[1][0, 0]:.4g} px"
        assert bare[0] > 10 * ours.rms or abs(bare[1][0, 0] / K[0, 0] - 1) > 0.1, no_guess
    except cv2.error as err:
        no_guess = f"cv2.error {str(err).strip().splitlines()[-1][:80]}"
    print(
        f"\n{side}: RMS ours from no guess {ours.rms:.4f} px, OpenCV from a guess {cv_rms:.4f} px, "
        f"OpenCV without one: {no_guess}"
    )
    assert ours.rms <= cv_rms + 0.001
    assert ours.rms == pytest.approx({"left": 0.1798, "right": 0.2060}[side], rel=0.01)  # docs/calibration.md
    assert ours.camera.param_dict["fx"] == pytest.approx(K[0, 0], rel=1e-3)
