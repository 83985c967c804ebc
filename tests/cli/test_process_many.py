"""`rig process` over several recordings through the installed console script: a Dask
LocalCluster by default, outputs per recording equal to single runs bit for bit, resume, a
summary file, and bad input (no recording, a scheduler that does not answer, a full disk)."""

from __future__ import annotations

import json
import socket
import subprocess
import time
from pathlib import Path

import cv2
import pytest

from calibration.atomic import is_temporary
from tests.helpers.command import assert_one_line_error, clean_env, run_rig
from tests.helpers.disks import tmpfs_disk
from tests.helpers.offline import VPC_ARGS, files_of, noisy_recording


def run(*args: str | Path, cache: Path) -> subprocess.CompletedProcess[str]:
    """``rig ARGS`` with its LUT cache under ``cache``."""
    return run_rig(args, clean_env(cache))


@pytest.fixture(scope="module")
def recs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("many")
    noisy_recording(root / "a", 5, seed=1)
    noisy_recording(root / "b", 4, seed=2)
    return root


def _options(recs: Path) -> list[str | Path]:
    return ["-c", recs / "a" / "rig.yaml", *VPC_ARGS, "--stereo", recs / "a" / "stereo.yaml"]


def test_several_recordings_on_a_local_cluster_equal_single_runs(recs: Path, tmp_path: Path) -> None:
    out, cache = tmp_path / "out", tmp_path / "c"
    many = run(
        "process", recs / "*", "--out", out, *_options(recs), "--workers", "2", "--chunk-size", "2",
        "--summary", tmp_path / "summary.json", cache=cache,
    )  # fmt: skip
    assert many.returncode == 0, many.stderr
    assert "processed 5 of 5 pairs -> " in many.stdout and "processed 4 of 4 pairs -> " in many.stdout
    assert sorted(p.name for p in out.iterdir()) == ["a", "b"]
    for name in ("a", "b"):
        single = run("process", recs / name, "--out", tmp_path / name, *_options(recs), cache=cache)
        assert single.returncode == 0, single.stderr
        assert files_of(out / name) == files_of(tmp_path / name), name
    doc = json.loads((tmp_path / "summary.json").read_text())
    assert [(r["recording"], r["written"], r["failed"]) for r in doc] == [("a", 5, []), ("b", 4, [])]
    # Resumed in this process: nothing left to do, nothing rewritten.
    (out / "b" / "depth" / "000002.png").unlink()
    again = run(
        "process", recs / "*", "--out", out, *_options(recs), "--resume", "--scheduler", "none", cache=cache
    )
    assert again.returncode == 0, again.stderr
    assert "processed 5 of 5 pairs, 5 already complete" in again.stdout
    assert "processed 4 of 4 pairs, 3 already complete" in again.stdout
    assert files_of(out / "b") == files_of(tmp_path / "b")


def test_resume_into_the_output_of_another_recording_is_refused(recs: Path, tmp_path: Path) -> None:
    out, cache = tmp_path / "out", tmp_path / "c"
    assert run("process", recs / "a", "--out", out, *_options(recs), cache=cache).returncode == 0
    before = files_of(out)
    other = run("process", recs / "b", "--out", out, *_options(recs), "--resume", cache=cache)
    line = assert_one_line_error(other)
    assert "run.json: the files there were made from another recording" in line and "--resume" in line
    assert files_of(out) == before  # a's files and run.json untouched


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_scheduler_that_does_not_answer_is_one_line_within_the_timeout(recs: Path, tmp_path: Path) -> None:
    address = f"tcp://127.0.0.1:{_free_port()}"
    t0 = time.monotonic()
    res = run("process", recs / "a", "--out", tmp_path / "out", *_options(recs), "--scheduler", address,
              "--scheduler-timeout", "2", cache=tmp_path / "c")  # fmt: skip
    elapsed = time.monotonic() - t0
    line = assert_one_line_error(res)
    assert f"{address}: no Dask scheduler answered within 2 s" in line
    assert not (tmp_path / "out").exists()  # nothing written before the scheduler answers
    print(f"\nunanswered scheduler: exit 2 after {elapsed:.1f} s (2 s timeout + start-up): {line}")


def test_what_is_not_a_recording_stops_before_any_output(recs: Path, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    line = assert_one_line_error(
        run("process", recs / "a", empty, "--out", tmp_path / "out", *_options(recs), cache=tmp_path)
    )
    assert f"{empty / 'recording.json'}: missing (not a recording directory)" in line
    assert not (tmp_path / "out").exists()
    nothing = run("process", tmp_path / "nothing*", "--out", tmp_path / "out", cache=tmp_path)
    assert_one_line_error(nothing, "no file or directory matches", "nothing*")
    twice = run("process", recs / "a", tmp_path / "x" / "a", "--out", tmp_path / "o", cache=tmp_path)
    assert_one_line_error(twice, "both write to", str(tmp_path / "o" / "a"))


def test_a_full_disk_stops_with_one_line_and_keeps_complete_pairs(tmp_path: Path) -> None:
    rec = noisy_recording(tmp_path / "rec", 8)
    reference = tmp_path / "reference"
    opts = ["-c", rec / "rig.yaml", *VPC_ARGS, "--stereo", rec / "stereo.yaml"]
    assert run("process", rec, "--out", reference, *opts, cache=tmp_path / "c").returncode == 0
    pair_bytes = sum(len(v) for k, v in files_of(reference).items() if "/000000." in k)
    disk = tmp_path / "disk"
    with tmpfs_disk(disk, 3 * pair_bytes + 8192):
        res = run("process", rec, "--out", disk / "out", *opts, cache=tmp_path / "c")
        line = assert_one_line_error(res)
        assert f"{disk / 'out'}: disk full" in line and "--resume" in line
        got, want = files_of(disk / "out"), files_of(reference)
        assert not [k for k in got if is_temporary(Path(k).name)]
        pngs = [k for k in got if k.endswith(".png")]
        assert 3 <= len(pngs) < len([k for k in want if k.endswith(".png")])
        for key in pngs:  # whatever is there is whole and the same as the reference's
            assert got[key] == want[key], key
            assert cv2.imread(str(disk / "out" / key), cv2.IMREAD_UNCHANGED) is not None
    print(f"\nfull disk (tmpfs of {3 * pair_bytes + 8192} bytes): {len(pngs)} files kept; {line}")
