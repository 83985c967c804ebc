"""`rig evaluate` through the installed console script: the quick run's outputs, and bad input."""

from __future__ import annotations

import csv
import json
import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import pytest

from rig.evaluate.provenance import source_revision
from tests.helpers.command import run_rig

MODELS = ["kannala_brandt", "mei", "scaramuzza", "equidistant", "double_sphere", "eucm"]
# The extrinsics chain's curves: the Kannala-Brandt lenses with calibrated / refined extrinsics.
EXTRINSICS = ["calibrated_extrinsics", "refined_extrinsics"]


def run(*args: str | Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return run_rig(args, timeout=timeout)


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("evaluate") / "paper-sim"
    res = run("evaluate", "--preset", "paper-sim", "--quick", "--out", out)
    assert res.returncode == 0, res.stderr
    assert "wrote" in res.stdout and "report.md" in res.stdout
    timings = json.loads((out / "run.json").read_text())["timings_s"]
    # docs/evaluation.md's figure for --quick: the sum of the stages' times run.json records.
    print(f"\nrig evaluate --preset paper-sim --quick: {sum(timings.values()):.1f} s ({timings})")
    assert set(timings) >= {"calibration", "depth_pipelines"} and all(t > 0 for t in timings.values())
    return out


def _results(out: Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads((out / "results.json").read_text())
    return doc


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_results_json_has_exactly_the_issue_keys_and_sane_calibrations(quick: Path) -> None:
    doc = _results(quick)
    assert set(doc) == {"preset", "calibration", "image_difference", "depth", "matchers", "extrinsics"}
    assert doc["preset"] == "paper-sim"
    assert list(doc["calibration"]) == MODELS
    for model, entry in doc["calibration"].items():
        assert entry["error"] is None, model
        # The detector's corners are ~0.08 px off; no model should miss them by much more.
        assert 0.0 < entry["rms_px"] < 0.25, (model, entry["rms_px"])
        assert entry["per_camera"]["left"]["n_views"] >= 10
    kb = doc["calibration"]["kannala_brandt"]["params"]
    assert set(kb) >= {"fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"}
    # paper-sim lens: f = 512 / π px at half size, centre (255.5, 255.5); KB must find it.
    assert kb["fx"] == pytest.approx(512 / math.pi, rel=0.01)
    assert kb["cx"] == pytest.approx(255.5, abs=1.0) and kb["cy"] == pytest.approx(255.5, abs=1.0)


@pytest.mark.slow
def test_depth_curves_grow_with_distance_and_theory_is_quadratic(quick: Path) -> None:
    depth = _results(quick)["depth"]
    assert set(depth) == {"reference", "true_lens", "theory", *MODELS, *EXTRINSICS}
    ref = depth["reference"]
    assert [p["k"] for p in ref] == [3.0, 8.0, 16.0]
    rms = [p["rms_m"] for p in ref]
    assert rms[0] < rms[1] < rms[2]
    for p in ref:
        assert 0.5 < p["valid_frac"] <= 1.0 and p["std_m"] <= p["rms_m"] + 1e-12
    theory = depth["theory"]
    sd = theory[0]["sigma_d_px"]
    assert 0.0 < sd < 0.5
    # σZ = Z²·σd/(fx·B) with the quick VPC's fx = 160 px and B = 0.2 m, Z = k·B.
    for p in theory:
        assert p["rms_m"] == pytest.approx((p["k"] * 0.2) ** 2 * sd / (160.0 * 0.2), rel=1e-9)
    assert [p["rms_m"] for p in theory] == sorted(p["rms_m"] for p in theory)
    for model in ("kannala_brandt", "true_lens"):
        pts = depth[model]
        assert all(p["rms_m"] is not None and p["valid_frac"] > 0.5 for p in pts)
        # A calibrated fisheye pipeline is within 2 % of the distance at every k.
        assert all(p["rms_m"] < 0.02 * p["k"] * 0.2 for p in pts)
        assert pts[-1]["rms_m"] > pts[0]["rms_m"]
    # The fit of a 3-point curve passes through its points.
    assert all(p["fit_rms_m"] == pytest.approx(p["rms_m"], rel=1e-6) for p in ref)


@pytest.mark.slow
def test_extrinsics_chain_true_calibrated_refined(quick: Path) -> None:
    """The pair calibrated from wedge boards, then refined from the room: both close to the true
    relative pose, the scale kept, and a depth error ratio to the Reference for each."""
    ex = _results(quick)["extrinsics"]
    assert ex["error"] is None and ex["model"] == "kannala_brandt"
    assert ex["common_views"] >= 6 and ex["stereo_rms_px"] < 0.1
    assert ex["calibrated"]["rotation_deg"] < 0.1 and ex["refined"]["rotation_deg"] < 0.1
    # Refinement never changes the baseline's length: the calibration's stays.
    assert ex["refined"]["baseline_mm"] == pytest.approx(ex["calibrated"]["baseline_mm"], abs=1e-9)
    r = ex["refinement"]
    assert r["inliers"] > 200 and r["frames"] == 2
    assert r["vertical_disparity_p50_px"][1] <= r["vertical_disparity_p50_px"][0] + 0.01
    ratios = ex["depth_rms_over_reference"]
    assert set(ratios) == {"true", "calibrated", "refined"} and all(1.0 < v < 20.0 for v in ratios.values())
    depth = _results(quick)["depth"]
    for curve in EXTRINSICS:
        assert all(p["rms_m"] < 0.02 * p["k"] * 0.2 for p in depth[curve])


@pytest.mark.slow
def test_image_difference_and_matchers_are_sane(quick: Path) -> None:
    doc = _results(quick)
    diff = doc["image_difference"]
    assert set(diff) == {"true_lens", *MODELS}
    assert all(0.0 < v < 30.0 for v in diff.values())
    # Calibrated Kannala-Brandt is within 25 % of the exact lens (the resampling floor).
    assert diff["kannala_brandt"] < 1.25 * diff["true_lens"]
    m = doc["matchers"]
    assert set(m) == {"sgbm", "sgbm_3way", "bm", "ours"}
    for entry in m.values():
        assert entry["time_ms"] > 0 and [p["k"] for p in entry["per_distance"]] == [3.0, 8.0, 16.0]
        assert all(0.3 < p["valid_frac"] <= 1.0 for p in entry["per_distance"])
    # The subpixel refinement beats SGBM_3WAY's own interpolation on every plane.
    for ours, plain in zip(m["ours"]["per_distance"], m["sgbm_3way"]["per_distance"], strict=True):
        assert ours["rms_inlier_px"] < plain["rms_inlier_px"]


@pytest.mark.slow
def test_csv_png_and_report_files_are_written_and_valid(quick: Path) -> None:
    depth_rows = _rows(quick / "depth.csv")
    assert {r["curve"] for r in depth_rows} == {"reference", "true_lens", "theory", *MODELS, *EXTRINSICS}
    assert len(depth_rows) == 3 * (len(MODELS) + len(EXTRINSICS) + 3)
    assert {r["model"] for r in _rows(quick / "calibration.csv")} == set(MODELS)
    assert len(_rows(quick / "image_difference.csv")) == len(MODELS) + 1
    assert len(_rows(quick / "matchers.csv")) == 4 * 3
    assert {r["curve"] for r in _rows(quick / "depth_fit.csv")} == {
        "reference",
        "true_lens",
        *MODELS,
        *EXTRINSICS,
    }
    pngs = [
        "depth_rms.png",
        "depth_ratio.png",
        "matchers.png",
        "image_difference.png",
        "calibration_coverage.png",
    ]
    for png in [*pngs, "difference/reference.png", "difference/kannala_brandt_diff.png"]:
        img = cv2.imread(str(quick / png))
        assert img is not None and img.shape[0] > 50 and img.shape[1] > 50, png
    report = (quick / "report.md").read_text()
    for heading in ("Calibration quality", "Distortion removal", "Depth quality", "Matcher choice",
                    "Extrinsics: calibrated from boards, refined from the scene",
                    "Agreement with the paper"):  # fmt: skip
        assert heading in report
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", report)
    assert len(links) >= 5 and all((quick / link).is_file() for link in links)
    assert re.search(r"\| (agrees|differs|not measured) \|", report)
    run_doc = json.loads((quick / "run.json").read_text())
    assert run_doc["settings"]["quick"] is True and run_doc["timings_s"]["calibration"] > 0
    assert run_doc["calibration_views"]["left"]["detected"] >= 10
    # The code it was made with (this checkout; see test_evaluate_provenance for the rest).
    source = source_revision()
    assert run_doc["source"] == (source.as_json() if source else None)
    if source is not None:
        assert f"`{source.commit[:12]}`" in (quick / "report.md").read_text()


def test_refuses_a_non_empty_out_directory(tmp_path: Path) -> None:
    (tmp_path / "keep.txt").write_text("mine")
    res = run("evaluate", "--quick", "--out", tmp_path)
    assert res.returncode == 2
    assert "not empty" in res.stderr and "--force" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert (tmp_path / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--preset", "unity"], "--preset must be one of"),
        (["--models", "kannala_brandt,fisheye9"], "fisheye9"),
        (["--models", ","], "--models"),
        (["--distances", "2,x"], "--distances"),
        (["--distances", "0.5"], "between 1 and 200"),
        (["--textures", "9"], "textures must be between 1 and 5"),
        (["--seed", "-3"], "seed"),
    ],
)
def test_bad_values_are_one_line_and_exit_2(
    tmp_path: Path,
    args: list[str],
    message: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # In process (the console script's own main()): the checks run before any work.
    from cli.main import main

    monkeypatch.setattr(sys, "argv", ["rig", "evaluate", "--quick", "--out", str(tmp_path / "out"), *args])
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.delenv("RIG_DEBUG", raising=False)
    with pytest.raises(SystemExit) as exit_info:
        main()
    err = capsys.readouterr().err
    assert exit_info.value.code == 2, err
    assert message in err and len(err.strip().splitlines()) == 1
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()
