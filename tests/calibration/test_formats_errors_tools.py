"""Malformed CamOdoCal, OCamCalib and OpenCV FileStorage files: one CalibrationFileError each,
naming the file and the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.calibration.test_formats_samples import (
    CAMODOCAL_KB,
    CAMODOCAL_MEI,
    CAMODOCAL_SCARAMUZZA,
    DELETE,
    OCAMCALIB_TEXT,
    Broken,
    check_broken,
    opencv_fisheye_entries,
    setter,
    storage_file,
    text_file,
)

CASES = [
    # ----- CamOdoCal -----
    Broken(
        "camodocal-model-type",
        storage_file(CAMODOCAL_KB, setter("model_type", "FOV"), "c.yaml"),
        "model_type",
        "unsupported model_type 'FOV'",
    ),
    Broken(
        "camodocal-missing-mu",
        storage_file(CAMODOCAL_KB, setter("projection_parameters.mu", DELETE), "c.yaml"),
        "projection_parameters.mu",
        "missing",
    ),
    Broken(
        "camodocal-mu-text",
        storage_file(CAMODOCAL_KB, setter("projection_parameters.mu", "big"), "c.xml"),
        "projection_parameters.mu",
        "must be a number",
    ),
    Broken(
        "camodocal-no-width",
        storage_file(CAMODOCAL_MEI, setter("image_width", DELETE), "c.yaml"),
        "image_width",
        "missing",
    ),
    Broken(
        "camodocal-no-xi",
        storage_file(CAMODOCAL_MEI, setter("mirror_parameters", DELETE), "c.yaml"),
        "mirror_parameters",
        "missing",
    ),
    Broken(
        "camodocal-ocam-p0",
        storage_file(CAMODOCAL_SCARAMUZZA, setter("poly_parameters.p0", 0.0), "c.yaml"),
        "poly_parameters",
        "p0 must not be zero",
    ),
    # Absurd magnitudes: one clear error, no overflow RuntimeWarning (see the filterwarnings below).
    Broken(
        "camodocal-ocam-cx-huge",
        storage_file(CAMODOCAL_SCARAMUZZA, setter("affine_parameters.cx", 1e200), "c.yaml"),
        "affine_parameters",
        "scaramuzza: distortion centre cx must be within [-1600, 3200]",
    ),
    Broken(
        "camodocal-ocam-width-huge",
        storage_file(CAMODOCAL_SCARAMUZZA, setter("image_width", 1e200), "c.yaml"),
        "image_width",
        "must be at most 100000, got 1e+200",
    ),
    Broken(
        "camodocal-ocam-ad-huge",
        storage_file(CAMODOCAL_SCARAMUZZA, setter("affine_parameters.ad", 1e300), "c.yaml"),
        "affine_parameters",
        "stretch matrix entry d must be within ±10",
    ),
    Broken(
        "camodocal-ocam-p2-huge",  # np.roots of dθ/dρ would overflow
        storage_file(CAMODOCAL_SCARAMUZZA, setter("poly_parameters.p2", 1e300), "c.yaml"),
        "poly_parameters",
        "coefficients from 1.74e-09 to 1e+300 in magnitude are too far apart",
    ),
    Broken(
        "camodocal-ocam-p4-huge",
        storage_file(CAMODOCAL_SCARAMUZZA, setter("poly_parameters.p4", 1e300), "c.yaml"),
        "poly_parameters",
        "poly coefficients are too large",
    ),
    Broken(
        "camodocal-ocam-p0-huge",  # consistent, but sees 1e-296° off axis
        storage_file(CAMODOCAL_SCARAMUZZA, setter("poly_parameters.p0", 1e300), "c.yaml"),
        "poly_parameters",
        "poly leaves a field of only",
    ),
    # ----- OCamCalib -----
    Broken(
        "ocam-count",
        text_file(OCAMCALIB_TEXT.replace("\n5 -3.25", "\n6 -3.25")),
        "pol",
        "declares 6 coefficients but lists 5",
    ),
    Broken("ocam-truncated", text_file(OCAMCALIB_TEXT.split("#affine")[0]), "affine", "the file ends early"),
    Broken("ocam-extra", text_file(OCAMCALIB_TEXT + "\n1 2 3\n"), None, "unexpected extra line"),
    Broken(
        "ocam-token",
        text_file(OCAMCALIB_TEXT.replace("1.001968", "1.00x968")),
        "affine",
        "'1.00x968' is not a finite number",
    ),
    Broken(
        "ocam-nan", text_file(OCAMCALIB_TEXT.replace("159.672870", "nan")), "invpol", "not a finite number"
    ),
    Broken(
        "ocam-size", text_file(OCAMCALIB_TEXT.replace("480 640", "480")), "image size", "expected 2 numbers"
    ),
    Broken(
        "ocam-center-huge",
        text_file(OCAMCALIB_TEXT.replace("261.744395 326.939156", "1e200 326.939156")),
        "center",
        "distortion centre cy must be within [-480, 960]",
    ),
    Broken(
        "ocam-affine-tiny",  # c ** -3 of the conversion overflows
        text_file(OCAMCALIB_TEXT.replace("1.001968 0.001400", "1e-300 0.001400")),
        "affine",
        "affine c = 1e-300 is out of range",
    ),
    Broken(
        "ocam-size-huge",
        text_file(OCAMCALIB_TEXT.replace("480 640", "480 1e200")),
        "image size",
        "height and width must be at most 100000",
    ),
    Broken(
        "ocam-affine-zero",
        text_file(OCAMCALIB_TEXT.replace("1.001968 0.001400", "0 0.001400")),
        None,
        "affine c must not be zero",
    ),
    # ----- OpenCV FileStorage -----
    Broken(
        "opencv-K-2x2",
        storage_file(opencv_fisheye_entries(), setter("K", np.eye(2)), "k.yaml"),
        "K",
        "must be a 3x3 matrix, got 2x2",
    ),
    Broken(
        "opencv-K-nan",
        storage_file(opencv_fisheye_entries(), setter("K", np.full((3, 3), np.nan)), "k.xml"),
        "K",
        "finite numbers only",
    ),
    Broken(
        "opencv-D-3",
        storage_file(opencv_fisheye_entries(), setter("D", np.zeros((1, 3))), "k.yaml"),
        "D",
        "3 coefficients",
    ),
    Broken(
        "opencv-no-size",
        storage_file(opencv_fisheye_entries(), setter("image_width", DELETE), "k.yaml"),
        "image_width",
        "missing",
    ),
    Broken(
        "opencv-xi-text",
        storage_file(opencv_fisheye_entries(), setter("xi", "one"), "k.yaml"),
        "xi",
        "must be a number",
    ),
    Broken(
        "opencv-k3",
        storage_file(opencv_fisheye_entries(), setter("D", np.array([[0.1, 0.01, 0, 0, 0.5]])), "k.yaml"),
        "D",
        "higher-order coefficients [0.5] are not supported",
    ),
    Broken(
        "opencv-stereo-no-T",
        storage_file(
            {
                "K1": np.eye(3),
                "D1": np.zeros(4),
                "K2": np.eye(3),
                "D2": np.zeros(4),
                "R": np.eye(3),
                "imageSize": np.array([64, 48]),
            },
            lambda d: None,
            "s.yaml",
        ),
        "T",
        "missing",
        "rig",
    ),
    Broken(
        "opencv-stereo-R",
        storage_file(
            {
                "K1": np.eye(3),
                "D1": np.zeros(4),
                "K2": np.eye(3),
                "D2": np.zeros(4),
                "R": np.ones((3, 3)),
                "T": np.zeros(3),
                "imageSize": np.array([64, 48]),
            },
            lambda d: None,
            "s.yaml",
        ),
        "R",
        "not a proper rotation",
        "rig",
    ),
]


@pytest.mark.filterwarnings("error::RuntimeWarning")  # a user sees the error line and nothing else
@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_malformed_file_raises_one_clear_error(tmp_path: Path, case: Broken) -> None:
    check_broken(tmp_path, case)
