"""Fisheye-aware corner refinement against exact corners of rendered boards (``camera.project``
of the true 3D corners), and on real images.

The premise is measured too: ``findChessboardCornersSB`` is ~0.1 px off the truth and pulled
inwards near a fisheye's rim; the refined corners are ~0.02 px off with no trend against the
angle off axis.
"""

from __future__ import annotations

import glob
import itertools
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.calibrate import calibrate_camera
from calibration.corner_refine import (
    CornerRefinement,
    board_neighbours,
    load_grey,
    refine_corners_local,
    refine_views,
)
from calibration.errors import CalibrationError, CalibrationFileError
from calibration.models import create
from calibration.targets import board_object_points, detect_chessboard, detect_chessboard_files
from rig.evaluate.renders import BOARD_BACKGROUND
from rig.sim import chessboard_scene, render
from tests.conftest import shared_file
from tests.helpers.boards import (
    BOARD,
    FINE_SUPERSAMPLE,
    board_pose,
    radial_errors,
    render_board,
    rendered_views,
    true_corners,
    true_lenses,
)

X = board_object_points(*BOARD, 0.05)
KB = true_lenses(480)["kannala_brandt"]
# Two boards near the rim of the KB lens: their far corners are 85-95° off axis.
RIM = [board_pose(74, 45, 0.6, (0, 0), 30), board_pose(72, 200, 0.6, (10, 0), -20)]


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def test_board_neighbours_of_a_small_grid() -> None:
    # 3 x 2 inner corners, x fastest:  0 1 2 / 3 4 5.  Columns: +x, -x, +y, -y.
    expected = [[1, -1, 3, -1], [2, 0, 4, -1], [-1, 1, 5, -1], [4, -1, -1, 0], [5, 3, -1, 1], [-1, 4, -1, 2]]
    np.testing.assert_array_equal(board_neighbours(board_object_points(3, 2, 0.03)), expected)


def test_board_neighbours_reject_non_grids() -> None:
    bent = board_object_points(3, 2, 0.03)
    bent[2, 2] = 0.01
    with pytest.raises(CalibrationError, match="planar board"):
        board_neighbours(bent)
    scattered = np.array([[0, 0, 0], [0.1, 0, 0], [0.5, 0.7, 0], [0.9, 0.2, 0]], float)
    with pytest.raises(CalibrationError, match="grid board"):
        board_neighbours(scattered)


@pytest.fixture(scope="module")
def rim_views() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """(image, SB corners, true corners, angles) of the two rim boards through the KB lens."""
    out = []
    for T in RIM:
        image = render_board(KB, T, supersample=FINE_SUPERSAMPLE)
        found = detect_chessboard(image, BOARD)
        assert found is not None
        out.append((image, found, *true_corners(KB, T)))
    return out


def test_refinement_removes_the_rim_bias(rim_views: list[tuple[np.ndarray, ...]]) -> None:
    raw_err, raw_rad, ref_err, ref_rad, angles = [], [], [], [], []
    for image, found, truth, angle in rim_views:
        res = refine_corners_local(image, found, KB, X)
        ok = res.ok
        assert ok.sum() >= len(ok) - 3  # at most the window past the lens's 98° limit is refused
        e, r = radial_errors(KB, found, truth)
        raw_err.append(e[ok])
        raw_rad.append(r[ok])
        e, r = radial_errors(KB, res.corners[ok], truth[ok])
        ref_err.append(e)
        ref_rad.append(r)
        angles.append(angle[ok])
        np.testing.assert_allclose(res.shift[ok], np.linalg.norm(res.corners[ok] - found[ok], axis=1))
    a = np.concatenate(angles)
    rim = a > 60
    assert (a > 90).sum() >= 5
    raw_bias, ref_bias = (
        float(np.concatenate(raw_rad)[rim].mean()),
        float(np.concatenate(ref_rad)[rim].mean()),
    )
    print(
        f"\nrim corners: SB {rms(np.concatenate(raw_err)):.4f} px RMS, radial bias {raw_bias:+.4f}; "
        f"refined {rms(np.concatenate(ref_err)):.4f} px RMS, radial bias {ref_bias:+.4f}"
    )
    assert raw_bias < -0.03  # the detector's curvature bias, the reason for all this
    assert abs(ref_bias) < 0.01 and rms(np.concatenate(ref_err)) <= 0.03


def test_refined_corners_do_not_depend_on_the_start(rim_views: list[tuple[np.ndarray, ...]]) -> None:
    """The result is the window's centre of symmetry, not a nudge of the start point."""
    image, found, truth, _ = rim_views[0]
    rng = np.random.default_rng(7)
    a = refine_corners_local(image, found, KB, X)
    b = refine_corners_local(image, truth + rng.uniform(-0.4, 0.4, truth.shape), KB, X)
    both = a.ok & b.ok
    assert both.sum() >= len(X) - 3
    assert np.abs(a.corners[both] - b.corners[both]).max() < 2e-3


def test_pinhole_render_and_straight_edges() -> None:
    """No distortion at all: the local view is the image itself, up to resampling."""
    camera = create("pinhole", 480, 480, fx=300.0, fy=300.0, cx=239.5, cy=239.5)
    T = board_pose(0, 0, 0.7, (25, -15), 15)
    image = render_board(camera, T, supersample=FINE_SUPERSAMPLE)
    found = detect_chessboard(image, BOARD)
    assert found is not None
    truth, _ = true_corners(camera, T)
    res = refine_corners_local(image, found, camera, X)
    assert res.ok.all() and res.reasons == {}
    assert rms(np.linalg.norm(res.corners - truth, axis=1)) <= 0.03
    # A BGR image of the same render gives the same corners.
    colour = refine_corners_local(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), found, camera, X)
    np.testing.assert_allclose(colour.corners, res.corners, atol=1e-9)


def test_uneven_light_and_noise() -> None:
    """Strong vignetting (a quarter of the light at 90° off axis) and sensor noise: the
    symmetry fit's illumination-gradient term keeps the rim corners unbiased."""
    T = RIM[0]
    scene = chessboard_scene(*BOARD, 0.05, T)
    image = render(scene, KB, np.eye(4), supersample=FINE_SUPERSAMPLE, vignetting=1.0, noise_std=1.5, seed=3,
                   background=BOARD_BACKGROUND).image  # fmt: skip
    found = detect_chessboard(image, BOARD)
    assert found is not None
    truth, _ = true_corners(KB, T)
    res = refine_corners_local(image, found, KB, X)
    e, r = radial_errors(KB, res.corners[res.ok], truth[res.ok])
    print(f"\nvignetting + noise: refined {rms(e):.4f} px RMS, radial bias {r.mean():+.4f} px")
    assert rms(e) <= 0.04 and abs(r.mean()) < 0.01


def test_corners_that_cannot_be_refined_are_left_out_with_a_reason(
    rim_views: list[tuple[np.ndarray, ...]],
) -> None:
    image, found, _, angle = rim_views[0]
    # Not detected stays not detected, without a reason.
    gappy = found.copy()
    gappy[[0, 5]] = np.nan
    res = refine_corners_local(image, gappy, KB, X)
    assert np.isnan(res.corners[[0, 5]]).all() and 0 not in res.reasons and 5 not in res.reasons
    assert np.isnan(res.shift[[0, 5]]).all()
    # A flat image: nothing to find.
    flat = refine_corners_local(np.full_like(image, 128), found, KB, X)
    assert not flat.ok.any() and set(flat.reasons.values()) == {"too little contrast around the corner"}
    # A lens that sees only 170°: corners past 85° are outside it, windows crossing 85° leave it.
    narrow = KB.replace(fov_deg=170.0)
    res = refine_corners_local(image, found, narrow, X)
    reasons = {res.reasons.get(int(i)) for i in np.flatnonzero(angle > 85.5)}
    assert reasons <= {"outside the lens model's field", "refinement window leaves the lens's field of view"}
    assert not res.ok[angle > 85.5].any() and res.ok[angle < 80].all()
    # The same board cut by the image edge: the corners near the cut are refused.
    x_cut = int(np.median(found[:, 0]))
    camera = KB.replace(width=x_cut, cx=KB.param_dict["cx"])
    res = refine_corners_local(image[:, :x_cut], found, camera, X)
    off = found[:, 0] > x_cut - 3
    assert off.any() and not res.ok[off].any()
    assert {res.reasons[int(i)] for i in np.flatnonzero(off)} == {"refinement window leaves the image"}


def test_bad_inputs_are_clear_errors(tmp_path: Path) -> None:
    image = np.zeros((480, 480), np.uint8)
    corners = np.zeros((len(X), 2))
    with pytest.raises(CalibrationError, match="image is 300x480 but the lens model is for 480x480"):
        refine_corners_local(np.zeros((480, 300), np.uint8), corners, KB, X)
    with pytest.raises(CalibrationError, match="53 corners but 54 object points"):
        refine_corners_local(image, corners[:53], KB, X)
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(CalibrationFileError, match=r"bad\.png: cannot be read as an image"):
        refine_corners_local(bad, corners, KB, X)
    with pytest.raises(CalibrationError, match="grey or BGR"):
        load_grey(np.zeros((4, 4, 2), np.uint8))


def test_load_grey_reads_files_and_converts_colour(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    path = tmp_path / "x.png"
    cv2.imwrite(str(path), bgr)
    # Files are read as the detector reads them (decoded to grey by OpenCV), arrays converted.
    as_read = np.asarray(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), dtype=np.float64)
    np.testing.assert_array_equal(load_grey(path), as_read)
    np.testing.assert_array_equal(load_grey(str(path)), as_read)
    np.testing.assert_array_equal(load_grey(bgr), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float64))
    assert np.abs(load_grey(path) - load_grey(bgr)).max() <= 1.0


def test_refine_views_keeps_views_without_an_image(rim_views: list[tuple[np.ndarray, ...]]) -> None:
    image, found, _, _ = rim_views[0]
    refined, rejected = refine_views([image, None], {0: found, 1: found}, KB, {0: X, 1: X}, ["a", "b"])
    np.testing.assert_array_equal(refined[1], found)
    direct: CornerRefinement = refine_corners_local(image, found, KB, X)
    np.testing.assert_array_equal(refined[0], direct.corners)
    assert [(r.view, r.view_name, r.corner, r.reason) for r in rejected] == [
        (0, "a", k, why) for k, why in direct.reasons.items()
    ]
    with pytest.raises(CalibrationError, match=r"^b: 2 corners but 54 object points"):
        refine_views([image, image], {1: found[:2]}, KB, {1: X}, ["a", "b"])


def test_calibrate_camera_checks_the_image_list() -> None:
    views = [true_corners(KB, board_pose(30, k * 90, 0.6, (10, 0), 0))[0] for k in range(4)]
    with pytest.raises(CalibrationError, match="3 images for 4 views"):
        calibrate_camera("kannala_brandt", [X] * 4, views, (480, 480), images=[None] * 3)
    with pytest.raises(CalibrationError, match="refine_rounds"):
        calibrate_camera("kannala_brandt", [X] * 4, views, (480, 480), images=[None] * 4, refine_rounds=0)
    # No image at all: the same result as without images, and no refinement report.
    plain = calibrate_camera("kannala_brandt", [X] * 4, views, (480, 480))
    none = calibrate_camera("kannala_brandt", [X] * 4, views, (480, 480), images=[None] * 4)
    assert none.refinement is None and plain.refinement is None
    np.testing.assert_array_equal(none.camera.params, plain.camera.params)


WIDE = ["double_sphere", "equidistant", "eucm", "kannala_brandt", "mei", "scaramuzza"]


@pytest.mark.slow
def test_detector_error_against_angle_off_axis() -> None:
    """Every wide model's renders (13 views each, 4x4 supersampled): SB against the refined
    corners (refined with the true lens), by 15° of angle off axis."""
    bins = np.arange(0, 106, 15)
    raw_e: list[np.ndarray] = []
    raw_r: list[np.ndarray] = []
    ref_e: list[np.ndarray] = []
    ref_r: list[np.ndarray] = []
    ang: list[np.ndarray] = []
    for name in WIDE:
        views = rendered_views(name)
        for image, found, truth, angle in zip(
            views.images, views.detections, views.truth, views.angles, strict=True
        ):
            if found is None:
                continue
            res = refine_corners_local(image, found, views.lens, X)
            ok = res.ok
            for out, pts in (((raw_e, raw_r), found[ok]), ((ref_e, ref_r), res.corners[ok])):
                e, r = radial_errors(views.lens, pts, truth[ok])
                out[0].append(e)
                out[1].append(r)
            ang.append(angle[ok])
    a = np.concatenate(ang)
    table = ["angle°     n   SB RMS  SB radial   refined RMS  refined radial"]
    for lo, hi in itertools.pairwise(bins):
        s = (a >= lo) & (a < hi)
        cells = [rms(np.concatenate(x)[s]) if k % 2 == 0 else float(np.concatenate(x)[s].mean())
                 for k, x in enumerate((raw_e, raw_r, ref_e, ref_r))]  # fmt: skip
        table.append(f"{lo:3d}-{hi:3d} {s.sum():5d}  {cells[0]:.4f}   {cells[1]:+.4f}" + " " * 6
                     + f"{cells[2]:.4f}       {cells[3]:+.4f}")  # fmt: skip
        if s.sum() >= 20:
            assert abs(cells[3]) <= 0.01  # no radial trend left
            if lo >= 60:
                assert cells[1] <= -0.03  # SB's inward pull at the rim
    all_raw, all_ref = np.concatenate(raw_e), np.concatenate(ref_e)
    table.append(
        f"all     {len(a):5d}  SB mean {all_raw.mean():.4f} RMS {rms(all_raw):.4f} max {all_raw.max():.4f};"
        f" refined mean {all_ref.mean():.4f} RMS {rms(all_ref):.4f} max {all_ref.max():.4f}"
    )
    print("\n" + "\n".join(table))
    assert rms(all_ref) <= 0.03 and rms(all_ref) < rms(all_raw) / 3
    # docs/calibration.md's figures: 0.088 px (-0.068 px radial at 75-90°) -> 0.019 px (-0.003 px).
    rim = (a >= 75) & (a < 90)
    assert rms(all_raw) == pytest.approx(0.0883, rel=0.15)
    assert float(np.concatenate(raw_r)[rim].mean()) == pytest.approx(-0.0679, rel=0.15)
    assert rms(all_ref) == pytest.approx(0.0191, rel=0.15)
    assert abs(float(np.concatenate(ref_r)[rim].mean())) <= 0.01
    assert len(all_ref) >= 0.99 * sum(
        len(d) for n in WIDE for d in rendered_views(n).detections if d is not None
    )


@pytest.mark.slow
@pytest.mark.parametrize("side", ["left", "right"])
def test_real_images_refinement_does_not_regress(side: str) -> None:
    """sourishg's real 960x600 fisheye images (JPEG, real blur and light): refinement lowers the
    reprojection error and keeps (nearly) every corner."""
    folder = shared_file("fisheye_stereo_sourishg/imgs")
    paths = sorted(
        glob.glob(str(folder / f"{side}*.jpg")), key=lambda p: int(re.findall(r"(\d+)\.jpg$", p)[0])
    )
    dets = detect_chessboard_files(paths, BOARD)
    obj = board_object_points(*BOARD, 0.02423)
    result = calibrate_camera(
        "kannala_brandt", [obj] * len(dets), [d.corners for d in dets], (960, 600),
        images=[d.source if d.ok else None for d in dets],
    )  # fmt: skip
    report = result.refinement
    assert report is not None
    print(
        f"\n{side}: RMS {report.rms_before:.4f} -> {report.rms_after:.4f} px, {report.rounds} rounds, "
        f"changes {', '.join(f'{c:.2g}' for c in report.changes_px)} px, mean shift "
        f"{report.mean_shift_px:.3f} px, {len(report.rejected)} corners left out"
    )
    assert report.converged and report.rms_after < report.rms_before
    # docs/calibration.md's figures: 0.180 / 0.206 px -> 0.161 / 0.170 px.
    before, after = {"left": (0.1798, 0.1605), "right": (0.2060, 0.1702)}[side]
    assert report.rms_before == pytest.approx(before, rel=0.01)
    assert report.rms_after == pytest.approx(after, rel=0.03)
    n_detected = sum(int(np.isfinite(d.corners).all(axis=1).sum()) for d in dets if d.corners is not None)
    assert report.n_corners >= 0.98 * n_detected
    assert len(result.views) == sum(d.ok for d in dets)
