"""`rig evaluate`: the paper's analysis reproduced by one command (see docs/evaluation.md).

``rig evaluate --preset paper-sim --out DIR`` calibrates every model on rendered chessboards,
compares each model's VPC image with the Reference camera's, measures the depth error of a
textured plane at 2…20 baselines through every model's pipeline, compares the matchers, and
writes results.json, CSV tables, PNG figures and report.md into DIR (see rig.evaluate.report).
``--quick`` runs a reduced version (half-size images, 3 distances, 2 textures).

``rig evaluate --study consistency REC --calibration RIG`` measures how the stereo pairs of a rig of
N cameras agree with each other on a recording (see cli.evaluate_consistency and docs/ring.md).

``rig evaluate --study wide-pair --preset prototype --out DIR`` measures instead how much of what
both lenses see the pinhole and lat-lon pairs turn into range, and how accurate (see
rig.evaluate.wide_pair and docs/wide-pair.md).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Annotated

import typer
from rich.progress import Progress
from rich.table import Table

from cli.console import console, progress_bar
from cli.errors import fail
from cli.evaluate_consistency import consistency_command
from cli.pair_options import CacheDirOption, CalibrationOption
from cli.pipeline_options import StereoOption, load_stereo_params
from cli.sim import PresetOption, parse_distances
from rig.evaluate import DEFAULT_MODELS, EvaluationRun, make_config, run_evaluation, write_outputs
from rig.evaluate.agreement import mean_ratio
from rig.evaluate.config import FULL_DISTANCES, QUICK_DISTANCES, default_lens
from rig.evaluate.depth_quality import REFERENCE, THEORY
from rig.evaluate.wide_pair import WideStudy, make_wide_config, run_wide_study, study_steps
from rig.evaluate.wide_pair_report import write_wide_outputs
from rig.sim.lens_effects import LENS_CHOICES
from rig.sim.presets import PRESETS

__all__ = ["register"]


class _RichSink:
    """Feeds the runner's steps into a rich progress bar."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.task = progress.add_task("evaluating", total=None)

    def start(self, total: int) -> None:
        self.progress.update(self.task, total=total)

    def step(self, description: str) -> None:
        self.progress.update(self.task, advance=1, description=description)


def _parse_models(text: str | None) -> list[str] | None:
    if text is None:
        return None
    models = [m.strip() for m in text.split(",") if m.strip()]
    if not models:
        fail(f"--models must be a comma-separated list of camera models, got {text!r}")
    return models


def _check_out(out: Path, force: bool) -> None:
    if out.exists() and not out.is_dir():
        fail(f"--out {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        fail(f"--out {out} is not empty; choose a new directory or pass --force to overwrite its files")


def _summary(run: EvaluationRun) -> Table:
    table = Table(title=f"rig evaluate {run.config.preset}")
    for col in ("model", "calibration RMS px", "image difference", "depth RMS / Reference"):
        table.add_column(col, justify="left" if col == "model" else "right")
    cal = run.calibration.models
    names = [n for n in run.depth if n not in (REFERENCE, THEORY)] + [m for m in cal if m not in run.depth]
    for name in names:
        mc = cal.get(name)
        rms = (
            "–"
            if mc is None
            else ("failed" if not mc.ok else f"{mc.results[run.calibration.lens_of[run.pair.left]].rms:.4f}")
        )
        diff = run.distortion.results.get(name)
        ratio = mean_ratio(run.depth[name], run.depth[REFERENCE]) if name in run.depth else math.nan
        table.add_row(
            name,
            rms,
            "–" if diff is None or not math.isfinite(diff.mad_whole) else f"{diff.mad_whole:.2f}",
            "–" if not math.isfinite(ratio) else f"{ratio:.3f}",
        )
    return table


def register(app: typer.Typer) -> None:
    @app.command("evaluate")
    def evaluate(
        recording: Annotated[
            Path | None,
            typer.Argument(metavar="REC", help="--study consistency: a recording of the rig's cameras."),
        ] = None,
        out: Annotated[
            Path | None,
            typer.Option("--out", "-o", metavar="DIR", help="Output directory (new or empty)."),
        ] = None,
        preset: PresetOption = "paper-sim",
        models: Annotated[
            str | None,
            typer.Option(
                metavar="MODELS",
                help="Camera models to calibrate, comma-separated.",
                show_default=",".join(DEFAULT_MODELS),
            ),
        ] = None,
        distances: Annotated[
            str | None,
            typer.Option(
                metavar="LIST",
                help="Plane distances in baselines, comma-separated.",
                show_default=f"{FULL_DISTANCES[0]:g}…{FULL_DISTANCES[-1]:g}; quick "
                f"{','.join(f'{k:g}' for k in QUICK_DISTANCES)}",
            ),
        ] = None,
        textures: Annotated[
            int | None,
            typer.Option(metavar="N", help="Textures averaged per distance.", show_default="3; quick 2"),
        ] = None,
        quick: Annotated[
            bool, typer.Option("--quick", help="Reduced run: half-size images, 3 distances, 2 textures.")
        ] = False,
        seed: Annotated[
            int, typer.Option(metavar="SEED", help="Seed of board poses, textures, noise and point sampling.")
        ] = 0,
        force: Annotated[bool, typer.Option("--force", help="Write into a non-empty --out.")] = False,
        study: Annotated[
            str,
            typer.Option(
                metavar="STUDY",
                help="paper (the paper's analysis), wide-pair (coverage and range error of the "
                "pinhole and lat-lon pairs over the lenses' overlap, in the room) or consistency (how "
                "the pairs of a rig of N cameras agree on REC).",
            ),
        ] = "paper",
        calibration: CalibrationOption = None,
        stereo_file: StereoOption = None,
        cache_dir: CacheDirOption = None,
        json_path: Annotated[
            Path | None,
            typer.Option(
                "--json", metavar="FILE", help="--study consistency: also write the figures as JSON."
            ),
        ] = None,
        lens: Annotated[
            str | None,
            typer.Option(
                metavar="LENS",
                help="The fisheye renders' lens: honest (fitted to real fisheyes: blur, rim darkening, "
                "exposure, noise) or ideal (none).",
                show_default="ideal for paper-sim, honest otherwise",
            ),
        ] = None,
    ) -> None:
        """Reproduce the paper's evaluation on a simulated rig (or the wide-pair study).

        Calibration of every model, distortion removal, depth error against distance, matcher
        comparison: results.json, CSV tables, figures and report.md in --out.
        """
        if study not in ("paper", "wide-pair", "consistency"):
            fail(f"--study must be paper, wide-pair or consistency, got {study!r}")
        if study == "consistency":
            if out is not None:
                fail("--out applies to --study paper and wide-pair; consistency prints (and --json writes)")
            consistency_command(recording, calibration, stereo_file, cache_dir, json_path)
            return
        given = [
            o for o, v in (("REC", recording), ("--calibration", calibration), ("--json", json_path)) if v
        ]
        if given:
            fail(f"{', '.join(given)} apply to --study consistency")
        if out is None:
            fail(f"--study {study} needs --out DIR")
        if preset not in PRESETS:
            fail(f"--preset must be one of {', '.join(PRESETS)}, got {preset!r}")
        if lens is not None and lens not in LENS_CHOICES:
            fail(f"--lens must be one of {', '.join(LENS_CHOICES)}, got {lens!r}")
        _check_out(out, force)
        if study == "wide-pair":
            given = [
                o
                for o, v in (("--models", models), ("--distances", distances), ("--textures", textures))
                if v
            ]
            if given:
                fail(f"{', '.join(given)} apply to --study paper, not wide-pair")
            _wide_pair(out, preset, quick, seed, lens or default_lens(preset), stereo_file)
            return
        if stereo_file is not None:
            fail("--stereo applies to --study wide-pair, not paper")
        config = make_config(
            preset,
            quick=quick,
            models=_parse_models(models),
            distances=parse_distances(distances) if distances is not None else None,
            textures=textures,
            seed=seed,
            lens=lens,
        )
        # Calibrated models may end a hair before the VPC's edge (a few pixels invalid); the
        # pipeline's warning about it would interrupt the progress bar: the report lists it.
        logging.getLogger("rig.pipeline").setLevel(logging.ERROR)
        with progress_bar() as progress:
            run = run_evaluation(config, _RichSink(progress))
        report = write_outputs(run, out)
        console.print(_summary(run))
        total = sum(run.timings_s.values())
        console.print(f"wrote {report} and the results next to it ({total:.0f} s)", highlight=False)


def _wide_pair(out: Path, preset: str, quick: bool, seed: int, lens: str, stereo_file: Path | None) -> None:
    stereo = load_stereo_params(stereo_file) if stereo_file is not None else None
    config = make_wide_config(preset, quick=quick, seed=seed, lens=lens, stereo=stereo)
    logging.getLogger("rig.pipeline").setLevel(logging.ERROR)  # each variant's notes: in the report
    with progress_bar() as progress:
        task = progress.add_task("wide pair", total=study_steps(config))
        result = run_wide_study(config, lambda what: progress.update(task, advance=1, description=what))
    report = write_wide_outputs(result, out)
    console.print(_wide_summary(result))
    console.print(
        f"wrote {report} and the results next to it ({result.timings_s['total']:.0f} s)", highlight=False
    )


def _wide_summary(result: WideStudy) -> Table:
    table = Table(
        title=f"rig evaluate --study wide-pair {result.config.preset}: overlap {result.overlap_sr:.2f} sr"
    )
    for col in (
        "rectified pair",
        "pixels",
        "valid sr",
        "within 3 % sr (of overlap)",
        "median error",
        "shared rays",
    ):
        table.add_column(col, justify="left" if col == "rectified pair" else "right")
    for r in result.results:
        shared = "–" if r.shared is None else f"{100 * r.shared[0]:.2f} % / {100 * r.shared[1]:.2f} %"
        table.add_row(
            r.variant.label,
            str(r.pixels),
            f"{r.valid_sr:.2f}",
            f"{r.within_sr[0.03]:.2f} ({100 * r.within_sr[0.03] / result.overlap_sr:.0f} %)",
            f"{100 * r.median_error:.2f} %",
            shared,
        )
    return table
