"""`rig calibrate intrinsics|stereo`: chessboard images -> calibration file (see docs/calibration.md);
`rig calibrate refine` (:mod:`cli.calibrate_refine`, docs/rectification.md).

``intrinsics`` writes a rig.yaml with one camera (identity pose); ``stereo`` writes the rig.yaml
of a pair. Both detect the board in every image (progress bar), list the images they skip and
why, calibrate from no guess, refine the corners for the fisheye with the lens found and
recalibrate (``--no-refine`` keeps the detector's corners; see calibration.corner_refine), print
a table of per-view errors and the RMS before/after refinement, and save a picture of the
residuals over the image.
"""

from __future__ import annotations

import glob
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from calibration.calibrate import CameraCalibration, calibrate_camera
from calibration.corner_refine import RefinementReport
from calibration.formats import load_camera, save_rig
from calibration.lm import LOSSES
from calibration.models import MODELS, CameraModel
from calibration.rig import Rig
from calibration.stereo_calibrate import StereoCalibration, calibrate_stereo
from calibration.targets import BoardSpec, Detection, detect_chessboard_files, parse_board
from cli.calibrate_refine import register_refine
from cli.console import console, err_console, progress_bar, warn
from cli.errors import fail
from rig.calibration_report import ResidualPanel, save_residual_plot

__all__ = ["expand_images", "register"]

# Module level: typer evaluates the (string) annotations in the module's namespace.
_MODEL_HELP = f"Camera model: {', '.join(sorted(MODELS))}."


def _natural_key(path: str) -> list[int | str]:
    """'left10.png' after 'left9.png'."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path)]


def expand_images(patterns: Sequence[str]) -> list[str]:
    """Files matching each glob (or named directly), naturally sorted, without duplicates."""
    found: set[str] = set()
    for pattern in patterns:
        matches = glob.glob(pattern)
        if not matches and Path(pattern).is_file():
            matches = [pattern]
        if not matches:
            fail(f"no images match {pattern!r}")
        found.update(m for m in matches if Path(m).is_file())
    return sorted(found, key=_natural_key)


def _detect(paths: list[str], board: BoardSpec, label: str, subpix: int) -> list[Detection]:
    with progress_bar() as progress:
        task = progress.add_task(f"detecting {board.cols}x{board.rows} board in {label}", total=len(paths))
        dets = detect_chessboard_files(
            paths, board.pattern_size, lambda _: progress.advance(task), subpix_window=subpix or None
        )
    for d in dets:
        if not d.ok:
            err_console.print(
                f"[yellow]skipped[/yellow] {d.source}: {d.reason}", highlight=False, soft_wrap=True
            )
    return dets


def _image_size(dets: Sequence[Detection]) -> tuple[int, int]:
    sized = [(d.source, d.image_size) for d in dets if d.image_size is not None]
    if not sized:
        fail("none of the images could be read")
    first, (w, h) = sized[0]
    for source, (w2, h2) in sized[1:]:
        if (w2, h2) != (w, h):
            fail(f"images differ in size: {first} is {w}x{h}, {source} is {w2}x{h2}")
    return (w, h)


def _check_options(model: str, loss: str, square: float, board: str) -> BoardSpec:
    if model not in MODELS:
        fail(f"--model must be one of {', '.join(sorted(MODELS))}, got {model!r}")
    if loss not in LOSSES:
        fail(f"--loss must be one of {', '.join(LOSSES)}, got {loss!r}")
    if not square > 0:
        fail(f"--square must be a positive size in metres, got {square}")
    return parse_board(board, square)


def _residuals_path(out: Path, residuals: Path | None) -> Path:
    return residuals if residuals is not None else out.with_name(out.stem + "_residuals.png")


def _fix_list(fix: str) -> list[str]:
    return [f.strip() for f in fix.split(",") if f.strip()]


def _load_intrinsics(path: Path | None, option: str) -> CameraModel | None:
    if path is None:
        return None
    if not path.is_file():
        fail(f"{option}: {path} not found")
    return load_camera(path)


def _summary(camera: CameraModel, std: dict[str, float]) -> str:
    parts = []
    for name, value in zip(camera.param_layout, camera.params, strict=True):
        s = std.get(name)
        parts.append(f"{name}={value:.6g}" + (f" ±{s:.2g}" if s is not None else ""))
    return ", ".join(parts)


def _mono_table(result: CameraCalibration) -> Table:
    table = Table(title=f"per-view reprojection error ({result.camera.name})")
    table.add_column("view")
    table.add_column("corners", justify="right")
    table.add_column("RMS px", justify="right")
    table.add_column("max px", justify="right")
    for name, r, res in zip(result.view_names, result.view_rms, result.residuals, strict=True):
        table.add_row(name, str(len(res)), f"{r:.3f}", f"{np.linalg.norm(res, axis=1).max():.3f}")
    for d in result.dropped:
        table.add_row(f"[yellow]{d.name}[/yellow]", "-", "-", f"[yellow]dropped: {d.reason}[/yellow]")
    return table


def _stereo_table(result: StereoCalibration) -> Table:
    left, right = result.rig.names
    table = Table(title="per-view reprojection error (px RMS)")
    table.add_column("view")
    table.add_column(left, justify="right")
    table.add_column(right, justify="right")
    for k, name in enumerate(result.view_names):
        cells = [result.view_rms[n][k] for n in (left, right)]
        table.add_row(name, *("-" if c is None else f"{c:.3f}" for c in cells))
    for cam, d in result.dropped:
        note = f"[yellow]dropped: {d.reason}[/yellow]"
        table.add_row(f"[yellow]{d.name}[/yellow]", *((note, "") if cam == left else ("", note)))
    return table


def _sources(dets: Sequence[Detection], refine: bool) -> list[str | None] | None:
    """Image files for corner refinement (None for images without a board), or None."""
    return [d.source if d.ok else None for d in dets] if refine else None


def _print_refinement(name: str, report: RefinementReport | None, refine: bool) -> None:
    if not refine:
        console.print(f"{name}: detector corners used as they are (--no-refine)", highlight=False)
        return
    if report is None:
        return
    out = len(report.rejected)
    reasons = ", ".join(f"{n} {why}" for why, n in sorted(report.reasons().items()))
    console.print(
        f"{name}: corner refinement: RMS {report.rms_before:.4f} -> {report.rms_after:.4f} px, "
        f"{report.rounds} round(s), corners moved {report.mean_shift_px:.3f} px on average, "
        f"{out} of {report.n_corners + out} corners left out" + (f" ({reasons})" if out else ""),
        highlight=False,
        soft_wrap=True,
    )
    if not report.converged:
        warn(f"{name}: corners still moved {report.changes_px[-1]:.2g} px in the last refinement round")


def _calibrating(message: str) -> Progress:
    progress = Progress(
        SpinnerColumn(), TextColumn(message), TimeElapsedColumn(), console=err_console, transient=True
    )
    progress.add_task(message, total=None)
    return progress


# Options both commands take (typer reads them from the Annotated metadata).
BoardOpt = Annotated[
    str, typer.Option("--board", metavar="COLSxROWS", help="Inner corners of the board, e.g. 9x6.")
]
SquareOpt = Annotated[float, typer.Option("--square", metavar="METRES", help="Square size.")]
ModelOpt = Annotated[str, typer.Option("--model", metavar="MODEL", help=_MODEL_HELP)]
FovOpt = Annotated[
    float | None, typer.Option("--fov-deg", metavar="DEG", help="Lens field of view to store.")
]
LossOpt = Annotated[
    str, typer.Option("--loss", metavar="LOSS", help="linear, huber or soft_l1 (robust, 1 px scale).")
]
SubpixOpt = Annotated[
    int,
    typer.Option(
        "--subpix", metavar="PX", help="Re-refine corners with cornerSubPix of this half-window; 0 = off."
    ),
]
ResidualsOpt = Annotated[
    Path | None,
    typer.Option(
        "--residuals", metavar="FILE", help="Residual picture to write.", show_default="OUT_residuals.png"
    ),
]
MinViewsOpt = Annotated[int, typer.Option("--min-views", metavar="N", help="Fewest usable views accepted.")]
RefineOpt = Annotated[
    bool,
    typer.Option(
        "--refine/--no-refine", help="Refine the corners for the fisheye with the lens found, recalibrate."
    ),
]


def register(app: typer.Typer) -> None:
    cal = typer.Typer(
        help="Calibrate cameras and the rig from chessboard images; refine the pair from a scene.",
        no_args_is_help=True,
    )

    @cal.command("intrinsics")
    def intrinsics(
        board: BoardOpt,
        square: SquareOpt,
        out: Annotated[
            Path, typer.Option("--out", metavar="FILE", help="rig.yaml to write (one camera, identity pose).")
        ],
        images: Annotated[
            list[str] | None,
            typer.Option("--images", metavar="GLOB", help="Chessboard images (quote the glob); repeatable."),
        ] = None,
        more_images: Annotated[
            list[str] | None,
            typer.Argument(metavar="IMAGES", help="More image files (an unquoted glob lands here)."),
        ] = None,
        model: ModelOpt = "kannala_brandt",
        name: Annotated[
            str, typer.Option("--name", metavar="NAME", help="Camera name in the file.")
        ] = "cam0",
        fov_deg: FovOpt = None,
        initial: Annotated[
            Path | None,
            typer.Option("--initial", metavar="FILE", help="Optional starting guess (any calibration file)."),
        ] = None,
        fix: Annotated[
            str,
            typer.Option(
                "--fix", metavar="NAMES", help="Parameters held at their start value, comma-separated."
            ),
        ] = "",
        loss: LossOpt = "linear",
        subpix: SubpixOpt = 0,
        residuals: ResidualsOpt = None,
        refine: RefineOpt = True,
        min_views: MinViewsOpt = 3,
    ) -> None:
        """Calibrate one camera's lens from chessboard images (no initial guess needed)."""
        spec = _check_options(model, loss, square, board)
        paths = expand_images([*(images or []), *(more_images or [])])
        if not paths:
            fail("no images given: use --images 'DIR/*.png'")
        dets = _detect(paths, spec, f"{len(paths)} images", subpix)
        size = _image_size(dets)
        guess = _load_intrinsics(initial, "--initial")
        extra = " with corner refinement" if refine else ""
        with _calibrating(f"calibrating {model} from {sum(d.ok for d in dets)} views{extra}"):
            result = calibrate_camera(
                model, [spec.object_points()] * len(dets), [d.corners for d in dets], size, guess,
                fix=_fix_list(fix), fov_deg=fov_deg, loss=loss, min_views=min_views,
                view_names=[Path(d.source).name for d in dets], images=_sources(dets, refine),
            )  # fmt: skip
        camera = result.camera
        save_rig(Rig({name: camera}, {name: np.eye(4)}), out)
        picture = _write_picture(
            _residuals_path(out, residuals),
            [ResidualPanel(name, size, _centre(camera), result.image_points, result.residuals)],
        )
        console.print(_mono_table(result))
        console.print(
            f"{name}: {camera.name} {size[0]}x{size[1]}, RMS {result.rms:.4f} px over {result.n_corners} "
            f"corners in {len(result.views)} views, up to {result.max_angle_deg:.1f}° off axis",
            highlight=False,
        )
        console.print(f"  {_summary(camera, result.param_std)}", highlight=False, soft_wrap=True)
        _print_refinement(name, result.refinement, refine)
        if not result.converged:
            warn(result.message)
        console.print(f"wrote {out} and {picture}", highlight=False)

    @cal.command("stereo")
    def stereo(
        left: Annotated[
            str, typer.Option("--left", metavar="GLOB", help="Left camera images (quote the glob).")
        ],
        right: Annotated[
            str,
            typer.Option("--right", metavar="GLOB", help="Right camera images, same count and order."),
        ],
        board: BoardOpt,
        square: SquareOpt,
        out: Annotated[Path, typer.Option("--out", metavar="FILE", help="rig.yaml to write.")],
        model: ModelOpt = "kannala_brandt",
        left_intrinsics: Annotated[
            Path | None,
            typer.Option("--left-intrinsics", metavar="FILE", help="Start from (or fix) this calibration."),
        ] = None,
        right_intrinsics: Annotated[
            Path | None,
            typer.Option("--right-intrinsics", metavar="FILE", help="Start from (or fix) this calibration."),
        ] = None,
        fix_intrinsics: Annotated[
            bool, typer.Option("--fix-intrinsics", help="Refine only the poses.")
        ] = False,
        fov_deg: FovOpt = None,
        loss: LossOpt = "linear",
        subpix: SubpixOpt = 0,
        residuals: ResidualsOpt = None,
        refine: RefineOpt = True,
        min_views: Annotated[
            int, typer.Option("--min-views", metavar="N", help="Fewest usable views, per camera and common.")
        ] = 3,
    ) -> None:
        """Calibrate a camera pair (any divergence, corners past 90° kept) and write rig.yaml."""
        spec = _check_options(model, loss, square, board)
        lpaths, rpaths = expand_images([left]), expand_images([right])
        if len(lpaths) != len(rpaths):
            fail(f"--left matches {len(lpaths)} images but --right matches {len(rpaths)} (paired in order)")
        ldets = _detect(lpaths, spec, f"{len(lpaths)} left images", subpix)
        rdets = _detect(rpaths, spec, f"{len(rpaths)} right images", subpix)
        lsize, rsize = _image_size(ldets), _image_size(rdets)
        linit = _load_intrinsics(left_intrinsics, "--left-intrinsics")
        rinit = _load_intrinsics(right_intrinsics, "--right-intrinsics")
        n_both = sum(a.ok and b.ok for a, b in zip(ldets, rdets, strict=True))
        pair_names = [
            f"{Path(a.source).name}|{Path(b.source).name}" for a, b in zip(ldets, rdets, strict=True)
        ]
        extra = " with corner refinement" if refine else ""
        with _calibrating(f"calibrating the pair ({n_both} views seen by both cameras){extra}"):
            result = calibrate_stereo(
                model, [spec.object_points()] * len(ldets), [d.corners for d in ldets],
                [d.corners for d in rdets], lsize, rsize, left_initial=linit, right_initial=rinit,
                fix_intrinsics=fix_intrinsics, fov_deg=fov_deg, loss=loss, min_views=min_views,
                min_common_views=min_views, view_names=pair_names, left_images=_sources(ldets, refine),
                right_images=_sources(rdets, refine),
            )  # fmt: skip
        save_rig(result.rig, out)
        panels = [
            ResidualPanel(
                n,
                size,
                _centre(result.cameras[n]),
                [p for p in result.image_points[n] if p is not None],
                [r for r in result.residuals[n] if r is not None],
            )
            for n, size in zip(result.rig.names, (lsize, rsize), strict=True)
        ]
        picture = _write_picture(_residuals_path(out, residuals), panels)
        console.print(_stereo_table(result))
        axes = result.rig.axis("left") @ result.rig.axis("right")
        console.print(
            f"rig: baseline {result.baseline_m * 1000:.2f} mm (±{result.translation_std_m * 1000:.2f}), "
            f"{np.degrees(np.arccos(np.clip(axes, -1, 1))):.2f}° between the optical axes "
            f"(rotation ±{result.rotation_std_deg:.3f}°), {len(result.common_views)} common views; "
            f"RMS {result.rms:.4f} px ("
            + ", ".join(f"{n} {v:.4f}" for n, v in result.camera_rms.items())
            + ")",
            highlight=False,
        )
        for n in result.rig.names:
            _print_refinement(n, result.refinement.get(n), refine)
        if not result.converged:
            warn(result.message)
        console.print(f"wrote {out} and {picture}", highlight=False)

    register_refine(cal)
    app.add_typer(cal, name="calibrate")


def _centre(camera: CameraModel) -> tuple[float, float]:
    p = camera.param_dict
    return float(p.get("cx", (camera.width - 1) / 2)), float(p.get("cy", (camera.height - 1) / 2))


def _write_picture(path: Path, panels: list[ResidualPanel]) -> Path:
    try:
        return save_residual_plot(path, panels)
    except OSError as err:
        fail(f"cannot write the residual picture {path}: {err.strerror or err}")
