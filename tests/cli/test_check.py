"""`rig check` through the installed console script on file cameras replaying the small demo
recording (as JPEG): a healthy rig passes; a half-rate camera, a corrupt camera, a calibration
of another size and swapped cameras each fail the check that names them; bad input is exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from calibration import load_rig, save_rig
from calibration.rig import Rig
from rig.sim import scale_camera

RIG = str(Path(sys.executable).with_name("rig"))
SECONDS = "2"


def run(*args: str | Path, columns: int = 300) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": str(columns)}
    env.pop("RIG_DEBUG", None)
    return subprocess.run([RIG, *map(str, args)], capture_output=True, text=True, env=env, timeout=120)


def write_config(
    path: Path, recording: Path, lut: Path, *, left_faults: list[dict[str, Any]] | None = None, **more: Any
) -> Path:
    def cam(name: str, faults: list[dict[str, Any]] | None) -> dict[str, Any]:
        return {"kind": "file", "recording": str(recording), "camera": name, "pace": 10.0, "loop": True,
                "faults": faults or []}  # fmt: skip

    doc = {
        "cameras": {"left": cam("left", left_faults), "right": cam("right", None)},
        "vpc": {"width": 320, "height": 240},
        "stereo": {"disparity_range": 64},
        "cache_dir": str(lut),
        **more,
    }
    path.write_text(yaml.safe_dump(doc))
    return path


RESULTS = ("pass", "warn", "fail", "n/a", "not measured")


def results(stdout: str) -> dict[tuple[str, str], tuple[str, str]]:
    """(check, camera) → (result, measured) from the printed table (check | measured | expected |
    result; the check cell ends in the camera's name, if any)."""
    out = {}
    for line in stdout.splitlines():
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) == 4 and cells[3] in RESULTS:
            check, _, camera = cells[0].rpartition(" ")
            if camera not in ("left", "right"):
                check, camera = cells[0], ""
            out[(check, camera)] = (cells[3], cells[1])
    return out


def test_a_healthy_rig_passes_every_check(jpeg_recording: Path, tmp_path: Path) -> None:
    res = run(
        "check", "-c", write_config(tmp_path / "rig.yaml", jpeg_recording, tmp_path / "lut"), "-s", SECONDS
    )
    assert res.returncode == 0, res.stdout + res.stderr
    got = results(res.stdout)
    assert {r for r, _ in got.values()} <= {"pass", "n/a"}, got
    for check in ("camera", "format", "frame rate", "timestamps", "dropped", "corrupt", "calibration"):
        assert got[(check, "left")][0] == got[(check, "right")][0] == "pass", check
    assert got[("USB", "left")][0] == "n/a" and got[("exposure", "right")][0] == "n/a"
    fps = float(got[("frame rate", "left")][1].split()[0])
    assert 9.0 <= fps <= 11.0
    assert got[("pairing", "")][0] == "pass" and "skew p50 0.0 ms" in got[("pairing", "")][1]
    rows_px = float(got[("rectified rows", "")][1].split()[0])
    assert rows_px < 0.5
    na = sum(r == "n/a" for r, _ in got.values())
    assert f"all {len(got) - na} checks passed, {na} do not apply" in res.stdout


def test_a_half_rate_camera_fails_its_frame_rate_and_drops(jpeg_recording: Path, tmp_path: Path) -> None:
    half = [{"kind": "rate", "factor": 0.5, "duration_s": 3600.0}]
    cfg = write_config(tmp_path / "rig.yaml", jpeg_recording, tmp_path / "lut", left_faults=half)
    res = run("check", "-c", cfg, "-s", SECONDS)
    assert res.returncode == 1, res.stdout + res.stderr
    got = results(res.stdout)
    assert got[("frame rate", "left")][0] == "fail" and got[("frame rate", "right")][0] == "pass"
    assert 4.0 <= float(got[("frame rate", "left")][1].split()[0]) <= 6.0
    assert got[("dropped", "left")][0] == "fail" and "lost" in got[("dropped", "left")][1]
    assert got[("dropped", "right")][0] == "fail"  # half its frames find no partner
    assert "checks failed" in res.stdout and "frame rate left" in res.stdout


def test_a_corrupt_camera_fails_its_corrupt_check(jpeg_recording: Path, tmp_path: Path) -> None:
    every_third = [{"kind": "corrupt", "count": 1, "at_frame": k} for k in range(1, 200, 3)]
    cfg = write_config(tmp_path / "rig.yaml", jpeg_recording, tmp_path / "lut", left_faults=every_third)
    res = run("check", "-c", cfg, "-s", SECONDS)
    assert res.returncode == 1, res.stdout + res.stderr
    got = results(res.stdout)
    assert got[("corrupt", "left")][0] == "fail" and got[("corrupt", "right")][0] == "pass"
    share = int(got[("corrupt", "left")][1].split("(")[1].split("%")[0])
    assert 25 <= share <= 40


def test_a_calibration_of_another_size_or_swapped_fails_and_says_why(
    jpeg_recording: Path, tmp_path: Path
) -> None:
    rig = load_rig(jpeg_recording / "calibration.yaml")
    double = Rig({n: scale_camera(m, 2.0) for n, m in rig.cameras.items()}, rig.T_rig_cam)
    save_rig(double, tmp_path / "double.yaml")
    swapped = Rig(
        {"left": rig.cameras["right"], "right": rig.cameras["left"]},
        {"left": rig.T_rig_cam["right"], "right": rig.T_rig_cam["left"]},
    )
    save_rig(swapped, tmp_path / "swapped.yaml")
    for cal in ("double", "swapped"):
        cfg = write_config(
            tmp_path / f"{cal}-rig.yaml", jpeg_recording, tmp_path / "lut",
            calibration={"path": str(tmp_path / f"{cal}.yaml")},
        )  # fmt: skip
        res = run("check", "-c", cfg, "-s", SECONDS)
        assert res.returncode == 1, res.stdout + res.stderr
        got = results(res.stdout)
        if cal == "double":
            assert got[("calibration", "left")][0] == got[("calibration", "right")][0] == "fail"
            assert "×0.5 its size" in res.stdout
            assert got[("rectified rows", "")][0] == "n/a"
        else:
            assert got[("calibration", "left")][0] == "pass"
            assert got[("rectified rows", "")][0] == "fail" and "are swapped" in res.stdout


def test_cameras_that_deliver_nothing_leave_their_checks_not_measured_in_80_columns(
    jpeg_recording: Path, tmp_path: Path
) -> None:
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "cameras": {
                    n: {"kind": "v4l2", "device": f"/dev/rig-test-absent-{n}"} for n in ("left", "right")
                },
                "calibration": {"path": str(jpeg_recording / "calibration.yaml")},
                "vpc": {"width": 320, "height": 240},
                "cache_dir": str(tmp_path / "lut"),
            }
        )
    )
    res = run("check", "-c", cfg, "-s", "1", columns=80)
    assert res.returncode == 1, res.stdout + res.stderr
    widths = [len(line) for line in res.stdout.splitlines()]
    assert max(widths) <= 80, res.stdout
    got = results(res.stdout)
    assert got[("camera", "left")][0] == got[("camera", "right")][0] == "fail"
    for check in ("dropped", "corrupt", "exposure", "calibration"):
        for camera in ("left", "right"):
            assert got[(check, camera)][0] == "not measured", (check, camera, got[(check, camera)])
    assert got[("rectified rows", "")][0] == "not measured"
    assert "pass" not in {r for r, _ in got.values()}, got
    summary = " ".join(res.stdout.split())
    assert "3 of 12 checks failed: camera left, camera right, pairing; 9 not measured (no frame)" in summary


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--seconds", "0"], "--seconds"),
        (["-c", "missing.yaml"], "missing.yaml"),
        (["-c", "no-cameras.yaml"], "field 'cameras' missing"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path: Path, args: list[str], needle: str) -> None:
    (tmp_path / "no-cameras.yaml").write_text("server: {port: 8123}\n")
    args = [str(tmp_path / a) if a.endswith(".yaml") else a for a in args]
    res = run("check", *args)
    assert res.returncode == 2, res.stdout + res.stderr
    assert needle in res.stderr
