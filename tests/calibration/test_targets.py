"""Calibration targets: board geometry, chessboard detection, FileStorage corner lists."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.errors import CalibrationError, CalibrationFileError
from calibration.models import create
from calibration.targets import (
    BoardSpec,
    board_object_points,
    detect_chessboard,
    detect_chessboard_files,
    parse_board,
    read_corner_lists,
    read_omnidir_corners,
)
from rig.sim import chessboard_corners
from tests.conftest import shared_file
from tests.helpers.boards import BOARD, board_pose, render_board, true_corners

JY = "opencv_fisheye_calib3_stereo_JY"


def test_board_points_match_the_renderer_and_opencv_order() -> None:
    # Independent reference: the renderer's own corner layout (row-major, x fastest).
    np.testing.assert_array_equal(board_object_points(9, 6, 0.025), chessboard_corners(9, 6, 0.025))
    pts = board_object_points(4, 3, 0.5)
    assert pts.shape == (12, 3)
    np.testing.assert_array_equal(pts[:5], [[0, 0, 0], [0.5, 0, 0], [1.0, 0, 0], [1.5, 0, 0], [0, 0.5, 0]])


@pytest.mark.parametrize(("text", "expected"), [("9x6", (9, 6)), ("8X5", (8, 5)), ("7×4", (7, 4))])
def test_parse_board(text: str, expected: tuple[int, int]) -> None:
    spec = parse_board(text, 0.03)
    assert spec.pattern_size == expected
    assert spec.object_points().shape == (expected[0] * expected[1], 3)


@pytest.mark.parametrize("text", ["9", "9x", "axb", "9x6x2", ""])
def test_parse_board_rejects_malformed(text: str) -> None:
    with pytest.raises(CalibrationError, match="COLSxROWS"):
        parse_board(text, 0.03)


@pytest.mark.parametrize(("cols", "rows", "square"), [(1, 6, 0.03), (9, 6, 0.0), (9, 6, -1.0)])
def test_board_spec_rejects_bad_geometry(cols: int, rows: int, square: float) -> None:
    with pytest.raises(CalibrationError):
        BoardSpec(cols, rows, square)


def _pinhole():  # type: ignore[no-untyped-def]
    return create("pinhole", 480, 480, fx=300.0, fy=300.0, cx=239.5, cy=239.5)


def test_detects_rendered_board_at_true_corners() -> None:
    camera = _pinhole()
    T = board_pose(0, 0, 0.7, (20, 10), 15)
    image = render_board(camera, T)
    truth, _ = true_corners(camera, T)
    for window in (None, 3):
        corners = detect_chessboard(image, BOARD, subpix_window=window)
        assert corners is not None
        err = np.linalg.norm(corners - truth, axis=1)
        # Rendered with exact geometry: the detector is accurate to a small fraction of a pixel.
        assert np.sqrt(np.mean(err**2)) < 0.15
        assert err.max() < 0.4
    colour = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    np.testing.assert_allclose(detect_chessboard(colour, BOARD), detect_chessboard(image, BOARD))


def test_no_board_gives_none() -> None:
    assert detect_chessboard(np.full((200, 300), 128, np.uint8), (9, 6)) is None


def test_detect_files_lists_bad_images(tmp_path: Path) -> None:
    camera = _pinhole()
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), render_board(camera, board_pose(0, 0, 0.7, (15, 0))))
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 480), 100, np.uint8))
    corrupt = tmp_path / "corrupt.jpg"
    corrupt.write_bytes(b"\xff\xd8 not really a jpeg")
    seen: list[str] = []
    dets = detect_chessboard_files([good, blank, corrupt, tmp_path / "missing.png"], BOARD, seen.append)  # type: ignore[arg-type]
    assert [d.ok for d in dets] == [True, False, False, False]
    assert (
        dets[0].image_size == (480, 480) and dets[0].corners is not None and dets[0].corners.shape == (54, 2)
    )
    assert "no 9x6 board" in (dets[1].reason or "")
    assert "cannot be read" in (dets[2].reason or "") and "cannot be read" in (dets[3].reason or "")
    assert len(seen) == 4


def test_reads_opencv_fisheye_corner_lists() -> None:
    left = read_corner_lists(shared_file(f"{JY}/left.xml"), 2)
    obj = read_corner_lists(shared_file(f"{JY}/object.xml"), 3)
    assert len(left) == len(obj) == 34
    assert all(v.shape == (48, 2) for v in left) and all(v.shape == (48, 3) for v in obj)
    # object.xml is an 8 x 6 grid of 0.0244 m squares, x fastest (SOURCE.md).
    np.testing.assert_allclose(obj[0], board_object_points(8, 6, 0.0244), atol=1e-7)
    # First numbers of left.xml as printed in the file.
    np.testing.assert_allclose(left[0][0], [537.51831054687500, 378.58633422851562])
    assert (left[0] > 0).all() and (left[0][:, 0] < 1280).all() and (left[0][:, 1] < 800).all()


def test_reads_omnidir_corner_data() -> None:
    mono = read_omnidir_corners(shared_file("opencv_contrib_omnidir/omni_calib_data.xml"))
    assert mono.image_sizes == {"imagePoints": (1280, 960)}
    assert len(mono.object_points) == 15 and mono.object_points[0].shape == (54, 3)
    assert all(p.shape == (54, 2) for p in mono.image_points["imagePoints"])
    stereo = read_omnidir_corners(shared_file("opencv_contrib_omnidir/omni_stereocalib_data.xml"))
    assert set(stereo.image_points) == {"imagePoints1", "imagePoints2"}
    assert stereo.image_sizes["imagePoints2"] == (704, 576)
    assert len(stereo.object_points) == 39 and len(stereo.image_points["imagePoints2"]) == 39


def test_corner_list_errors_name_file_and_field(tmp_path: Path) -> None:
    with pytest.raises(CalibrationFileError, match="file not found"):
        read_corner_lists(tmp_path / "nope.xml", 2)
    junk = tmp_path / "junk.xml"
    junk.write_text("this is not FileStorage")
    with pytest.raises(CalibrationFileError, match=r"junk\.xml"):
        read_corner_lists(junk, 2)
    odd = tmp_path / "odd.xml"
    odd.write_text(
        '<?xml version="1.0"?>\n<opencv_storage>\n<image_0>\n  1. 2. 3.</image_0>\n</opencv_storage>\n'
    )
    with pytest.raises(CalibrationFileError, match=r"odd\.xml: field 'image_0': expected a multiple of 2"):
        read_corner_lists(odd, 2)
    empty = tmp_path / "empty.xml"
    empty.write_text('<?xml version="1.0"?>\n<opencv_storage>\n<other>1</other>\n</opencv_storage>\n')
    with pytest.raises(CalibrationFileError, match="no views"):
        read_corner_lists(empty, 2)
    with pytest.raises(CalibrationFileError, match="field 'objectPoints'"):
        read_omnidir_corners(empty)
