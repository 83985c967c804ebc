"""`rig record` as users run it: the real console script in subprocesses (byte-exact re-record,
kill -9, SIGTERM, bad input), and in-process for an injected full disk."""

from __future__ import annotations

import filecmp
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import build_app
from rig.recording import Recording
from tests.helpers.command import RIG, run_rig
from tests.helpers.recordings import write_recording
from tests.helpers.waiting import wait_for
from tests.reliability.fake_disk import Budget
from tests.rig.test_recording_writer import disk  # noqa: F401 - fixture


def rig(*args: str) -> subprocess.CompletedProcess[str]:
    return run_rig(args, timeout=60)


def tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


@pytest.mark.parametrize("ext", [".jpg", ".png"])
def test_replayed_recording_re_records_byte_identical(tmp_path: Path, ext: str) -> None:
    # Seq gaps and a constant right skew: the copy must keep both exactly.
    seqs = [0, 1, 2, 4, 5, 9, 10, 11]
    src = write_recording(
        tmp_path / "src", ext=ext, seqs=seqs, right_skew_ns=1_234_567, calibration="cameras: {}\n"
    )
    res = rig("record", "--replay", str(src), "--out", str(tmp_path / "out"))
    assert res.returncode == 0, res.stderr
    assert "recorded 8 pairs" in res.stdout and "end of recording" in res.stdout
    out = tmp_path / "out"
    files = [f for f in tree(src) if f != "recording.json"]
    assert files == [f for f in tree(out) if f != "recording.json"]
    assert "frames.csv" in files and "calibration.yaml" in files and len(files) == 2 + 2 * len(seqs)
    for f in files:
        assert (src / f).read_bytes() == (out / f).read_bytes(), f
    assert Recording(out).meta["source"] == {"replay": str(src)}


def test_frames_limit_records_the_first_pairs(tmp_path: Path) -> None:
    src = write_recording(tmp_path / "src", 20)
    res = rig("record", "--replay", str(src), "--out", str(tmp_path / "out"), "--frames", "5")
    assert res.returncode == 0, res.stderr
    rec = Recording(tmp_path / "out")
    assert [p.seq for p in rec.pairs] == list(range(5))
    lines = (src / "frames.csv").read_text().splitlines()[:6]
    assert (tmp_path / "out/frames.csv").read_text().splitlines() == lines


def live_config(tmp_path: Path, src: Path, fps: float = 30.0) -> Path:
    cfg = tmp_path / "rig.yaml"
    cam = f"{{kind: file, recording: {src.name}, pace: {fps}, loop: true, timestamps: live}}"
    cfg.write_text(f"cameras:\n  left: {cam}\n  right: {cam}\n")
    return cfg


def wait_rows(index: Path, n: int, proc: subprocess.Popen[str], timeout_s: float = 30.0) -> None:
    def written() -> bool:
        assert proc.poll() is None, proc.communicate()
        return index.exists() and index.read_text().count("\n") > n

    wait_for(written, timeout_s, f"{n} rows in {index}", poll_s=0.05)


def test_kill_9_loses_at_most_the_pair_in_flight(tmp_path: Path) -> None:
    src = write_recording(tmp_path / "src", 10)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [str(RIG), "record", "--config", str(live_config(tmp_path, src, 60.0)), "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        wait_rows(out / "frames.csv", 15, proc)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=30)
    rec = Recording(out)
    assert len(rec) >= 15
    seqs = [p.seq for p in rec.pairs]
    assert seqs == sorted(set(seqs))
    for p in rec.pairs:  # every indexed pair is complete and byte-exact
        for cam in ("left", "right"):
            assert rec.read_bytes(p, cam) == (src / f"{cam}/{p.seq % 10:06d}.jpg").read_bytes()
            assert rec.read_image(p, cam).shape == (120, 160, 3)
    indexed = {cam: {Path(p.file(cam)).name for p in rec.pairs} for cam in ("left", "right")}
    for cam in ("left", "right"):
        orphans = {f.name for f in (out / cam).iterdir()} - indexed[cam]
        assert len(orphans) <= 1, orphans  # the pair in flight, at most
    lost = max(len({f.name for f in (out / c).iterdir()} - indexed[c]) for c in ("left", "right"))
    assert lost + rec.truncated_tail <= 1


def test_sigterm_stops_cleanly_with_a_summary(tmp_path: Path) -> None:
    src = write_recording(tmp_path / "src", 10)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [str(RIG), "record", "--config", str(live_config(tmp_path, src)), "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    wait_rows(out / "frames.csv", 5, proc)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    rec = Recording(out)
    assert f"recorded {len(rec)} pairs" in " ".join(stdout.split()) and "stopped: signal" in stdout
    assert not rec.truncated_tail
    assert sorted(f.name for f in (out / "left").iterdir()) == [Path(p.left_file).name for p in rec.pairs]


def test_seconds_limit_and_source_metadata(tmp_path: Path) -> None:
    src = write_recording(tmp_path / "src", 10)
    cfg = live_config(tmp_path, src)
    res = rig("record", "--config", str(cfg), "--out", str(tmp_path / "out"), "--seconds", "0.5")
    assert res.returncode == 0, res.stderr
    rec = Recording(tmp_path / "out")
    assert "stopped: seconds" in res.stdout and len(rec) >= 1
    assert rec.meta["source"] == {"config": str(cfg)} and rec.meta["capture"]["left"]["kind"] == "file"


def test_full_disk_stops_with_one_line_and_keeps_what_was_written(
    tmp_path: Path,
    disk: Budget,  # noqa: F811
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    src = write_recording(tmp_path / "src", 20)
    frame_bytes = sum(f.stat().st_size for f in (src / "left").iterdir()) // 20
    disk.remaining = 4096 + 7 * 2 * frame_bytes  # room for the header files and about 7 pairs
    result = CliRunner().invoke(build_app(), ["record", "--replay", str(src), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    err = " ".join(result.output.split())
    assert "disk full" in err and "stays readable" in err
    rec = Recording(tmp_path / "out")
    assert 3 <= len(rec) < 20 and f"({len(rec)} pairs written" in err
    for p in rec.pairs:
        assert filecmp.cmp(rec.path(p.left_file), src / p.left_file, shallow=False)
        img = cv2.imdecode(np.frombuffer(rec.read_bytes(p, "right"), np.uint8), cv2.IMREAD_COLOR)
        assert img is not None


def run_main(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], args: list[str]
) -> tuple[int, str]:
    """``rig ARGS`` through the console script's entry point (cli.main.main), in-process."""
    from cli.main import main

    monkeypatch.setattr(sys, "argv", ["rig", *args])
    with pytest.raises(SystemExit) as exc:
        main()
    code = exc.value.code
    return (code if isinstance(code, int) else 1), capsys.readouterr().err


@pytest.mark.parametrize(
    "args,message",
    [
        (["record", "--out", "x"], "give exactly one of --config FILE or --replay RECORDING"),
        (["record", "--out", "x", "--replay", "a", "--config", "b"], "give exactly one of"),
        (["record", "--out", "x", "--replay", "a", "--frames", "2", "--seconds", "1"], "at most one of"),
        (
            ["record", "--out", "x", "--config", "/nonexistent/rig.yaml"],
            "/nonexistent/rig.yaml: config file not found",
        ),
        (
            ["record", "--out", "x", "--replay", "/nonexistent/rec"],
            "/nonexistent/rec: not a recording directory",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    args: list[str],
    message: str,
) -> None:
    monkeypatch.chdir(tmp_path)
    code, err = run_main(monkeypatch, capsys, args)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and message in lines[0] and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_bad_input_from_the_console_script(tmp_path: Path) -> None:
    res = run_rig(["record", "--out", "x"], timeout=60, cwd=tmp_path)
    assert (
        res.returncode == 2
        and res.stderr.strip() == "error: give exactly one of --config FILE or --replay RECORDING"
    )


def test_config_errors_name_file_and_field(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    cfg = tmp_path / "rig.yaml"
    out = str(tmp_path / "out")
    cfg.write_text(
        "cameras:\n  left: {kind: v4l2, device: 0, fourcc: H264}\n  right: {kind: v4l2, device: 1}\n"
    )
    code, err = run_main(monkeypatch, capsys, ["record", "--config", str(cfg), "--out", out])
    assert code == 2 and f"{cfg}: field 'cameras.left.fourcc'" in err and not (tmp_path / "out").exists()
    cfg.write_text("cameras:\n  left: {kind: file}\n  right: {kind: v4l2, device: 1}\n")
    code, err = run_main(monkeypatch, capsys, ["record", "--config", str(cfg), "--out", out])
    assert code == 2 and "field 'cameras.left.recording'" in err
    cfg.write_text("nothing: here\n")
    code, err = run_main(monkeypatch, capsys, ["record", "--config", str(cfg), "--out", out])
    assert code == 2 and "field 'cameras' missing" in err
    cfg.write_text("cameras: [unclosed\n")
    code, err = run_main(monkeypatch, capsys, ["record", "--config", str(cfg), "--out", out])
    assert code == 2 and f"{cfg}: not valid YAML" in err


def test_out_directory_with_a_recording_is_refused(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    src = write_recording(tmp_path / "src", 3)
    before = (src / "frames.csv").read_bytes()
    code, err = run_main(monkeypatch, capsys, ["record", "--replay", str(src), "--out", str(src)])
    assert code == 2 and "already holds a recording" in err
    assert (src / "frames.csv").read_bytes() == before and len(Recording(src)) == 3


def test_a_camera_that_never_comes_up_fails_the_recording_cleanly(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "cameras:\n  left: {kind: v4l2, device: /nonexistent/rig/left}\n"
        "  right: {kind: v4l2, device: /nonexistent/rig/right}\n"
    )
    out = tmp_path / "out"
    args = ["record", "--config", str(cfg), "--out", str(out), "--startup-timeout", "0.3"]
    code, err = run_main(monkeypatch, capsys, args)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "/nonexistent/rig/left: no such device" in err and "no pair recorded" in err
    assert not out.exists()  # nothing half-made to clean up
