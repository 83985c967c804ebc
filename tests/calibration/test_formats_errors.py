"""Malformed files (any file, rig.yaml, Kalibr, basalt): each broken variant raises one
CalibrationFileError naming the file and the field (test_formats_errors_tools.py: the others)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration import CalibrationFileError, detect_format, load_camera, load_rig
from tests.calibration.test_formats_samples import (
    CAMODOCAL_KB,
    DELETE,
    NAN,
    OCAMCALIB_TEXT,
    ROT_SCALED,
    Broken,
    check_broken,
    json_file,
    kalibr_doc,
    rig_doc,
    setter,
    storage_file,
    text_file,
    yaml_file,
)

CASES = [
    # ----- any file -----
    Broken("missing-file", lambda tmp: tmp / "nope.yaml", None, "file not found"),
    Broken("directory", lambda tmp: tmp, None, "is a directory"),
    Broken("empty", text_file(""), None, "file is empty"),
    Broken("whitespace", text_file("  \n\n\t\n"), None, "file is empty"),
    Broken("binary-junk", text_file(bytes(range(256)) * 4, "calib.yaml"), None, "binary content"),
    Broken("latin1", text_file(b"cameras: {caf\xe9: 1}\n", "calib.yaml"), None, "not UTF-8"),
    Broken("bad-yaml", text_file("cameras: [1, 2\n  left: {", "calib.yaml"), None, "not valid YAML"),
    Broken("bad-json", text_file('{"value0": {"intrinsics": [', "calib.json"), None, "not valid JSON"),
    Broken(
        "bad-xml",
        text_file("<?xml version='1.0'?>\n<opencv_storage><K>1</opencv", "c.xml"),
        None,
        "not valid OpenCV FileStorage XML",
    ),
    Broken(
        "yaml-list", text_file("- 1\n- 2\n", "calib.yaml"), None, "not a calibration file of a known format"
    ),
    Broken(
        "yaml-scalar", text_file("hello world\n", "calib.yaml"), None, "not a calibration file of a known"
    ),
    Broken("unrelated-json", text_file('{"name": "x"}', "calib.json"), None, "known format"),
    # ----- rig.yaml -----
    Broken(
        "rig-fx-text",
        yaml_file(rig_doc, setter("cameras.left.params.fx", "abc")),
        "cameras.left.params.fx",
        "must be a number, got text 'abc'",
    ),
    Broken(
        "rig-fx-nan",
        yaml_file(rig_doc, setter("cameras.left.params.fx", NAN)),
        "cameras.left.params.fx",
        "must be finite",
    ),
    Broken(
        "rig-fx-bool",
        yaml_file(rig_doc, setter("cameras.left.params.fx", True)),
        "cameras.left.params.fx",
        "must be a number, got a boolean",
    ),
    Broken(
        "rig-fx-negative",
        yaml_file(rig_doc, setter("cameras.left.params.fx", -5.0)),
        "cameras.left.params",
        "fx and fy must be positive",
    ),
    Broken(
        "rig-missing-fy",
        yaml_file(rig_doc, setter("cameras.right.params.fy", DELETE)),
        "cameras.right.params.fy",
        "missing",
    ),
    Broken(
        "rig-unknown-param",
        yaml_file(rig_doc, setter("cameras.left.params.k9", 0.1)),
        "cameras.left.params.k9",
        "unknown parameter of model 'kannala_brandt'",
    ),
    Broken(
        "rig-params-list",
        yaml_file(rig_doc, setter("cameras.left.params", [1, 2])),
        "cameras.left.params",
        "must be a mapping",
    ),
    Broken(
        "rig-unknown-model",
        yaml_file(rig_doc, setter("cameras.left.model", "fishy")),
        "cameras.left.model",
        "unknown camera model 'fishy'",
    ),
    Broken(
        "rig-missing-model",
        yaml_file(rig_doc, setter("cameras.left.model", DELETE)),
        "cameras.left.model",
        "missing",
    ),
    Broken(
        "rig-width-negative",
        yaml_file(rig_doc, setter("cameras.left.width", -640)),
        "cameras.left.width",
        "must be at least 1",
    ),
    Broken(
        "rig-width-fraction",
        yaml_file(rig_doc, setter("cameras.left.width", 640.5)),
        "cameras.left.width",
        "must be an integer",
    ),
    Broken(
        "rig-width-huge",
        yaml_file(rig_doc, setter("cameras.left.width", 10**400)),
        "cameras.left.width",
        "must be finite",
    ),
    Broken(
        "rig-width-1e200",  # finite, but no image is that large (MAX_IMAGE_SIZE_PX)
        yaml_file(rig_doc, setter("cameras.left.width", 1e200)),
        "cameras.left.width",
        "must be at most 100000, got 1e+200",
    ),
    Broken(
        "rig-list-for-scalar",
        yaml_file(rig_doc, setter("cameras.left.params.cx", [1.0, 2.0])),
        "cameras.left.params.cx",
        "must be a number, got a list of 2",
    ),
    Broken(
        "rig-T-3x4",
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam", np.eye(4)[:3].tolist())),
        "cameras.right.T_rig_cam",
        "must be a 4x4 matrix, got 3x4",
    ),
    Broken(
        "rig-T-ragged",
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam.1", [0.0, 1.0])),
        "cameras.right.T_rig_cam",
        "rows must all have the same length",
    ),
    Broken(
        "rig-T-not-rigid",
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam", ROT_SCALED)),
        "cameras.right.T_rig_cam",
        "not a proper rotation",
    ),
    Broken(
        "rig-T-rotation-huge",  # R Rᵀ would overflow: still one clear error, no warning
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam.0.1", 1e200)),
        "cameras.right.T_rig_cam",
        "not a proper rotation",
    ),
    Broken(
        "rig-T-translation-huge",  # the baseline's norm would overflow: one clear error, no warning
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam.0.3", 1e200)),
        "cameras.right.T_rig_cam",
        "translation [1e+200, 0.0, 0.0] is beyond ±1e+06",
    ),
    Broken(
        "rig-T-nan",
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam.0.3", NAN)),
        "cameras.right.T_rig_cam[0][3]",
        "must be finite, got nan",
    ),
    Broken(
        "rig-T-text",
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam.2.1", "x")),
        "cameras.right.T_rig_cam[2][1]",
        "must be a number",
    ),
    Broken(
        "rig-T-missing",
        yaml_file(rig_doc, setter("cameras.right.T_rig_cam", DELETE)),
        "cameras.right.T_rig_cam",
        "missing",
    ),
    Broken("rig-version", yaml_file(rig_doc, setter("version", 2)), "version", "unsupported version 2"),
    Broken("rig-no-cameras", yaml_file(rig_doc, setter("cameras", {})), "cameras", "at least one camera"),
    Broken(
        "rig-camera-null",
        yaml_file(rig_doc, setter("cameras.left", None)),
        "cameras.left",
        "must be a mapping",
    ),
    # ----- Kalibr -----
    Broken(
        "kalibr-intrinsics-short",
        yaml_file(kalibr_doc, setter("cam0.intrinsics", [1.0, 2.0, 3.0])),
        "cam0.intrinsics",
        "must have 4 entries, got 3",
    ),
    Broken(
        "kalibr-intrinsic-text",
        yaml_file(kalibr_doc, setter("cam0.intrinsics.2", "cx")),
        "cam0.intrinsics[2]",
        "must be a number",
    ),
    Broken(
        "kalibr-intrinsic-nan",
        yaml_file(kalibr_doc, setter("cam0.intrinsics.0", NAN)),
        "cam0.intrinsics[0]",
        "must be finite",
    ),
    Broken(
        "kalibr-camera-model",
        yaml_file(kalibr_doc, setter("cam0.camera_model", "fisheye624")),
        "cam0.camera_model",
        "unsupported camera_model 'fisheye624'",
    ),
    Broken(
        "kalibr-fov",
        yaml_file(kalibr_doc, setter("cam1.distortion_model", "fov")),
        "cam1.distortion_model",
        "'fov' with camera_model 'pinhole' is not supported",
    ),
    Broken(
        "kalibr-coeffs-short",
        yaml_file(kalibr_doc, setter("cam0.distortion_coeffs", [0.1, 0.2, 0.3])),
        "cam0.distortion_coeffs",
        "needs 4 distortion_coeffs, got 3",
    ),
    Broken(
        "kalibr-resolution",
        yaml_file(kalibr_doc, setter("cam0.resolution", [640])),
        "cam0.resolution",
        "must have 2 entries",
    ),
    Broken("kalibr-no-cam0", yaml_file(kalibr_doc, setter("cam0", DELETE)), "cam0", "missing"),
    Broken(
        "kalibr-fx-negative",
        yaml_file(kalibr_doc, setter("cam0.intrinsics.0", -190.0)),
        "cam0",
        "fx and fy must be positive",
    ),
    Broken(
        "kalibr-T-2x2",
        yaml_file(kalibr_doc, setter("cam1.T_cn_cnm1", [[1, 0], [0, 1]])),
        "cam1.T_cn_cnm1",
        "must be a 4x4 matrix",
        "rig",
    ),
    Broken(
        "kalibr-T-last-row",
        yaml_file(kalibr_doc, setter("cam1.T_cn_cnm1.3", [0, 0, 1, 1])),
        "cam1.T_cn_cnm1",
        "last row must be [0, 0, 0, 1]",
        "rig",
    ),
    Broken(
        "kalibr-T-translation-huge",
        yaml_file(kalibr_doc, setter("cam1.T_cn_cnm1.0.3", 1e200)),
        "cam1.T_cn_cnm1",
        "translation [1e+200,",
        "rig",
    ),
    # ----- basalt -----
    Broken(
        "basalt-camera-type",
        json_file(setter("value0.intrinsics.1.camera_type", "fov")),
        "value0.intrinsics[1].camera_type",
        "unsupported camera_type 'fov'",
    ),
    Broken(
        "basalt-missing-fx",
        json_file(setter("value0.intrinsics.0.intrinsics.fx", DELETE)),
        "value0.intrinsics[0].intrinsics.fx",
        "missing",
    ),
    Broken(
        "basalt-resolution-count",
        json_file(setter("value0.resolution", [[512, 512]])),
        "value0.resolution",
        "must have 2 entries, got 1",
    ),
    Broken(
        "basalt-quaternion",
        json_file(setter("value0.T_imu_cam.1.qw", 3.0)),
        "value0.T_imu_cam[1]",
        "unit length",
        "rig",
    ),
    Broken(
        "basalt-translation-huge",  # the relative pose's baseline would overflow
        json_file(setter("value0.T_imu_cam.1.px", 1e200)),
        None,
        "not a usable rig: T_right_left: translation [4.70963e+199,",
        "rig",
    ),
    Broken(
        "basalt-quaternion-huge",  # its squares overflow float64: still one clear error, no warning
        json_file(setter("value0.T_imu_cam.1.qx", 1e200)),
        "value0.T_imu_cam[1]",
        "unit length, got |q| = 1e+200",
        "rig",
    ),
    Broken(
        "basalt-px-text",
        json_file(setter("value0.T_imu_cam.0.px", "0.1")),
        "value0.T_imu_cam[0].px",
        "must be a number, got text",
        "rig",
    ),
    Broken(
        "basalt-ucm-alpha",
        json_file(setter("value0.intrinsics.1.intrinsics.alpha", 1.0)),
        "value0.intrinsics[1].intrinsics",
        "ucm alpha must be in [0, 1)",
        "rig",
    ),
]


@pytest.mark.filterwarnings("error::RuntimeWarning")  # a user sees the error line and nothing else
@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_malformed_file_raises_one_clear_error(tmp_path: Path, case: Broken) -> None:
    check_broken(tmp_path, case)


def test_single_camera_formats_refuse_load_rig(tmp_path: Path) -> None:
    for write in (text_file(OCAMCALIB_TEXT), storage_file(CAMODOCAL_KB, lambda d: None, "c.yaml")):
        path = write(tmp_path)
        assert load_camera(path) is not None
        with pytest.raises(CalibrationFileError, match="holds one camera; a rig needs two"):
            load_rig(path)


def test_detect_format_reports_unknown_content(tmp_path: Path) -> None:
    path = text_file("just: some\nyaml: file\n", "rig.yaml")(tmp_path)
    with pytest.raises(CalibrationFileError, match=r"rig\.yaml: not a calibration file of a known format"):
        detect_format(path)
