"""The settings ``rig serve`` runs with: every configured value is validated even where a flag
takes its place, every mistake is listed at once, what ``--demo`` or ``--recording`` replace is
said to be ignored, the demo makes an API token when none is configured (and its URL carries it),
and a ``rig`` command off PATH is said with the way to reach it."""

from __future__ import annotations

from pathlib import Path

import pytest

import cli.serve
from cli.serve import command_hint, serve_settings, served_url
from service.errors import SettingsError
from tests.helpers.command import assert_one_line_error, clean_env, run_rig
from tests.helpers.service import SmallRecording

V4L2_CAMERAS = """
cameras:
  left: {kind: v4l2, device: /dev/rig-left}
  right: {kind: v4l2, device: /dev/rig-right}
"""


@pytest.fixture
def demo_is(small_recording: SmallRecording, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The demo recording without rendering it: the small recording stands in."""
    monkeypatch.setattr(cli.serve, "demo_recording", lambda: small_recording.loop)
    return small_recording.loop


def test_several_wrong_fields_are_listed_in_one_line(tmp_path: Path) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text("server: {port: 99999, jpeg_quality: true, stale_after_s: .inf}\nstereo: {median: 4}\n")
    line = assert_one_line_error(run_rig(["serve", "--config", str(cfg)], clean_env(tmp_path)), str(cfg))
    for field in ("server.port", "server.jpeg_quality", "server.stale_after_s", "stereo.median"):
        assert f"field '{field}'" in line, line
    assert "not a boolean" in line and "finite number" in line


def test_a_flag_does_not_hide_a_wrong_value(tmp_path: Path) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text("server: {port: eighty}\n")
    args = ["serve", "--config", str(cfg), "--port", "0", "--recording", str(tmp_path / "none")]
    assert_one_line_error(run_rig(args, clean_env(tmp_path)), str(cfg), "server.port")
    with pytest.raises(SettingsError, match=r"server\.port"):
        serve_settings(cfg, port=0)


def test_the_demo_says_it_ignores_the_configured_cameras(
    tmp_path: Path, demo_is: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(V4L2_CAMERAS + "calibration: {path: rig.yaml}\nvpc: {width: 320, height: 240}\n")
    settings = serve_settings(cfg, demo=True)
    err = capsys.readouterr().err
    assert "--demo: the configured cameras and calibration are ignored" in " ".join(err.split())
    assert settings.cameras is not None and settings.cameras.left.kind == "file"
    assert settings.calibration.path == demo_is / "calibration.yaml"
    assert settings.rectified.width == 320  # what the demo does not replace is used
    serve_settings(cfg, demo=True, calibration=tmp_path / "other.yaml")
    assert "--calibration is ignored with --demo" in " ".join(capsys.readouterr().err.split())


def test_a_recording_says_it_ignores_the_configured_cameras(
    tmp_path: Path, small_recording: SmallRecording, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(V4L2_CAMERAS)
    settings = serve_settings(cfg, recording=small_recording.loop)
    assert "--recording: the configured cameras are ignored" in " ".join(capsys.readouterr().err.split())
    assert settings.cameras is not None and settings.cameras.right.kind == "file"


def test_replaced_values_are_still_validated(tmp_path: Path, demo_is: Path) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(V4L2_CAMERAS.replace("/dev/rig-right}", "/dev/rig-right, fps: true}"))
    with pytest.raises(SettingsError, match=r"field 'cameras\.right\.fps': must be a number, not a boolean"):
        serve_settings(cfg, demo=True)


def test_a_vpc_that_cannot_fit_in_memory_is_refused_at_start(tmp_path: Path, jpeg_recording: Path) -> None:
    # SGBM's full mode keeps a 4-byte cost per pixel and disparity: 8192² × 1024 × 4 = 256 GiB.
    env = clean_env(
        tmp_path,
        RIG_VPC__WIDTH="8192",
        RIG_VPC__HEIGHT="8192",
        RIG_STEREO__DISPARITY_RANGE="1024",
        RIG_STEREO__SGBM_MODE="hh",
        RIG_STEREO__FULL_DP="true",
    )
    result = run_rig(["serve", "--recording", str(jpeg_recording), "--port", "0"], env)
    line = assert_one_line_error(
        result, "field 'rectified': a 8192x8192 pinhole pair with 1024 disparities needs about"
    )
    assert "matcher" in line and "MiB this machine has left" in line


@pytest.mark.parametrize(
    ("value", "needle"),
    [
        ("2", "field 'panorama': the calibration"),  # a two-camera rig has no panorama
        ("30", "panorama.px_per_deg"),
    ],
)
def test_a_panorama_the_rig_cannot_have_is_refused_at_start(
    tmp_path: Path, jpeg_recording: Path, value: str, needle: str
) -> None:
    env = clean_env(tmp_path, RIG_PANORAMA__PX_PER_DEG=value)
    result = run_rig(["serve", "--recording", str(jpeg_recording), "--port", "0"], env)
    assert_one_line_error(result, needle)


def test_the_demo_makes_an_api_token_unless_one_is_configured(
    tmp_path: Path, demo_is: Path, small_recording: SmallRecording, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("RIG_API_TOKEN", raising=False)
    made = [serve_settings(None, demo=True).server.token for _ in range(2)]
    assert all(t is not None and len(t) >= 32 for t in made) and made[0] != made[1]
    # No cameras configured: the demo all the same, with its token.
    assert serve_settings(None).server.token is not None
    # A configured token is the one used; a recording gets none it was not given.
    cfg = tmp_path / "rig.yaml"
    cfg.write_text("server: {api_token: configured-token-0123456789}\n")
    assert serve_settings(cfg, demo=True).server.token == "configured-token-0123456789"
    monkeypatch.setenv("RIG_API_TOKEN", "environment-token-0123456789")
    assert serve_settings(None, demo=True).server.token == "environment-token-0123456789"
    monkeypatch.delenv("RIG_API_TOKEN")
    assert serve_settings(None, recording=small_recording.loop).server.token is None


def test_the_dashboard_url_carries_a_made_token(tmp_path: Path, demo_is: Path) -> None:
    from service.settings import load_settings

    settings = serve_settings(None, demo=True)
    assert served_url(settings, 8123) == "http://127.0.0.1:8123/"
    assert served_url(settings, 8123, "abc") == "http://127.0.0.1:8123/?token=abc"
    v6 = load_settings(None, {"server": {"host": "::1"}})
    assert served_url(v6, 9000) == "http://[::1]:9000/"


def test_the_rig_command_off_path_is_said_with_the_way_to_reach_it(tmp_path: Path) -> None:
    bindir = tmp_path / "venv" / "bin"
    bindir.mkdir(parents=True)
    script = bindir / "rig"
    script.write_text("#!/bin/sh\n")
    script.chmod(0o755)
    hint = command_hint(str(script), "/usr/bin:/bin")
    assert hint is not None and f"{bindir / 'rig'}" in hint and f". {bindir / 'activate'}" in hint
    assert command_hint(str(script), f"/usr/bin:{bindir}") is None  # on PATH: nothing to say
    assert command_hint("/usr/lib/python3/cli/__main__.py", "/usr/bin") is None  # python -m cli
