"""Bad input through the API: hypothesis-generated malformed calibration files of every supported
format and malformed recording directories raise only the documented errors
(CalibrationFileError / RecordingError naming the file) — and whatever is accepted is usable:
finite parameters, proper rotations, frames that decode or are refused. Never another exception,
never silent nonsense."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calibration import CalibrationFileError, load_camera, load_rig
from calibration.models import CameraModel
from calibration.rig import Rig
from rig.capture.file_camera import FileCamera
from rig.capture.recorder import replay_capture_config
from rig.errors import ConfigError, CorruptFrameError, EndOfStream, RecordingError
from rig.recording import Recording
from tests.helpers.recordings import file_camera_config, write_recording
from tests.reliability.malformed import CALIBRATION_SAMPLES, malformed_calibration, malformed_recording

pytestmark = [pytest.mark.timeout(600)]

CALIBRATION_EXAMPLES = 100
RECORDING_EXAMPLES = 500
_RNG = np.random.default_rng(7)
_DIRS = _RNG.normal(size=(200, 3))
_DIRS[:, 2] = np.abs(_DIRS[:, 2])
FORWARD_POINTS = _DIRS / np.linalg.norm(_DIRS, axis=1, keepdims=True)


def check_camera(model: CameraModel) -> None:
    """An accepted camera must be usable: sane size, finite parameters and projections."""
    assert isinstance(model, CameraModel)
    assert model.width > 0 and model.height > 0
    assert np.isfinite(model.params).all(), model.param_dict
    px, ok = model.project(FORWARD_POINTS)
    assert np.isfinite(px[ok]).all()
    rays, ok = model.unproject(px[ok]) if ok.any() else (np.zeros((0, 3)), np.zeros(0, bool))
    assert np.isfinite(rays[ok]).all()


def check_rig(rig: Rig) -> None:
    assert isinstance(rig, Rig) and len(rig.names) >= 2
    for name in rig.names:
        check_camera(rig.cameras[name])
        T = np.asarray(rig.T_rig_cam[name])
        assert T.shape == (4, 4) and np.isfinite(T).all()
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-6)
        assert np.linalg.det(R) > 0 and np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9)


def names_the_file(err: Exception, path: Path) -> None:
    assert str(err).startswith(f"{path}: "), str(err)


@pytest.mark.filterwarnings("ignore::hypothesis.errors.NonInteractiveExampleWarning")
@pytest.mark.parametrize("name", list(CALIBRATION_SAMPLES))
@settings(
    max_examples=CALIBRATION_EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_malformed_calibration_files_raise_only_calibration_file_errors(
    tmp_path: Path, name: str, data: st.DataObject
) -> None:
    path = data.draw(malformed_calibration(name, tmp_path))
    try:
        check_camera(load_camera(path))
    except CalibrationFileError as err:
        names_the_file(err, path)
    try:
        check_rig(load_rig(path))
    except CalibrationFileError as err:
        names_the_file(err, path)


@pytest.fixture(scope="module")
def good_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("bad-rec") / "good", 4, calibration="cameras: {}\n")


def read_every_frame(rec: Recording) -> None:
    for pair in rec.pairs:
        for cam in ("left", "right"):
            try:
                img = rec.read_image(pair, cam)
            except RecordingError as err:
                assert str(rec.root) in str(err), str(err)  # names the file
                continue
            assert img.size > 0


def replay_left_camera(root: Path) -> None:
    """The file camera over the recording: frames or the documented per-frame errors."""
    try:
        cam = FileCamera(file_camera_config(root, "left", pace="fast", timestamps="recorded"), "left")
    except (RecordingError, ConfigError) as err:
        assert str(root) in str(err)
        return
    cam.open()
    for _ in range(10):
        try:
            frame = cam.read(0.1)
        except CorruptFrameError as err:
            assert str(root) in str(err)
            continue
        except EndOfStream:
            break
        assert frame is not None and frame.raw is not None


@settings(
    max_examples=RECORDING_EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_malformed_recordings_raise_only_recording_errors(
    good_recording: Path, tmp_path: Path, data: st.DataObject
) -> None:
    root, edits = data.draw(malformed_recording(good_recording, tmp_path / "rec"))
    try:
        rec = Recording(root)
    except RecordingError as err:
        assert str(err).startswith(str(root)), (edits, str(err))
    else:
        read_every_frame(rec)
    try:
        replay_capture_config(root)
    except RecordingError as err:
        assert str(err).startswith(str(root)), (edits, str(err))
    replay_left_camera(root)
