"""`rig process` through the installed console script (real subprocess, real files)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from calibration import save_rig
from calibration.geometry import invert_transform
from calibration.rig import Rig
from rig.depth import depth_from_png_mm
from rig.recording import RecordingWriter
from rig.rectified import RectifiedPairConfig
from tests.helpers.command import clean_env, run_rig
from tests.helpers.shots import StereoShot, central_box, plane_shot, prototype_rig

VPC = RectifiedPairConfig(width=320, height=240)
VPC_ARGS = ["--vpc-size", "320x240", "--vpc-hfov", "90"]
STEREO_64 = "disparity_range: 64\n"


def run(*args: str | Path, tmp: Path) -> subprocess.CompletedProcess[str]:
    """``rig ARGS`` with its LUT cache under ``tmp``."""
    return run_rig(args, clean_env(tmp))


def within_2_percent(depth_png: Path, truth: np.ndarray) -> float:
    mm = np.asarray(cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED))
    assert mm.dtype == np.uint16 and mm.shape == truth.shape
    depth = depth_from_png_mm(mm)
    box = central_box(truth.shape)
    rel = np.abs(depth[box] - truth[box]) / truth[box]
    return float(np.mean(np.nan_to_num(rel, nan=np.inf) <= 0.02))


def kalibr_camchain(rig: Rig) -> dict[str, object]:
    """The rig as Kalibr writes it: cam0 = left, cam1 = right with T_cn_cnm1 = T_right_left."""
    doc: dict[str, object] = {}
    for i, name in enumerate(("left", "right")):
        p = rig.cameras[name].param_dict
        cam: dict[str, object] = {
            "camera_model": "pinhole",
            "distortion_model": "equidistant",
            "intrinsics": [p["fx"], p["fy"], p["cx"], p["cy"]],
            "distortion_coeffs": [p["k1"], p["k2"], p["k3"], p["k4"]],
            "resolution": [rig.cameras[name].width, rig.cameras[name].height],
            "rostopic": f"/cam{i}/image_raw",
        }
        if i == 1:
            T = invert_transform(rig.T_rig_cam["right"]) @ rig.T_rig_cam["left"]
            cam["T_cn_cnm1"] = T.tolist()
        doc[f"cam{i}"] = cam
    return doc


@pytest.fixture(scope="module")
def shot() -> StereoShot:
    return plane_shot(5.0, scale=0.5, vpc=VPC)


def write_recording(root: Path, shot: StereoShot, seqs: list[int], colour: bool = False) -> Path:
    left, right = shot.left, shot.right
    if colour:
        left = (left[..., None] * np.array([0.7, 0.9, 1.0])).astype(np.uint8)
        right = (right[..., None] * np.array([0.7, 0.9, 1.0])).astype(np.uint8)
    with RecordingWriter(root, meta={"generator": "test"}) as w:
        for seq in seqs:
            w.write_images(seq, seq * 1000, seq * 1000 + 5, left, right)
    save_rig(shot.rig, root / "rig.yaml")
    (root / "stereo.yaml").write_text(STEREO_64)
    return root


def small(rec: Path) -> list[str | Path]:
    """The test VPC and 64 disparities (at 320 px, 128 would leave 40 % of the columns unmatched)."""
    return [*VPC_ARGS, "--stereo", rec / "stereo.yaml"]


@pytest.mark.slow
def test_process_a_rig_sim_recording(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    sim_args = ["--preset", "prototype", "--scale", "0.5", "--scene", "plane", "--distances", "4.5,9"]
    # The honest lens's optics and exposures, 1 grey level of gaussian noise, no rim darkening.
    sim_args += ["--supersample", "2", "--lens", "honest", "--noise", "1", "--vignetting", "0"]
    sim = run("sim", *sim_args, "--out", rec, *VPC_ARGS, tmp=tmp_path)
    assert sim.returncode == 0, sim.stderr
    # At 320 px wide, 64 disparities (Z > 2.5 B at fx = 160) keep the left band of unmatched
    # columns out of the central box.
    (tmp_path / "stereo.yaml").write_text(STEREO_64)
    out = tmp_path / "out"
    # No --calibration: the recording's own calibration.yaml is used.
    res = run("process", rec, "--out", out, *VPC_ARGS, "--stereo", tmp_path / "stereo.yaml", tmp=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "processed 2 of 2 pairs" in res.stdout and "calibration.yaml" in res.stdout
    for seq in (0, 1):
        truth = np.load(rec / "ground_truth" / "depth" / f"{seq:06d}.npy")
        assert within_2_percent(out / "depth" / f"{seq:06d}.png", truth) >= 0.95


def test_output_layout_vpc_json_and_depth(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [3, 4])
    (tmp_path / "stereo.yaml").write_text("disparity_range: 64\nsgbm_mode: 2  # ROS number of 3way\n")
    out = tmp_path / "out"
    res = run(
        "process", rec, "--calibration", rec / "rig.yaml", "--out", out, *VPC_ARGS,
        "--stereo", tmp_path / "stereo.yaml", "--ply", "--preview", tmp=tmp_path,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in out.iterdir()) == [
        "cloud", "depth", "left", "preview", "range", "right", "run.json", "vpc.json"
    ]  # fmt: skip
    run_doc = json.loads((out / "run.json").read_text())
    assert run_doc["recording"] == str(rec.resolve())
    assert run_doc["products"] == ["range", "depth", "left", "right", "cloud", "preview"]
    assert run_doc["stereo"]["disparity_range"] == 64 and run_doc["vpc"]["width"] == 320
    for sub in ("depth", "range", "left", "right"):
        assert sorted(p.name for p in (out / sub).iterdir()) == ["000003.png", "000004.png"]
    doc = json.loads((out / "vpc.json").read_text())
    assert list(doc) == ["projection", "width", "height", "fx", "fy", "cx", "cy", "baseline_m", "R_rig_vpc"]
    assert doc["projection"] == "pinhole" and np.allclose(doc["R_rig_vpc"], shot.pair.R_rig_rect)
    assert (doc["width"], doc["height"]) == (320, 240)
    assert doc["fx"] == pytest.approx(160.0) and doc["cx"] == pytest.approx(159.5)
    assert doc["baseline_m"] == pytest.approx(shot.rig.baseline())
    left = np.asarray(cv2.imread(str(out / "left" / "000003.png"), cv2.IMREAD_UNCHANGED))
    assert left.shape == (240, 320) and left.dtype == np.uint8
    assert within_2_percent(out / "depth" / "000003.png", shot.depth) >= 0.95
    preview = np.asarray(cv2.imread(str(out / "preview" / "000003.png"), cv2.IMREAD_UNCHANGED))
    assert preview.shape == (240, 640 + 72, 3)  # left view | colour depth | colour bar in metres
    assert np.array_equal(preview[:, :320, 0], left)  # the left part is the left rectified image
    ply = (out / "cloud" / "000003.ply").read_bytes()
    assert ply.startswith(b"ply\nformat binary_little_endian 1.0\n")


def test_missing_and_corrupt_frames_are_reported_by_seq_and_skipped(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [0, 5, 7, 9])
    (rec / "right" / "000005.png").unlink()
    (rec / "left" / "000007.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not an image")
    out = tmp_path / "out"
    res = run("process", rec, "--calibration", rec / "rig.yaml", "--out", out, *VPC_ARGS, tmp=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "skipped seq 5" in res.stderr and "000005.png" in res.stderr
    assert "skipped seq 7" in res.stderr and "not a readable image" in res.stderr
    assert "processed 2 of 4 pairs, 2 skipped" in res.stdout
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["000000.png", "000009.png"]
    assert "Traceback" not in res.stderr


def test_kalibr_camchain_gives_the_same_depth(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [0])
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(kalibr_camchain(shot.rig)))
    outs = {}
    for name, cal in (("yaml", rec / "rig.yaml"), ("kalibr", tmp_path / "camchain.yaml")):
        outs[name] = tmp_path / name
        res = run("process", rec, "-c", cal, "-o", outs[name], *small(rec), tmp=tmp_path)
        assert res.returncode == 0, res.stderr
    a = np.asarray(cv2.imread(str(outs["yaml"] / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED), dtype=int)
    b = np.asarray(cv2.imread(str(outs["kalibr"] / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED), dtype=int)
    both = (a > 0) & (b > 0)
    assert both.mean() > 0.6
    assert np.mean(np.abs(a - b)[both] <= 1) > 0.99
    assert json.loads((outs["kalibr"] / "vpc.json").read_text())["baseline_m"] == pytest.approx(
        shot.rig.baseline()
    )
    assert within_2_percent(outs["kalibr"] / "depth" / "000000.png", shot.depth) >= 0.95


def test_colour_recording(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [0], colour=True)
    out = tmp_path / "out"
    res = run("process", rec, "-c", rec / "rig.yaml", "-o", out, *small(rec), tmp=tmp_path)
    assert res.returncode == 0, res.stderr
    left = np.asarray(cv2.imread(str(out / "left" / "000000.png"), cv2.IMREAD_UNCHANGED))
    assert left.shape == (240, 320, 3)
    assert within_2_percent(out / "depth" / "000000.png", shot.depth) >= 0.95


def test_bad_calibration_and_options_exit_2_with_one_line(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [0])
    bad = tmp_path / "bad.yaml"
    bad.write_text("cameras:\n  left: {model: kannala_brandt, width: 640}\n")
    cases: list[tuple[list[str | Path], str]] = [
        (["-c", bad], str(bad)),
        (["-c", tmp_path / "missing.yaml"], "missing.yaml"),
        (["-c", rec / "rig.yaml", "--vpc-size", "320by240"], "--vpc-size"),
        (["-c", rec / "rig.yaml", "--vpc-hfov", "200"], "--vpc-hfov"),
    ]
    for extra, needle in cases:
        res = run("process", rec, "-o", tmp_path / "out", *extra, tmp=tmp_path)
        assert res.returncode == 2, (extra, res.stdout, res.stderr)
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], res.stderr
    # A recording without calibration.yaml needs --calibration.
    res = run("process", rec, "-o", tmp_path / "out2", tmp=tmp_path)
    assert res.returncode == 2 and "--calibration" in res.stderr


def test_no_processable_pair_is_an_error(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [0, 1])
    for p in (rec / "left").iterdir():
        p.write_bytes(b"garbage")
    res = run("process", rec, "-c", rec / "rig.yaml", "-o", tmp_path / "out", *VPC_ARGS, tmp=tmp_path)
    assert res.returncode == 2
    assert "skipped seq 0" in res.stderr and "skipped seq 1" in res.stderr
    assert "no pair of 2" in res.stderr


def test_a_swapped_calibration_stops_with_one_line_naming_it(tmp_path: Path, shot: StereoShot) -> None:
    # Before: exit status 0 and a few per cent of the pixels with (wrong) depth.
    rec = write_recording(tmp_path / "rec", shot, [0, 1, 2])
    rig = shot.rig
    swapped = Rig(
        {"left": rig.cameras["right"], "right": rig.cameras["left"]},
        {"left": rig.T_rig_cam["right"], "right": rig.T_rig_cam["left"]},
    )
    save_rig(swapped, tmp_path / "swapped.yaml")
    res = run(
        "process",
        rec,
        "-c",
        tmp_path / "swapped.yaml",
        "-o",
        tmp_path / "out",
        *small(rec),
        tmp=tmp_path,
    )
    assert res.returncode == 2, (res.stdout, res.stderr)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "calibration check on pair 0: cameras left and right are swapped" in lines[0]
    assert not (tmp_path / "out" / "depth" / "000000.png").exists()
    # rig export mcap makes the same check, with the same line, and writes nothing.
    exported = run(
        "export", "mcap", rec, "-c", tmp_path / "swapped.yaml", "--out", tmp_path / "x.mcap", *small(rec),
        tmp=tmp_path,
    )  # fmt: skip
    assert exported.returncode == 2, (exported.stdout, exported.stderr)
    assert [ln for ln in exported.stderr.splitlines() if ln.strip()] == lines
    assert not list(tmp_path.glob("x.mcap*"))
    # The check can be skipped (then the wrong depth is the user's choice).
    forced = run(
        "process", rec, "-c", tmp_path / "swapped.yaml", "-o", tmp_path / "out2", *small(rec),
        "--no-calibration-check", tmp=tmp_path,
    )  # fmt: skip
    assert forced.returncode == 0 and "processed 3 of 3 pairs" in forced.stdout


def test_a_calibration_of_another_size_is_one_line_not_one_per_frame(
    tmp_path: Path, shot: StereoShot
) -> None:
    # Before: one "skipped seq N: left image is 640x480 but its calibration is 1280x960" per frame.
    rec = write_recording(tmp_path / "rec", shot, list(range(6)))
    save_rig(prototype_rig(1.0), tmp_path / "full.yaml")  # the same lenses at twice the size
    res = run(
        "process",
        rec,
        "-c",
        tmp_path / "full.yaml",
        "-o",
        tmp_path / "out",
        *small(rec),
        tmp=tmp_path,
    )
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert (
        "camera left: the frames of" in lines[0]
        and "are 640x480 but the calibration is for 1280x960" in lines[0]
    )
    assert "(the frames are ×0.5 its size)" in lines[0]


def test_the_right_calibration_passes_the_check_silently(tmp_path: Path, shot: StereoShot) -> None:
    rec = write_recording(tmp_path / "rec", shot, [0])
    res = run("process", rec, "-c", rec / "rig.yaml", "-o", tmp_path / "out", *small(rec), tmp=tmp_path)
    assert res.returncode == 0 and "calibration check" not in res.stderr, res.stderr
