"""`rig lut build|show`: build the VPC lookup tables into the cache, list the cache (see docs/stereo.md)."""

from __future__ import annotations

import time
from typing import Annotated

import typer
from rich.table import Table

from cli.console import console, warn
from cli.pair_options import (
    CacheDirOption,
    CalibrationOption,
    FieldOption,
    PinholeHfovOption,
    PinholeSizeOption,
    PitchOption,
    ProjectionOption,
    PxPerDegOption,
    YawOption,
    load_calibration,
    make_pair_config,
)
from rig.errors import ConfigError
from rig.lut import percent_valid
from rig.lut_cache import LutCache, lut_key
from rig.rectified import design_rectified_pair
from rig.stereo import StereoParams

__all__ = ["register"]


def _age(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 172800:
        return f"{seconds / 3600:.0f} h"
    return f"{seconds / 86400:.0f} d"


def register(app: typer.Typer) -> None:
    lut = typer.Typer(help="Build and list cached VPC lookup tables.", no_args_is_help=True)

    @lut.command("build")
    def build(
        calibration: CalibrationOption = None,
        projection: ProjectionOption = None,
        vpc_hfov: PinholeHfovOption = None,
        vpc_size: PinholeSizeOption = None,
        px_per_deg: PxPerDegOption = None,
        field: FieldOption = None,
        yaw: YawOption = None,
        pitch: PitchOption = None,
        cache_dir: CacheDirOption = None,
        rebuild: Annotated[bool, typer.Option("--rebuild", help="Rebuild even if cached.")] = False,
    ) -> None:
        """Build (or find) the LUT of each camera for the rectified pair.

        Prints each table's path, key, valid fraction and build time. A lat-lon field leaves room
        for the default stereo settings' unmatched columns, as the service and rig process do.
        """
        if calibration is None:
            raise ConfigError("rig lut build: --calibration FILE is required")
        rig, _ = load_calibration(calibration)
        config = make_pair_config(
            vpc_size, vpc_hfov, yaw, pitch, projection=projection, px_per_deg=px_per_deg, field=field
        )
        pair = design_rectified_pair(rig, config, blind_band_px=StereoParams().blind_band_px)
        if pair.field_note:
            warn(pair.field_note)
        cache = LutCache(cache_dir)
        table = Table(title=f"{pair.describe()}, B {pair.baseline_m:.4f} m")
        for col in ("camera", "path", "key", "valid", "build ms", "source"):
            table.add_column(col)
        for name in (pair.left, pair.right):
            model, R = rig.cameras[name], pair.R_cam_rect[name]
            if rebuild:
                cache.discard(lut_key(model, R, pair.camera))
            t0 = time.perf_counter()
            got = cache.get(model, R, pair.camera)
            ms = got.build_ms if not got.hit else (time.perf_counter() - t0) * 1e3
            frac = got.lut.valid_fraction
            table.add_row(
                name,
                str(got.path),
                got.key[:16],
                percent_valid(frac),
                f"{ms:.1f}",
                "cache (load)" if got.hit else "built",
            )
            if frac < 1.0 and pair.projection == "pinhole":  # a lat-lon field spans the overlap by design
                valid = percent_valid(frac)
                warn(f"the pinhole pair leaves camera '{name}''s field: only {valid} of its pixels are valid")
        console.print(table)

    @lut.command("show")
    def show(
        cache_dir: CacheDirOption = None,
        clear: Annotated[bool, typer.Option("--clear", help="Delete every cached table.")] = False,
    ) -> None:
        """List the cached tables (key, size, age, what each maps, check); --clear empties the cache."""
        cache = LutCache(cache_dir)
        if clear:
            n = cache.clear()
            console.print(f"removed {n} table(s) from {cache.directory}")
            return
        entries = cache.entries()
        if not entries:
            console.print(f"no cached tables in {cache.directory}")
            return
        table = Table(title=str(cache.directory))
        for col in ("key", "size", "age", "table", "valid", "status"):
            table.add_column(col)
        for e in entries:
            table.add_row(
                e.path.stem[:16],
                f"{e.size_bytes / 1e6:.1f} MB",
                _age(e.age_s),
                e.summary,
                "" if e.valid_fraction is None else f"{100 * e.valid_fraction:.1f}%",
                "ok" if e.ok else f"[red]bad[/red]: {e.problem}",
            )
        console.print(table)

    app.add_typer(lut, name="lut")
