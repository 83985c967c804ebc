"""Rendered recordings with ground truth (``rig sim``): the recording layout (docs/design.md) plus
``calibration.yaml`` and ``ground_truth/``.

Layout written under ``out``::

    recording.json, frames.csv, left/NNNNNN.png, right/NNNNNN.png   (rig.recording)
    calibration.yaml                         the preset's rig (rig.yaml, version 1)
    ground_truth/scene.json                  what each seq shows (below)
    ground_truth/range/NNNNNN.npy            float32 (H, W) distance along each LEFT rectified
                                             pixel's ray (either projection), m, NaN = none
    ground_truth/depth/NNNNNN.npy            float32 (H, W) z in the LEFT VPC frame, m, NaN = none
                                             (the pinhole pair only)
    ground_truth/reference/left/NNNNNN.png   with ``reference``: the Reference, the ideal
                                             rectified view (pinhole or lat-lon) at the left
                                             VPC pose
    ground_truth/reference/right/NNNNNN.png  ... and at the right VPC pose

The rectified views are those of ``vpc`` (default RectifiedPairConfig()); a lat-lon field's default adds
``blind_band_px`` columns (default: the default stereo settings') as the pipeline does, so the
ground truth is per pixel of what ``rig process`` writes with the same settings.

Scenes: ``plane`` puts the paper's fronto-parallel target at each distance (in baselines) for
``frames_per_distance`` frames; ``room`` moves the rig along a short path through the demo room
for ``frames`` frames. The fisheye views go through the preset's lens effects (``lens="honest"``,
:mod:`rig.sim.lens_effects`) or none (``"ideal"``). A pair is indexed in frames.csv only after
its ground truth is on disk, so every indexed pair has ground truth even if the run is killed.
"""

from __future__ import annotations

import errno
import io
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.atomic import write_atomic
from calibration.formats import save_rig
from calibration.geometry import make_transform, rot_y
from rig.errors import ConfigError, DiskFullError, RecordingError, SimulationError
from rig.recording import RecordingWriter
from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.sim.lens_effects import LensEffects, lens_for
from rig.sim.pair_render import PairRenderer, RenderedPair
from rig.sim.presets import Preset, get_preset
from rig.sim.scene import Scene, plane_scene, room_scene
from rig.sim.textures import texture_name
from rig.stereo import StereoParams

__all__ = [
    "GROUND_TRUTH_VERSION",
    "SCENES",
    "ProgressCallback",
    "check_effects",
    "room_path",
    "simulate_recording",
]

SCENES = ("plane", "room")
GROUND_TRUTH_VERSION = 2
DEFAULT_DISTANCES = (3.0, 5.0, 10.0)
DEFAULT_ROOM_FRAMES = 5

#: ``progress(done, total)`` as the work advances: ``done`` counts pairs (fractional while one
#: renders; the whole number after each pair is written), ``total`` the pairs to render.
ProgressCallback = Callable[[float, int], None]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class _Shot:
    """One pair to render: the scene, the rig's pose in it and its ground-truth description."""

    scene: Scene
    T_world_rig: F64
    info: dict[str, Any]


def room_path(index: int, count: int) -> F64:
    """Rig pose (4, 4) for frame ``index`` of ``count`` in the room: 1.5 m forward from
    z = -0.5, swaying ±0.3 m sideways and ±12° in yaw (stays clear of the boxes)."""
    a = index / max(1, count - 1)
    phase = 2.0 * math.pi * a
    return make_transform(
        rot_y(math.radians(12.0) * math.sin(phase)), [0.3 * math.sin(phase), 0.0, -0.5 + 1.5 * a]
    )


def _shots(
    preset: Preset,
    scene: str,
    distances: Sequence[float] | None,
    frames_per_distance: int,
    frames: int | None,
    texture: str | int,
    seed: int,
) -> list[_Shot]:
    baseline = preset.rig.baseline()
    if scene == "plane":
        if frames is not None:
            raise ConfigError(
                "frames applies to the room scene; the plane scene uses distances x frames_per_distance"
            )
        ks = [float(k) for k in (DEFAULT_DISTANCES if distances is None else distances)]
        if not ks or not all(math.isfinite(k) and k > 0 for k in ks):
            raise ConfigError(f"distances must be positive numbers of baselines, got {list(distances or [])}")
        name = texture_name(texture)
        out = []
        for k in ks:
            sc = plane_scene(k * baseline, name, seed)
            info = {**sc.info, "distance_baselines": k}
            out += [_Shot(sc, np.eye(4), info) for _ in range(frames_per_distance)]
        return out
    if scene == "room":
        if distances is not None or frames_per_distance != 1:
            raise ConfigError(
                "distances and frames_per_distance apply to the plane scene; the room scene takes frames"
            )
        n = DEFAULT_ROOM_FRAMES if frames is None else int(frames)
        if n < 1:
            raise ConfigError(f"frames must be >= 1, got {frames}")
        sc = room_scene(seed)
        return [_Shot(sc, room_path(i, n), {**sc.info, "path_index": i}) for i in range(n)]
    raise ConfigError(f"unknown scene {scene!r}; valid scenes: {', '.join(SCENES)}")


def _write_atomic(path: Path, data: bytes) -> None:
    write_atomic(path, data, fsync=False)


def _write_error(root: Path, err: OSError) -> RecordingError:
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return DiskFullError(f"{root}: disk full; every pair indexed so far has its ground truth")
    return RecordingError(f"{root}: cannot write the recording ({err.strerror or err})")


def _png(img: NDArray[Any]) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise SimulationError("could not encode a rendered image as PNG")
    return bytes(buf.tobytes())


def _npy(array: NDArray[Any]) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _ground_truth_doc(
    p: Preset, scene: str, pair: RectifiedPair, vpc: RectifiedPairConfig, band: int
) -> dict[str, Any]:
    """scene.json without its frames: the rig, the rectified pair and what each file holds."""
    view = (
        {"hfov_deg": vpc.hfov_deg}
        if pair.projection == "pinhole"
        else {"px_per_deg": vpc.resolution_px_per_deg}
    )
    doc: dict[str, Any] = {
        "version": GROUND_TRUTH_VERSION,
        "preset": p.name,
        "scene": scene,
        "baseline_m": p.rig.baseline(),
        "vpc": {**pair.as_json(), **view, "blind_band_px": band},
        "T_rig_vpc": {n: T.tolist() for n, T in pair.T_rig_rect.items()},
        "range": {
            "frame": "left rectified view",
            "quantity": "distance along the pixel's ray",
            "units": "m",
            "dtype": "float32",
            "invalid": "NaN",
        },
    }
    if pair.projection == "pinhole":
        doc["depth"] = {
            "frame": "left VPC",
            "quantity": "z",
            "units": "m",
            "dtype": "float32",
            "invalid": "NaN",
        }
    doc["frames"] = []
    return doc


def check_effects(noise: float, vignetting: float, supersample: int) -> None:
    """ConfigError for a sensor noise, vignetting or supersampling a render cannot take."""
    if not (math.isfinite(noise) and noise >= 0):
        raise ConfigError(f"noise must be >= 0 grey levels, got {noise!r}")
    if not (math.isfinite(vignetting) and 0 <= vignetting <= 1):
        raise ConfigError(f"vignetting must be in [0, 1], got {vignetting!r}")
    if isinstance(supersample, bool) or int(supersample) != supersample or not 1 <= supersample <= 16:
        raise ConfigError(f"supersample must be an integer in [1, 16], got {supersample!r}")


def _frame_seed(seed: int, seq: int, camera: int) -> int:
    return int(np.random.SeedSequence([seed, seq, camera]).generate_state(1)[0])


def _sensor(
    p: Preset, lens: str | LensEffects, noise_std: float | None, vignetting: float | None
) -> tuple[LensEffects, float, float]:
    """The fisheyes' lens effects and the simple sensor model's noise and vignetting: an explicit
    ``noise_std`` replaces the lens's noise, an explicit ``vignetting`` its rim darkening."""
    effects = lens_for(lens, p.lens) if isinstance(lens, str) else lens
    noise = 0.0 if noise_std is None else float(noise_std)
    vig = 0.0 if vignetting is None else float(vignetting)
    if noise_std is not None:
        effects = effects.noiseless()
    if vignetting is not None:
        effects = replace(effects, illumination=())
    return effects, noise, vig


def simulate_recording(
    preset: Preset | str,
    scene: str,
    out: str | Path,
    distances: Sequence[float] | None = None,
    frames_per_distance: int = 1,
    texture: str | int = 0,
    seed: int = 0,
    noise_std: float | None = None,
    *,
    frames: int | None = None,
    vignetting: float | None = None,
    supersample: int = 3,
    color: bool = False,
    vpc: RectifiedPairConfig | None = None,
    blind_band_px: int | None = None,
    lens: str | LensEffects = "honest",
    reference: bool = False,
    progress: ProgressCallback | None = None,
) -> Path:
    """Render a recording of ``scene`` ("plane" | "room") seen by ``preset``'s rig into ``out``.

    plane: ``distances`` in baselines (default 3, 5, 10), ``frames_per_distance`` pairs each;
    room: ``frames`` pairs along :func:`room_path` (default 5). ``lens``: "honest" (the preset's
    :class:`LensEffects`), "ideal" (none) or explicit effects; ``noise_std`` (gaussian, grey
    levels) replaces the lens's sensor noise and ``vignetting`` (:func:`vignetting_factor`'s
    strength) its rim darkening when given. Ground truth is for the rectified pair of ``vpc``
    (default RectifiedPairConfig()) and, for a lat-lon field, ``blind_band_px`` (see the module doc);
    ``reference`` adds the Reference pair's images. ``out`` must not exist or be an empty
    directory. Returns ``out``.
    """
    p = get_preset(preset) if isinstance(preset, str) else preset
    if isinstance(frames_per_distance, bool) or int(frames_per_distance) < 1:
        raise ConfigError(f"frames_per_distance must be >= 1, got {frames_per_distance!r}")
    shots = _shots(p, scene, distances, int(frames_per_distance), frames, texture, int(seed))
    effects, noise, vig = _sensor(p, lens, noise_std, vignetting)
    check_effects(noise, vig, supersample)
    band = StereoParams().blind_band_px if blind_band_px is None else int(blind_band_px)
    pair = design_rectified_pair(p.rig, vpc, blind_band_px=band)
    root = Path(out)
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise RecordingError(f"{root}: already exists and is not an empty directory; choose a new --out")
    gt = root / "ground_truth"
    pinhole = pair.projection == "pinhole"
    subdirs = (
        "range",
        *(("reference/left", "reference/right") if reference else ()),
        *(("depth",) if pinhole else ()),
    )
    try:
        for sub in subdirs:
            (gt / sub).mkdir(parents=True, exist_ok=True)
        save_rig(p.rig, root / "calibration.yaml")
    except OSError as err:
        raise _write_error(root, err) from err
    period_ns = round(1e9 / p.fps)
    meta = {
        "generator": "rig sim",
        "preset": p.name,
        "scene": scene,
        "fps": p.fps,
        "distances": list(dict.fromkeys(s.info["distance_baselines"] for s in shots))
        if scene == "plane"
        else None,
        "frames": len(shots),
        "texture": shots[0].info.get("texture"),
        "seed": int(seed),
        "lens": effects.name,
        "lens_effects": asdict(effects),
        "noise_std": noise,
        "vignetting": vig,
        "supersample": int(supersample),
        "color": bool(color),
    }
    doc = _ground_truth_doc(p, scene, pair, vpc or RectifiedPairConfig(), band)
    renderer = PairRenderer(
        p.rig, pair, supersample=int(supersample), color=color, lens=effects, noise_std=noise,
        vignetting=vig, reference=reference, frames=len(shots),
    )  # fmt: skip
    with RecordingWriter(root, meta=meta) as writer:
        for seq, shot in enumerate(shots):
            seeds = (_frame_seed(int(seed), seq, 0), _frame_seed(int(seed), seq, 1))
            step = None if progress is None else _pair_progress(progress, seq, len(shots))
            rendered = renderer.render(shot.scene, shot.T_world_rig, seeds, step)
            entry = {"seq": seq, **shot.info, "T_world_rig": shot.T_world_rig.tolist()}
            _write_truth(root, doc, entry, rendered, (pair.left, pair.right), pinhole)
            ts = seq * period_ns
            writer.write_images(seq, ts, ts, rendered.views[0].image, rendered.views[1].image)
            if progress is not None:
                progress(seq + 1, len(shots))
    return root


def _pair_progress(progress: ProgressCallback, seq: int, total: int) -> Callable[[float], None]:
    def step(fraction: float) -> None:
        progress(seq + min(fraction, 0.999), total)

    return step


def _write_truth(
    root: Path,
    doc: dict[str, Any],
    entry: dict[str, Any],
    rendered: RenderedPair,
    cams: tuple[str, str],
    pinhole: bool,
) -> None:
    """Write one pair's ground truth and scene.json with its ``entry`` added (atomically)."""
    seq = entry["seq"]
    rel = {"range": f"ground_truth/range/{seq:06d}.npy"}
    rel |= {"depth": f"ground_truth/depth/{seq:06d}.npy"} if pinhole else {}
    refs = rendered.references
    if refs is not None:
        rel |= {n: f"ground_truth/reference/{n}/{seq:06d}.png" for n in cams}
    try:
        _write_atomic(root / rel["range"], _npy(rendered.truth.distance))
        if pinhole:
            _write_atomic(root / rel["depth"], _npy(rendered.truth.depth))
        if refs is not None:
            for n, ref in zip(cams, refs, strict=True):
                _write_atomic(root / rel[n], _png(ref.image))
        entry |= {k: rel[k] for k in ("range", "depth") if k in rel}
        if refs is not None:
            entry["reference"] = {n: rel[n] for n in cams}
        doc["frames"].append(entry)
        _write_atomic(root / "ground_truth" / "scene.json", json.dumps(doc, indent=2).encode() + b"\n")
    except OSError as err:
        raise _write_error(root, err) from err
