"""`rig calibrate refine` end to end through the installed console script: a recording rendered
by a rig whose right camera is turned (its calibration.yaml holds that truth) refined from the
nominal calibration, the output file and the original kept, and bad input as one line, exit 2."""

from __future__ import annotations

import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.formats import load_rig, save_rig
from calibration.rig import Rig
from rig.recording import RecordingWriter
from tests.helpers.command import assert_one_line_error, run_rig
from tests.rig.rectification_renders import nominal_rig, perturbed, relative_rotation_error_deg, render_room


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_rig(args)


@pytest.fixture(scope="module")
def knocked(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Rig]:
    """A room recording of the half-size prototype whose right camera was turned (0.4, -0.6, 0.3)°
    and moved 1 mm along the baseline, and the nominal calibration as a file."""
    root = tmp_path_factory.mktemp("refine-cli")
    truth = perturbed(nominal_rig(), (0.4, -0.6, 0.3), along_baseline_m=0.001)
    rec = render_room(root / "rec", frames=2, truth=truth)
    nominal = root / "nominal.yaml"
    save_rig(nominal_rig(), nominal)
    return rec, nominal, truth


@pytest.mark.slow
def test_refines_a_knocked_rig_and_writes_the_corrected_calibration(
    knocked: tuple[Path, Path, Rig], tmp_path: Path
) -> None:
    rec, nominal, truth = knocked
    out = tmp_path / "refined.yaml"
    res = run("calibrate", "refine", rec, "--calibration", nominal, "--out", out, "--vpc-size", "320x240")
    assert res.returncode == 0, res.stderr
    print(res.stdout)
    refined = load_rig(out)
    before = relative_rotation_error_deg(load_rig(nominal), truth)
    after = relative_rotation_error_deg(refined, truth)
    print(f"relative rotation error: {before:.4f}° before, {after:.4f}° after")
    assert before > 0.7 and after <= 0.02
    assert refined.baseline() == pytest.approx(load_rig(nominal).baseline(), abs=1e-12)  # never the scale
    for text in ("x, the baseline (pitch)", "y, vertical (vergence)", "total angle", "vertical disparity",
                 "before p50", "after p50", "baseline direction", f"wrote {out}"):  # fmt: skip
        assert text in res.stdout, text
    assert not list(tmp_path.glob("*.orig.yaml"))


@pytest.mark.slow
def test_in_place_keeps_the_original(knocked: tuple[Path, Path, Rig], tmp_path: Path) -> None:
    rec, nominal, truth = knocked
    calibration = tmp_path / "rig.yaml"
    calibration.write_bytes(nominal.read_bytes())
    res = run("calibrate", "refine", rec, "-c", calibration, "--out", calibration, "--frames", "1")
    assert res.returncode == 0, res.stderr
    backup = tmp_path / "rig.orig.yaml"
    assert backup.read_bytes() == nominal.read_bytes()
    assert f"the original is kept as {backup}" in " ".join(res.stdout.split())
    assert relative_rotation_error_deg(load_rig(calibration), truth) <= 0.05


def _recording(root: Path, left: np.ndarray, right: np.ndarray, cameras: list[str] | None = None) -> Path:
    """Two sets of ``cameras`` (default: left and right), the first camera's frame ``left``."""
    names = cameras or ["left", "right"]
    with RecordingWriter(root, cameras=names) as writer:
        for seq in range(2):
            writer.write_set_images(seq, [seq * 33_000_000] * len(names), [left, right][: len(names)])
    return root


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path) -> None:
    nominal = tmp_path / "nominal.yaml"
    save_rig(nominal_rig(), nominal)
    cam = nominal_rig().cameras["left"]
    texture = np.random.default_rng(0).integers(0, 256, (cam.height, cam.width), dtype=np.uint8)
    left = cv2.GaussianBlur(texture, (5, 5), 1.5)
    rec = _recording(tmp_path / "textured", left, cv2.flip(left, 1))
    rng = np.random.default_rng(1)
    wall = [np.clip(120 + rng.normal(0, 1.5, left.shape), 0, 255).astype(np.uint8) for _ in range(2)]
    out = tmp_path / "out.yaml"
    assert_one_line_error(
        run("calibrate", "refine", _recording(tmp_path / "blank", *wall), "-c", nominal, "--out", out),
        "not enough matches",
    )
    assert_one_line_error(
        run("calibrate", "refine", _recording(tmp_path / "same", left, left), "-c", nominal, "--out", out),
        "a recording of one camera",
    )
    mono = _recording(tmp_path / "mono", left, left, ["left"])
    assert_one_line_error(
        run("calibrate", "refine", mono, "-c", nominal, "--out", out), "camera(s) left only"
    )
    assert_one_line_error(
        run("calibrate", "refine", tmp_path / "nowhere", "-c", nominal, "--out", out), "nowhere"
    )
    assert_one_line_error(
        run("calibrate", "refine", rec, "-c", nominal, "--out", out, "--baseline-direction", "sideways"),
        "--baseline-direction",
    )
    stereo = tmp_path / "stereo.yaml"
    stereo.write_text("lr_check_scale: 1\n")
    assert_one_line_error(
        run("calibrate", "refine", rec, "-c", nominal, "--out", out, "--stereo", stereo),
        "--stereo applies to a ring",
    )
    single = tmp_path / "single.yaml"
    save_rig(Rig({"left": load_rig(nominal).cameras["left"]}, {"left": np.eye(4)}), single)
    assert_one_line_error(run("calibrate", "refine", rec, "-c", single, "--out", out), "holds one camera")
    other = tmp_path / "other.yaml"
    rig = load_rig(nominal)
    save_rig(Rig({"front": rig.cameras["left"], "back": rig.cameras["right"]},
                 {"front": rig.T_rig_cam["left"], "back": rig.T_rig_cam["right"]}), other)  # fmt: skip
    assert_one_line_error(run("calibrate", "refine", rec, "-c", other, "--out", out), "no camera 'left'")
    assert not out.exists()
