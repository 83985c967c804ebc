"""`rig calibrate refine REC --calibration FILE --out FILE` (docs/rectification.md): the pair's
relative rotation (and, where the scene constrains it, its baseline direction; never the scale)
refined from the scene of a recording.

Matches up to ``--frames`` pairs spread over the recording (progress bar), prints the correction
in degrees about the rectified pair's axes with its 1σ, what happened to the baseline direction,
and the vertical disparity of the consistent matches before and after in the pinhole pair of the
``--vpc-*`` options; writes the corrected calibration as rig.yaml atomically. ``--out`` may be
the calibration file itself: its original is then kept as ``<name>.orig<suffix>`` first (once).
With ``--floor-height M`` the vergence is found from the floor instead (:mod:`cli.calibrate_floor`);
a recording of a ring (more than two cameras) refines every camera at once (:mod:`cli.calibrate_ring`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from calibration.relative_pose import RelativePoseOptions
from cli.calibrate_floor import refine_from_floor
from cli.calibrate_ring import RING_FRAMES, refine_ring_recording
from cli.console import console, progress_bar
from cli.errors import fail
from cli.pair_options import (
    CalibrationOption,
    PinholeHfovOption,
    PinholeSizeOption,
    PitchOption,
    YawOption,
    load_calibration,
    make_pair_config,
)
from cli.pipeline_options import StereoOption, load_stereo_params
from rig.errors import RigError
from rig.recording import Recording
from rig.rectification import RectificationRefinement, RefineOptions, refine_recording
from rig.rectification.measure import VerticalDisparity
from rig.rectification.refine import save_refined

__all__ = ["register_refine"]

_DIRECTION = {"auto": "auto", "estimate": "always", "keep": "never"}


def _vd(m: VerticalDisparity) -> str:
    if not m.ok or m.p50_px is None or m.p95_px is None:
        return f"– ({m.reason})"
    return f"p50 {m.p50_px:.3f} px, p95 {m.p95_px:.3f} px ({m.count} matches in the pair)"


def _report(result: RectificationRefinement) -> Table:
    fit = result.fit
    table = Table(title="right camera correction")
    for col in ("axis", "correction °", "1σ °"):
        table.add_column(col, justify="left" if col == "axis" else "right")
    axes = ("x, the baseline (pitch)", "y, vertical (vergence)", "z, the look direction (roll)")
    for axis, deg, sigma in zip(axes, fit.rotation_deg, fit.rotation_sigma_deg, strict=True):
        table.add_row(axis, f"{deg:+.4f}", f"{sigma:.4f}")
    table.add_row("total angle", f"{fit.angle_deg:.4f}", f"{fit.angle_sigma_deg:.4f}")
    return table


def _is_ring(recording: Path) -> bool:
    """A recording directory of more than two cameras (a bag or a broken directory: not a ring;
    the pair's path reports what is wrong with it)."""
    try:
        return len(Recording(recording).cameras) > 2
    except (OSError, ValueError, RigError):
        return False


def register_refine(cal: typer.Typer) -> None:
    """Add ``refine`` to the ``rig calibrate`` group."""

    @cal.command("refine")
    def refine(
        recording: Annotated[
            Path, typer.Argument(metavar="REC", help="Recording whose scene refines the pair.")
        ],
        out: Annotated[Path, typer.Option("--out", metavar="FILE", help="rig.yaml to write.")],
        calibration: CalibrationOption = None,
        frames: Annotated[
            int | None,
            typer.Option(
                "--frames",
                metavar="N",
                help="Pairs (sets of a ring) used, evenly spread over the recording: 20 (a ring: 3).",
            ),
        ] = None,
        baseline_direction: Annotated[
            str,
            typer.Option(
                "--baseline-direction",
                metavar="MODE",
                help="auto (estimated where the scene constrains it), estimate, or keep.",
            ),
        ] = "auto",
        min_matches: Annotated[
            int, typer.Option("--min-matches", metavar="N", help="Fewest consistent matches to accept.")
        ] = 100,
        vpc_size: PinholeSizeOption = "640x480",
        vpc_hfov: PinholeHfovOption = 90.0,
        yaw: YawOption = 0.0,
        pitch: PitchOption = 0.0,
        floor_height: Annotated[
            float | None,
            typer.Option(
                "--floor-height",
                metavar="M",
                help="Instead: the vergence from a floor this far below the rig's origin (metres).",
            ),
        ] = None,
        stereo: StereoOption = None,
    ) -> None:
        """Refine the pair's relative rotation (a ring: every camera's) from the scene of a
        recording and write rig.yaml. A ring's couples are measured with ``--stereo``'s
        parameters (default: the defaults): give the ones the service serves depth with."""
        if frames is not None and not 1 <= frames <= 100_000:
            fail(f"--frames must be in [1, 100000], got {frames}")
        if _is_ring(recording):
            if floor_height is not None:
                fail("--floor-height applies to a two-camera rig; this recording holds a ring")
            params = None
            if stereo is not None:
                params = load_stereo_params(stereo)
                console.print(
                    f"couples measured with the stereo parameters of {stereo}",
                    highlight=False,
                    soft_wrap=True,
                )
            refine_ring_recording(recording, calibration, out, frames or RING_FRAMES, params)
            return
        if stereo is not None:
            fail(
                "--stereo applies to a ring, whose couples' agreement is measured with it; a pair's "
                "refinement measures vertical disparity, without the matcher"
            )
        frames = frames or 20
        if floor_height is not None:
            scene_only = (baseline_direction, min_matches, vpc_size, vpc_hfov, yaw, pitch)
            if scene_only != ("auto", 100, "640x480", 90.0, 0.0, 0.0):
                fail(
                    "--baseline-direction, --min-matches, --vpc-*, --yaw and --pitch do not apply with "
                    "--floor-height (the floor is seen through today's pair)"
                )
            refine_from_floor(recording, calibration, out, floor_height, frames)
            return
        if baseline_direction not in _DIRECTION:
            fail(f"--baseline-direction must be auto, estimate or keep, got {baseline_direction!r}")
        if min_matches < 10:
            fail(f"--min-matches must be at least 10, got {min_matches}")
        vpc = make_pair_config(vpc_size, vpc_hfov, yaw, pitch)
        rec = Recording(recording)
        rig, cal_path = load_calibration(calibration, rec.calibration_path)
        options = RefineOptions(
            frames=frames,
            min_matches=min_matches,
            pose=RelativePoseOptions(estimate_direction=_DIRECTION[baseline_direction]),
        )
        with progress_bar() as bar:
            task = bar.add_task(f"matching pairs of {recording}", total=None)
            result = refine_recording(
                rec, rig, vpc, options, lambda done, total: bar.update(task, completed=done, total=total)
            )
        for seq, why in result.skipped.items():
            console.print(f"[yellow]skipped[/yellow] seq {seq}: {why}", highlight=False, soft_wrap=True)
        backup = save_refined(result.rig_after, out, cal_path)
        fit = result.fit
        console.print(_report(result))
        console.print(
            f"from {fit.n_inliers} of {result.matches} matches in {len(result.matches_per_frame)} pairs "
            f"(robust σ {fit.sigma_deg:.4f}°); baseline direction {fit.direction_note}; baseline length "
            f"kept at {result.rig_after.baseline(result.left, result.right) * 1000:.2f} mm",
            highlight=False,
        )
        console.print(
            f"vertical disparity ({vpc.width}x{vpc.height}, {vpc.hfov_deg:g}° pinhole pair): "
            f"before {_vd(result.before)}; after {_vd(result.after)}",
            highlight=False,
        )
        kept = f" (the original is kept as {backup})" if backup is not None else ""
        console.print(f"wrote {out}{kept}; calibration was {cal_path}", highlight=False)
