"""A quick run of every benchmark, only to keep the scripts working (docs/performance.md: benchmarks
are not tests). Nothing here asserts a time: only that each script runs end to end, measures what it
says (positive rates, no failed frames or requests) and writes its JSON document."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from bench import (
    api_load,
    coarse_to_fine,
    dask_scale,
    hostile,
    lut_build,
    memory,
    process,
    rectification,
    ring_analysis,
    ring_consistency,
    ring_cost,
    startup,
    worker,
)
from calibration.models import MODELS, KannalaBrandtModel
from rig.depth import depth_to_png_mm, latlon_range
from rig.evaluate.consistency_study import consistency_study
from rig.sim import get_preset
from rig.stereo import StereoParams
from tests.conftest import shared_file
from tests.helpers.ring import RING_DIR, load_ring


def _written(path: Path, doc: dict) -> dict:
    on_disk = json.loads(path.read_text())
    assert on_disk["benchmark"] == doc["benchmark"]
    for key in ("cpu", "cpus", "load_avg", "numpy", "opencv"):
        assert key in on_disk["machine"], key
    return on_disk


def test_worker_bench_compares_the_service_worker_with_the_floor(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "w.json", worker.main(["--quick", "--json", str(tmp_path / "w.json")]))
    (row,) = doc["rows"]
    assert row["vpc"] == [160, 120] and row["disparities"] == 32
    assert row["floor_fps"] > 0 and row["ours_fps"] > 0 and row["floor_ms_per_frame"] > 0
    assert row["worker_errors"] == 0
    assert row["ours_latency_ms"]["n"] > 0 and row["ours_latency_ms"]["p50"] > 0
    assert math.isfinite(row["throughput_ratio"]) and math.isfinite(row["latency_ratio"])
    # The same-work loop (the pipeline called in a plain loop) is timed alongside the floor.
    assert row["same_work_fps"] > 0 and row["same_work_ms_per_frame"] > 0
    assert math.isfinite(row["throughput_ratio_same_work"]) and math.isfinite(row["latency_ratio_same_work"])
    assert len(row["runs"]["same_work_fps"]) == doc["repeat"]
    # Throughput and latency: alternating floor / ours windows of one runtime, a ratio per pair.
    runs = row["runs"]
    assert doc["windows"] == 2
    assert len(runs["floor_fps"]) == len(runs["ours_fps"]) == len(runs["latency_floor_ms"]) == 2
    for key in ("throughput_ratio", "latency_ratio"):
        ratios = runs[key]
        assert len(ratios) == doc["windows"] and all(r > 0 for r in ratios), key
        q1, q3 = row[f"{key}_iqr"]
        assert min(ratios) <= q1 <= row[key] <= q3 <= max(ratios), key
    # The paced windows' latencies are the results they timed (a few per window at least).
    assert row["ours_latency_ms"]["n"] >= 2 * doc["windows"]
    # No throughput ratio passes what the CPU per frame allows (with a margin for timing noise).
    assert 0 < row["ours_cores_busy"] <= doc["machine"]["cpus_usable"] * 1.1
    assert row["throughput_ratio"] <= row["cpu_ceiling_ratio"] * 1.1
    assert set(row["ours_stage_ms"]) >= {"decode", "remap", "match", "refine", "total"}


def test_process_bench_compares_rig_process_with_the_floor(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "p.json", process.main(["--quick", "--json", str(tmp_path / "p.json")]))
    (row,) = doc["rows"]
    assert row["vpc"] == [160, 120] and row["failures"] == 0
    assert row["floor_pairs_per_s"] > 0 and row["ours_pairs_per_s"] > 0 and row["floor_ms_per_pair"] > 0
    ratios = row["runs"]["throughput_ratio"]
    assert len(ratios) == doc["windows"] == 2 and all(r > 0 for r in ratios)
    q1, q3 = row["throughput_ratio_iqr"]
    assert min(ratios) <= q1 <= row["throughput_ratio"] <= q3 <= max(ratios)
    start = row["startup"]
    assert 0 < start["python"] < start["one_pair"] and start["help"] > 0 and start["imports"] > 0


def test_process_bench_runs_the_lat_lon_pair_and_its_floor_writes_the_range(
    bench_env: Path, tmp_path: Path
) -> None:
    doc = _written(
        tmp_path / "p.json",
        process.main(["--quick", "--projection", "latlon", "--json", str(tmp_path / "p.json")]),
    )
    (row,) = doc["rows"]
    assert row["projection"] == "latlon" and row["failures"] == 0 and row["ours_pairs_per_s"] > 0
    # The floor's range (uint16 mm) is the pipeline's formula on the same disparity.
    pipe = process.bench_input(
        process.MjpegSpec(frames=4, views=1, scale=0.25),
        *process._configuration("latlon", True)[:2],
        tmp_path,
    ).pipeline
    cam = pipe.pair.camera
    rng = np.random.default_rng(1)
    fixed = rng.integers(-16, 16 * 32, size=(cam.height, cam.width)).astype(np.int16)
    floor_mm = process._floor_millimetres(pipe)(fixed)
    ours_m = latlon_range(np.where(fixed > 0, fixed / 16.0, np.nan).astype(np.float32), cam, pipe.baseline_m)
    ours_mm = depth_to_png_mm(ours_m).astype(np.int64)  # 0: invalid or beyond 65.535 m
    both = (floor_mm > 0) & (ours_mm > 0)
    assert both.mean() > 0.8 and np.abs(floor_mm[both].astype(np.int64) - ours_mm[both]).max() <= 1
    assert not (floor_mm[fixed <= 0]).any()


@pytest.mark.slow
def test_coarse_to_fine_bench_times_the_search_its_parts_and_the_alternatives(
    bench_env: Path, tmp_path: Path
) -> None:
    doc = _written(tmp_path / "c.json", coarse_to_fine.main(["--quick", "--json", str(tmp_path / "c.json")]))
    rows = {r["call"]: r for r in doc["rows"]}
    assert rows[coarse_to_fine.EXACT]["ratio"] == 1.0
    whole, coarse, fine = (
        rows[k]["cpu_ms"] for k in (coarse_to_fine.C2F, coarse_to_fine.COARSE, coarse_to_fine.FINE)
    )
    assert whole > 0 and coarse > 0 and fine == pytest.approx(whole - coarse)
    assert len(rows) == 11 and all(r["cpu_ms"] > 0 for k, r in rows.items() if k != coarse_to_fine.FINE)


def test_dask_bench_runs_each_mode_over_every_recording(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "d.json", dask_scale.main(["--quick", "--json", str(tmp_path / "d.json")]))
    assert doc["pairs"] == doc["recordings"] * 4 and doc["recordings"] == 2
    assert set(doc["pairs_per_s"]) == {"here", "1 worker", "2 workers"}
    assert all(v > 0 for v in doc["pairs_per_s"].values())
    for mode in ("1 worker", "2 workers"):
        assert doc["ratio"][mode] == pytest.approx(doc["pairs_per_s"][mode] / doc["pairs_per_s"]["here"])
        assert doc["cluster_start_s"][mode] > 0
    # What bounds many machines: bytes per pair in and out, the tables shipped once per worker.
    assert doc["bytes_per_pair"]["read"] > 0 and doc["bytes_per_pair"]["written"] > 0
    assert doc["lut_bytes"] >= 2 * 160 * 120 * 15  # map_x, map_y, map1, map2, valid per camera


def test_lut_bench_times_every_model_and_the_cache(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "l.json", lut_build.main(["--quick", "--json", str(tmp_path / "l.json")]))
    rows = {r["model"]: r for r in doc["rows"]}
    assert set(rows) == set(MODELS)
    for name, r in rows.items():
        assert r["opencv_ms"] > 0 and r["cold_ms"] > 0 and r["warm_ms"] > 0, name
        assert 0.0 < r["valid_fraction"] <= 1.0, name
        assert len(r["runs"]["cold"]["wall"]) == doc["repeat"]


def test_lut_bench_fits_every_model_to_the_prototype_lens() -> None:
    lens = get_preset("prototype").rig.cameras["left"]
    assert isinstance(lens, KannalaBrandtModel)
    models = lut_build.fitted_models(lens)
    assert set(models) == set(MODELS)
    # Each fit reproduces the lens within a few pixels over 60° (pinhole) or 95° (the others).
    for name, model in models.items():
        field = math.radians(55.0 if name == "pinhole" else 90.0)
        theta = np.linspace(0.05, field, 40)
        rays = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
        want, ok_ref = lens.project(rays)
        got, ok = model.project(rays)
        assert ok.all() and ok_ref.all(), name
        assert np.abs(got - want).max() < 5.0, name


@pytest.mark.slow
def test_api_load_bench_serves_every_client(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "a.json", api_load.main(["--quick", "--json", str(tmp_path / "a.json")]))
    loaded = [p for p in doc["phases"] if p["clients"] > 0]
    assert {(p["clients"], p["endpoint"]) for p in loaded} == {
        (n, e) for n in (1, 4) for e in ("/depth", "/health")
    }
    for p in loaded:
        assert p["requests"] > 0 and p["errors"] == 0, p
        assert p["latency_ms"]["p99"] >= p["latency_ms"]["p50"] > 0
    assert doc["idle_fps"] > 0


@pytest.mark.slow
def test_memory_bench_samples_the_service(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "m.json", memory.main(["--quick", "--json", str(tmp_path / "m.json")]))
    assert len(doc["samples"]) >= 3
    assert doc["peak_mb"] >= doc["start_mb"] > 10
    assert doc["frames_processed"] > 0 and doc["client_requests"]["failed"] == 0
    assert math.isfinite(doc["slope_mb_per_min"])
    # Every sample read the service's heap figures too; each in-use figure is below the RSS.
    assert len(doc["heap_samples"]) == len(doc["samples"])
    for (_, rss_mb), (_, heap) in zip(doc["samples"], doc["heap_samples"], strict=True):
        assert 0 < heap["rig_malloc_in_use_bytes"] / (1 << 20) < rss_mb
        assert heap["rig_python_allocated_blocks"] > 10_000
    assert set(doc["heap_slopes_second_half"]) == {"rig_malloc_in_use_bytes", "rig_python_allocated_blocks"}


def test_memory_slope_is_least_squares() -> None:
    assert memory.slope_mb_per_min([0.0, 60.0, 120.0], [100.0, 101.0, 102.0]) == pytest.approx(1.0)
    assert memory.slope_mb_per_min([0.0, 30.0], [50.0, 50.0]) == pytest.approx(0.0)
    assert memory.slope_mb_per_min([5.0], [50.0]) == 0.0


@pytest.mark.slow
def test_startup_bench_times_warm_and_cold_starts(bench_env: Path, tmp_path: Path) -> None:
    doc = _written(tmp_path / "s.json", startup.main(["--quick", "--json", str(tmp_path / "s.json")]))
    assert set(doc["median_s"]) == {"imports", "warm", "cold LUTs"}
    assert all(v > 0 for v in doc["median_s"].values())


def test_window_minima_keep_each_windows_floor() -> None:
    points = [(0.0, 5.0), (10.0, 3.0), (59.0, 4.0), (61.0, 9.0), (130.0, 2.0), (170.0, 1.0)]
    assert memory.window_minima(points, 60.0) == [(30.0, 3.0), (90.0, 9.0), (150.0, 1.0)]
    assert memory.window_minima([], 60.0) == []


def test_rectification_bench_times_a_check_and_the_worker_with_and_without(
    bench_env: Path, tmp_path: Path
) -> None:
    path = tmp_path / "r.json"
    argv = ["--quick", "--windows", "1", "--window-s", "2", "--interval", "0.5", "--json", str(path)]
    doc = _written(path, rectification.main(argv))
    med = doc["median_ms"]
    assert med["check_wall"] > 0 and med["check_cpu"] > 0 and med["sift_cpu"] > 0
    assert 0 < doc["cpu_ratio_to_bare_sift"] < 10 and 0 < doc["duty_cycle_one_core"] < 1
    impact = doc["worker_impact"]
    assert len(impact["fps_on"]) == len(impact["fps_off"]) == 1 and impact["fps_off"][0] > 0
    assert impact["checks_per_window"][0] >= 1 and impact["ratio"] > 0


def test_hostile_bench_runs_its_attacks(bench_env: Path, tmp_path: Path) -> None:
    out = tmp_path / "h.json"
    doc = _written(
        out, hostile.main(["--quick", "--attack", "patch", "--attack", "headers", "--json", str(out)])
    )
    patch = doc["patch"]
    assert patch["acknowledged"] == patch["different_fields"] > 0 and patch["lost_updates"] == 0
    assert patch["same_field_last_wins"] is True
    assert doc["headers"]["lines"]["status"] == doc["headers"]["giant"]["status"] == 431
    assert doc["headers"]["lines"]["health"]["failures"] == 0


def test_ring_consistency_bench_measures_the_real_ring(bench_env: Path, tmp_path: Path) -> None:
    data = shared_file(RING_DIR)
    path = tmp_path / "ring.json"
    doc = _written(path, ring_consistency.main(["--quick", "--data", str(data), "--json", str(path)]))
    assert doc["pairs"] == ["cam1|cam2", "cam2|cam3", "cam3|cam4", "cam4|cam1"] and doc["frames"] == 1
    assert all(row["matches"] >= 80 and row["p50_px"] < 2.5 for row in doc["loader"])  # 121-243, 1.0-1.7 px
    couples = doc["today"]["couples"]
    assert len(couples) == 4
    for figures in couples.values():
        assert 0.0 < figures["median_abs"] < 1.0 and 0.0 < figures["both_share"] < 1.0
    assert all(0.0 < p["mean_coverage"] < 1.0 for p in doc["today"]["pairs"].values())


def test_ring_analysis_splits_a_search_s_points_by_the_other_s_range(lut_cache: Path) -> None:
    """bench.ring_consistency 2b's split: each search's points, on one real frame, by whether the
    other search ranges their source pixel; the two parts are the whole study's points."""
    ring = load_ring(shared_file(RING_DIR))
    frames = ring.frames[:1]
    studies = [
        consistency_study(
            ring.rig,
            frames,
            stereo=StereoParams(coarse_to_fine=c2f),
            cache_dir=str(lut_cache),
            keep_ranges=True,
        )
        for c2f in (False, True)
    ]
    for mine, other in (studies, studies[::-1]):
        split = ring_analysis.only_points(mine, other)
        for c in mine.couples:
            also, only = split[c.couple.label]
            assert also.r_source.size + only.r_source.size == c.figures.points
            assert int(also.both.sum() + only.both.sum()) == c.figures.both
            theirs = {p.names: p.ranges[0].range for p in other.pairs}[c.couple.source].ravel()
            assert np.isfinite(theirs[also.source_index]).all() and np.isnan(theirs[only.source_index]).all()
    # The coarse-to-fine search ranges more of the ring (measured 0.17 more per pair on 3 frames).
    c2f_only = ring_analysis.only_points(studies[1], studies[0])
    assert all(only.both.sum() > 10000 for _, only in c2f_only.values())


def test_matched_coverage_keeps_each_search_s_most_confident_pixels(lut_cache: Path) -> None:
    """bench.ring_consistency 2b's comparison at the same coverage, on one real frame: with no
    threshold it is the study itself; a threshold brings each search to the coverage asked for
    from below; the pixels it keeps are the most confident ones."""
    ring = load_ring(shared_file(RING_DIR))
    frames = ring.frames[:1]
    study = consistency_study(ring.rig, frames, cache_dir=str(lut_cache))
    ranges = ring_analysis.ConfidentRanges.of_study(study, frames)
    mean_coverage = float(np.mean([p.mean_coverage for p in study.pairs]))
    assert ranges.coverage(-1.0) == pytest.approx(mean_coverage, abs=1e-9)
    assert ranges.threshold_for(mean_coverage + 0.01) == -1.0
    whole = ranges.figures(-1.0)
    for c in study.couples:
        assert whole[c.couple.label] == c.figures
    target = 0.6 * mean_coverage
    (level,) = ring_analysis.matched_coverage([ranges], [target])[target]
    assert 0.0 < level.threshold < 1.0
    assert target - 0.01 < level.coverage <= target  # bisection to 2^-24 of the threshold
    pair = study.pairs[0].names
    kept = ranges.above(pair, 0, level.threshold).range
    conf = ranges.outputs[pair][0][1]
    dropped = np.isfinite(ranges.outputs[pair][0][0]) & np.isnan(kept)
    assert dropped.any() and conf[dropped].max() <= level.threshold < conf[np.isfinite(kept)].min()
    assert all(f.both < whole[label].both for label, f in level.figures.items())


def test_ring_cost_bench_times_the_pairs_and_the_panorama(bench_env: Path, tmp_path: Path) -> None:
    path = tmp_path / "ring_cost.json"
    doc = _written(path, ring_cost.main(["--quick", "--panorama-px-per-deg", "1.5", "--json", str(path)]))
    assert (doc["cameras"], doc["pairs"]) == (4, 4) and doc["panorama_size"] == [540, 270]
    for key in (
        "floor_pairs_per_s",
        "pairs_per_s_one_after_the_other",
        "panorama_frames_per_s",
        "ours_sets_per_s",
    ):
        assert doc[key] > 0, key
    assert doc["ours_pairs_per_s"] == doc["ours_sets_per_s"] * 4
    assert doc["budget_bytes"] == sum(doc["budget_parts"].values()) and doc["budget_parts"]["panorama"] > 0
