"""The real ring's accuracy without ground truth (docs/ring.md): ../shared/data/
ring_sweepnet_indoor (four ~220° fisheyes ~92° apart, 0.3 m baselines, three synchronised
frames; its OCamCalib models and poses, read by the test helper :mod:`tests.helpers.ring`).

1. The loader's check: the adjacent pairs from geometry, their baselines and the vertical
   disparity of SIFT matches in their rectified views (near zero when the poses are read right).
2. Today's defaults: every adjacent pair through the depth pipeline on every frame; per couple
   of pairs sharing a camera the consistency figures (:mod:`rig.evaluate.consistency`), per pair
   the coverage of its view.
2b. The other search (not with ``--quick``): the coarse-to-fine option (``coarse_to_fine:
   true``; the exact search when the stereo settings ask for the coarse-to-fine one) on the same
   frames, both searches' figures on the points both give range for, and each search's points
   split by whether the other ranges their source pixel (what only one search ranges, against
   the rest of its range), and both at the same coverage (each its most confident pixels).
3. The same after ``rig calibrate refine``'s refinement of each pair on the ring's frames
   (:func:`rig.rectification.refine.refine_frames`, the library behind the command: it turns
   each pair's right camera; each pair then runs on its own refined calibration).
4. ``--analysis`` (default on): where the disagreement and the coverage loss are
   (:mod:`bench.ring_analysis`).
5. ``--renders``: the ring's own calibration rendered in the demo room (about 3 minutes), the
   measure with the exact calibration and with errors of known kinds.
6. The joint refinement of the whole ring (:func:`rig.ring_refine.refine_ring`: one rotation per
   camera fitted to every pair's matches at once), measured before and after, and whether its
   gate applies it, measured with the stereo settings of the other sections (``--stereo``).

Run: ``.venv/bin/python -m bench.ring_consistency`` (``--quick``: one frame, no refinement or
analysis). Not a speed benchmark: it prints accuracy figures.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from bench.common import (
    add_stereo_argument,
    bench_cache_dir,
    console,
    finish,
    machine_info,
    print_machine,
    stereo_overrides,
)
from bench.ring_analysis import (
    PERTURBATIONS,
    ConfidentRanges,
    common_figures,
    couple_bins,
    coverage_bins,
    coverage_with,
    disparity_shares,
    matched_coverage,
    only_points,
    vertical_by_angle,
)
from calibration.rig import Rig
from rig.evaluate.consistency import ConsistencyFigures
from rig.evaluate.consistency_study import ConsistencyStudy, consistency_study, pair_pipelines
from rig.evaluate.ring_renders import render_rig_shot
from rig.rectification import EpipolarViews, RayMatches, VerticalDisparity, match_pair, vertical_disparity
from rig.rectification.refine import refine_frames
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from rig.ring import PairNames, adjacent_pairs
from rig.ring_refine import RingRefineOptions, refine_ring
from rig.sim import room_scene
from rig.sim.simulate import room_path
from rig.stereo import StereoParams
from tests.helpers.ring import RING_DIR, RealRing, load_ring

__all__ = ["main"]

U8 = NDArray[np.uint8]


def _default_data() -> Path:
    root = Path(os.environ.get("RIG_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    return root / RING_DIR


def _pair_rows(
    rig: Rig, frames: Sequence[dict[str, U8]], a: str, b: str
) -> tuple[RayMatches, VerticalDisparity]:
    """SIFT matches of the pair a|b over ``frames`` (epipolar views at half the lenses'
    resolution) and their vertical disparity in the pair's rectified views of ``rig``."""
    views = EpipolarViews(rig, a, b, scale=0.5)
    m = RayMatches.concat([match_pair(views, f[a], f[b], frame=i) for i, f in enumerate(frames)])
    return m, vertical_disparity(
        design_rectified_pair(rig, RectifiedPairConfig(left=a, right=b)), m.left, m.right
    )


def _loader_check(
    ring: RealRing, pairs: Sequence[PairNames]
) -> tuple[list[dict[str, Any]], dict[PairNames, RayMatches]]:
    table = Table(title="1. the loader: adjacent pairs from geometry, SIFT matches in their rectified views")
    for col in ("pair", "baseline m", "matches", "median |vertical disparity| px", "signed median px"):
        table.add_column(col, justify="right")
    rows, matches = [], {}
    for a, b in pairs:
        matches[(a, b)], vd = _pair_rows(ring.rig, ring.frames, a, b)
        row = {
            "pair": f"{a}|{b}",
            "baseline_m": ring.rig.baseline(a, b),
            "matches": vd.count,
            "p50_px": vd.p50_px,
            "median_px": vd.median_px,
        }
        rows.append(row)
        table.add_row(
            f"{a}|{b}",
            f"{ring.rig.baseline(a, b):.3f}",
            str(vd.count),
            f"{vd.p50_px or float('nan'):.2f}",
            f"{vd.median_px or float('nan'):+.2f}",
        )
    console.print(table)
    return rows, matches


def _figures_row(f: ConsistencyFigures) -> list[str]:
    return [
        f"{f.points}", f"{f.both_share:.3f}", f"{100 * f.median_abs:.2f} %",
        f"{100 * f.median_signed:+.2f} %", f"{f.within_3:.3f}", f"{f.within_10:.3f}",
        f"{f.median_abs_px:.2f}", f"{f.median_signed_px:+.2f}",
    ]  # fmt: skip


_FIGURE_COLUMNS = (
    "points",
    "both range",
    "median |e|",
    "signed median",
    "within 3 %",
    "within 10 %",
    "median |dd| px",
    "signed dd px",
)


def _print_study(title: str, study: ConsistencyStudy) -> dict[str, Any]:
    table = Table(title=f"{title}: couples of pairs sharing a camera ({study.frames} frames pooled)")
    table.add_column("couple (source → target)")
    for col in _FIGURE_COLUMNS:
        table.add_column(col, justify="right")
    table.add_column("median |e| per frame", justify="right")
    for c in study.couples:
        per = " ".join(f"{100 * f.median_abs:.1f}" for f in c.per_frame)
        table.add_row(c.couple.label, *_figures_row(c.figures), per)
    console.print(table)
    cov = Table(title=f"{title}: coverage (solid angle with range / the view's)")
    for col in ("pair", "per frame", "mean"):
        cov.add_column(col, justify="right")
    for p in study.pairs:
        cov.add_row(p.label, " ".join(f"{c:.3f}" for c in p.coverage), f"{p.mean_coverage:.3f}")
    console.print(cov)
    return study.as_dict()


SEARCH_NAMES = {True: "coarse-to-fine", False: "exact"}


def _versus_other_search(
    ring: RealRing,
    pairs: Sequence[PairNames],
    stereo: StereoParams,
    study: ConsistencyStudy,
    confident: ConfidentRanges,
    cache: str,
) -> dict[str, Any]:
    """2b. The other search (the exact one's coarse-to-fine option, or back) on the same frames,
    and both searches' figures on the pixels where both give range (each pair, each frame);
    ``confident``: ``study``'s pairs with their confidence."""
    mine, theirs_c2f = SEARCH_NAMES[stereo.coarse_to_fine], not stereo.coarse_to_fine
    other = SEARCH_NAMES[theirs_c2f]
    other_study = consistency_study(
        ring.rig,
        ring.frames,
        pairs,
        stereo=stereo.model_copy(update={"coarse_to_fine": theirs_c2f}),
        cache_dir=cache,
        keep_ranges=True,
    )
    title = f"2b. the {other} search (coarse_to_fine: {str(theirs_c2f).lower()}), the ring's calibration"
    out = {other: _print_study(title, other_study)}
    ours, theirs = common_figures([study, other_study])
    table = Table(title=f"2b. on the pixels where both searches give range: {mine} / {other}")
    table.add_column("couple (source → target)")
    for col in ("points both range", "median |e|", "within 3 %", "within 10 %", "median |dd| px"):
        table.add_column(col, justify="right")
    for label, a in ours.items():
        b = theirs[label]
        table.add_row(
            label,
            f"{a.both} / {b.both}",
            f"{100 * a.median_abs:.2f} / {100 * b.median_abs:.2f} %",
            f"{a.within_3:.3f} / {b.within_3:.3f}",
            f"{a.within_10:.3f} / {b.within_10:.3f}",
            f"{a.median_abs_px:.2f} / {b.median_abs_px:.2f}",
        )
    console.print(table)
    out["common"] = {label: {mine: ours[label].as_dict(), other: theirs[label].as_dict()} for label in ours}
    out["only"] = {
        mine: _only_table(study, other_study, mine, other),
        other: _only_table(other_study, study, other, mine),
    }
    searches = {mine: confident, other: ConfidentRanges.of_study(other_study, ring.frames)}
    least = min(float(np.mean([p.mean_coverage for p in s.pairs])) for s in (study, other_study))
    out["matched_coverage"] = _matched_coverage_table(searches, least)
    return out


def _matched_coverage_table(searches: dict[str, ConfidentRanges], least: float) -> dict[str, Any]:
    """The searches at the same coverage: each keeps its most confident pixels down to ``least``
    (the smaller of their coverages), and to 3/4 and 1/2 of it
    (:func:`bench.ring_analysis.matched_coverage`)."""
    names = list(searches)
    levels = matched_coverage(list(searches.values()), [least, 0.75 * least, 0.5 * least])
    table = Table(title=f"2b. at the same coverage, each search's most confident pixels: {' / '.join(names)}")
    for col in ("coverage", "confidence >", "couple (source → target)", "median |e|", "within 10 %"):
        table.add_column(col, justify="right")
    out: dict[str, Any] = {}
    for target, per_search in levels.items():
        for label in per_search[0].figures:
            f = [lv.figures[label] for lv in per_search]
            table.add_row(
                " / ".join(f"{lv.coverage:.3f}" for lv in per_search),
                " / ".join(f"{lv.threshold:.3f}" for lv in per_search),
                label,
                " / ".join(f"{100 * x.median_abs:.2f}" for x in f) + " %",
                " / ".join(f"{x.within_10:.3f}" for x in f),
            )
        out[f"{target:.3f}"] = {
            name: {
                "threshold": lv.threshold,
                "coverage": lv.coverage,
                "figures": {k: v.as_dict() for k, v in lv.figures.items()},
            }
            for name, lv in zip(names, per_search, strict=True)
        }
    console.print(table)
    return out


def _only_table(a: ConsistencyStudy, b: ConsistencyStudy, name_a: str, name_b: str) -> dict[str, Any]:
    """The ``a`` search's points split by whether the ``b`` search ranges their source pixel:
    whether what only one search ranges is as good as the rest of its range."""
    table = Table(
        title=f"2b. the {name_a} search's points, by whether the {name_b} search ranges their source pixel"
    )
    table.add_column("couple (source → target)")
    for col in ("points both range: also / only", "median |e|", "median |dd| px", "median range m"):
        table.add_column(col, justify="right")
    out = {}
    for label, parts in only_points(a, b).items():
        figures = [ConsistencyFigures.of(t) for t in parts]
        far = [
            float(np.median(t.r_target[t.both])) if figures[k].both else float("nan")
            for k, t in enumerate(parts)
        ]
        also, only = figures
        table.add_row(
            label,
            f"{also.both} / {only.both}",
            f"{100 * also.median_abs:.2f} / {100 * only.median_abs:.2f} %",
            f"{also.median_abs_px:.2f} / {only.median_abs_px:.2f}",
            f"{far[0]:.2f} / {far[1]:.2f}",
        )
        out[label] = {"also": also.as_dict(), "only": only.as_dict(), "median_range_m": far}
    console.print(table)
    return out


def _refined(
    ring: RealRing, pairs: Sequence[PairNames], matches: dict[PairNames, RayMatches]
) -> tuple[dict[PairNames, Rig], list[dict[str, Any]]]:
    table = Table(title="3. rig calibrate refine on each pair (the ring's frames)")
    for col in (
        "pair",
        "matches",
        "inliers",
        "turned deg",
        "about x, y, z deg",
        "|vert. disp.| before → after px",
    ):
        table.add_column(col, justify="right")
    rigs, rows = {}, []
    for a, b in pairs:
        r = refine_frames(ring.rig, [(f[a], f[b]) for f in ring.frames], RectifiedPairConfig(left=a, right=b))
        rigs[(a, b)] = r.rig_after
        row = {
            "pair": f"{a}|{b}", "matches": r.matches, "inliers": int(r.fit.inliers.sum()),
            "angle_deg": r.fit.angle_deg, "rotation_deg": list(r.fit.rotation_deg),
            "p50_before_px": r.before.p50_px, "p50_after_px": r.after.p50_px,
        }  # fmt: skip
        rows.append(row)
        table.add_row(
            f"{a}|{b}", str(r.matches), str(row["inliers"]), f"{r.fit.angle_deg:.3f}",
            " ".join(f"{x:+.3f}" for x in r.fit.rotation_deg),
            f"{r.before.p50_px:.2f} → {r.after.p50_px:.2f}",
        )  # fmt: skip
    console.print(table)
    table = Table(
        title="3. the SIFT matches' vertical disparity by angle off the rim-most lens: ring's → refined"
    )
    for col in ("pair", "bin deg", "matches", "median |vert. disp.| px", "signed median px"):
        table.add_column(col, justify="right")
    for (a, b), row in zip(pairs, rows, strict=True):
        before = vertical_by_angle(ring.rig, (a, b), matches[(a, b)])
        after = vertical_by_angle(rigs[(a, b)], (a, b), matches[(a, b)])
        row["vertical_by_angle"] = {"before": before, "after": after}
        for (lo, hi, n, p50, med), (_, _, _, p50r, medr) in zip(before, after, strict=True):
            table.add_row(
                f"{a}|{b}", f"{lo:g}–{hi:g}", str(n), f"{p50:.2f} → {p50r:.2f}", f"{med:+.2f} → {medr:+.2f}"
            )
    console.print(table)
    return rigs, rows


def _analysis(
    ring: RealRing,
    study: ConsistencyStudy,
    confident: ConfidentRanges,
    pairs: Sequence[PairNames],
    cache: str,
) -> dict[str, Any]:
    out: dict[str, Any] = {"couples": {}, "coverage": {}}
    for c in study.couples:
        table = Table(title=f"4. {c.couple.label}: disagreement by where the points are")
        table.add_column("binned by")
        table.add_column("bin", justify="right")
        for col in _FIGURE_COLUMNS:
            table.add_column(col, justify="right")
        rows = []
        for b in couple_bins(study, c):
            table.add_row(b.by, f"{b.lo:g}–{b.hi:g}", *_figures_row(b.figures))
            rows.append({"by": b.by, "lo": b.lo, "hi": b.hi, **b.figures.as_dict()})
        console.print(table)
        assert c.points is not None
        shares = disparity_shares(c.points)
        console.print(
            f"  {c.couple.label}: disparity disagreement "
            + ", ".join(f"{k} {v:.2f}" for k, v in shares.items())
        )
        out["couples"][c.couple.label] = {"bins": rows, "disparity": shares}
    trusted = {thr: confident.figures(thr) for thr in (0.3, 0.6)}
    table = Table(title="4. the pixels the pipeline's confidence trusts (both pairs above the threshold)")
    table.add_column("confidence >")
    table.add_column("couple")
    for col in _FIGURE_COLUMNS:
        table.add_column(col, justify="right")
    for thr, per in trusted.items():
        for label, f in per.items():
            table.add_row(f"{thr:g}", label, *_figures_row(f))
    console.print(table)
    out["confidence"] = {str(t): {k: f.as_dict() for k, f in per.items()} for t, per in trusted.items()}
    for label, cov_rows in coverage_bins(study, ring.frames).items():
        table = Table(title=f"4. {label}: coverage by where the view is")
        for col in ("binned by", "bin", "share of the view", "coverage"):
            table.add_column(col, justify="right")
        for by, lo, hi, share, cov in cov_rows:
            table.add_row(by, f"{lo:g}–{hi:g}", f"{share:.3f}", f"{cov:.3f}")
        console.print(table)
        out["coverage"][label] = cov_rows
    wide = coverage_with(ring.rig, ring.frames, pairs, StereoParams(disparity_range=192), cache)
    console.print("  coverage with 192 disparities: " + ", ".join(f"{k} {v:.3f}" for k, v in wide.items()))
    out["coverage_192_disparities"] = wide
    # The OCamCalib files alone bound no lens field: the models stay valid to the sensor's corners
    # (about 155° off the axis), black beyond the lens's ~113°, and the views take that in.
    unbounded = Rig(
        {n: c.replace(fov_deg=None, invpol=c.param_dict["invpol"]) for n, c in ring.rig.cameras.items()},
        dict(ring.rig.T_rig_cam),
    )
    loose = consistency_study(unbounded, ring.frames, pairs, cache_dir=cache)
    console.print(
        "  the lenses' fields unbounded (the OCamCalib files alone): coverage "
        + ", ".join(f"{p.label} {p.mean_coverage:.3f}" for p in loose.pairs)
        + "; median |e| "
        + ", ".join(f"{c.couple.label} {100 * c.figures.median_abs:.2f} %" for c in loose.couples)
    )
    out["fields_unbounded"] = loose.as_dict()
    return out


def _renders(ring: RealRing, pairs: Sequence[PairNames], cache: str) -> dict[str, Any]:
    t0 = time.perf_counter()
    pipes = pair_pipelines(ring.rig, pairs, cache_dir=cache)
    shot = render_rig_shot(
        room_scene(0), ring.rig, pipes, room_path(2, 5), supersample=2, noise_std=1.5, vignetting=0.35
    )
    took = time.perf_counter() - t0
    console.print(f"5. the ring's calibration rendered in the demo room ({took:.0f} s)")
    table = Table(
        title="5. renders of the ring's calibration: the pipeline given the exact one or one with errors"
    )
    for col in (
        "calibration given to the pipeline",
        "median |e| (couples)",
        "signed median",
        "median |dd| px",
        "within 3 %",
        "coverage (pairs)",
        "median |vert. disp.| px (pairs)",
    ):
        table.add_column(col, justify="right")
    out = {}
    for label, change in PERTURBATIONS:
        study = consistency_study(change(ring.rig), [shot.images], pairs, cache_dir=cache)
        fs = [c.figures for c in study.couples]
        cov = [p.coverage[0] for p in study.pairs]
        rows = [_pair_rows(change(ring.rig), [shot.images], a, b)[1].p50_px for a, b in pairs]
        vertical = [float("nan") if v is None else v for v in rows]

        def span(values: list[float], fmt: str) -> str:
            return f"{format(min(values), fmt)} – {format(max(values), fmt)}"

        table.add_row(
            label, span([100 * f.median_abs for f in fs], ".2f") + " %",
            span([100 * f.median_signed for f in fs], "+.2f") + " %",
            span([f.median_abs_px for f in fs], ".2f"), span([f.within_3 for f in fs], ".2f"),
            span(cov, ".3f"), span(vertical, ".2f"),
        )  # fmt: skip
        out[label] = {**study.as_dict(), "vertical_p50_px": vertical}
    console.print(table)
    return out


def _ring_refined(ring: RealRing, stereo: StereoParams, settings: str, cache: str) -> dict[str, Any]:
    result = refine_ring(ring.rig, ring.frames, options=RingRefineOptions(cache_dir=cache, stereo=stereo))
    table = Table(
        title=f"6. the whole ring refined at once ({settings}): vertical disparity p50 and coverage"
    )
    for col in ("pair", "camera turned deg", "|vert. disp.| before → after px", "coverage before → after"):
        table.add_column(col, justify="right")
    for a, b in result.vertical_before:
        turn = np.linalg.norm(result.corrections_deg[b])
        v0, v1 = result.vertical_before[(a, b)].p50_px, result.vertical_after[(a, b)].p50_px
        c0, c1 = result.coverage_before[(a, b)], result.coverage_after[(a, b)]
        table.add_row(f"{a}|{b}", f"{b} {turn:.3f}", f"{v0:.2f} → {v1:.2f}", f"{c0:.3f} → {c1:.3f}")
    console.print(table)
    for label, before in result.agreement_before.items():
        after = result.agreement_after[label]
        console.print(f"  {label}: median disagreement {100 * before:.2f} → {100 * after:.2f} %")
    console.print(f"  applied: {result.applied}" + (f" ({result.reason})" if result.reason else ""))
    return {
        "applied": result.applied,
        "reason": result.reason,
        "corrections_deg": {k: v.tolist() for k, v in result.corrections_deg.items()},
        "agreement": {k: [v, result.agreement_after[k]] for k, v in result.agreement_before.items()},
    }


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="the ring's folder (default: $RIG_SHARED_DATA/" + RING_DIR + ")",
    )
    parser.add_argument("--quick", action="store_true", help="one frame, no refinement or analysis")
    parser.add_argument("--no-analysis", action="store_true", help="skip section 4")
    parser.add_argument(
        "--renders", action="store_true", help="section 5: render the ring's calibration (minutes)"
    )
    parser.add_argument("--json", type=Path, default=None, metavar="FILE", help="also write results here")
    add_stereo_argument(parser)
    args = parser.parse_args(argv)
    stereo = StereoParams(**stereo_overrides(args.stereo))
    settings = f"today's defaults{', ' + args.stereo if args.stereo else ''}"
    info = machine_info()
    print_machine(info, "the real ring's consistency (accuracy without ground truth)")
    ring = load_ring(args.data or _default_data())
    if args.quick:
        ring = RealRing(ring.root, ring.rig, ring.frames[:1])
    cache = str(bench_cache_dir() / "lut")
    pairs = adjacent_pairs(ring.rig)
    console.print(f"pairs from geometry: {', '.join('|'.join(p) for p in pairs)}; {len(ring.frames)} frames")
    results: dict[str, Any] = {"pairs": ["|".join(p) for p in pairs], "frames": len(ring.frames)}
    results["loader"], matches = _loader_check(ring, pairs)
    keep = not (args.quick or args.no_analysis)
    versus = not args.quick  # against the other search on the same points
    study = consistency_study(
        ring.rig,
        ring.frames,
        pairs,
        stereo=stereo,
        cache_dir=cache,
        keep_ranges=keep or versus,
        keep_points=keep,
    )
    results["stereo"] = stereo.model_dump()
    results["today"] = _print_study(f"2. {settings}, the ring's calibration", study)
    # The pairs once more with their confidence, for 2b and 4 alike.
    confident = ConfidentRanges.of_study(study, ring.frames) if keep or versus else None
    if confident is not None and versus:
        results["versus_other_search"] = _versus_other_search(ring, pairs, stereo, study, confident, cache)
    if not args.quick:
        rigs, results["refinement"] = _refined(ring, pairs, matches)
        refined = consistency_study(ring.rig, ring.frames, pairs, stereo=stereo, cache_dir=cache, rigs=rigs)
        results["refined"] = _print_study(f"3. {settings}, each pair refined", refined)
        results["ring_refined"] = _ring_refined(ring, stereo, settings, cache)
    if confident is not None and keep:
        results["analysis"] = _analysis(ring, study, confident, pairs, cache)
    if args.renders:
        results["renders"] = _renders(ring, pairs, cache)
    return finish("ring_consistency", info, results, args.json, None)


if __name__ == "__main__":
    main()
