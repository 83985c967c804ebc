"""Rendered recordings of a ring of N cameras (``rig sim --rig ring4``): the N-camera recording
layout (docs/design.md) with ``calibration.yaml`` and the exact range of every stereo pair and of
the panorama.

Layout written under ``out``::

    recording.json, frames.csv, cam1/NNNNNN.png ... camN/NNNNNN.png      (rig.recording)
    calibration.yaml                          the ring's rig (rig.yaml, version 1)
    ground_truth/<A>-<B>/scene.json           per pair: today's ground_truth/ layout (rig.sim.simulate)
    ground_truth/<A>-<B>/range/NNNNNN.npy     float32 (H, W) distance along each of the pair's LEFT
                                              rectified pixel's rays, m, NaN = none
    ground_truth/panorama.json                the panorama (rig.panorama.PanoramaSpec.as_json), frames
    ground_truth/panorama/NNNNNN.npy          float32 (H, W) distance from the panorama's origin along
                                              each panorama pixel's ray, m, NaN = none

The pairs are the rig's (:func:`rig.ring.stereo_pairs`), each with the rectified settings ``vpc``
(``left``/``right`` set to the pair's cameras) and, for a lat-lon field, ``blind_band_px``
columns, as ``rig process`` designs them; the panorama is :class:`rig.panorama.PanoramaSpec`'s at
``panorama_px_per_deg``. Only the room scene: the rig moves along
:func:`rig.sim.simulate.room_path`. A set is indexed in frames.csv only after its ground truth is
on disk.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from calibration.formats import save_rig
from rig.errors import ConfigError, RecordingError
from rig.panorama import DEFAULT_PANORAMA_PX_PER_DEG, PanoramaSpec
from rig.recording import RecordingWriter
from rig.rectified import RectifiedPair, RectifiedPairConfig, design_rectified_pair
from rig.rig_pipeline import pair_config
from rig.ring import pair_label, stereo_pairs
from rig.sim.lens_effects import LensEffects
from rig.sim.presets import Preset
from rig.sim.render import render, render_range
from rig.sim.scene import room_scene
from rig.sim.simulate import (
    DEFAULT_ROOM_FRAMES,
    GROUND_TRUTH_VERSION,
    _frame_seed,
    _npy,
    _sensor,
    _write_atomic,
    _write_error,
    check_effects,
    room_path,
)
from rig.stereo import StereoParams

__all__ = ["simulate_ring_recording"]

_RANGE_DOC = {
    "frame": "left rectified view",
    "quantity": "distance along the pixel's ray",
    "units": "m",
    "dtype": "float32",
    "invalid": "NaN",
}


def _pair_doc(preset: Preset, pair: RectifiedPair, vpc: RectifiedPairConfig, band: int) -> dict[str, Any]:
    """A pair's scene.json without its frames (the fields of rig.sim.simulate's)."""
    view = (
        {"hfov_deg": vpc.hfov_deg}
        if pair.projection == "pinhole"
        else {"px_per_deg": vpc.resolution_px_per_deg}
    )
    return {
        "version": GROUND_TRUTH_VERSION,
        "preset": preset.name,
        "scene": "room",
        "pair": [pair.left, pair.right],
        "baseline_m": pair.baseline_m,
        "vpc": {**pair.as_json(), **view, "blind_band_px": band},
        "T_rig_vpc": {n: T.tolist() for n, T in pair.T_rig_rect.items()},
        "range": dict(_RANGE_DOC),
        "frames": [],
    }


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    _write_atomic(path, json.dumps(doc, indent=2).encode() + b"\n")


def simulate_ring_recording(
    preset: Preset,
    out: str | Path,
    *,
    frames: int | None = None,
    seed: int = 0,
    noise_std: float | None = None,
    vignetting: float | None = None,
    supersample: int = 3,
    color: bool = False,
    vpc: RectifiedPairConfig | None = None,
    blind_band_px: int | None = None,
    panorama_px_per_deg: float = DEFAULT_PANORAMA_PX_PER_DEG,
    progress: Callable[[int, int], None] | None = None,
    lens: str | LensEffects = "honest",
) -> Path:
    """Render ``frames`` sets (default 5) of the demo room seen by ``preset``'s ring into ``out``
    (see the module doc); ``out`` must not exist or be an empty directory. Returns ``out``.
    ``lens``, ``noise_std`` and ``vignetting`` as :func:`rig.sim.simulate.simulate_recording`
    takes them: each camera through the lens effects of its index in the ring (the honest lens's
    exposures repeat every two cameras)."""
    rig = preset.rig
    n = DEFAULT_ROOM_FRAMES if frames is None else int(frames)
    if n < 1:
        raise ConfigError(f"frames must be >= 1, got {frames}")
    effects, noise, vig = _sensor(preset, lens, noise_std, vignetting)
    check_effects(noise, vig, supersample)
    band = StereoParams().blind_band_px if blind_band_px is None else int(blind_band_px)
    base = vpc or RectifiedPairConfig()
    pairs = {
        pair_label(names): design_rectified_pair(rig, pair_config(base, names), blind_band_px=band)
        for names in stereo_pairs(rig)
    }
    if not pairs:
        raise ConfigError(f"rig {preset.name}: no two cameras see a common direction: no stereo pair")
    spec = PanoramaSpec.for_rig(rig, panorama_px_per_deg)
    root = Path(out)
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise RecordingError(f"{root}: already exists and is not an empty directory; choose a new --out")
    gt = root / "ground_truth"
    try:
        for label in [*pairs, "panorama"]:
            (gt / label / ("range" if label != "panorama" else "")).mkdir(parents=True, exist_ok=True)
        save_rig(rig, root / "calibration.yaml")
    except OSError as err:
        raise _write_error(root, err) from err
    docs = {label: _pair_doc(preset, pair, base, band) for label, pair in pairs.items()}
    pano_doc: dict[str, Any] = {**spec.as_json(list(pairs)), "version": GROUND_TRUTH_VERSION, "frames": []}
    scene = room_scene(int(seed))
    period_ns = round(1e9 / preset.fps)
    meta = {
        "generator": "rig sim",
        "preset": preset.name,
        "scene": "room",
        "fps": preset.fps,
        "frames": n,
        "seed": int(seed),
        "lens": effects.name,
        "lens_effects": asdict(effects),
        "noise_std": noise,
        "vignetting": vig,
        "supersample": int(supersample),
        "color": bool(color),
        "pairs": list(pairs),
    }
    with RecordingWriter(root, meta=meta, cameras=rig.names) as writer:
        for seq in range(n):
            T_world_rig = room_path(seq, n)
            images = [
                render(
                    scene,
                    rig.cameras[name],
                    T_world_rig @ rig.T_rig_cam[name],
                    supersample=supersample,
                    noise_std=noise,
                    vignetting=vig,
                    seed=_frame_seed(int(seed), seq, i),
                    color=color,
                    lens=effects,
                    camera_index=i,
                ).image
                for i, name in enumerate(rig.names)
            ]
            entry = {"seq": seq, **scene.info, "path_index": seq, "T_world_rig": T_world_rig.tolist()}
            try:
                for label, pair in pairs.items():
                    rel = f"ground_truth/{label}/range/{seq:06d}.npy"
                    truth, _ = render_range(scene, pair.camera, T_world_rig @ pair.T_rig_rect[pair.left])
                    _write_atomic(root / rel, _npy(truth))
                    docs[label]["frames"].append({**entry, "range": rel})
                    _write_atomic(
                        gt / label / "scene.json", json.dumps(docs[label], indent=2).encode() + b"\n"
                    )
                rel = f"ground_truth/panorama/{seq:06d}.npy"
                truth, _ = render_range(scene, spec.camera, T_world_rig @ spec.T_rig_pano)
                _write_atomic(root / rel, _npy(truth))
                pano_doc["frames"].append({**entry, "range": rel})
                _write_atomic(gt / "panorama.json", json.dumps(pano_doc, indent=2).encode() + b"\n")
            except OSError as err:
                raise _write_error(root, err) from err
            ts = seq * period_ns
            writer.write_set_images(seq, [ts] * len(images), images)
            if progress is not None:
                progress(seq + 1, n)
    return root
