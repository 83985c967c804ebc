"""`rig calibrate refine REC --floor-height M` through the installed console script: a room
recording of the half-size prototype (honest lens) whose right camera is turned 0.3° about y,
refined from the nominal calibration and the room's floor 1.2 m down; a correct rig with a wrong
height is not applied and nothing is written; bad input is one line, exit 2."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from calibration.formats import load_rig, save_rig
from tests.helpers.command import assert_one_line_error, run_rig
from tests.rig.rectification_renders import nominal_rig, perturbed, relative_rotation_error_deg, render_room

TRUTH_DEG = (0.0, 0.3, 0.0)


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_rig(("calibrate", "refine", *args))


@pytest.fixture(scope="module")
def nominal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("floor-cli") / "nominal.yaml"
    save_rig(nominal_rig(), path)
    return path


@pytest.fixture(scope="module")
def turned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return render_room(
        tmp_path_factory.mktemp("floor-turned") / "rec", 2, perturbed(nominal_rig(), TRUTH_DEG)
    )


@pytest.fixture(scope="module")
def correct(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return render_room(tmp_path_factory.mktemp("floor-correct") / "rec", 2, nominal_rig())


@pytest.mark.slow
def test_the_floor_finds_the_vergence_and_writes_it(turned: Path, nominal: Path, tmp_path: Path) -> None:
    out = tmp_path / "refined.yaml"
    res = run(turned, "-c", nominal, "--out", out, "--floor-height", "1.2", "--frames", "2")
    assert res.returncode == 0, res.stderr
    print(res.stdout)
    truth = perturbed(nominal_rig(), TRUTH_DEG)
    before = relative_rotation_error_deg(load_rig(nominal), truth)
    after = relative_rotation_error_deg(load_rig(out), truth)
    print(f"relative rotation error: {before:.4f}° before, {after:.4f}° after")
    assert before == pytest.approx(0.3, abs=1e-6) and after < 0.025
    text = " ".join(res.stdout.split())
    for needle in ("about y (vergence", "about z (the look direction", "floor residual", "range error",
                   "flatness", "vertical disparity p50", "applied", f"wrote {out}"):  # fmt: skip
        assert needle in text, needle


def test_not_applied_writes_nothing(correct: Path, nominal: Path, tmp_path: Path) -> None:
    """The correct rig told a floor 5 cm too low: the turn it fits would move the rows apart."""
    out = tmp_path / "refined.yaml"
    res = run(correct, "-c", nominal, "--out", out, "--floor-height", "1.25", "--frames", "2")
    assert res.returncode == 0, res.stderr
    text = " ".join(res.stdout.split())
    assert "not applied: the vertical disparity p50" in text
    assert f"{out} not written; calibration stays {nominal}" in text
    assert not out.exists()


def test_bad_input_is_one_line_and_exit_2(correct: Path, nominal: Path, tmp_path: Path) -> None:
    out = tmp_path / "refined.yaml"
    for height in ("0", "-1.2", "nan", "1000"):
        assert_one_line_error(
            run(correct, "-c", nominal, "--out", out, "--floor-height", height, "--frames", "1"),
            "floor height must be a number of metres in [0.01, 100]",
        )
    assert_one_line_error(
        run(correct, "-c", nominal, "--out", out, "--floor-height", "0.3", "--frames", "1"),
        "no floor in view: ",
        "is the floor in view, and its height right?",
    )
    assert_one_line_error(
        run(correct, "-c", nominal, "--out", out, "--floor-height", "1.2", "--pitch", "-30"),
        "do not apply with --floor-height",
    )
    assert_one_line_error(
        run(tmp_path / "nowhere", "-c", nominal, "--out", out, "--floor-height", "1.2"), "nowhere"
    )
    assert not out.exists()
