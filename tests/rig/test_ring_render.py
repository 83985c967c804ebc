"""The consistency measure on a rendered ring with its exact calibration: ring4 (four prototype
lenses at 90° on a 72 mm square) in the demo room, every adjacent pair through today's default
pipeline (lat-lon 5.585 px/deg, 96 disparities). ``pytest -s`` prints the figures docs/ring.md
quotes."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.rig import Rig
from rig.evaluate.consistency import ConsistencyFigures, PairRange, couples, transfer_range, view_mask
from rig.evaluate.consistency_study import ConsistencyStudy, consistency_study, pair_pipelines
from rig.evaluate.ring_renders import RigShot, render_rig_shot
from rig.field import pixel_solid_angles
from rig.panorama import DISAGREE, PairOutput, PanoramaSpec, fuse_panorama, lenses_seeing
from rig.ring import adjacent_pairs
from rig.ring_refine import RingRefineOptions, refine_ring
from rig.sim import room_scene
from rig.sim.presets import get_ring_preset
from rig.sim.render import render_range
from rig.sim.simulate import room_path
from rig.stereo import StereoParams

pytestmark = pytest.mark.slow


@functools.cache
def _shot(cache: str) -> tuple[RigShot, ConsistencyStudy]:
    preset = get_ring_preset("ring4")
    rig = preset.rig
    pairs = adjacent_pairs(rig)
    pipes = pair_pipelines(rig, pairs, cache_dir=cache)
    shot = render_rig_shot(
        room_scene(0), rig, pipes, room_path(2, 5),
        supersample=2, noise_std=preset.noise_std, vignetting=preset.vignetting,
    )  # fmt: skip
    study = consistency_study(rig, [shot.images], pairs, cache_dir=cache, keep_ranges=True)
    return shot, study


@pytest.fixture(scope="module")
def ring4(tmp_path_factory: pytest.TempPathFactory) -> tuple[RigShot, ConsistencyStudy]:
    return _shot(str(tmp_path_factory.mktemp("lut")))


#: Per search: the largest couple median |e| and the smallest within-10 % share allowed. The
#: coarse-to-fine search (the default) agrees less with itself than the exact search on this render
#: (measured 1.0-1.2 % against 0.74-0.84 %; docs/stereo.md, "Coarse-to-fine search").
AGREEMENT_BARS = {"exact": (0.01, 0.95), "coarse-to-fine": (0.013, 0.87)}


@pytest.mark.parametrize("search", ["coarse-to-fine", "exact"])
def test_rendered_ring_agrees_with_itself_within_one_percent(
    ring4: tuple[RigShot, ConsistencyStudy], search: str, tmp_path: Path
) -> None:
    shot, study = ring4
    if search == "coarse-to-fine":  # the fixture's study is the defaults', the exact search
        rig = get_ring_preset("ring4").rig
        c2f = StereoParams(coarse_to_fine=True)
        study = consistency_study(
            rig, [shot.images], adjacent_pairs(rig), stereo=c2f, cache_dir=str(tmp_path), keep_ranges=True
        )
    largest_median, smallest_within_10 = AGREEMENT_BARS[search]
    assert [p.names for p in study.pairs] == [
        ("cam1", "cam2"),
        ("cam2", "cam3"),
        ("cam3", "cam4"),
        ("cam4", "cam1"),
    ]
    print()
    for p in study.pairs:
        r, truth = p.ranges[0].range, shot.truth[p.names]
        ok = np.isfinite(r) & np.isfinite(truth)
        err = float(np.median(np.abs(r[ok] / truth[ok] - 1.0)))
        print(
            f"ring4 {search} {p.label}: coverage {p.coverage[0]:.3f}, median error against the truth "
            f"{err:.4f}"
        )
        assert p.coverage[0] > 0.90  # measured 0.953-0.962
        assert err < 0.006  # measured 0.0036-0.0044
    for c in study.couples:
        f = c.figures
        print(
            f"ring4 {search} {c.couple.label}: both {f.both_share:.3f}, median |e| {f.median_abs:.4f}, "
            f"signed "
            f"{f.median_signed:+.4f}, within 3 % {f.within_3:.3f}, 10 % {f.within_10:.3f}, "
            f"median |dd| {f.median_abs_px:.3f} px"
        )
    for c in study.couples:
        f = c.figures
        assert f.points > 20000 and f.both_share > 0.6  # measured 0.74-0.77
        assert f.median_abs <= largest_median
        assert abs(f.median_signed) < 0.002 and f.within_10 > smallest_within_10


def test_the_honest_lens_disagrees_more_but_far_from_the_real_ring(
    ring4: tuple[RigShot, ConsistencyStudy], tmp_path: Path
) -> None:
    """The same shot through the honest lens (rig.sim.lens_effects: blur growing to the rim,
    rim darkening, each camera's exposure, sensor noise) instead of the ideal lens with the
    simple sensor model: every couple disagrees more, but by half a point, not the real ring's
    4-9 % (docs/ring.md, "On renders")."""
    _, ideal = ring4
    preset = get_ring_preset("ring4")
    rig = preset.rig
    pairs = adjacent_pairs(rig)
    pipes = pair_pipelines(rig, pairs, cache_dir=str(tmp_path))
    shot = render_rig_shot(room_scene(0), rig, pipes, room_path(2, 5), supersample=2, lens=preset.lens)
    study = consistency_study(rig, [shot.images], pairs, cache_dir=str(tmp_path), keep_ranges=True)
    print()
    for p in study.pairs:
        r, truth = p.ranges[0].range, shot.truth[p.names]
        ok = np.isfinite(r) & np.isfinite(truth)
        err = float(np.median(np.abs(r[ok] / truth[ok] - 1.0)))
        print(f"ring4 honest lens {p.label}: coverage {p.coverage[0]:.3f}, median error {err:.4f}")
        assert p.coverage[0] > 0.92 and err < 0.007  # measured 0.948-0.952, 0.0045-0.0055
    for c, before in zip(study.couples, ideal.couples, strict=True):
        f = c.figures
        print(
            f"ring4 honest lens {c.couple.label}: both {f.both_share:.3f}, median |e| {f.median_abs:.4f} "
            f"(ideal lens {before.figures.median_abs:.4f}), signed {f.median_signed:+.4f}, within 3 % "
            f"{f.within_3:.3f}, 10 % {f.within_10:.3f}, median |dd| {f.median_abs_px:.3f} px"
        )
        # Measured 1.26-1.42 % against 0.75-0.85 %; within 10 % 0.928-0.943.
        assert before.figures.median_abs < f.median_abs < 0.016
        assert abs(f.median_signed) < 0.003 and f.within_10 > 0.9


def test_rendered_truth_is_consistent_to_interpolation(ring4: tuple[RigShot, ConsistencyStudy]) -> None:
    """The renderer's exact range of each pair (ray-cast independently per pair) through the
    measure: what remains is interpolation between pixels."""
    shot, study = ring4
    views = {p.names: p.ranges[0] for p in study.pairs}
    band = StereoParams().blind_band_px
    for c in couples(list(views)):
        src, tgt = (
            PairRange(
                views[n].pair,
                np.where(views[n].view, shot.truth[n], np.nan).astype(np.float32),
                views[n].view,
            )
            for n in (c.source, c.target)
        )
        f = ConsistencyFigures.of(transfer_range(src, tgt, c.shared))
        assert f.both_share > 0.99 and f.median_abs < 1e-4, (c.label, f)
    pipe = study.pairs[0].pipeline
    assert np.array_equal(
        views[pipe.names].view, view_mask(pipe.luts["cam1"].valid, pipe.luts["cam2"].valid, band)
    )


def test_the_rendered_rings_panorama_is_the_truth_where_two_lenses_see(
    ring4: tuple[RigShot, ConsistencyStudy],
) -> None:
    """The 360° panorama fused from the four pairs against the renderer's exact range along the
    panorama's own rays, over every direction at least two lenses see (a direction without
    range counts as wrong)."""
    shot, study = ring4
    rig = get_ring_preset("ring4").rig
    outputs = []
    for p in study.pairs:
        pipe = p.pipeline
        frame = pipe.process(*(shot.images[n] for n in pipe.names))
        outputs.append(
            PairOutput(
                p.label,
                pipe.pair,
                frame.range,
                frame.disparity,
                frame.confidence,
                pipe.stereo.confidence_sigma,
            )
        )
    spec = PanoramaSpec.for_rig(rig)
    pano = fuse_panorama(spec, outputs)
    truth, _ = render_range(room_scene(0), spec.camera, shot.T_world_rig @ spec.T_rig_pano)
    seen = (lenses_seeing(rig, spec) >= 2) & np.isfinite(truth)
    solid = pixel_solid_angles(spec.camera)
    close = np.isfinite(pano.range) & (np.abs(pano.range / truth - 1.0) < 0.03)
    within = float(solid[seen & close].sum() / solid[seen].sum())
    flagged = float(solid[seen & ((pano.flags & DISAGREE) > 0)].sum() / solid[seen].sum())
    print(f"\nring4 panorama: {100 * within:.1f} % of the directions two lenses see within 3 % of the "
          f"truth; {100 * flagged:.1f} % flagged as pairs disagreeing")  # fmt: skip
    assert within >= 0.85


def test_a_turned_ring_is_refined_back_and_the_refinement_measured(
    ring4: tuple[RigShot, ConsistencyStudy], tmp_path_factory: pytest.TempPathFactory
) -> None:
    """Three cameras of the rendered ring turned by 0.2–0.3° (the first holds the rig frame): the
    joint refinement finds them again, lowers every pair's vertical disparity and every couple's
    disagreement, and so is applied."""
    shot, _ = ring4
    truth = get_ring_preset("ring4").rig
    turned = {"cam2": (0.3, 0.0, 0.1), "cam3": (0.0, -0.2, 0.2), "cam4": (-0.2, 0.2, 0.0)}
    T = {}
    for name in truth.names:
        Tn = truth.T_rig_cam[name].copy()
        Tn[:3, :3] = Tn[:3, :3] @ Rotation.from_rotvec(np.radians(turned.get(name, (0, 0, 0)))).as_matrix()
        T[name] = Tn
    wrong = Rig(dict(truth.cameras), T)
    result = refine_ring(
        wrong, [shot.images], options=RingRefineOptions(cache_dir=tmp_path_factory.mktemp("lut"))
    )
    print()
    for p, before in result.vertical_before.items():
        print(f"{p}: vertical disparity p50 {before.p50_px:.2f} -> {result.vertical_after[p].p50_px:.2f} px")
    for label, before in result.agreement_before.items():
        print(
            f"{label}: median disagreement {100 * before:.2f} -> {100 * result.agreement_after[label]:.2f} %"
        )
    assert result.applied, result.reason
    for name in truth.names:
        R_err = result.rig.T_rig_cam[name][:3, :3].T @ truth.T_rig_cam[name][:3, :3]
        assert np.degrees(np.linalg.norm(Rotation.from_matrix(R_err).as_rotvec())) < 0.05, name
    assert all(result.vertical_after[p].p50_px < 0.5 * v.p50_px for p, v in result.vertical_before.items())
    assert all(result.agreement_after[k] < v for k, v in result.agreement_before.items())
