"""cli.errors: every exception a command raises ends as one line on stderr and its exit status,
the same in process (CliRunner) and through the console script, and never as a traceback unless
RIG_DEBUG=1."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

import cli.lut
from calibration.errors import CalibrationError, CalibrationFileError, ModelError
from cli.errors import CommandError, MappedErrorsGroup, fail
from cli.main import build_app
from rig.errors import ConfigError, DiskFullError, RigError
from service.errors import RecordingConflict, ServiceError, SettingsError
from tests.helpers.command import assert_one_line_error, run_rig

CASES: list[tuple[BaseException, int, str]] = [
    (CommandError("give exactly one of --a and --b"), 2, "error: give exactly one of --a and --b"),
    (CalibrationError("calibration went wrong"), 2, "error: calibration went wrong"),
    (
        CalibrationFileError("/x/rig.yaml", "must be a number", "cam0.fx"),
        2,
        "error: /x/rig.yaml: field 'cam0.fx'",
    ),
    (ModelError("unknown model 'fisheye9'"), 2, "error: unknown model 'fisheye9'"),
    (RigError("camera\nleft gone"), 2, "error: camera left gone"),  # one line, even from two
    (RigError("cameras [left] and [/right]"), 2, "error: cameras [left] and [/right]"),  # not markup
    (ConfigError("--vpc-size must look like 640x480"), 2, "error: --vpc-size must look like 640x480"),
    (DiskFullError("disk full"), 2, "error: disk full"),
    (ServiceError("cannot listen on 127.0.0.1:80"), 2, "error: cannot listen on 127.0.0.1:80"),
    (SettingsError("rig.yaml: field 'server.port'"), 2, "error: rig.yaml: field 'server.port'"),
    (RecordingConflict("recording 'a' is running"), 2, "error: recording 'a' is running"),
    (KeyboardInterrupt(), 130, "interrupted"),
    (ZeroDivisionError("division by zero"), 1, "internal error: ZeroDivisionError: division by zero"),
]


def app_raising(err: BaseException) -> typer.Typer:
    """A two-command app on the rig command's group class; ``boom`` raises ``err``."""
    app = typer.Typer(cls=MappedErrorsGroup)

    @app.command()
    def boom() -> None:
        raise err

    @app.command()
    def fine() -> None:
        typer.echo("ok")

    return app


@pytest.mark.parametrize(("err", "status", "line"), CASES, ids=[type(c[0]).__name__ for c in CASES])
def test_each_exception_is_one_line_and_its_exit_status(
    err: BaseException, status: int, line: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("RIG_DEBUG", raising=False)
    res = CliRunner().invoke(app_raising(err), ["boom"], env={"COLUMNS": "200"})
    lines = [x for x in res.output.splitlines() if x.strip()]
    assert res.exit_code == status, res.output
    assert len(lines) == 1 and lines[0].startswith(line), res.output
    assert "Traceback" not in res.output
    if status == 1:
        assert lines[0].endswith("(run with RIG_DEBUG=1 for the traceback)")


def test_rig_debug_lets_the_exception_through(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RIG_DEBUG", "1")
    res = CliRunner().invoke(app_raising(ZeroDivisionError("boom")), ["boom"])
    assert isinstance(res.exception, ZeroDivisionError)


def test_fail_raises_a_command_error() -> None:
    with pytest.raises(CommandError, match="bad --x"):
        fail("bad --x")


def test_usage_errors_of_typer_keep_their_usage_line() -> None:
    res = CliRunner().invoke(app_raising(RuntimeError()), ["fine", "--no-such-option"])
    assert res.exit_code == 2 and "No such option" in res.output and "Usage:" in res.output


def test_an_internal_error_in_process_is_one_line_exit_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from cli.main import main

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("LUT cache exploded")

    monkeypatch.delenv("RIG_DEBUG", raising=False)
    monkeypatch.setattr(cli.lut, "LutCache", broken)
    monkeypatch.setattr(sys, "argv", ["rig", "lut", "show"])
    with pytest.raises(SystemExit) as exc:
        main()
    err = capsys.readouterr().err
    assert exc.value.code == 1
    assert err.strip().splitlines() == [
        "internal error: RuntimeError: LUT cache exploded (run with RIG_DEBUG=1 for the traceback)"
    ]


def test_bad_input_through_the_console_script_is_exit_2_one_line(tmp_path: Path) -> None:
    res = run_rig(["process", tmp_path / "missing", "--out", tmp_path / "out"], timeout=60)
    assert_one_line_error(res, "missing")


def test_the_real_app_maps_errors_in_process(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RIG_DEBUG", raising=False)
    res = CliRunner().invoke(build_app(), ["sim", "--out", str(tmp_path / "o"), "--preset", "nope"])
    assert res.exit_code == 2 and res.output.strip().startswith("error: unknown --preset 'nope'")
