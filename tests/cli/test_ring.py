"""Rings of N cameras through the console script: `rig sim --rig ring4` renders an N-camera
recording with the exact range of every pair and of the panorama, `rig process` writes every
pair's outputs and the 360° panorama, `rig evaluate --study consistency` measures the pairs against
each other; the real ring of ../shared/data processes end to end. ``pytest -s`` prints the
figures (docs/ring.md)."""

from __future__ import annotations

import json
import subprocess
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration import load_rig
from rig.depth import depth_from_png_mm
from rig.field import pixel_solid_angles
from rig.panorama import PanoramaSpec, lenses_seeing
from rig.recording import Recording
from rig.sim.presets import get_ring_preset
from tests.conftest import shared_file
from tests.helpers.command import assert_one_line_error, clean_env, run_rig
from tests.helpers.ring import RING_CAMERAS, RING_DIR, load_ring, write_ring_recording
from tests.helpers.rings import IDEAL_LENS_ARGS

pytestmark = pytest.mark.slow

PAIRS = ["cam1-cam2", "cam2-cam3", "cam3-cam4", "cam4-cam1"]


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One LUT cache (XDG cache) for the module's commands."""
    return tmp_path_factory.mktemp("ring-home")


def rig_cmd(home: Path, *args: str | Path, timeout: float = 900) -> subprocess.CompletedProcess[str]:
    result = run_rig(args, clean_env(home), timeout=timeout)
    assert result.returncode == 0, result.stderr
    return result


@pytest.fixture(scope="module")
def ring4(home: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ring4") / "rec"
    rig_cmd(
        home, "sim", "--rig", "ring4", *IDEAL_LENS_ARGS, "--frames", "1", "--supersample", "2", "--out", out
    )
    return out


@pytest.fixture(scope="module")
def processed(home: Path, ring4: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ring4-out")
    result = rig_cmd(home, "process", ring4, "--out", out, "--ply")
    assert "processed 1 of 1 sets" in result.stdout
    return out


def test_sim_writes_a_recording_of_four_cameras_with_truth(ring4: Path) -> None:
    rec = Recording(ring4)
    assert rec.cameras == list(RING_CAMERAS) and len(rec.pairs) == 1
    assert (ring4 / "frames.csv").read_text().splitlines()[0] == (
        "seq,cam1_ts_ns,cam2_ts_ns,cam3_ts_ns,cam4_ts_ns,cam1_file,cam2_file,cam3_file,cam4_file"
    )
    assert load_rig(ring4 / "calibration.yaml").names == list(RING_CAMERAS)
    for pair in PAIRS:
        doc = json.loads((ring4 / "ground_truth" / pair / "scene.json").read_text())
        assert (
            doc["pair"] == pair.split("-")
            and doc["frames"][0]["range"] == f"ground_truth/{pair}/range/000000.npy"
        )
    pano = json.loads((ring4 / "ground_truth" / "panorama.json").read_text())
    assert (pano["width"], pano["height"], pano["pairs"]) == (1440, 720, PAIRS)
    assert np.load(ring4 / "ground_truth" / "panorama" / "000000.npy").shape == (720, 1440)


def test_sim_renders_a_ring_through_the_honest_lens_unless_told(
    ring4: Path, home: Path, tmp_path: Path
) -> None:
    """``--lens`` applies to a ring as to a pair: the honest lens by default, each camera with the
    exposure of its index; the module's ring4 is the ideal lens with the simple sensor model."""
    out = tmp_path / "honest"
    result = rig_cmd(home, "sim", "--rig", "ring4", "--scale", "0.25", "--frames", "1", "--supersample", "1",
                     "--out", out)  # fmt: skip
    assert "honest lens" in result.stdout
    meta = json.loads((out / "recording.json").read_text())
    honest = get_ring_preset("ring4").scaled(0.25).lens
    assert (meta["lens"], meta["lens_effects"]) == ("honest", json.loads(json.dumps(asdict(honest))))
    assert (meta["noise_std"], meta["vignetting"]) == (0.0, 0.0)  # the lens's own noise and rim
    ideal = json.loads((ring4 / "recording.json").read_text())
    assert (ideal["lens"], ideal["noise_std"], ideal["vignetting"]) == ("ideal", 1.5, 0.35)
    # The honest lens's exposures alternate (cameras 1 and 3 darker than 2 and 4 here).
    mean = [float(cv2.imread(str(out / c / "000000.png"), cv2.IMREAD_GRAYSCALE).mean()) for c in RING_CAMERAS]
    gains = [honest.exposure(k).gain for k in range(4)]
    assert (mean[0] < mean[1]) == (gains[0] < gains[1]) and (mean[2] < mean[3]) == (gains[2] < gains[3])
    bad = run_rig(("sim", "--rig", "ring4", "--lens", "fisheye", "--out", tmp_path / "x"), clean_env(home))
    assert_one_line_error(bad, "unknown --lens 'fisheye'")


def test_process_writes_every_pair_and_a_panorama_within_3_percent(ring4: Path, processed: Path) -> None:
    for pair in PAIRS:
        d = processed / pair
        assert {p.name for p in d.iterdir()} == {"range", "left", "right", "vpc.json", "run.json"}
        png = np.asarray(cv2.imread(str(d / "range" / "000000.png"), cv2.IMREAD_UNCHANGED))
        truth = np.load(ring4 / "ground_truth" / pair / "range" / "000000.npy")
        assert png.dtype == np.uint16 and png.shape == truth.shape
        r = depth_from_png_mm(png)
        ok = np.isfinite(r) & np.isfinite(truth)
        err = float(np.median(np.abs(r[ok] / truth[ok] - 1.0)))
        print(f"\nring4 {pair}: median range error {100 * err:.2f} % over {ok.mean():.3f} of its view")
        assert err < 0.01
        run = json.loads((d / "run.json").read_text())
        assert [run["vpc"]["left"], run["vpc"]["right"]] == pair.split("-")
    doc = json.loads((processed / "panorama.json").read_text())
    assert doc["pairs"] == PAIRS and (doc["width"], doc["height"]) == (1440, 720)
    rig = load_rig(ring4 / "calibration.yaml")
    spec = PanoramaSpec.for_rig(rig, doc["px_per_deg"])
    assert np.allclose(doc["R_rig_pano"], spec.R_rig_pano) and np.allclose(doc["origin_m"], spec.origin)
    png = np.asarray(cv2.imread(str(processed / "panorama" / "000000.png"), cv2.IMREAD_UNCHANGED))
    assert png.dtype == np.uint16 and png.shape == (720, 1440)
    pano = depth_from_png_mm(png)
    truth = np.load(ring4 / "ground_truth" / "panorama" / "000000.npy")
    seen = (lenses_seeing(rig, spec) >= 2) & np.isfinite(truth)
    solid = pixel_solid_angles(spec.camera)
    close = np.isfinite(pano) & (np.abs(pano / truth - 1.0) < 0.03)
    within = float(solid[seen & close].sum() / solid[seen].sum())
    print(f"ring4 rig process panorama: {100 * within:.1f} % of the directions two lenses see within 3 %")
    assert within >= 0.85  # measured 97.3 %
    ply = (processed / "cloud" / "000000.ply").read_bytes()
    vertices = int(ply.split(b"element vertex ")[1].split(b"\n")[0])
    # One point per ranged pixel: the PNG's zeros also hold ranges beyond its 65.535 m.
    nonzero = int(np.count_nonzero(png))
    assert nonzero <= vertices <= nonzero * 1.001


def test_resume_keeps_complete_sets_and_scheduler_is_refused(
    home: Path, ring4: Path, processed: Path
) -> None:
    before = (processed / "panorama" / "000000.png").stat().st_mtime_ns
    result = rig_cmd(home, "process", ring4, "--out", processed, "--ply", "--resume")
    assert "processed 1 of 1 sets, 1 already complete" in result.stdout
    assert (processed / "panorama" / "000000.png").stat().st_mtime_ns == before
    refused = run_rig(["process", ring4, "--out", processed, "--scheduler", "local"], clean_env(home))
    assert_one_line_error(refused, "--scheduler local", "more than two cameras", "--scheduler none")


def test_the_consistency_study_of_the_rendered_ring(home: Path, ring4: Path, tmp_path: Path) -> None:
    result = rig_cmd(home, "evaluate", "--study", "consistency", ring4, "--json", tmp_path / "c.json")
    assert "cam1|cam2 → cam2|cam3" in result.stdout
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["frames"] == 1 and list(doc["pairs"]) == [p.replace("-", "|") for p in PAIRS]
    for label, c in doc["couples"].items():
        print(f"ring4 {label}: median |e| {100 * c['median_abs']:.2f} %, both {c['both_share']:.3f}")
        assert c["median_abs"] <= 0.01 and c["both_share"] > 0.6  # measured 0.72-0.86 %, 0.73-0.77


def test_the_real_ring_processes_end_to_end(home: Path, tmp_path: Path) -> None:
    ring = load_ring(shared_file(RING_DIR))
    rec = write_ring_recording(ring, tmp_path / "real")
    out = tmp_path / "out"
    result = rig_cmd(home, "process", rec, "--out", out, timeout=1800)
    assert "processed 3 of 3 sets" in result.stdout
    for pair in PAIRS:
        names = sorted(p.name for p in (out / pair / "range").iterdir())
        assert names == ["000000.png", "000001.png", "000002.png"], pair
    for seq in range(3):
        png = np.asarray(cv2.imread(str(out / "panorama" / f"{seq:06d}.png"), cv2.IMREAD_UNCHANGED))
        ranged = float(np.count_nonzero(png)) / png.size
        print(f"\nreal ring set {seq}: the panorama ranges {100 * ranged:.1f} % of its pixels")
        assert png.shape == (720, 1440) and ranged > 0.1
