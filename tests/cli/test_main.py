"""The ``rig`` command's surface: ``--version``, ``-h``/``--help`` on every command, and one help
style (uppercase metavars, defaults only as ``[default: ...]``)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from importlib.metadata import version
from typing import Any

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from cli.main import DISTRIBUTION, build_app
from tests.helpers.command import run_rig

# Metavars name what a value is: FILE, DIR, WxH, COLSxROWS, DEG, N, CAMERA=TOPIC ... (the "x" of a
# size aside, upper case).
METAVAR = re.compile(r"^[A-Z][A-Z_]*(x[A-Z]+|=[A-Z][A-Z_]*)?$|^WxH$")


def _commands(command: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], Any]]:
    """Every command below ``command`` (groups too) as (argv path, command)."""
    yield path, command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, (*path, name))


ALL = [path for path, _ in _commands(get_command(build_app()))]


def test_version_prints_the_installed_package_version() -> None:
    res = run_rig(["--version"], timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"rig ({DISTRIBUTION}) {version(DISTRIBUTION)}"


def test_short_help_on_the_root_and_process_from_the_console_script() -> None:
    root = run_rig(["-h"], timeout=60)
    assert root.returncode == 0, root.stderr
    for command in (
        "serve",
        "process",
        "record",
        "export",
        "check",
        "devices",
        "calibrate",
        "lut",
        "sim",
        "evaluate",
    ):
        assert re.search(rf"│ {command} ", root.stdout), command
    assert "--version" in root.stdout
    process = run_rig(["process", "-h"], timeout=60)
    assert process.returncode == 0, process.stderr
    assert "Usage: rig process [OPTIONS] {RECORDING}" in process.stdout
    assert "--vpc-size" in process.stdout and "WxH" in process.stdout


@pytest.mark.parametrize("path", ALL, ids=lambda p: " ".join(p) or "rig")
@pytest.mark.parametrize("flag", ["-h", "--help"])
def test_help_on_every_command(path: tuple[str, ...], flag: str) -> None:
    res = CliRunner().invoke(build_app(), [*path, flag], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert f"Usage: rig {' '.join(path)}".replace("  ", " ") in res.output


def test_every_option_value_has_an_uppercase_metavar_and_defaults_are_shown_one_way() -> None:
    offenders = []
    for path, command in _commands(get_command(build_app())):
        for param in command.params:
            where = f"rig {' '.join(path)} {param.name}"
            help_text = getattr(param, "help", None) or ""
            if re.search(r"\bdefault\b", help_text, re.IGNORECASE):
                offenders.append(f"{where}: default in the help text ({help_text!r})")
            if getattr(param, "is_flag", False) or getattr(param, "hidden", False):
                continue
            if param.metavar is None or not METAVAR.match(param.metavar):
                offenders.append(f"{where}: metavar {param.metavar!r}")
    assert not offenders, "\n".join(offenders)
