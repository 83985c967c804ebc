"""What one ``rig evaluate`` run does: preset, models, distances, textures and the sizes that
``--quick`` reduces. Every number the report states comes from here.

Full run: the preset's own image size, 24 calibration views, the product's default VPC
(640×480, 90°), planes at k = 2, 3, …, 20 baselines with 3 textures; supersampling 3×3 for the
boards and the room, 2×2 for the four renders of each of the 57 planes (they are most of the
run's time; 3×3 took 1.5× as long); the extrinsics chain from up to 12 wedge boards and 3 room
pairs.
Quick run (tests, smoke checks): the preset scaled to half size, 10 views and one round of corner
refinement, a 320×240 VPC, planes at k = 3, 8, 16 with 2 textures, supersampling 2×2 throughout;
the extrinsics chain from up to 8 wedge boards and 2 room pairs.

The fisheye renders (boards, planes, room) go through the ``lens`` effects: ``honest`` (the
preset's lens fitted to real fisheyes, :mod:`rig.sim.lens_effects`) or ``ideal`` (none). The
default is ``ideal`` for ``paper-sim``, the paper's virtual rig (its Unity lenses are ideal:
that is what reproduces the paper), ``honest`` for every other preset.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from calibration.models import MODELS
from rig.errors import ConfigError
from rig.rectified import RectifiedPairConfig
from rig.sim.lens_effects import LensEffects, check_lens
from rig.sim.presets import PRESETS, Preset
from rig.sim.textures import TEXTURES
from rig.stereo import StereoParams

__all__ = [
    "DEFAULT_MODELS",
    "FULL_DISTANCES",
    "QUICK_DISTANCES",
    "EvalConfig",
    "default_lens",
    "make_config",
    "stereo_for",
]

#: The six calibrated models (the paper's three, its "atan", and two modern ones).
DEFAULT_MODELS: tuple[str, ...] = (
    "kannala_brandt",
    "mei",
    "scaramuzza",
    "equidistant",
    "double_sphere",
    "eucm",
)
FULL_DISTANCES: tuple[float, ...] = tuple(float(k) for k in range(2, 21))
QUICK_DISTANCES: tuple[float, ...] = (3.0, 8.0, 16.0)

# Matcher search: the nearest plane's disparity (fx / k) plus this margin must fit in the range.
_DISPARITY_MARGIN = 1.1
# Fewest VPC columns left for matching after the disparity range.
_MIN_MATCH_COLUMNS = 64


@dataclass(frozen=True)
class EvalConfig:
    """One evaluation run (see the module doc for the full/quick values)."""

    preset: str
    models: tuple[str, ...]
    distances: tuple[float, ...]  # plane distances in baselines
    textures: tuple[str, ...]  # texture names of rig.sim.TEXTURES
    quick: bool
    seed: int
    scale: float  # preset image scale (1 = the preset's size)
    vpc: RectifiedPairConfig
    supersample: int  # calibration boards and the room (sharp edges)
    plane_supersample: int  # the depth planes (most of the run's time)
    calibration_views: int
    refine_corners: bool = True  # fisheye-aware corner refinement in the calibration
    refine_rounds: int = 3  # at most this many refine → recalibrate rounds
    samples: int = 1000  # random points per plane (the paper's normalised sample size)
    vicinity_frac: float = 0.1  # plane vicinity: |distance to plane| <= this x plane distance
    square_m: float = 0.05  # chessboard square
    board: tuple[int, int] = (9, 6)  # chessboard inner corners (cols, rows)
    stereo: StereoParams = field(default_factory=StereoParams)
    extrinsics_model: str = "kannala_brandt"  # lenses of the extrinsics chain (rig.evaluate.extrinsics)
    stereo_views: int = 12  # wedge boards for the pair's calibration (at most; those both lenses see)
    refine_frames: int = 3  # room pairs the extrinsics are refined from
    lens: str = "honest"  # the fisheye renders' lens effects: honest or ideal

    def lens_effects(self, preset: Preset) -> LensEffects | None:
        """The fisheye renders' lens effects for ``preset`` (None: the ideal lens)."""
        return preset.lens if self.lens == "honest" else None

    def describe(self) -> dict[str, object]:
        """JSON-able summary for run.json and the report."""
        return {
            "preset": self.preset,
            "lens": self.lens,
            "quick": self.quick,
            "seed": self.seed,
            "models": list(self.models),
            "distances_baselines": list(self.distances),
            "textures": list(self.textures),
            "image_scale": self.scale,
            "vpc": self.vpc.model_dump(),
            "supersample": self.supersample,
            "plane_supersample": self.plane_supersample,
            "calibration_views": self.calibration_views,
            "refine_corners": self.refine_corners,
            "refine_rounds": self.refine_rounds,
            "board": {"cols": self.board[0], "rows": self.board[1], "square_m": self.square_m},
            "samples_per_plane": self.samples,
            "vicinity_frac": self.vicinity_frac,
            "stereo": self.stereo.model_dump(),
            "extrinsics": {
                "model": self.extrinsics_model,
                "stereo_views": self.stereo_views,
                "refine_frames": self.refine_frames,
            },
        }


def stereo_for(vpc: RectifiedPairConfig, nearest_k: float) -> StereoParams:
    """The product's default stereo settings with a disparity range that reaches the nearest
    plane (``fx / k`` px plus 10 %); ConfigError when that leaves too few columns to match."""
    width, _, hfov_deg = vpc.pinhole_size
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    need = fx / nearest_k * _DISPARITY_MARGIN
    rng = max(16, 16 * math.ceil(need / 16.0 - 1e-9))  # fx = 320.00000000000006 is 320
    if rng > width - _MIN_MATCH_COLUMNS:
        k_min = fx * _DISPARITY_MARGIN / (width - _MIN_MATCH_COLUMNS)
        raise ConfigError(
            f"a plane at {nearest_k:g} baselines needs {rng} disparities, too many for a {width} px "
            f"wide VPC; use distances of at least {k_min:.2g} baselines"
        )
    return StereoParams(disparity_range=rng)


def _check_models(models: Sequence[str]) -> tuple[str, ...]:
    out = tuple(dict.fromkeys(m.strip() for m in models if m.strip()))
    if not out:
        raise ConfigError("models: give at least one camera model")
    unknown = [m for m in out if m not in MODELS]
    if unknown:
        raise ConfigError(f"models: unknown {', '.join(unknown)}; known: {', '.join(sorted(MODELS))}")
    return out


def _check_distances(distances: Sequence[float]) -> tuple[float, ...]:
    ks = tuple(sorted(dict.fromkeys(float(k) for k in distances)))
    if not ks:
        raise ConfigError("distances: give at least one plane distance in baselines")
    bad = [k for k in ks if not (math.isfinite(k) and 1.0 <= k <= 200.0)]
    if bad:
        raise ConfigError(f"distances must be between 1 and 200 baselines, got {', '.join(map(str, bad))}")
    return ks


def make_config(
    preset: str,
    *,
    quick: bool = False,
    models: Sequence[str] | None = None,
    distances: Sequence[float] | None = None,
    textures: int | None = None,
    seed: int = 0,
    lens: str | None = None,
) -> EvalConfig:
    """The run for ``preset`` (a name of :data:`rig.sim.PRESETS`); ``None`` picks the default
    of the full or quick run (``lens``: :func:`default_lens`). Raises ConfigError naming the bad
    value."""
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; valid presets: {', '.join(PRESETS)}")
    chosen_lens = check_lens(default_lens(preset) if lens is None else lens)
    n_tex = (2 if quick else 3) if textures is None else int(textures)
    if not 1 <= n_tex <= len(TEXTURES):
        raise ConfigError(f"textures must be between 1 and {len(TEXTURES)}, got {textures}")
    if isinstance(seed, bool) or not 0 <= int(seed) < 2**31:
        raise ConfigError(f"seed must be an integer in [0, 2^31), got {seed!r}")
    ks = _check_distances(
        distances if distances is not None else (QUICK_DISTANCES if quick else FULL_DISTANCES)
    )
    # The paper's method: the pinhole pair.
    vpc = RectifiedPairConfig(width=320, height=240) if quick else RectifiedPairConfig(projection="pinhole")
    chosen = _check_models(models if models is not None else DEFAULT_MODELS)
    return EvalConfig(
        preset=preset,
        models=chosen,
        distances=ks,
        textures=tuple(TEXTURES[:n_tex]),
        quick=quick,
        seed=int(seed),
        scale=0.5 if quick else 1.0,
        vpc=vpc,
        supersample=2 if quick else 3,
        plane_supersample=2,
        calibration_views=10 if quick else 24,
        refine_rounds=1 if quick else 3,
        stereo=stereo_for(vpc, ks[0]),
        extrinsics_model="kannala_brandt" if "kannala_brandt" in chosen else chosen[0],
        stereo_views=8 if quick else 12,
        refine_frames=2 if quick else 3,
        lens=chosen_lens,
    )


def default_lens(preset: str) -> str:
    """``ideal`` for the paper's virtual rig, ``honest`` for the others (the module doc)."""
    return "ideal" if preset == "paper-sim" else "honest"
