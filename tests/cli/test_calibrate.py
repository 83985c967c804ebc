"""`rig calibrate intrinsics|stereo` end to end through the installed console script, on rendered
chessboard images written as PNG files (true lens and mount known; 480x480, 2x2 supersampled).
Corner refinement is on by default; ``--no-refine`` keeps the detector's corners."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.formats import load_camera, load_rig
from calibration.geometry import invert_transform, rotation_angle
from rig.sim import divergent_rig
from tests.helpers.boards import (
    board_pose,
    circle_views,
    image_difference,
    render_board,
    true_lenses,
)
from tests.helpers.command import run_rig

LENS = true_lenses(480)["kannala_brandt"]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_rig(args)


@pytest.fixture(scope="module")
def mono_images(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("mono")
    poses = circle_views()
    for i in (0, 1, 2, 3, 4, 5, 7, 9, 11):  # centre, 35° ring and rim views
        cv2.imwrite(str(folder / f"view{i:02d}.png"), render_board(LENS, poses[i]))
    (folder / "view99.png").write_bytes(PNG_SIGNATURE + b"truncated garbage")
    return folder


@pytest.fixture(scope="module")
def stereo_images(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """Boards in the overlap wedge of an 87°, 2°-pitched rig rendered in both cameras."""
    folder = tmp_path_factory.mktemp("stereo")
    rig = divergent_rig(LENS, LENS, 0.072, 87.0, 2.0)
    wedge = [
        board_pose(th, ph, 0.45, tilt, spin)
        for th, ph, tilt, spin in [
            (0, 0, (0, 0), 0), (20, 0, (15, 0), 10), (20, 180, (0, 15), -10), (25, 90, (0, -20), 20),
            (25, 270, (20, 0), 30), (30, 30, (0, 0), -20), (30, 150, (0, 0), 15), (15, 220, (-15, 10), 5),
            (10, 45, (30, 0), 45), (10, 135, (-30, 0), -45),
        ]
    ]  # fmt: skip
    for k, T_rig_board in enumerate(wedge):
        for name in ("left", "right"):
            T = invert_transform(rig.T_rig_cam[name]) @ T_rig_board
            cv2.imwrite(str(folder / f"{name}{k}.png"), render_board(LENS, T))
    return folder, invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]


def test_intrinsics_from_rendered_images(mono_images: Path, tmp_path: Path) -> None:
    out = tmp_path / "cam.yaml"
    proc = run(
        "calibrate", "intrinsics", "--model", "kannala_brandt", "--images", mono_images / "*.png",
        "--board", "9x6", "--square", "0.05", "--out", out, "--name", "front",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    # The corrupt image is listed with its reason and skipped.
    assert "view99.png" in proc.stderr and "cannot be read" in proc.stderr
    assert "view00.png" in proc.stdout and "RMS" in proc.stdout
    before, after = _refinement_rms(proc.stdout, "front")
    assert after < before
    camera = load_camera(out, "front")
    assert camera.name == "kannala_brandt" and (camera.width, camera.height) == (480, 480)
    rms, worst, _ = image_difference(LENS, camera)

    raw_out = tmp_path / "raw.yaml"
    proc = run(
        "calibrate", "intrinsics", "--model", "kannala_brandt", "--images", mono_images / "*.png",
        "--board", "9x6", "--square", "0.05", "--out", raw_out, "--name", "front", "--no-refine",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "corner refinement" not in proc.stdout and "--no-refine" in proc.stdout
    raw_rms, raw_worst, _ = image_difference(LENS, load_camera(raw_out, "front"))
    print(f"\nlens over the image circle: --no-refine {raw_rms:.4f} (max {raw_worst:.4f}) px, "
          f"refined {rms:.4f} (max {worst:.4f}) px")  # fmt: skip
    assert rms <= 0.1 and worst <= 0.2 and rms < raw_rms / 2, (rms, worst, raw_rms)
    picture = tmp_path / "cam_residuals.png"
    assert picture.read_bytes()[:8] == PNG_SIGNATURE
    image = cv2.imread(str(picture))
    assert image is not None and image.shape[0] > 200 and image.shape[1] > 200


def _refinement_rms(stdout: str, name: str) -> tuple[float, float]:
    """(before, after) RMS from the line `NAME: corner refinement: RMS a -> b px, ...`."""
    found = re.search(rf"^{name}: corner refinement: RMS ([0-9.]+) -> ([0-9.]+) px", stdout, re.MULTILINE)
    assert found is not None, stdout
    return float(found[1]), float(found[2])


def test_too_few_views_is_exit_2_with_one_line(mono_images: Path, tmp_path: Path) -> None:
    few = tmp_path / "few"
    few.mkdir()
    for name in ("view00.png", "view99.png"):
        shutil.copy(mono_images / name, few / name)
    proc = run(
        "calibrate", "intrinsics", "--images", few / "*.png", "--board", "9x6", "--square", "0.05",
        "--out", tmp_path / "cam.yaml",
    )  # fmt: skip
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "only 1 usable view(s), need at least 3" in errors[0]
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "cam.yaml").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--board", "9", "--square", "0.05"], "COLSxROWS"),
        (["--board", "9x6", "--square", "-1"], "--square must be a positive"),
        (["--board", "9x6", "--square", "0.05", "--model", "fisheye"], "--model must be one of"),
        (["--board", "9x6", "--square", "0.05", "--loss", "cauchy"], "--loss must be one of"),
    ],
)
def test_bad_options_are_one_line(mono_images: Path, tmp_path: Path, args: list[str], message: str) -> None:
    proc = run(
        "calibrate", "intrinsics", "--images", mono_images / "*.png", "--out", tmp_path / "x.yaml", *args
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("error:") and message in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_no_matching_images(tmp_path: Path) -> None:
    proc = run(
        "calibrate", "intrinsics", "--images", tmp_path / "*.png", "--board", "9x6", "--square", "0.05",
        "--out", tmp_path / "x.yaml",
    )  # fmt: skip
    assert proc.returncode == 2 and "no images match" in proc.stderr


def test_stereo_from_rendered_images(stereo_images: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    folder, T_true = stereo_images
    out = tmp_path / "rig.yaml"
    proc = run(
        "calibrate", "stereo", "--left", folder / "left*.png", "--right", folder / "right*.png",
        "--board", "9x6", "--square", "0.05", "--out", out, "--model", "kannala_brandt",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "left0.png|right0.png" in proc.stdout and "baseline" in proc.stdout
    for name in ("left", "right"):
        before, after = _refinement_rms(proc.stdout, name)
        assert after < before
    rig = load_rig(out)
    assert rig.names == ["left", "right"]
    T_est = invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]
    rot = math.degrees(rotation_angle((invert_transform(T_true) @ T_est)[:3, :3]))
    trans = float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    print(f"\nstereo from 10 image pairs, no guess: {rot:.4f}°, {trans * 1e3:.3f} mm")
    assert rot < 0.05 and trans < 0.5e-3, (rot, trans)  # the calibration tolerance, end to end
    assert (tmp_path / "rig_residuals.png").read_bytes()[:8] == PNG_SIGNATURE


def test_stereo_with_fixed_intrinsics_and_mismatched_lists(
    stereo_images: tuple[Path, np.ndarray], tmp_path: Path
) -> None:
    folder, T_true = stereo_images
    # The true lens as an intrinsics file, as `rig calibrate intrinsics` writes it.
    from calibration.formats import save_rig
    from calibration.rig import Rig

    lens_file = tmp_path / "lens.yaml"
    save_rig(Rig({"cam0": LENS}, {"cam0": np.eye(4)}), lens_file)
    out = tmp_path / "rig.yaml"
    proc = run(
        "calibrate", "stereo", "--left", folder / "left*.png", "--right", folder / "right*.png",
        "--board", "9x6", "--square", "0.05", "--out", out, "--left-intrinsics", lens_file,
        "--right-intrinsics", lens_file, "--fix-intrinsics",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    _refinement_rms(proc.stdout, "left")
    rig = load_rig(out)
    assert rig.cameras["left"] == LENS and rig.cameras["right"] == LENS
    T_est = invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]
    rot = math.degrees(rotation_angle((invert_transform(T_true) @ T_est)[:3, :3]))
    trans = float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    print(f"\nstereo with the true lenses held: {rot:.4f}°, {trans * 1e3:.3f} mm")
    assert rot < 0.02 and trans < 0.2e-3, (rot, trans)

    proc = run(
        "calibrate", "stereo", "--left", folder / "left*.png", "--right", folder / "right1*.png",
        "--board", "9x6", "--square", "0.05", "--out", out,
    )  # fmt: skip
    assert proc.returncode == 2 and "--left matches 10 images but --right matches 1" in proc.stderr
