"""The pair stays rectified, on renders with known truth: the vertical disparity measure, the
offline refinement from a recording's scene (perturbations of 0.1–1° about each axis and 1 mm
along the baseline), bad input, and the live monitor with its online refinement.

One small render (the half-size prototype in the textured room, two pairs) serves every test;
calibrations handed to the code are the render's truth perturbed, so the code must find its way
back to the truth. ``pytest -s`` prints the figures docs/rectification.md quotes.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from calibration.formats import load_rig, save_rig
from calibration.rig import Rig
from rig.errors import RecordingError, RectificationError
from rig.pipeline import DepthPipeline
from rig.recording import Recording, RecordingWriter
from rig.rectification import EpipolarViews, RefineOptions, match_pair, refine_recording, vertical_disparity
from rig.rectification.monitor import RectificationConfig, RectificationMonitor
from rig.rectification.refine import backup_path, save_refined
from rig.rectified import design_rectified_pair
from tests.rig.rectification_renders import (
    VPC,
    perturbed,
    relative_rotation_error_deg,
    render_room,
    true_vertical_disparity,
)

# Combinations of 0.1–1° about the rig's x (the baseline), y (vertical) and z (forward), each
# with the right camera 1 mm further along the baseline (the scale, which is never estimated).
PERTURBATIONS = [(0.1, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0), (0.5, -0.3, 0.8), (-1.0, 1.0, 1.0)]


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Rig]:
    out = render_room(tmp_path_factory.mktemp("rectification") / "room")
    rec = Recording(out)
    assert rec.calibration_path is not None
    return out, load_rig(rec.calibration_path)


def monitor_of(
    rig: Rig,
    options: RectificationConfig,
    applied: list[Rig] | None = None,
    cache: Path | None = None,
    **kw: Any,
) -> tuple[RectificationMonitor, DepthPipeline]:
    """A monitor of the pair in effect of a pipeline of ``rig``; a correction it applies takes
    effect in that pipeline and is appended to ``applied``."""
    pipeline = DepthPipeline(rig, VPC, cache_dir=cache, tune_malloc=False)

    def apply(new: Rig) -> None:
        pipeline.apply(rig=new)
        if applied is not None:
            applied.append(new)

    return RectificationMonitor(lambda: pipeline.in_effect, lambda: None, options, apply, **kw), pipeline


def gray_pairs(root: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    rec = Recording(root)
    return [
        (rec.read_image(p, "left", cv2.IMREAD_GRAYSCALE), rec.read_image(p, "right", cv2.IMREAD_GRAYSCALE))
        for p in rec.pairs
    ]


def test_measured_vertical_disparity_follows_the_geometry(room: tuple[Path, Rig]) -> None:
    """The matches' row differences agree with the vertical disparity the calibration error
    causes on the true surfaces (ground-truth depth), for the true and a rotated calibration."""
    root, truth = room
    left, right = gray_pairs(root)[0]
    for calib in (truth, perturbed(truth, (0.3, 0.0, 0.0))):
        views = EpipolarViews(calib)
        m = match_pair(views, left, right)
        measured = vertical_disparity(design_rectified_pair(calib, VPC), m.left, m.right)
        true_dv = true_vertical_disparity(root, truth, calib)
        print(f"\nmatches {len(m)}, in the VPC {measured.count}: measured p50 {measured.p50_px:.3f} px, "
              f"true p50 {np.median(true_dv):.3f} px")  # fmt: skip
        assert measured.ok and measured.count > 100
        assert measured.p50_px == pytest.approx(float(np.median(true_dv)), abs=0.08)
    # 0.3° about the baseline moves every row by fy · sec²φ · 0.3°: 0.84 px on the centre row of
    # a 320×240, 90° pair, 1.31 px on its top and bottom rows.
    assert 160 * math.radians(0.3) < measured.p50_px < 160 * 1.5625 * math.radians(0.3)


@pytest.mark.parametrize("deg", PERTURBATIONS, ids=lambda d: "_".join(f"{x:+g}" for x in d))
def test_refinement_recovers_the_true_rotation(
    room: tuple[Path, Rig], deg: tuple[float, float, float]
) -> None:
    root, truth = room
    calibration = perturbed(truth, deg, along_baseline_m=0.001)
    result = refine_recording(Recording(root), calibration, VPC)
    err = relative_rotation_error_deg(result.rig_after, truth)
    true_before = true_vertical_disparity(root, truth, calibration)
    true_after = true_vertical_disparity(root, truth, result.rig_after)
    fit = result.fit
    print(
        f"\nperturbation {deg}°: recovered to {err:.4f}° "
        f"(correction {fit.angle_deg:.3f}° ± {fit.angle_sigma_deg:.3f}°, "
        f"{fit.n_inliers} of {result.matches} matches; baseline direction {fit.direction_note}); "
        f"vertical disparity p50 measured {result.before.p50_px:.3f} -> {result.after.p50_px:.3f} px, "
        f"true {np.median(true_before):.3f} -> {np.median(true_after):.3f} px"
    )
    assert err <= 0.02
    assert float(np.median(true_after)) <= 0.1
    assert result.after.p50_px is not None and result.after.p50_px <= 0.1
    assert result.before.p50_px is not None and result.before.p50_px > result.after.p50_px
    # The scale is never touched: the calibration's (wrong by 1 mm) baseline stays.
    assert result.rig_after.baseline() == pytest.approx(calibration.baseline(), abs=1e-12)


def _write_recording(
    root: Path, pairs: list[tuple[np.ndarray, np.ndarray]], cameras: list[str] | None = None
) -> Path:
    names = cameras or ["left", "right"]
    with RecordingWriter(root, cameras=names) as writer:
        for seq, images in enumerate(pairs):
            writer.write_set_images(seq, [seq * 33_000_000] * len(names), list(images[: len(names)]))
    return root


def test_bad_input_is_one_clear_error(room: tuple[Path, Rig], tmp_path: Path) -> None:
    root, truth = room
    left, right = gray_pairs(root)[0]
    rng = np.random.default_rng(0)

    def blank() -> np.ndarray:  # a white wall: sensor noise only
        return np.clip(128 + rng.normal(0, 1.5, left.shape), 0, 255).astype(np.uint8)

    with pytest.raises(RectificationError, match="not enough matches"):
        refine_recording(
            Recording(_write_recording(tmp_path / "blank", [(blank(), blank())] * 3)), truth, VPC
        )
    with pytest.raises(RectificationError, match="not enough matches"):  # lens caps on
        refine_recording(
            Recording(_write_recording(tmp_path / "dark", [(left * 0, left * 0)] * 2)), truth, VPC
        )
    with pytest.raises(RecordingError, match="one camera"):
        refine_recording(Recording(_write_recording(tmp_path / "same", [(left, left)] * 2)), truth, VPC)
    with pytest.raises(RecordingError, match="camera\\(s\\) left only"):
        refine_recording(
            Recording(_write_recording(tmp_path / "mono", [(left, right)], ["left"])), truth, VPC
        )
    # Too few frames' worth of matches for the requested minimum: an error, not a guess.
    with pytest.raises(RectificationError, match="not enough"):
        refine_recording(Recording(root), truth, VPC, RefineOptions(frames=1, min_matches=100_000))


def test_monitor_measures_degrades_and_refines(
    room: tuple[Path, Rig], tmp_path: Path, lut_cache: Path
) -> None:
    """A calibration 0.7° off: degraded after two checks, corrected after three agreeing ones,
    then ok, with the truth recovered; the LUT swap hook gets the corrected rig once, and it is
    persisted over the calibration file with the original kept."""
    root, truth = room
    pairs = gray_pairs(root)
    applied: list[Rig] = []
    calibration = tmp_path / "rig.yaml"
    save_rig(perturbed(truth, (0.3, 0.5, -0.4)), calibration)
    original = calibration.read_bytes()
    options = RectificationConfig(auto_refine=True, persist_path=calibration)
    monitor, pipeline = monitor_of(
        load_rig(calibration), options, applied, lut_cache, calibration_path=calibration
    )
    assert monitor.status().state == "waiting"
    states = []
    for k in range(5):
        monitor.check(*pairs[k % len(pairs)])
        states.append(monitor.status().state)
    status = monitor.status()
    print(f"\nmonitor states {states}; last check {status.check_wall_ms:.0f} ms wall, "
          f"{status.check_cpu_ms:.0f} ms CPU on its thread; {status.refinement}")  # fmt: skip
    assert states[:2] == ["ok", "degraded"]
    assert len(applied) == 1 and status.corrections_applied == 1
    # The history keeps it, with the pair's drift from the calibration it started with.
    (correction,) = monitor.corrections
    assert correction.total_deg == pytest.approx(status.counters["drift_deg"])
    assert 0.5 < correction.total_deg < 1.0 and correction.angle_deg == pytest.approx(
        correction.total_deg, abs=1e-6
    )
    assert states[-1] == "ok" and status.p50_px is not None and status.p50_px < 0.2
    assert relative_rotation_error_deg(applied[0], truth) <= 0.02
    assert relative_rotation_error_deg(pipeline.rig, truth) <= 0.02
    assert (tmp_path / "rig.orig.yaml").read_bytes() == original
    assert relative_rotation_error_deg(load_rig(calibration), truth) <= 0.02


def test_save_refined_keeps_the_original(room: tuple[Path, Rig], tmp_path: Path) -> None:
    _, truth = room
    source = tmp_path / "camchain.yaml"
    save_rig(perturbed(truth, (0.2, 0.0, 0.0)), source)
    before = source.read_bytes() + b"# the user's own comment\n"
    source.write_bytes(before)
    # Another file: written, the calibration untouched, no backup.
    assert save_refined(truth, tmp_path / "refined.yaml", source) is None
    assert source.read_bytes() == before and not backup_path(source).exists()
    assert relative_rotation_error_deg(load_rig(tmp_path / "refined.yaml"), truth) < 1e-12
    # In place: the original's bytes kept once, and not overwritten by a second refinement.
    assert save_refined(perturbed(truth, (0.1, 0.0, 0.0)), source, source) == tmp_path / "camchain.orig.yaml"
    assert save_refined(truth, source, source) == tmp_path / "camchain.orig.yaml"
    assert (tmp_path / "camchain.orig.yaml").read_bytes() == before
    assert relative_rotation_error_deg(load_rig(source), truth) < 1e-12
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "camchain.orig.yaml",
        "camchain.yaml",
        "refined.yaml",
    ]


def test_monitor_low_texture_is_never_an_alarm(room: tuple[Path, Rig], lut_cache: Path) -> None:
    root, truth = room
    left, _ = gray_pairs(root)[0]
    blank = np.full_like(left, 90)
    monitor, _ = monitor_of(
        perturbed(truth, (1.0, 0.0, 0.0)), RectificationConfig(auto_refine=True), cache=lut_cache
    )
    for _ in range(3):
        monitor.check(blank, blank)
    status = monitor.status()
    assert status.state == "not enough matches" and status.checks_without_enough_matches == 3
    assert status.corrections_applied == 0 and status.p50_px is None
    # A textured patch in one corner only: matches, but bunched in one place.
    patch = blank.copy()
    texture = gray_pairs(root)[0][0]
    h, w = patch.shape
    patch[: h // 4, : w // 4] = texture[: h // 4, : w // 4]
    monitor.check(patch, patch)
    assert monitor.status().state == "not enough matches"


def test_online_refinement_never_applies_an_unjustified_step(room: tuple[Path, Rig], lut_cache: Path) -> None:
    root, truth = room
    pairs = gray_pairs(root)
    # Already right: nothing to gain.
    applied: list[Rig] = []
    auto = RectificationConfig(auto_refine=True)
    monitor, _ = monitor_of(truth, auto, applied, lut_cache)
    for k in range(4):
        monitor.check(*pairs[k % 2])
    assert not applied and "no correction" in (monitor.status().refinement or "")
    # Beyond the step bound: reported, not applied (and the status is degraded, so it is seen).
    options = RectificationConfig(auto_refine=True, max_step_deg=0.5)
    monitor, _ = monitor_of(perturbed(truth, (0.8, 0.0, 0.0)), options, applied, lut_cache)
    for k in range(4):
        monitor.check(*pairs[k % 2])
    status = monitor.status()
    assert not applied and "max_step_deg" in (status.refinement or "") and status.state == "degraded"
    # Checks that disagree (the right image shifted by 2 px every other time): not stable.
    left, right = pairs[0]
    shifted = np.roll(right, 2, axis=0)
    monitor, _ = monitor_of(perturbed(truth, (0.3, 0.0, 0.0)), auto, applied, lut_cache)
    for k in range(4):
        monitor.check(left, shifted if k % 2 else right)
    assert not applied and "disagree" in (monitor.status().refinement or "")


def test_corrections_never_ratchet_past_the_total_bound(room: tuple[Path, Rig], lut_cache: Path) -> None:
    """Each step under max_step_deg, but the sum bounded too: a correction that would take the
    pair further than max_total_deg from its calibration is refused, and the service says
    recalibrate (where four small steps once walked a camera 3.2° away)."""
    root, truth = room
    pairs = gray_pairs(root)
    applied: list[Rig] = []
    options = RectificationConfig(auto_refine=True, max_step_deg=1.0, max_total_deg=0.3)
    monitor, pipeline = monitor_of(perturbed(truth, (0.5, 0.0, 0.0)), options, applied, lut_cache)
    for k in range(5):
        monitor.check(*pairs[k % 2])
    status = monitor.status()
    assert not applied and monitor.corrections == [] and status.counters["drift_deg"] == 0.0
    assert "recalibrate" in (status.refinement or "") and "max_total_deg 0.3°" in (status.refinement or "")
    assert status.state == "degraded" and "recalibrate" in (status.reason or "")
    assert pipeline.in_effect.revision == 1  # nothing reached the pipeline
