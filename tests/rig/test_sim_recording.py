"""``simulate_recording`` and ``rig sim``: the recording layout, calibration, exact ground truth,
and one-line errors from the real console script."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.formats import load_rig
from rig.errors import ConfigError, RecordingError
from rig.recording import FRAMES_HEADER, Recording
from rig.rectified import RectifiedPairConfig
from rig.sim import Preset, get_preset, simulate_recording
from tests.helpers.command import assert_one_line_error, run_rig

SMALL_VPC = RectifiedPairConfig(width=160, height=120)


def small_preset(name: str = "paper-sim", scale: float = 0.25) -> Preset:
    return get_preset(name).scaled(scale)


def test_plane_recording_layout_and_ground_truth(tmp_path: Path) -> None:
    preset = small_preset()
    out = tmp_path / "rec"
    seen: list[tuple[float, int]] = []
    simulate_recording(
        preset, "plane", out, distances=(4.0, 5.0), frames_per_distance=2, texture="paper", seed=3,
        noise_std=2.0, supersample=2, vpc=SMALL_VPC, reference=True,
        progress=lambda d, t: seen.append((d, t)),
    )  # fmt: skip
    # Whole pairs once each is written, fractions of a pair while it renders, never backwards.
    assert [(d, t) for d, t in seen if d == int(d)] == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert any(d != int(d) for d, _ in seen) and all(a[0] <= b[0] for a, b in itertools.pairwise(seen))
    rec = Recording(out)
    assert (out / "frames.csv").read_text().splitlines()[0] == ",".join(FRAMES_HEADER)
    assert [p.seq for p in rec.pairs] == [0, 1, 2, 3]
    period = round(1e9 / preset.fps)
    assert [p.left_ts_ns for p in rec.pairs] == [i * period for i in range(4)]
    assert all(p.left_ts_ns == p.right_ts_ns for p in rec.pairs)
    assert rec.meta["generator"] == "rig sim" and rec.meta["preset"] == "paper-sim"
    assert rec.meta["scene"] == "plane" and rec.meta["distances"] == [4.0, 5.0] and rec.meta["fps"] == 30.0
    left = rec.read_image(rec.pairs[0], "left")
    assert left.shape == (256, 256) and left.dtype == np.uint8
    assert rec.pairs[0].left_file == "left/000000.png"
    # Noise differs between repeated frames of one distance; the scene does not.
    assert not np.array_equal(left, rec.read_image(rec.pairs[1], "left"))
    assert np.abs(left.astype(int) - rec.read_image(rec.pairs[1], "left")).mean() < 4

    assert rec.calibration_path is not None
    rig = load_rig(rec.calibration_path)
    for name in ("left", "right"):
        assert rig.cameras[name] == preset.rig.cameras[name]
        np.testing.assert_allclose(rig.T_rig_cam[name], preset.rig.T_rig_cam[name], atol=1e-15)

    doc = json.loads((out / "ground_truth" / "scene.json").read_text())
    assert doc["preset"] == "paper-sim" and doc["baseline_m"] == pytest.approx(0.2)
    assert doc["vpc"]["width"] == 160 and doc["vpc"]["fx"] == pytest.approx(80.0)
    assert [f["seq"] for f in doc["frames"]] == [0, 1, 2, 3]
    for frame, k in zip(doc["frames"], (4.0, 4.0, 5.0, 5.0), strict=True):
        assert frame["kind"] == "plane" and frame["texture"] == "paper" and frame["seed"] == 3
        assert frame["distance_baselines"] == k and frame["distance_m"] == pytest.approx(0.2 * k)
        depth = np.load(out / frame["depth"])
        # The plane is fronto-parallel to the rig and the left VPC looks straight ahead: z = k·B.
        assert depth.dtype == np.float32 and depth.shape == (120, 160)
        np.testing.assert_allclose(depth, np.float32(0.2 * k), rtol=1e-6)
        ref_l = cv2.imread(str(out / frame["reference"]["left"]), cv2.IMREAD_UNCHANGED)
        ref_r = cv2.imread(str(out / frame["reference"]["right"]), cv2.IMREAD_UNCHANGED)
        assert ref_l.shape == (120, 160) and ref_r.shape == (120, 160)
        # A rectified pair: the right image is the left shifted by fx·B/Z = 80/k px (integer here).
        disp = round(80.0 / k)
        diff = np.abs(ref_l[:, disp:].astype(int) - ref_r[:, :-disp])
        assert diff.mean() < 1.0, (k, diff.mean())


def test_room_recording_moves_through_a_closed_room(tmp_path: Path) -> None:
    out = simulate_recording(small_preset("prototype", 0.125), "room", tmp_path / "room", frames=2,
                             supersample=1, vpc=SMALL_VPC, color=True)  # fmt: skip
    rec = Recording(out)
    assert len(rec) == 2 and rec.read_image(rec.pairs[0], "left").shape == (120, 160, 3)
    doc = json.loads((out / "ground_truth" / "scene.json").read_text())
    poses = [np.array(f["T_world_rig"]) for f in doc["frames"]]
    assert not np.allclose(poses[0], poses[1])
    for f in doc["frames"]:
        depth = np.load(out / f["depth"])
        assert np.isfinite(depth).all() and (depth > 0).all()  # the room encloses the rig


def test_every_indexed_pair_has_ground_truth_after_a_crash(tmp_path: Path) -> None:
    def crash(done: float, total: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    out = tmp_path / "rec"
    with pytest.raises(KeyboardInterrupt):
        simulate_recording(small_preset(), "plane", out, distances=(3, 4, 5), supersample=1, vpc=SMALL_VPC,
                           reference=True, progress=crash)  # fmt: skip
    rec = Recording(out)
    assert [p.seq for p in rec.pairs] == [0, 1]
    doc = json.loads((out / "ground_truth" / "scene.json").read_text())
    for pair in rec.pairs:
        entry = doc["frames"][pair.seq]
        assert (out / entry["depth"]).is_file() and (out / entry["reference"]["left"]).is_file()


def test_simulate_recording_rejects_bad_requests(tmp_path: Path) -> None:
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "x").write_text("keep me")
    with pytest.raises(RecordingError, match="not an empty directory"):
        simulate_recording(small_preset(), "plane", busy)
    assert (busy / "x").read_text() == "keep me"
    with pytest.raises(ConfigError, match="plane, room"):
        simulate_recording(small_preset(), "forest", tmp_path / "a")
    with pytest.raises(ConfigError, match="room scene takes frames"):
        simulate_recording(small_preset(), "room", tmp_path / "b", distances=(3,))
    with pytest.raises(ConfigError, match="paper-sim, prototype"):
        simulate_recording("unity", "plane", tmp_path / "c")
    with pytest.raises(ConfigError, match="distances"):
        simulate_recording(small_preset(), "plane", tmp_path / "d", distances=(3, -1))


def test_rig_sim_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "sim"
    res = run_rig([
        "sim", "--preset", "prototype", "--scene", "plane", "--distances", "4,8", "--scale", "0.125",
        "--supersample", "2", "--vpc-size", "160x120", "--texture", "bricks", "--noise", "0",
        "--reference", "--out", str(out),
    ])  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "wrote 2 pairs" in res.stdout
    expected_files = [
        "recording.json", "frames.csv", "calibration.yaml", "left/000000.png", "right/000001.png",
        "ground_truth/scene.json", "ground_truth/depth/000001.npy",
        "ground_truth/reference/left/000000.png", "ground_truth/reference/right/000001.png",
    ]  # fmt: skip
    for rel in expected_files:
        assert (out / rel).is_file(), rel
    rec = Recording(out)
    assert len(rec) == 2 and rec.meta["texture"] == "bricks" and rec.meta["noise_std"] == 0.0
    assert rec.read_image(rec.pairs[1], "right").shape == (120, 160)
    depth = np.load(out / "ground_truth/depth/000001.npy")
    np.testing.assert_allclose(depth, np.float32(8 * 0.072), rtol=1e-6)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--preset", "unity"], "paper-sim, prototype"),
        (["--scene", "forest"], "plane, room"),
        (["--distances", "3,x"], "--distances"),
        (["--distances", "-1"], "--distances"),
        (["--noise", "-2"], "--noise"),
        (["--seed", "abc"], "--seed"),
        (["--texture", "marble"], "noise, blobs"),
        (["--vpc-size", "10by10"], "--vpc-size"),
        (["--scene", "room", "--distances", "3"], "--frames"),
        (["--supersample", "0"], "--supersample"),
        (["--lens", "perfect"], "honest, ideal"),
    ],
)
def test_rig_sim_bad_arguments_fail_in_one_line(tmp_path: Path, args: list[str], needle: str) -> None:
    assert_one_line_error(run_rig(["sim", *args, "--out", str(tmp_path / "never")]), needle)
    assert not (tmp_path / "never").exists()


def test_rig_sim_refuses_a_non_empty_out(tmp_path: Path) -> None:
    (tmp_path / "keep.txt").write_text("data")
    assert_one_line_error(run_rig(["sim", "--out", str(tmp_path)]), "not an empty directory")
    assert (tmp_path / "keep.txt").read_text() == "data" and sorted(p.name for p in tmp_path.iterdir()) == [
        "keep.txt"
    ]
