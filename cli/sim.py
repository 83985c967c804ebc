"""`rig sim`: render a recording of a simulated rig with exact ground truth.

``rig sim --preset paper-sim --scene plane --distances 3,5,10 --out DIR`` writes the usual
recording layout (see docs/cameras.md) plus ``calibration.yaml`` and ``ground_truth/`` (see
``rig.sim.simulate``).
``rig sim --rig ring4 --out DIR`` renders a ring of N cameras instead (the room; see
``rig.sim.ring_recording``): an N-camera recording with the exact range of every stereo pair and
of the 360° panorama.
``--scene plane`` renders the fronto-parallel target at each distance (in baselines),
``--frames-per-distance`` pairs each; ``--scene room`` renders ``--frames`` pairs along a path
through the demo room (``--distances`` does not apply there). Numbers are parsed here, so a bad
value is one line on stderr and exit status 2.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.progress import TimeRemainingColumn

from cli.console import console, progress_bar
from cli.errors import fail
from cli.pair_options import (
    FieldOption,
    PinholeSizeOption,
    ProjectionOption,
    PxPerDegOption,
    make_pair_config,
)
from cli.pipeline_options import load_stereo_params
from rig.sim.lens_effects import LENS_CHOICES
from rig.sim.presets import PRESETS, RING_PRESETS, Preset, get_preset, get_ring_preset
from rig.sim.simulate import DEFAULT_DISTANCES, DEFAULT_ROOM_FRAMES, SCENES, simulate_recording
from rig.sim.textures import TEXTURES, texture_name
from rig.stereo import StereoParams

if TYPE_CHECKING:
    from rig.rectified import RectifiedPairConfig

__all__ = ["PresetOption", "parse_distances", "register"]

PresetOption = Annotated[str, typer.Option(metavar="PRESET", help=f"Simulated rig: {', '.join(PRESETS)}.")]


def _int(option: str, text: str, lo: int, hi: int) -> int:
    try:
        value = int(text.strip())
    except ValueError:
        fail(f"{option} must be an integer, got {text!r}")
    if not lo <= value <= hi:
        fail(f"{option} must be in [{lo}, {hi}], got {value}")
    return value


def _float(option: str, text: str, lo: float, hi: float) -> float:
    try:
        value = float(text.strip())
    except ValueError:
        fail(f"{option} must be a number, got {text!r}")
    if not (math.isfinite(value) and lo <= value <= hi):
        fail(f"{option} must be in [{lo:g}, {hi:g}], got {text}")
    return value


def parse_distances(text: str) -> list[float]:
    """``"3,5,10"`` -> [3.0, 5.0, 10.0] (baselines); one-line failure on anything else."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        fail(f"--distances must be comma-separated numbers of baselines like 3,5,10, got {text!r}")
    if not values or not all(math.isfinite(v) and 0 < v <= 1000 for v in values):
        fail(f"--distances must be positive numbers of baselines (at most 1000), got {text!r}")
    return values


def register(app: typer.Typer) -> None:
    @app.command("sim")
    def sim(
        out: Annotated[
            Path, typer.Option("--out", "-o", metavar="DIR", help="New (or empty) recording directory.")
        ],
        preset: PresetOption = "paper-sim",
        ring: Annotated[
            str | None,
            typer.Option(
                "--rig",
                metavar="RING",
                help=f"Render a ring of N cameras instead of --preset's pair: {', '.join(RING_PRESETS)}.",
            ),
        ] = None,
        scene: Annotated[
            str | None,
            typer.Option(
                metavar="SCENE",
                help="plane (the paper's target) or room (demo).",
                show_default="plane; room with --rig",
            ),
        ] = None,
        distances: Annotated[
            str | None,
            typer.Option(
                metavar="LIST",
                help="plane: target distances in baselines, comma-separated.",
                show_default=",".join(f"{d:g}" for d in DEFAULT_DISTANCES),
            ),
        ] = None,
        frames_per_distance: Annotated[
            str, typer.Option(metavar="N", help="plane: pairs per distance.")
        ] = "1",
        frames: Annotated[
            str | None,
            typer.Option(
                metavar="N", help="room: pairs along the path.", show_default=str(DEFAULT_ROOM_FRAMES)
            ),
        ] = None,
        texture: Annotated[
            str, typer.Option(metavar="TEXTURE", help=f"plane texture: {', '.join(TEXTURES)} or its index.")
        ] = TEXTURES[0],
        seed: Annotated[
            str, typer.Option(metavar="SEED", help="Seed of textures, room layout and noise.")
        ] = "0",
        lens: Annotated[
            str,
            typer.Option(
                metavar="LENS",
                help="honest: the preset's lens and sensor effects fitted to real fisheyes (blur "
                "growing to the rim, rim darkening, per-camera exposure, noise); ideal: none.",
            ),
        ] = "honest",
        noise: Annotated[
            str | None,
            typer.Option(
                metavar="STD",
                help="Gaussian sensor noise std in grey levels, instead of the lens's noise.",
                show_default="the lens's",
            ),
        ] = None,
        vignetting: Annotated[
            str | None,
            typer.Option(
                metavar="STRENGTH",
                help="Vignetting strength 0..1 (1 - k(1 - cos⁴(θ/2))), instead of the lens's rim darkening.",
                show_default="the lens's",
            ),
        ] = None,
        reference: Annotated[
            bool,
            typer.Option(
                "--reference/--no-reference",
                help="Also render the Reference images (ideal rectified views) into ground_truth/.",
            ),
        ] = False,
        supersample: Annotated[
            str, typer.Option(metavar="N", help="Sub-pixel rays per axis (anti-aliasing).")
        ] = "3",
        scale: Annotated[
            str,
            typer.Option(
                metavar="FACTOR", help="Scale the preset cameras' images (e.g. 0.5 for quick runs)."
            ),
        ] = "1",
        projection: ProjectionOption = None,
        vpc_size: PinholeSizeOption = None,
        vpc_hfov: Annotated[
            str | None,
            typer.Option(
                "--vpc-hfov", metavar="DEG", help="Pinhole: horizontal field of view.", show_default="90"
            ),
        ] = None,
        px_per_deg: PxPerDegOption = None,
        field: FieldOption = None,
        stereo: Annotated[
            Path | None,
            typer.Option(
                "--stereo",
                metavar="FILE",
                help="Stereo parameters rig process will use: a lat-lon field leaves room for their "
                "unmatched columns.",
                show_default="the defaults",
            ),
        ] = None,
        color: Annotated[bool, typer.Option("--color/--gray", help="Render BGR colour frames.")] = False,
        panorama_px_per_deg: Annotated[
            str | None,
            typer.Option(
                "--panorama-px-per-deg",
                metavar="PPD",
                help="--rig: the panorama's resolution (rig process's --panorama-px-per-deg).",
                show_default="4",
            ),
        ] = None,
    ) -> None:
        """Render a simulated recording with ground truth (range, depth and Reference images of the
        rectified pair)."""
        scene = _scene_of(ring, scene, panorama_px_per_deg)
        if preset not in PRESETS:
            fail(f"unknown --preset {preset!r}; valid presets: {', '.join(PRESETS)}")
        if scene not in SCENES:
            fail(f"unknown --scene {scene!r}; valid scenes: {', '.join(SCENES)}")
        if lens not in LENS_CHOICES:
            fail(f"unknown --lens {lens!r}; valid: {', '.join(LENS_CHOICES)}")
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            fail(f"{out}: already exists and is not an empty directory; choose a new --out")
        if scene == "room" and (distances is not None or frames_per_distance.strip() != "1"):
            fail("--distances and --frames-per-distance apply to --scene plane; use --frames for the room")
        if scene == "plane" and frames is not None:
            fail("--frames applies to --scene room; use --distances and --frames-per-distance for the plane")
        ks = parse_distances(distances) if distances is not None else None
        per_distance = _int("--frames-per-distance", frames_per_distance, 1, 10_000)
        n_frames = _int("--frames", frames, 1, 100_000) if frames is not None else None
        try:
            tex = texture_name(texture)
        except ValueError as err:
            fail(f"--texture: {err}")
        seed_value = _int("--seed", seed, 0, 2**63 - 1)
        noise_std = _float("--noise", noise, 0.0, 255.0) if noise is not None else None
        vig = _float("--vignetting", vignetting, 0.0, 1.0) if vignetting is not None else None
        ss = _int("--supersample", supersample, 1, 16)
        factor = _float("--scale", scale, 0.01, 8.0)
        hfov = _float("--vpc-hfov", vpc_hfov, 1.0, 179.0) if vpc_hfov is not None else None
        vpc = make_pair_config(vpc_size, hfov, projection=projection, px_per_deg=px_per_deg, field=field)
        params = load_stereo_params(stereo) if stereo is not None else StereoParams()

        if ring is not None:
            pano = _float("--panorama-px-per-deg", panorama_px_per_deg or "4", 0.25, 20.0)
            options = (n_frames, seed_value, noise_std, vig, ss, color, vpc, params.blind_band_px, pano, lens)
            _ring(get_ring_preset(ring).scaled(factor), out, *options)
            return
        chosen = get_preset(preset)
        if factor != 1.0:
            chosen = chosen.scaled(factor)
        count = (
            len(ks or DEFAULT_DISTANCES) * per_distance
            if scene == "plane"
            else (n_frames or DEFAULT_ROOM_FRAMES)
        )
        start = time.monotonic()
        with progress_bar(TimeRemainingColumn(), transient=False, on_stdout=True) as bar:
            task = bar.add_task(f"rendering {scene} ({chosen.name}, {lens} lens)", total=count)

            def step(done: float, total: int) -> None:
                bar.update(task, completed=done, total=total)

            simulate_recording(
                chosen,
                scene,
                out,
                distances=ks,
                frames_per_distance=per_distance,
                texture=tex,
                seed=seed_value,
                noise_std=noise_std,
                frames=n_frames,
                vignetting=vig,
                supersample=ss,
                color=color,
                vpc=vpc,
                blind_band_px=params.blind_band_px,
                lens=lens,
                reference=reference,
                progress=step,
            )
        elapsed = time.monotonic() - start
        cam = chosen.rig.cameras["left"]
        what = (
            f"distances {','.join(f'{k:g}' for k in (ks or DEFAULT_DISTANCES))} baselines "
            f"(baseline {chosen.rig.baseline() * 1000:.0f} mm), texture {tex}"
            if scene == "plane"
            else "room path"
        )
        console.print(
            f"[green]wrote[/green] {count} pairs of {cam.width}x{cam.height} ({chosen.name}, {what}, "
            f"{lens} lens) to {out} in {elapsed:.1f} s",
            highlight=False,
        )
        gt = json.loads((out / "ground_truth" / "scene.json").read_text())["vpc"]
        what = "range and depth" if vpc.projection == "pinhole" else "range"
        refs = ", Reference images" if reference else ""
        console.print(
            f"ground truth: {out / 'ground_truth'} (left {vpc.projection} view's {what} "
            f"{gt['width']}x{gt['height']} .npy{refs}, scene.json); "
            "calibration: calibration.yaml",
            highlight=False,
        )


def _scene_of(ring: str | None, scene: str | None, panorama_px_per_deg: str | None) -> str:
    """The scene to render (a ring's: the room; a pair's default: the plane), checking that
    ``--rig`` and ``--panorama-px-per-deg`` go together and with the room."""
    if ring is None:
        if panorama_px_per_deg is not None:
            fail("--panorama-px-per-deg applies to --rig (a ring's panorama)")
        return scene or "plane"
    if ring not in RING_PRESETS:
        fail(f"unknown --rig {ring!r}; valid rings: {', '.join(RING_PRESETS)}")
    if scene not in (None, "room"):
        fail(f"--rig renders --scene room, not {scene}")
    return "room"


def _ring(
    chosen: Preset,
    out: Path,
    frames: int | None,
    seed: int,
    noise_std: float | None,
    vignetting: float | None,
    supersample: int,
    color: bool,
    vpc: RectifiedPairConfig,
    blind_band_px: int,
    panorama_px_per_deg: float,
    lens: str,
) -> None:
    """``rig sim --rig``: the ring's recording (rig.sim.ring_recording)."""
    from rig.sim.ring_recording import simulate_ring_recording

    start = time.monotonic()
    count = frames or DEFAULT_ROOM_FRAMES
    with progress_bar(TimeRemainingColumn(), transient=False, on_stdout=True) as bar:
        task = bar.add_task(f"rendering room ({chosen.name}, {lens} lens)", total=count)
        simulate_ring_recording(
            chosen,
            out,
            frames=count,
            seed=seed,
            noise_std=noise_std,
            vignetting=vignetting,
            supersample=supersample,
            color=color,
            vpc=vpc,
            blind_band_px=blind_band_px,
            panorama_px_per_deg=panorama_px_per_deg,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
            lens=lens,
        )
    pairs = json.loads((out / "recording.json").read_text())["pairs"]
    console.print(
        f"[green]wrote[/green] {count} sets of {len(chosen.rig.names)} cameras ({chosen.name}, {lens} lens, "
        "room path) "
        f"to {out} in {time.monotonic() - start:.1f} s",
        highlight=False,
    )
    console.print(
        f"ground truth: {out / 'ground_truth'} (range of the pairs {', '.join(pairs)} and of the panorama, "
        ".npy; panorama.json); calibration: calibration.yaml",
        highlight=False,
    )
