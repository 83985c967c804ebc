"""The live rectification measure and the online refinement in a running service: a replayed
recording whose calibration was turned 0.6° away from the truth is measured, reported degraded,
corrected online (lookup tables rebuilt and swapped while the worker goes on, no frame lost) and
the correction persisted; with the true calibration the service stays ok."""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from calibration.formats import load_rig, save_rig
from rig.counters import counters_of
from service.health_report import HealthReport
from service.runtime import Runtime
from service.settings import load_settings
from tests.helpers.service import InProcessServer, SmallRecording, metric_values, service_overrides
from tests.helpers.waiting import wait_for
from tests.rig.rectification_renders import perturbed, relative_rotation_error_deg

FAST_CHECKS = {"check_interval_s": 0.5, "confirm_checks": 2}
Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]


def _runtime(rec: SmallRecording, tmp: Path, lut_cache: Path, calibration: Path, **rect: object) -> Runtime:
    doc = service_overrides(rec.loop, tmp, lut_cache)
    doc["calibration"] = {"path": str(calibration)}
    doc["rectification"] = {**FAST_CHECKS, **rect}
    return Runtime.build(load_settings(None, doc))


def test_a_turned_calibration_is_corrected_online_without_losing_a_frame(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    truth = load_rig(small_recording.loop / "calibration.yaml")
    calibration = tmp_path / "rig.yaml"
    save_rig(perturbed(truth, (0.3, 0.4, -0.3)), calibration)
    original = calibration.read_bytes()
    runtime = _runtime(
        small_recording, tmp_path, lut_cache, calibration, auto_refine=True, persist_path=str(calibration)
    )
    monitor = runtime.rectification
    assert monitor is not None
    published: list[tuple[float, int]] = []
    observe = runtime.worker._on_result

    def record(result, timings):  # type: ignore[no-untyped-def]
        published.append((time.monotonic(), result.index))
        if observe is not None:
            observe(result, timings)

    runtime.worker._on_result = record
    runtime.start()
    try:

        def degraded_report() -> HealthReport | None:
            report = runtime.health()
            measure = report.rectification
            return report if measure is not None and measure.state == "degraded" else None

        report = wait_for(degraded_report, 60, "the rectification measure to turn degraded")
        assert any(r.startswith("rectification: vertical disparity p50") for r in report.reasons), (
            report.reasons
        )
        wait_for(lambda: monitor.status().corrections_applied == 1, 90, "the online correction")
        swapped_at = time.monotonic()
        wait_for(lambda: any(t > swapped_at + 1.0 for t, _ in published), 30, "frames after the swap")
        wait_for(lambda: runtime.health().status == "ok", 30, "ok again")
        print(f"\nafter the correction: {runtime.health().rectification}")
    finally:
        runtime.stop()
    stats = runtime.worker.stats()
    assert stats.counters["errors"] == 0
    # Every pair the worker took was published, in order, before and after the swap (the longest
    # pause between two results is printed, not asserted: on a loaded machine it is the machine's).
    indexes = [i for _, i in published]
    assert indexes == list(range(1, len(indexes) + 1))
    gaps = [b - a for (a, _), (b, _) in itertools.pairwise(published)]
    print(f"{len(indexes)} results, longest pause {max(gaps):.2f} s")
    # The running pipeline, the monitor (which reads the pipeline's pair in effect) and
    # /calibration's rig are the corrected one.
    assert runtime.pipeline.rig is runtime.rig and monitor.pair is runtime.pipeline.pair
    assert relative_rotation_error_deg(runtime.pipeline.rig, truth) < 0.05
    assert relative_rotation_error_deg(load_rig(calibration), truth) < 0.05
    assert (tmp_path / "rig.orig.yaml").read_bytes() == original


def test_the_true_calibration_stays_ok_and_unchanged(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    calibration = small_recording.loop / "calibration.yaml"
    runtime = _runtime(small_recording, tmp_path, lut_cache, calibration, auto_refine=True)
    monitor = runtime.rectification
    assert monitor is not None
    rig = runtime.pipeline.rig
    runtime.start()
    try:
        wait_for(lambda: monitor.status().checks >= 4, 60, "four checks")
        status = runtime.health().rectification
    finally:
        runtime.stop()
    assert status is not None
    print(f"\ntrue calibration: {status.state}, p50 {status.p50_px} px, p95 {status.p95_px} px, "
          f"{status.matches} matches, {status.check_wall_ms:.0f} ms per check")  # fmt: skip
    assert status.state in ("ok", "not enough matches")
    assert status.corrections_applied == 0 and runtime.pipeline.rig is rig
    if status.state == "ok":
        assert status.p50_px is not None and status.p50_px < 0.3


def test_measurement_can_be_switched_off(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    calibration = small_recording.loop / "calibration.yaml"
    runtime = _runtime(small_recording, tmp_path, lut_cache, calibration, enabled=False)
    assert runtime.rectification is None and runtime.health().rectification is None


#: Figures that grow with time between checks (the age of the last one).
AGES = ("rig_rectification_last_check_age_s",)


def _one_measure(client: httpx.Client) -> tuple[dict[str, Any], Samples] | None:
    """/health and the rectification samples of /metrics of one measure: /metrics before and after
    /health the same but for the ages, and as many checks in both (a check every 0.5 s; else
    None)."""
    before = _rectification_samples(client.get("/metrics").text)
    health: dict[str, Any] = client.get("/health").json()
    after = _rectification_samples(client.get("/metrics").text)
    checks = after.get(("rig_rectification_checks_total", ()))
    steady = {k: v for k, v in before.items() if k[0] not in AGES} == {
        k: v for k, v in after.items() if k[0] not in AGES
    }
    return (health, after) if steady and health["rectification"]["checks"] == checks else None


def _rectification_samples(text: str) -> Samples:
    return {k: v for k, v in metric_values(text).items() if k[0].startswith("rig_rectification_")}


def test_health_and_metrics_report_the_measure(
    small_recording: SmallRecording, lut_cache: Path, tmp_path: Path
) -> None:
    """Over HTTP: /health's rectification object (degraded with a reason for a calibration 0.6°
    off, online refinement off) and the same figures in /metrics: every figure the counter table
    declares for the rectification, equal for one measure."""
    truth = load_rig(small_recording.loop / "calibration.yaml")
    calibration = tmp_path / "rig.yaml"
    save_rig(perturbed(truth, (0.3, 0.4, -0.3)), calibration)
    doc = service_overrides(small_recording.loop, tmp_path, lut_cache)
    doc["calibration"] = {"path": str(calibration)}
    doc["rectification"] = FAST_CHECKS
    app = InProcessServer(load_settings(None, doc)).start()
    try:
        app.wait_ready()

        # /health turns degraded for other reasons too (a camera dropping frames on a loaded
        # machine), so wait for the rectification measure itself.
        def degraded_health() -> dict[str, Any] | None:
            body: dict[str, Any] = app.client.get("/health").json()
            return body if (body.get("rectification") or {}).get("state") == "degraded" else None

        wait_for(degraded_health, 60, "the rectification measure to turn degraded")
        health, samples = wait_for(
            lambda: _one_measure(app.client), 30, "/health and /metrics of one measure"
        )
    finally:
        app.stop()
    rect = health["rectification"]
    assert rect["state"] == "degraded" and rect["degraded"] is True and rect["auto_refine"] is False
    assert (
        rect["vertical_disparity_p50_px"] > 0.5 and rect["checks"] >= 2 and rect["corrections_applied"] == 0
    )
    assert any(r.startswith("rectification: vertical disparity p50") for r in health["reasons"])
    compared = 0
    for spec in counters_of("rectification"):
        key = (spec.metric_sample, tuple(sorted(spec.metric_labels)))
        value = rect[spec.name]
        if value is None:  # nothing measured yet: no sample
            assert key not in samples, spec.name
            continue
        if spec.metric_sample in AGES:  # /metrics was read after /health's document was made
            assert samples[key] >= float(value) * spec.metric_scale, spec.name
        else:
            assert samples[key] == pytest.approx(float(value) * spec.metric_scale, rel=1e-12), spec.name
        compared += 1
    # The measure's figures are among them: the quantiles, degraded, the checks.
    assert samples[("rig_rectification_vertical_disparity_px", (("quantile", "0.5"),))] == pytest.approx(
        rect["vertical_disparity_p50_px"], rel=1e-12
    )
    assert samples[("rig_rectification_degraded", ())] == 1.0
    assert compared >= 8, compared
