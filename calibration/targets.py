"""Calibration targets: chessboard geometry, chessboard detection in images, and corner lists
stored in OpenCV FileStorage XML (OpenCV's fisheye test set, the omnidir tutorial data).

Detected corners are what ``cv2.findChessboardCornersSB`` finds; on a fisheye they are biased
(~0.1 px, pulled inwards near the rim), which :mod:`calibration.corner_refine` removes with the
lens model once a first calibration exists (``calibrate_camera(..., images=...)``).

Shapes: object points (N, 3) float64 in the board frame (z = 0 for planar boards), image points
(N, 2) float64 pixels (u, v) with (0, 0) the centre of the top-left pixel (OpenCV's convention
for detected corners too).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.errors import CalibrationError, CalibrationFileError

__all__ = [
    "BoardSpec",
    "Detection",
    "OmnidirCorners",
    "board_object_points",
    "detect_chessboard",
    "detect_chessboard_files",
    "parse_board",
    "read_corner_lists",
    "read_omnidir_corners",
]

F64 = NDArray[np.float64]

# SB copes with strong fisheye distortion at the image edge; ACCURACY refines corners to ~0.02 px.
SB_FLAGS = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-5)


def board_object_points(cols: int, rows: int, square_m: float) -> F64:
    """Inner corners of a ``cols x rows`` chessboard, (cols*rows, 3), x fastest, z = 0.

    The order matches ``cv2.findChessboardCornersSB``'s output: row by row, ``cols`` per row.
    """
    if cols < 2 or rows < 2:
        raise CalibrationError(f"a chessboard needs at least 2x2 inner corners, got {cols}x{rows}")
    if not square_m > 0:
        raise CalibrationError(f"chessboard square size must be positive, got {square_m}")
    ii, jj = np.meshgrid(np.arange(cols), np.arange(rows))
    pts = np.zeros((rows * cols, 3))
    pts[:, 0] = ii.ravel() * square_m
    pts[:, 1] = jj.ravel() * square_m
    return pts


@dataclass(frozen=True)
class BoardSpec:
    """A chessboard with ``cols x rows`` inner corners and squares of ``square_m`` metres."""

    cols: int
    rows: int
    square_m: float

    def __post_init__(self) -> None:
        board_object_points(self.cols, self.rows, self.square_m)  # validates

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> F64:
        return board_object_points(self.cols, self.rows, self.square_m)


def parse_board(text: str, square_m: float) -> BoardSpec:
    """``"9x6"`` (inner corners, columns x rows) -> BoardSpec; CalibrationError when malformed."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError as err:
        raise CalibrationError(f"board must be COLSxROWS inner corners such as 9x6, got {text!r}") from err
    return BoardSpec(cols, rows, float(square_m))


def detect_chessboard(
    image: NDArray[np.generic], pattern_size: tuple[int, int], subpix_window: int | None = None
) -> F64 | None:
    """Inner corners (cols*rows, 2) of a chessboard in a grey or BGR image, or None if not found.

    ``subpix_window`` (half-size, px): re-refine the corners with ``cv2.cornerSubPix``. SB's own
    refinement scatters less but, where a fisheye squeezes squares near the rim, pulls corners
    inwards by up to ~0.1 px; the gradient-based refinement stays unbiased under such local
    affine squeeze. The window is capped below half the smallest corner spacing.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        # SB wants 8-bit; scale 16-bit/float renders to the full range.
        lo, hi = float(np.min(img)), float(np.max(img))
        img = np.clip((img.astype(np.float64) - lo) * (255.0 / max(hi - lo, 1e-12)), 0, 255).astype(np.uint8)
    grey = img if img.ndim == 2 else np.asarray(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    found, corners = cv2.findChessboardCornersSB(grey, pattern_size, flags=SB_FLAGS)
    if not found or corners is None:
        return None
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if subpix_window:
        grid = pts.reshape(pattern_size[1], pattern_size[0], 2)
        spacing = min(
            float(np.linalg.norm(np.diff(grid, axis=0), axis=2).min()),
            float(np.linalg.norm(np.diff(grid, axis=1), axis=2).min()),
        )
        win = min(int(subpix_window), int(spacing / 2) - 1)
        if win >= 1:
            refined = cv2.cornerSubPix(
                grey, pts.astype(np.float32).reshape(-1, 1, 2), (win, win), (-1, -1), _SUBPIX_CRITERIA
            )
            pts = np.asarray(refined, dtype=np.float64).reshape(-1, 2)
    return pts


@dataclass(frozen=True)
class Detection:
    """Result of looking for the board in one image file: corners, or the reason there are none."""

    source: str
    corners: F64 | None
    image_size: tuple[int, int] | None  # (width, height)
    reason: str | None = None

    @property
    def ok(self) -> bool:
        return self.corners is not None


def detect_chessboard_files(
    paths: Iterable[str | Path],
    pattern_size: tuple[int, int],
    on_image: Callable[[Detection], None] | None = None,
    subpix_window: int | None = None,
) -> list[Detection]:
    """Detect the board in every file; unreadable files and missing boards become a Detection
    with a reason (never an exception). ``on_image`` is called after each file (progress)."""
    out: list[Detection] = []
    for p in paths:
        path = str(p)
        image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if image is None:
            det = Detection(path, None, None, "cannot be read as an image")
        else:
            size = (int(image.shape[1]), int(image.shape[0]))
            corners = detect_chessboard(image, pattern_size, subpix_window)
            reason = None if corners is not None else f"no {pattern_size[0]}x{pattern_size[1]} board found"
            det = Detection(path, corners, size, reason)
        out.append(det)
        if on_image is not None:
            on_image(det)
    return out


# ----- OpenCV FileStorage corner lists ---------------------------------------------------------


def _open_storage(path: str | Path) -> cv2.FileStorage:
    p = Path(path)
    if not p.is_file():
        raise CalibrationFileError(p, "file not found")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as err:  # the Python binding wraps parse errors in SystemError
        raise CalibrationFileError(p, "not an OpenCV FileStorage file (XML/YAML/JSON)") from err
    if not fs.isOpened():
        raise CalibrationFileError(p, "not an OpenCV FileStorage file")
    return fs


def _node_array(node: cv2.FileNode, path: Path, field: str, width: int) -> F64:
    """A matrix node or a plain sequence of numbers -> (N, width) float64."""
    if node.isSeq():
        # Plain sequences (OpenCV's fisheye test XML) cannot be read with node.mat().
        vals = np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
    else:
        mat = node.mat()
        if mat is None:
            raise CalibrationFileError(path, "expected a matrix or a sequence of numbers", field)
        vals = np.asarray(mat, dtype=np.float64).ravel()
    if vals.size == 0 or vals.size % width:
        raise CalibrationFileError(path, f"expected a multiple of {width} numbers, got {vals.size}", field)
    if not np.isfinite(vals).all():
        raise CalibrationFileError(path, "contains non-finite numbers", field)
    return vals.reshape(-1, width)


def read_corner_lists(path: str | Path, width: int, prefix: str = "image_") -> list[F64]:
    """Per-view arrays from keys ``image_0, image_1, ...`` (OpenCV's fisheye test layout:
    ``left.xml``/``right.xml`` with ``width=2``, ``object.xml`` with ``width=3``)."""
    p = Path(path)
    fs = _open_storage(p)
    try:
        views: list[F64] = []
        while True:
            node = fs.getNode(f"{prefix}{len(views)}")
            if node.empty():
                break
            views.append(_node_array(node, p, f"{prefix}{len(views)}", width))
    finally:
        fs.release()
    if not views:
        raise CalibrationFileError(p, f"no views (keys {prefix}0, {prefix}1, ...)", f"{prefix}0")
    return views


@dataclass(frozen=True)
class OmnidirCorners:
    """Corner data as ``cv::omnidir`` tutorials store it: shared object points, one or two cameras."""

    object_points: list[F64]
    image_points: dict[str, list[F64]]  # key in the file ("imagePoints", "imagePoints1", ...)
    image_sizes: dict[str, tuple[int, int]]  # same keys -> (width, height)


def read_omnidir_corners(path: str | Path) -> OmnidirCorners:
    """Read ``objectPoints`` and ``imagePoints`` / ``imagePoints1`` + ``imagePoints2`` (sequences
    of matrices, one per view) and ``imageSize`` / ``imageSize1`` / ``imageSize2``."""
    p = Path(path)
    fs = _open_storage(p)
    try:
        obj = _read_view_sequence(fs, p, "objectPoints", 3)
        images: dict[str, list[F64]] = {}
        sizes: dict[str, tuple[int, int]] = {}
        for key, size_key in (
            ("imagePoints", "imageSize"),
            ("imagePoints1", "imageSize1"),
            ("imagePoints2", "imageSize2"),
        ):
            if fs.getNode(key).empty():
                continue
            views = _read_view_sequence(fs, p, key, 2)
            if len(views) != len(obj):
                raise CalibrationFileError(p, f"{len(views)} views but {len(obj)} in objectPoints", key)
            for i, (o, im) in enumerate(zip(obj, views, strict=True)):
                if len(o) != len(im):
                    raise CalibrationFileError(
                        p, f"view {i}: {len(im)} points but {len(o)} object points", key
                    )
            images[key] = views
            size = (
                _node_array(fs.getNode(size_key), p, size_key, 2)
                if not fs.getNode(size_key).empty()
                else None
            )
            if size is None:
                raise CalibrationFileError(p, "missing image size", size_key)
            sizes[key] = (int(size[0, 0]), int(size[0, 1]))
    finally:
        fs.release()
    if not images:
        raise CalibrationFileError(p, "no image points (imagePoints or imagePoints1/2)", "imagePoints")
    return OmnidirCorners(obj, images, sizes)


def _read_view_sequence(fs: cv2.FileStorage, path: Path, key: str, width: int) -> list[F64]:
    node = fs.getNode(key)
    if node.empty():
        raise CalibrationFileError(path, "missing", key)
    if not node.isSeq():
        return [_node_array(node, path, key, width)]
    return [_node_array(node.at(i), path, f"{key}[{i}]", width) for i in range(node.size())]
