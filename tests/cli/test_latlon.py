"""`rig sim` and `rig process` with the lat-lon pair through the installed console script:
ground truth, outputs and their accuracy against it (``rig sim``'s default honest lens), and bad
input as one line, exit status 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration import save_rig
from calibration.geometry import make_transform, rot_y
from calibration.models import create
from calibration.rig import Rig
from rig.depth import depth_from_png_mm
from rig.recording import RecordingWriter
from tests.cli.test_process import run

LATLON = ["--projection", "latlon", "--px-per-deg", "1.4"]
STEREO_32 = "disparity_range: 32\n"


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A quarter-size prototype's room pair with the lat-lon ground truth of 32 disparities."""
    tmp = tmp_path_factory.mktemp("latlon-cli")
    (tmp / "stereo.yaml").write_text(STEREO_32)
    rec = tmp / "rec"
    res = run(
        "sim", "--preset", "prototype", "--scene", "room", "--frames", "1", "--scale", "0.25",
        "--supersample", "2", *LATLON, "--stereo", tmp / "stereo.yaml", "--out", rec, tmp=tmp / "c",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "left latlon view's range" in res.stdout
    return rec


def test_sim_writes_the_lat_lon_ground_truth(room: Path) -> None:
    doc = json.loads((room / "ground_truth" / "scene.json").read_text())
    assert doc["vpc"]["projection"] == "latlon" and doc["vpc"]["blind_band_px"] == 32
    assert not (room / "ground_truth" / "depth").exists()
    truth = np.load(room / doc["frames"][0]["range"])
    assert truth.shape == (doc["vpc"]["height"], doc["vpc"]["width"])
    assert np.isfinite(truth).mean() > 0.99  # the closed room: every ray hits a wall


def test_process_writes_range_and_vpc_json_of_the_lat_lon_pair(room: Path, tmp_path: Path) -> None:
    stereo = room.parent / "stereo.yaml"
    out = tmp_path / "out"
    res = run(
        "process", room, "--out", out, *LATLON, "--stereo", stereo, "--ply", "--preview", tmp=tmp_path / "c"
    )
    assert res.returncode == 0, res.stderr
    assert "processed 1 of 1 pairs" in res.stdout and "lat-lon" in res.stdout and "1.400 px/deg" in res.stdout
    assert sorted(p.name for p in out.iterdir()) == [
        "cloud",
        "left",
        "preview",
        "range",
        "right",
        "run.json",
        "vpc.json",
    ]
    doc = json.loads((out / "vpc.json").read_text())
    assert list(doc) == ["projection", "width", "height", "fx", "fy", "cx", "cy", "baseline_m", "R_rig_vpc"]
    assert doc["projection"] == "latlon" and doc["fx"] == pytest.approx(math.degrees(1.4))
    assert np.allclose(np.array(doc["R_rig_vpc"]) @ np.array(doc["R_rig_vpc"]).T, np.eye(3), atol=1e-12)
    gt = json.loads((room / "ground_truth" / "scene.json").read_text())
    assert {k: doc[k] for k in ("width", "height", "cx", "cy")} == {
        k: gt["vpc"][k] for k in ("width", "height", "cx", "cy")
    }
    mm = np.asarray(cv2.imread(str(out / "range" / "000000.png"), cv2.IMREAD_UNCHANGED))
    assert mm.dtype == np.uint16 and mm.shape == (doc["height"], doc["width"])
    rng = depth_from_png_mm(mm)
    truth = np.load(room / gt["frames"][0]["range"])
    ok = np.isfinite(rng) & np.isfinite(truth)
    err = np.abs(rng[ok] / truth[ok] - 1.0)
    # Quarter-size lenses at 1.4 px/deg: coarse, but the whole overlap (floor, ceiling) has range.
    assert ok.mean() > 0.35 and np.median(err) < 0.06
    assert (out / "cloud" / "000000.ply").read_bytes().startswith(b"ply\n")


def test_a_field_wider_than_the_overlap_is_clipped_with_one_line(room: Path, tmp_path: Path) -> None:
    stereo = room.parent / "stereo.yaml"
    res = run(
        "process", room, "--out", tmp_path / "o", *LATLON, "--field", "170x300", "--stereo", stereo,
        tmp=tmp_path / "c",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stderr.splitlines() if "clipped" in ln]
    assert len(lines) == 1 and "% of the requested field is in the overlap" in lines[0]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--projection", "latlon", "--vpc-size", "320x240"], "--vpc-size apply to --projection pinhole"),
        (["--projection", "pinhole", "--px-per-deg", "3"], "--px-per-deg apply to --projection latlon"),
        (["--projection", "latlon", "--yaw", "10"], "--yaw centre an explicit lat-lon --field"),
        (["--projection", "fisheye"], "--projection must be one of pinhole, latlon"),
        (["--field", "100by80"], "--field must look like 100x180"),
        (["--px-per-deg", "100"], "--px-per-deg:"),
    ],
)
def test_bad_projection_options_are_one_line(
    room: Path, tmp_path: Path, args: list[str], needle: str
) -> None:
    res = run("process", room, "--out", tmp_path / "o", *args, tmp=tmp_path / "c")
    assert res.returncode == 2, res.stdout
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], res.stderr


def test_a_rig_without_overlap_is_one_line(tmp_path: Path) -> None:
    pin = create("pinhole", 64, 48, fx=32.0, fy=32.0, cx=31.5, cy=23.5)  # 90° views 160° apart
    rig = Rig(
        {"left": pin, "right": pin.replace()},
        {
            "left": make_transform(rot_y(math.radians(-80)), [-0.05, 0.0, 0.0]),
            "right": make_transform(rot_y(math.radians(80)), [0.05, 0.0, 0.0]),
        },
    )
    rec = tmp_path / "rec"
    with RecordingWriter(rec) as writer:
        writer.write_images(0, 0, 0, np.zeros((48, 64), np.uint8), np.zeros((48, 64), np.uint8))
    save_rig(rig, rec / "calibration.yaml")
    res = run("process", rec, "--out", tmp_path / "o", "--projection", "latlon", tmp=tmp_path / "c")
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "no stereo overlap" in lines[0], res.stderr


def test_evaluate_wide_pair_quick_writes_the_study(tmp_path: Path) -> None:
    out = tmp_path / "wide"
    res = run(
        "evaluate",
        "--study",
        "wide-pair",
        "--preset",
        "prototype",
        "--quick",
        "--out",
        out,
        tmp=tmp_path / "c",
    )
    assert res.returncode == 0, res.stderr
    assert "overlap 3.67 sr" in res.stdout and "wrote" in res.stdout
    for name in (
        "wide_pair.json",
        "wide_pair.csv",
        "wide_pair_by_angle.csv",
        "wide_pair.png",
        "wide_pair.md",
    ):
        assert (out / name).is_file(), name
    doc = json.loads((out / "wide_pair.json").read_text())
    assert doc["settings"]["quick"] is True and len(doc["variants"]) == 4
    bad = run(
        "evaluate", "--study", "wide-pair", "--textures", "2", "--out", tmp_path / "b", tmp=tmp_path / "c"
    )
    assert bad.returncode == 2 and "--textures apply to --study paper" in bad.stderr
