"""``rig ... | head``: when stdout's reader goes away, the command ends quietly (no "internal
error", no traceback), whether the help, a command's table or a plain write met the closed pipe."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

from cli.console import BROKEN_PIPE
from tests.helpers.command import RIG, clean_env


def into_closed_pipe(argv: Sequence[str | Path], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` with stdout a pipe nobody reads any more (``| head`` after its lines)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run(
            [str(a) for a in argv], stdout=write_end, stderr=subprocess.PIPE, text=True, env=env, timeout=120
        )
    finally:
        os.close(write_end)


@pytest.mark.parametrize(
    "args", [["export", "mcap", "--help"], ["-h"], ["--version"], ["lut", "show"]], ids=" ".join
)
def test_the_rig_command_ends_quietly_into_a_closed_pipe(tmp_path: Path, args: list[str]) -> None:
    result = into_closed_pipe([RIG, *args], clean_env(tmp_path, COLUMNS="80"))
    assert result.stderr == ""
    assert result.returncode == BROKEN_PIPE


def test_a_command_whose_plain_write_meets_a_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    # A command of the rig group class writing past the pipe buffer with print(): BrokenPipeError
    # inside the command, where every other exception becomes "internal error: ...".
    program = (
        "import typer\n"
        "from cli.errors import MappedErrorsGroup\n"
        "app = typer.Typer(cls=MappedErrorsGroup)\n"
        "@app.command('spill')\n"
        "def spill() -> None:\n"
        "    print('x' * 1_000_000)\n"
        "@app.callback()\n"
        "def root() -> None: ...\n"
        "app(prog_name='rig')\n"
    )
    result = into_closed_pipe([sys.executable, "-c", program, "spill"], clean_env(tmp_path))
    assert "internal error" not in result.stderr and "Traceback" not in result.stderr
    assert result.stderr == ""
    assert result.returncode == BROKEN_PIPE
