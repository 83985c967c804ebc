"""Settings: YAML file + RIG_* environment, precedence, relative paths, errors naming file and
field, and the loopback-or-token rule."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.capture.config import FileCameraConfig, V4L2CameraConfig, load_capture_config
from rig.errors import ConfigError
from service.errors import SettingsError
from service.settings import Settings, is_loopback, load_settings, settings_summary

TOKEN = "a-token-of-sufficient-length"


@pytest.fixture(autouse=True)
def clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for name in list(os.environ):
        if name.startswith("RIG_"):
            monkeypatch.delenv(name)


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_defaults_bind_loopback_and_build_nothing() -> None:
    s = load_settings()
    assert s.server.host == "127.0.0.1"
    assert s.server.port == 8000
    assert s.server.api_token is None
    assert s.server.cors_origins == []
    assert s.server.depth_scale_m == 0.001
    assert s.cameras is None
    assert s.rectified.projection == "latlon" and s.rectified.width is None and s.vpc is None
    assert s.stereo.disparity_range == 96 and s.stereo.lr_check


def test_yaml_file_with_relative_paths_resolved_against_the_file(tmp_path: Path) -> None:
    cfg = tmp_path / "conf"
    cfg.mkdir()
    path = write(
        cfg / "rig.yaml",
        """
server: {port: 9123, recordings_dir: recs, depth_scale_m: 0.0001, cors_origins: ["http://a.test"]}
cameras:
  left: {kind: file, recording: ../rec, pace: 30.0, loop: true}
  right: {kind: v4l2, device: /dev/rig/right}
calibration: {path: calib/rig.yaml}
vpc: {width: 320, height: 240, hfov_deg: 80}
stereo: {disparity_range: 64, sgbm_mode: 2}
cache_dir: lut
""",
    )
    s = load_settings(path)
    assert s.server.port == 9123
    assert s.server.recordings_dir == cfg / "recs"
    assert s.server.depth_scale_m == 0.0001
    assert s.server.cors_origins == ["http://a.test"]
    assert s.calibration.path == cfg / "calib" / "rig.yaml"
    assert s.cache_dir == cfg / "lut"
    assert s.cameras is not None
    assert isinstance(s.cameras.left, FileCameraConfig)
    assert s.cameras.left.recording == cfg / ".." / "rec"
    assert isinstance(s.cameras.right, V4L2CameraConfig) and s.cameras.right.device == "/dev/rig/right"
    assert s.rectified.hfov_deg == 80  # read from the section's first name, vpc:
    assert s.stereo.sgbm_mode == "3way"  # ROS numbering 2 = SGBM_3WAY


def test_rig_record_reads_the_cameras_rig_serve_reads(tmp_path: Path) -> None:
    """One reader of the config file (rig.settings_model.read_config_file) and one rule for its
    relative recording paths: ``rig record --config`` gets the cameras ``rig serve`` gets, and
    the same line for a file neither can read."""
    cfg = tmp_path / "conf"
    cfg.mkdir()
    path = write(
        cfg / "rig.yaml",
        "cameras:\n  left: {kind: file, recording: ../rec, camera: left}\n"
        "  right: {kind: file, recording: /abs/rec, camera: right}\nserver: {port: 9123}\n",
    )
    served = load_settings(path).cameras
    assert served is not None and served == load_capture_config(path)
    assert isinstance(served.left, FileCameraConfig) and served.left.recording == cfg / ".." / "rec"
    assert isinstance(served.right, FileCameraConfig) and served.right.recording == Path("/abs/rec")
    for name, text in (("yaml", "cameras: [1, 2\n"), ("list", "- a\n"), ("missing", None)):
        bad = tmp_path / f"{name}.yaml"
        if text is not None:
            write(bad, text)
        with pytest.raises(SettingsError) as by_serve:
            load_settings(bad)
        with pytest.raises(ConfigError) as by_record:
            load_capture_config(bad)
        assert str(by_serve.value) == str(by_record.value) and str(bad) in str(by_record.value)


def test_environment_overrides_file_and_overrides_beat_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = write(tmp_path / "c.yaml", "server: {port: 9000, jpeg_quality: 70}\n")
    monkeypatch.setenv("RIG_SERVER__PORT", "9001")
    monkeypatch.setenv("RIG_CONFIG", str(path))
    s = load_settings()
    assert s.server.port == 9001  # env beats the file
    assert s.server.jpeg_quality == 70  # the file beats the default
    s2 = load_settings(None, {"server": {"port": 9002}})
    assert s2.server.port == 9002 and s2.server.jpeg_quality == 70


def test_token_from_rig_api_token(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RIG_API_TOKEN", TOKEN)
    s = load_settings(None, {"server": {"host": "0.0.0.0"}})
    assert s.server.token == TOKEN
    assert TOKEN not in repr(s)  # SecretStr
    summary = settings_summary(s)
    assert summary["server"]["api_token_set"] is True
    assert TOKEN not in str(summary)


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.20", "::", "robot.local"])
def test_non_loopback_bind_without_token_is_refused(host: str) -> None:
    with pytest.raises(SettingsError, match=r"field 'server'.*non-loopback.*RIG_API_TOKEN"):
        load_settings(None, {"server": {"host": host}})


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.53", "::1", "localhost"])
def test_loopback_hosts(host: str) -> None:
    assert is_loopback(host)
    assert load_settings(None, {"server": {"host": host}}).server.host == host


def test_short_token_rejected(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RIG_API_TOKEN", "short")
    with pytest.raises(SettingsError, match=r"environment RIG_API_TOKEN: field 'server.api_token'.*16"):
        load_settings()


def test_bad_value_in_file_names_file_and_field(tmp_path: Path) -> None:
    path = write(tmp_path / "bad.yaml", "server: {port: 70000}\n")
    with pytest.raises(SettingsError) as info:
        load_settings(path)
    assert str(path) in str(info.value) and "field 'server.port'" in str(info.value)


def test_bad_value_in_env_names_the_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RIG_SERVER__JPEG_QUALITY", "abc")
    with pytest.raises(
        SettingsError, match=r"environment RIG_SERVER__JPEG_QUALITY: field 'server.jpeg_quality'"
    ):
        load_settings()


def test_bad_camera_field_names_the_yaml_path(tmp_path: Path) -> None:
    path = write(
        tmp_path / "cams.yaml",
        "cameras:\n  left: {kind: v4l2, device: 0, fps: -1}\n  right: {kind: v4l2, device: 1}\n",
    )
    with pytest.raises(SettingsError, match=r"field 'cameras.left.fps'"):
        load_settings(path)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("server: [1, 2\n", "not valid YAML"),
        ("- a\n- b\n", "must hold a mapping"),
        ("bogus_section: 1\n", "field 'bogus_section'"),
        ("server: {depth_scale_m: 0.01}\n", "field 'server.depth_scale_m'"),
        ("stereo: {disparity_range: 50}\n", "field 'stereo'.*multiple of 16"),
        ("server: {color_range_m: [5, 1]}\n", "field 'server.color_range_m'"),
    ],
)
def test_bad_config_files(tmp_path: Path, text: str, match: str) -> None:
    path = write(tmp_path / "x.yaml", text)
    with pytest.raises(SettingsError, match=match):
        load_settings(path)


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(SettingsError, match="config file not found"):
        load_settings(tmp_path / "nope.yaml")


def test_empty_file_is_defaults(tmp_path: Path) -> None:
    assert load_settings(write(tmp_path / "empty.yaml", "")) == Settings()
