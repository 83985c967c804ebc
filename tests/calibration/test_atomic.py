"""calibration.atomic, the one writer of files in place for every package: whole or not at all,
the replaced file's permissions kept, nothing left behind by a failed write, a killed writer's
temporaries swept; directories built in one go, the first of racing builds kept."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from calibration.atomic import (
    TEMP_MARK,
    atomic_directory,
    atomic_file,
    is_temporary,
    sweep_temporaries,
    write_atomic,
)


def test_a_write_replaces_the_file_whole_and_keeps_its_permissions(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    write_atomic(path, b"first")
    assert path.read_bytes() == b"first" and os.listdir(tmp_path) == ["rig.yaml"]
    path.chmod(0o600)
    with atomic_file(path) as f:
        f.write(b"sec")
        assert path.read_bytes() == b"first"  # readers see the old file until the rename
        f.write(b"ond")
    assert path.read_bytes() == b"second"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert os.listdir(tmp_path) == ["rig.yaml"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "results.json"
    write_atomic(path, b"old")
    with pytest.raises(OSError) as err, atomic_file(path) as f:
        f.write(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert err.value.errno == errno.ENOSPC
    assert path.read_bytes() == b"old" and os.listdir(tmp_path) == ["results.json"]
    with pytest.raises(OSError):  # the directory is gone: the temporary cannot even be made
        write_atomic(tmp_path / "gone" / "x.json", b"x")


def test_a_killed_writers_temporary_is_swept(tmp_path: Path) -> None:
    script = (
        "import os, sys\n"
        "from calibration.atomic import atomic_file\n"
        "with atomic_file(sys.argv[1]) as f:\n"
        "    f.write(b'half a file'); f.flush(); os._exit(9)\n"
    )
    res = subprocess.run([sys.executable, "-c", script, str(tmp_path / "000001.png")], timeout=60)
    assert res.returncode == 9
    (left,) = os.listdir(tmp_path)  # no file under the final name, only the temporary
    assert is_temporary(left) and TEMP_MARK in left and left.startswith(".000001.png")
    assert sweep_temporaries(tmp_path) == 1 and os.listdir(tmp_path) == []


def _complete(directory: Path) -> bool:
    return (directory / "done").is_file()


def test_a_directory_appears_whole_and_a_racing_build_keeps_the_first(tmp_path: Path) -> None:
    final = tmp_path / "render"
    dead = tmp_path / f".render{TEMP_MARK}999999999"  # a build whose process is gone
    (dead / "half").mkdir(parents=True)
    with atomic_directory(final, complete=_complete) as tmp:
        assert not dead.exists() and not final.exists()
        (tmp / "done").write_text("first")
    assert (final / "done").read_text() == "first" and os.listdir(tmp_path) == ["render"]
    with atomic_directory(final, complete=_complete) as tmp:  # lost the race: dropped
        (tmp / "done").write_text("second")
    assert (final / "done").read_text() == "first" and os.listdir(tmp_path) == ["render"]
    (final / "done").rename(final / "half")  # the one there is not whole: a build over it says so
    with pytest.raises(OSError), atomic_directory(final, complete=_complete) as tmp:
        (tmp / "done").write_text("third")
    assert os.listdir(tmp_path) == ["render"]
    with pytest.raises(ValueError), atomic_directory(tmp_path / "other", complete=_complete):
        raise ValueError("the build failed")
    assert os.listdir(tmp_path) == ["render"]
