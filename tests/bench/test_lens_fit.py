"""The honest renderer's fit (``bench.lens_fit``): its edge-width measurement finds the blur the
renderer put in, its overlap and noise fits recover known parameters, and the script runs on the
real images end to end. Speed: ``bench.render_speed`` runs and its "same output" case is the
earlier renderer's output bit for bit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench import lens_ablation, lens_fit, render_speed
from bench.lens_measure import edge_widths, sigma_from_width, width_calibration
from bench.lens_overlap import OverlapSamples
from calibration.geometry import make_transform, rot_x, rot_y
from calibration.models import PinholeModel
from rig.sim import ImageTexture, Scene, TexturedRect, render
from rig.sim.lens_effects import LensEffects
from tests.conftest import shared_file


@pytest.fixture(scope="module")
def calibration() -> tuple[np.ndarray, np.ndarray]:
    return width_calibration(np.random.default_rng(1), images=1)


def _checker_wall(distance_m: float) -> Scene:
    """A wall of 0.125 m squares of grey 60 and 200 (sharp: 2048 texels a metre), turned 20°."""
    squares = (np.add.outer(np.arange(2048) // 256, np.arange(2048) // 256) % 2).astype(np.float32)
    texture = ImageTexture(60.0 + 140.0 * squares, (1.0, 1.0))
    T = make_transform(rot_y(0.35) @ rot_x(-0.2), [0.0, 0.0, distance_m])
    return Scene([TexturedRect(T, (3.0, 3.0), texture)])


@pytest.mark.parametrize("sigma", [0.6, 1.1])
def test_the_edge_measurement_finds_the_blur_the_renderer_put_in(
    calibration: tuple[np.ndarray, np.ndarray], sigma: float
) -> None:
    """A checker wall rendered through a lens of constant blur σ (and 0.8 grey levels of noise):
    the 20th percentile of its edge widths, through the synthetic calibration, is σ."""
    cam = PinholeModel(480, 360, fx=420.0, fy=420.0, cx=239.5, cy=179.5)
    lens = LensEffects(name="test", blur_centre_px=sigma, read_noise=0.8)
    image = render(_checker_wall(1.0), cam, np.eye(4), supersample=4, lens=lens, seed=2).image
    valid = np.zeros(image.shape, bool)
    valid[12:-12, 12:-12] = True
    edges = edge_widths(image, valid, np.random.default_rng(3))
    assert edges.width.size > 300
    measured = float(sigma_from_width(float(np.percentile(edges.width, 20)), calibration))
    assert measured == pytest.approx(sigma, rel=0.12)


def test_the_overlap_fit_recovers_rim_darkening_gains_and_gammas() -> None:
    """Synthetic matched points made with known parameters (and 5 % scatter, some outliers)."""
    rng = np.random.default_rng(4)
    n = 4000
    a = rng.integers(0, 4, n)
    b = (a + 1) % 4
    xa, xb = rng.uniform(0.05, 0.95, n), rng.uniform(0.05, 0.95, n)
    gain, gamma = np.array([1.0, 1.1, 0.95, 1.05]), np.array([1.0, 1.08, 0.97, 1.0])
    scene = np.exp(rng.uniform(np.log(20), np.log(200), n))
    pivot = float(np.exp(np.mean(np.log(scene))))

    def grey(cam: np.ndarray, x: np.ndarray) -> np.ndarray:
        ri = 1 - 0.1 * x**2 - 0.25 * x**4
        out: np.ndarray = gain[cam] * pivot * (scene * ri / pivot) ** gamma[cam]
        return out * np.exp(rng.normal(0, 0.05, n))

    ga, gb = grey(a, xa), grey(b, xb)
    gb[:200] *= 3.0  # occlusions, moving people
    fit = lens_fit.fit_illumination(OverlapSamples(a, b, xa, xb, ga, gb), 4)
    np.testing.assert_allclose(fit["c"], [-0.1, -0.25], atol=0.04)
    np.testing.assert_allclose(fit["gain"], gain, rtol=0.03)
    np.testing.assert_allclose(fit["gamma"], gamma, atol=0.03)


def test_the_blur_fit_separates_the_shared_curve_from_each_cameras_defocus() -> None:
    x = np.array([0.1, 0.25, 0.4, 0.55, 0.65, 0.75, 0.85, 0.93])
    curve = 0.5 + 0.8 * x**4
    counts = np.full(x.size, 200.0)
    curves = [(x, np.hypot(curve, d), counts) for d in (0.0, 0.6, 0.9)]
    (s0, s1, p), defocus = lens_fit.fit_blur(curves)
    assert (s0, s1, p) == pytest.approx((0.5, 0.8, 4.0), rel=0.05)
    np.testing.assert_allclose(defocus, [0.0, 0.6, 0.9], atol=0.02)


@pytest.mark.slow
def test_lens_fit_runs_on_the_real_images(tmp_path: Path) -> None:
    shared_file("ring_sweepnet_indoor")  # the real images it fits (a skip or, in CI, a failure)
    doc = lens_fit.main(["--quick", "--json", str(tmp_path / "fit.json")])
    assert json.loads((tmp_path / "fit.json").read_text())["benchmark"] == "lens_fit"
    # The ring's measured PSFs (bins with enough edges): between a third of a pixel and 2.5 px.
    sigma = np.array([doc["curves"][f"ring cam{k}"]["sigma_px"] for k in range(1, 5)], dtype=float)
    measured = sigma[np.isfinite(sigma)]
    assert measured.size >= 10 and measured.min() > 0.3 and measured.max() < 2.5, sigma
    assert len(doc["ring_blur"]["defocus"]) == 4
    ill = doc["illumination"]
    assert ill["points"] > 500 and 0.3 < 1 + sum(ill["c"]) < 1.0  # darker at the field edge
    assert all(0.8 < g < 1.25 for g in ill["gain"])
    read, shot = doc["noise"]["ring cam1"]
    assert 0.1 < read < 3.0 and shot >= 0.0


@pytest.mark.slow
def test_render_speed_runs_and_the_same_output_is_the_earlier_renderers(tmp_path: Path) -> None:
    doc = render_speed.main(["--quick", "--json", str(tmp_path / "speed.json")])
    assert doc["same_output"] == {"max_grey_diff": 0.0, "max_range_rel_diff": 0.0}
    for case in render_speed.CASES:
        assert doc["per_pair"][case]["wall_s"] > 0


@pytest.mark.slow
def test_lens_ablation_runs_and_the_ideal_lens_is_the_kindest(tmp_path: Path) -> None:
    doc = lens_ablation.main(["--quick", "--json", str(tmp_path / "ablation.json")])
    rows = doc["variants"]
    assert set(rows) == set(lens_ablation.variants(LensEffects()))
    assert rows["ideal"]["within_3pct"] > rows["honest"]["within_3pct"] > 0.3
    assert all(0.0 < r["within_3pct"] <= r["valid"] <= 1.0 for r in rows.values())
