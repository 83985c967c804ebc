"""Bad input through the real console script (subprocesses): generated malformed calibration files
of every format given to ``rig process``, ``rig lut build`` and ``rig serve``, and generated
malformed recordings given to ``rig process``, ``rig record --replay`` and ``rig serve
--recording``: exit status 2, exactly one line on stderr naming the file, never a traceback.
Missing and corrupt frames inside a valid recording are reported per pair, as documented.

The number of subprocesses is bounded (about 1.5 s each): two generated files per calibration
format and a dozen recordings, derandomized so CI runs the same cases every time.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from calibration import CalibrationFileError, Rig, load_rig
from calibration.formats import dump_rig_yaml
from rig.errors import RecordingError
from rig.recording import Recording
from tests.calibration.test_formats_samples import rig_doc
from tests.helpers.command import assert_one_line_error, clean_env, run_rig
from tests.helpers.recordings import write_recording
from tests.reliability.malformed import CALIBRATION_SAMPLES, malformed_calibration, malformed_recording

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

SUBPROCESS_SETTINGS = settings(
    max_examples=2,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[
        HealthCheck.function_scoped_fixture,
        HealthCheck.too_slow,
        HealthCheck.filter_too_much,
    ],
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("bad-cli")
    calibration = tmp / "rig.yaml"
    calibration.write_text(dump_rig_yaml(Rig.from_dict(rig_doc())))
    rec = write_recording(tmp / "rec", 4, calibration=calibration.read_text())
    return {"tmp": tmp, "calibration": calibration, "recording": rec}


def calibration_command(kind: str, bad: Path, inputs: dict[str, Path], out: Path) -> list[str]:
    if kind == "process":
        return ["process", str(inputs["recording"]), "--calibration", str(bad), "--out", str(out)]
    if kind == "lut":
        return ["lut", "build", "--calibration", str(bad), "--cache-dir", str(out / "cache")]
    return ["serve", "--recording", str(inputs["recording"]), "--calibration", str(bad), "--port", "0"]


@pytest.mark.parametrize("name", list(CALIBRATION_SAMPLES))
@SUBPROCESS_SETTINGS
@given(data=st.data())
def test_malformed_calibration_through_the_cli(
    inputs: dict[str, Path], tmp_path: Path, name: str, data: st.DataObject
) -> None:
    case_dir = tmp_path / "case"
    shutil.rmtree(case_dir, ignore_errors=True)
    case_dir.mkdir()
    bad = data.draw(malformed_calibration(name, case_dir))
    try:  # only files the loaders refuse: a valid file would (rightly) start the command
        load_rig(bad)
        accepted = True
    except CalibrationFileError:
        accepted = False
    assume(not accepted)
    kind = data.draw(st.sampled_from(["process", "lut", "serve"]))
    result = run_rig(calibration_command(kind, bad, inputs, case_dir / "out"), clean_env(tmp_path))
    assert_one_line_error(result, str(bad))
    assert not (case_dir / "out" / "depth").exists()  # nothing processed from a bad calibration


def recording_command(kind: str, root: Path, inputs: dict[str, Path], out: Path) -> list[str]:
    if kind == "process":
        return ["process", str(root), "--calibration", str(inputs["calibration"]), "--out", str(out)]
    if kind == "record":
        return ["record", "--replay", str(root), "--out", str(out)]
    return ["serve", "--recording", str(root), "--calibration", str(inputs["calibration"]), "--port", "0"]


@settings(SUBPROCESS_SETTINGS, max_examples=12)
@given(data=st.data())
def test_malformed_recordings_through_the_cli(
    inputs: dict[str, Path], tmp_path: Path, data: st.DataObject
) -> None:
    root, edits = data.draw(malformed_recording(inputs["recording"], tmp_path / "rec"))
    try:  # structural damage: the index or metadata cannot be read
        Recording(root)
        readable = True
    except RecordingError:
        readable = False
    assume(not readable)
    out = tmp_path / "out"
    shutil.rmtree(out, ignore_errors=True)
    kind = data.draw(st.sampled_from(["process", "record", "serve"]))
    result = run_rig(recording_command(kind, root, inputs, out), clean_env(tmp_path))
    assert_one_line_error(result, str(root))
    assert not (out / "frames.csv").exists() and not (out / "depth").exists(), edits


# ----- damaged frames in a readable recording ---------------------------------------------------
@pytest.fixture
def damaged(jpeg_recording: Path, tmp_path: Path) -> tuple[Path, dict[int, str]]:
    """The 3-pair JPEG recording with pair 1's left frame deleted and pair 2's right frame cut
    in half; returns it and the damaged file of each broken seq."""
    root = tmp_path / "damaged"
    shutil.copytree(jpeg_recording, root)
    rec = Recording(root)
    p1, p2 = rec.pairs[1], rec.pairs[2]
    (root / p1.left_file).unlink()
    data = (root / p2.right_file).read_bytes()
    (root / p2.right_file).write_bytes(data[: len(data) // 2])
    return root, {p1.seq: p1.left_file, p2.seq: p2.right_file}


def test_process_reports_each_damaged_pair_and_keeps_the_rest(
    damaged: tuple[Path, dict[int, str]], tmp_path: Path
) -> None:
    root, broken = damaged
    out = tmp_path / "out"
    args = [
        "process",
        str(root),
        "--out",
        str(out),
        "--vpc-size",
        "160x120",
        "--cache-dir",
        str(tmp_path / "c"),
    ]
    result = run_rig(args, clean_env(tmp_path))
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and "processed 1 of 3 pairs" in " ".join(result.stdout.split())
    lines = [line.strip() for line in result.stderr.splitlines() if line.strip()]
    # Each damaged pair as it is skipped, then again in the closing summary.
    live, summary = lines[:2], lines[2:]
    assert len(lines) == 4 and all(line.startswith("skipped seq") for line in live), result.stderr
    for kind, listed in (("skipped", live), ("failed", summary)):
        for line, (seq, rel) in zip(listed, sorted(broken.items()), strict=True):
            assert line.startswith(f"{kind} seq {seq}:") and rel in line, result.stderr
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["000000.png"]


def test_process_with_no_readable_pair_fails_with_one_error_line(
    damaged: tuple[Path, dict[int, str]], tmp_path: Path
) -> None:
    root, _ = damaged
    rec = Recording(root)
    (root / rec.pairs[0].right_file).write_bytes(b"\xff\xd8 not a jpeg")
    args = ["process", str(root), "--out", str(tmp_path / "out"), "--vpc-size", "160x120"]
    result = run_rig([*args, "--cache-dir", str(tmp_path / "c")], clean_env(tmp_path))
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and "Traceback" not in result.stderr
    # One warning per pair as it is met, the summary's list of them, then the one error line.
    assert [line.strip().split(":")[0] for line in lines] == [
        "skipped seq 0",
        "skipped seq 1",
        "skipped seq 2",
        "failed seq 0",
        "failed seq 1",
        "failed seq 2",
        "error",
    ]
    assert lines[-1] == f"error: no pair of 3 in {root} could be processed (3 skipped)"


def test_replay_of_damaged_frames_counts_them_and_records_the_rest(
    damaged: tuple[Path, dict[int, str]], tmp_path: Path
) -> None:
    root, broken = damaged
    out = tmp_path / "copy"
    result = run_rig(["record", "--replay", str(root), "--out", str(out)], clean_env(tmp_path))
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    summary = " ".join(result.stdout.split())
    assert "recorded 1 pairs" in summary and "corrupt: left 1, right 1" in summary, summary
    src, copy = Recording(root), Recording(out)
    assert copy.pairs == [p for p in src.pairs if p.seq not in broken]
    for p in copy.pairs:
        assert copy.read_bytes(p, "left") == src.read_bytes(p, "left")
