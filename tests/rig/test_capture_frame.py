"""Frames: structural checks and the lazy, decode-once image, against cv2.imdecode."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rig.capture.faults import FaultPlan, parse_fault
from rig.capture.frame import Frame, FramePair, encoded_problem, format_of_path
from rig.errors import CorruptFrameError
from tests.helpers.recordings import encode, frame_image


def decodes(data: bytes) -> bool:
    return bool(data) and cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) is not None


@pytest.mark.parametrize("ext,fmt", [(".jpg", "jpeg"), (".png", "png")])
def test_valid_frames_pass_and_damaged_ones_are_caught(ext: str, fmt: str) -> None:
    data = encode(frame_image("left", 3), ext)
    assert encoded_problem(data, fmt) is None  # type: ignore[arg-type]
    for bad in (data[: len(data) // 2], data[:-1], b"", bytes(200)):
        assert encoded_problem(bad, fmt) is not None  # type: ignore[arg-type]
        assert not decodes(bad)  # the check agrees with OpenCV's decoder


def test_jpeg_zero_padding_after_eoi_is_accepted() -> None:
    # Some UVC cameras pad MJPEG buffers with zeros after EOI; OpenCV decodes those fine.
    data = encode(frame_image("left", 1), ".jpg") + bytes(64)
    assert encoded_problem(data, "jpeg") is None
    assert decodes(data)


def test_image_is_decoded_once_and_matches_opencv() -> None:
    data = encode(frame_image("right", 5), ".png")
    f = Frame("right", 5, 123, "png", host_ns=0, raw=data)
    assert not f.decoded
    img = f.image
    assert f.decoded and f.image is img
    np.testing.assert_array_equal(img, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED))
    assert f.extension == ".png"


def imdecode(data: bytes, flags: int) -> np.ndarray:
    return np.asarray(cv2.imdecode(np.frombuffer(data, np.uint8), flags))


@pytest.mark.parametrize("ext,fmt", [(".jpg", "jpeg"), (".png", "png")])
@pytest.mark.parametrize("colour_first", [False, True])
def test_gray_is_the_luma_decode_whatever_was_decoded_before(ext: str, fmt: str, colour_first: bool) -> None:
    data = encode(frame_image("left", 7), ext)
    f = Frame("left", 7, 0, fmt, host_ns=0, raw=data)  # type: ignore[arg-type]
    if colour_first:
        assert f.image.ndim == 3
    gray = f.gray
    assert f.decoded and f.gray is gray and gray.dtype == np.uint8
    # OpenCV's gray decode (for JPEG the coded Y component, not a BGR → gray of the colour image).
    np.testing.assert_array_equal(gray, imdecode(data, cv2.IMREAD_GRAYSCALE))
    assert f.image.ndim == 3  # the colour image stays available, decoded on its own
    if fmt == "jpeg":
        # Close to the colour image's conversion (which goes through upsampled chroma and
        # clipped RGB, so it differs most at saturated colour edges), but not computed from it.
        diff = np.abs(gray.astype(int) - cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY).astype(int))
        assert diff.mean() < 1.0 and np.percentile(diff, 99) <= 6 and diff.any()


def test_gray_of_a_gray_jpeg_is_its_image() -> None:
    data = encode(cv2.cvtColor(frame_image("right", 2), cv2.COLOR_BGR2GRAY), ".jpg")
    f = Frame("right", 2, 0, "jpeg", host_ns=0, raw=data)
    np.testing.assert_array_equal(f.gray, f.image)


def test_gray_of_a_decoded_frame_is_opencvs_conversion() -> None:
    img = frame_image("left", 4)
    f = Frame.from_image("left", 4, 0, img, host_ns=0)
    np.testing.assert_array_equal(f.gray, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    flat = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    assert Frame.from_image("left", 5, 0, flat, host_ns=0).gray is flat


def test_corrupt_frame_raises_for_gray_too() -> None:
    data = encode(frame_image("left", 9), ".jpg")
    f = Frame("left", 9, 0, "jpeg", host_ns=0, raw=data[: len(data) // 2], source="x/000009.jpg")
    for view in ("gray", "image", "gray"):
        with pytest.raises(CorruptFrameError, match=r"camera left: frame 9 \(x/000009.jpg\): JPEG truncated"):
            getattr(f, view)
    assert not f.decoded


def test_corrupt_frame_raises_every_time_naming_camera_and_seq() -> None:
    data = encode(frame_image("left", 9), ".jpg")
    plan = FaultPlan()
    plan.inject(parse_fault({"kind": "corrupt"}), 0)
    mangled, what = plan.mangle(data)
    assert what == "corrupt" and len(mangled) == len(data) and mangled[:2] == data[:2]
    assert not decodes(mangled)
    f = Frame("left", 9, 0, "jpeg", host_ns=0, raw=mangled, source="x/000009.jpg")
    for _ in range(2):
        with pytest.raises(CorruptFrameError, match=r"camera left: frame 9 \(x/000009.jpg\)"):
            _ = f.image
    with pytest.raises(CorruptFrameError):
        f.check_structure()


def test_bgr_frames_carry_their_image_and_no_bytes() -> None:
    img = frame_image("left", 0)
    f = Frame.from_image("left", 0, 10, img, host_ns=11)
    assert f.image is img and f.raw is None and f.extension is None
    f.check_structure()  # nothing to check, no error
    with pytest.raises(ValueError):
        Frame("left", 0, 0, "jpeg", host_ns=0)


def test_pair_properties() -> None:
    a = Frame("left", 4, 1_000, "jpeg", 0, raw=b"x")
    b = Frame("right", 4, 1_300, "jpeg", 0, raw=b"y")
    p = FramePair(a, b)
    assert (p.seq, p.ts_ns, p.skew_ns) == (4, 1_000, -300)


def test_format_of_path() -> None:
    assert format_of_path("left/000001.JPG") == "jpeg"
    assert format_of_path("a.png") == "png"
    with pytest.raises(CorruptFrameError, match="unsupported"):
        format_of_path("a.bmp")
