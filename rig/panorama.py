"""One 360° range panorama from the range of every pair of a rig (docs/ring.md, "The panorama").

The panorama is an equirectangular image (:class:`calibration.models.EquirectModel`: 360° of
azimuth across, 180° of elevation down) about the rig's **origin** (the mean of the cameras'
optical centres) in the panorama frame ``R_rig_pano``: y is the rig's down (the opposite of
:func:`rig.ring.rig_up`: the normal of the plane the optical axes span), z the mean optical axis made
horizontal (the first camera's when the axes cancel, as on a ring), x = y × z. Each pixel holds
the range from the origin along its ray, metres.

**Fusion.** Each pair's range is read along every panorama ray: the point ``origin + r·ray``
that the pair ranges is found by fixed-point steps (from the ray seen from the pair's camera,
then corrected for the parallax between that camera and the origin: exact, not assumed away),
the pair's range sampled bilinearly where its neighbouring pixels agree and from the nearest
valid pixel across a depth edge (never a blend of two surfaces). Each sample carries its
predicted relative error ``σ_r / r = σ_d / d``: the matcher's disparity uncertainty ``σ_d``
(from the confidence, ``σ_d = −σ0 · ln(confidence)``, or ``default_sigma_px`` without one) over
the disparity ``d`` there, the pair's parallax. Per panorama pixel the pair
with the smallest predicted error is the **best**; the pairs whose range agrees with the best
within ``agree_sigmas`` of their combined predicted error are averaged with inverse-variance
weights (flag :data:`FUSED` when more than one). A pair that sees the pixel and disagrees beyond
that is not averaged in: the best pair's range stands and the pixel is flagged
:data:`DISAGREE` (a surface seen differently by two pairs: an occlusion edge, a mismatch, or a
calibration error: never an average of wrong values). Nothing fills holes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field

from calibration.models import EquirectModel
from calibration.rig import Rig
from rig.errors import ConfigError
from rig.rectified import RectifiedPair
from rig.resample import corners_at, padded_surface, sample_padded
from rig.ring import rig_up
from rig.settings_model import SettingsModel

__all__ = [
    "DEFAULT_PANORAMA_PX_PER_DEG",
    "DISAGREE",
    "FUSED",
    "PairOutput",
    "PanoramaConfig",
    "PanoramaFrame",
    "PanoramaSpec",
    "fuse_panorama",
    "lenses_seeing",
]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: Panorama resolution when none is asked for: coarser than the pairs' lat-lon views (5.6 px/deg),
#: so that their samples cover it without holes.
DEFAULT_PANORAMA_PX_PER_DEG = 4.0
#: The resolutions a panorama may have: a coarser one has too few pixels to show a room, a finer
#: one more than the pairs' lat-lon views can fill.
PANORAMA_PX_PER_DEG_RANGE = (0.25, 20.0)
#: Flag: the range is the inverse-variance mean of two or more pairs that agree.
FUSED = 1
#: Flag: a pair that sees this direction disagrees with the best one beyond their predicted error.
DISAGREE = 2


class PanoramaConfig(SettingsModel):
    """The panorama of a rig of more than two cameras (the service's ``panorama:`` section)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    px_per_deg: float = Field(
        DEFAULT_PANORAMA_PX_PER_DEG,
        ge=PANORAMA_PX_PER_DEG_RANGE[0],
        le=PANORAMA_PX_PER_DEG_RANGE[1],
        description="pixels per degree of azimuth and elevation (4: 1440x720; the fusion's cost goes "
        "with its square)",
    )


@dataclass(frozen=True)
class PanoramaSpec:
    """Where the panorama is: its projection (``camera``), its frame in the rig (``R_rig_pano``,
    columns x, y, z) and its centre ``origin`` (rig frame, m)."""

    camera: EquirectModel
    R_rig_pano: F64
    origin: F64
    # Each pair's far-field pixels of the panorama's rays, by the pair design's id (_far_field).
    _far_fields: dict[int, tuple[RectifiedPair, NDArray[np.intp], F64]] = field(
        default_factory=dict, compare=False, repr=False
    )

    @classmethod
    def for_rig(cls, rig: Rig, px_per_deg: float = DEFAULT_PANORAMA_PX_PER_DEG) -> PanoramaSpec:
        """The panorama of ``rig`` (see the module doc for its frame and origin)."""
        low, high = PANORAMA_PX_PER_DEG_RANGE
        if not (math.isfinite(px_per_deg) and low <= px_per_deg <= high):
            raise ConfigError(f"panorama: px_per_deg must be in [{low:g}, {high:g}], got {px_per_deg!r}")
        axes = np.array([rig.axis(n) for n in rig.names])
        down = -rig_up(rig)
        forward = axes.mean(axis=0)
        forward -= np.dot(forward, down) * down
        if np.linalg.norm(forward) < 0.1:  # a ring: the axes cancel out
            forward = axes[0] - np.dot(axes[0], down) * down
        forward /= np.linalg.norm(forward)
        R = np.column_stack([np.cross(down, forward), down, forward])
        origin = np.mean([rig.center(n) for n in rig.names], axis=0)
        return cls(EquirectModel.whole_sphere(px_per_deg), R, origin)

    @functools.cached_property
    def rays_rig(self) -> F64:
        """The unit ray of every panorama pixel (H·W, 3), row-major, in the rig frame (made once)."""
        cam = self.camera
        v, u = np.mgrid[0 : cam.height, 0 : cam.width]
        rays, _ = cam.unproject(np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64), in_image=False)
        out: F64 = rays @ self.R_rig_pano.T
        out.setflags(write=False)
        return out

    @property
    def px_per_deg(self) -> float:
        return math.radians(self.camera.fx)

    @property
    def T_rig_pano(self) -> F64:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R_rig_pano, self.origin
        return T

    def as_json(self, pairs: Sequence[str] = ()) -> dict[str, Any]:
        """``panorama.json`` (docs/ring.md)."""
        c = self.camera
        return {
            "projection": "equirect",
            "width": c.width,
            "height": c.height,
            "px_per_deg": self.px_per_deg,
            "fx": c.fx,
            "fy": c.fy,
            "cx": c.cx,
            "cy": c.cy,
            "R_rig_pano": self.R_rig_pano.tolist(),
            "origin_m": self.origin.tolist(),
            "units": "range in metres along each pixel's ray from the origin; PNG: uint16 mm, 0 = none",
            "flags": {str(FUSED): "fused from several pairs that agree", str(DISAGREE): "pairs disagree"},
            "pairs": list(pairs),
        }


@dataclass(frozen=True)
class PairOutput:
    """One pair's output as the fusion takes it: its name (``"A-B"``), its rectified pair, and
    its range, disparity (px) and confidence (or None) on the left view (H, W), NaN invalid."""

    name: str
    pair: RectifiedPair
    range: F32
    disparity: F32
    confidence: F32 | None = None
    confidence_sigma_px: float = 0.1


@dataclass(frozen=True)
class PanoramaFrame:
    """A fused panorama (H, W): ``range`` float32 m from the origin (NaN: none), ``sigma``
    float32 m its predicted standard deviation, ``source`` int8 the index of the best pair (−1:
    none), ``flags`` uint8 (:data:`FUSED`, :data:`DISAGREE`), ``samples`` uint8 how many pairs
    range the pixel."""

    range: F32
    sigma: F32
    source: NDArray[np.int8]
    flags: NDArray[np.uint8]
    samples: NDArray[np.uint8]


def _far_field(spec: PanoramaSpec, pair: RectifiedPair) -> tuple[NDArray[np.intp], F64]:
    """The panorama rays that land in ``pair``'s left view when seen from its camera as if
    infinitely far (indices (M,) into :attr:`PanoramaSpec.rays_rig`), and those pixels (M, 2):
    where every ray's fixed-point steps start. Made once per pair design (kept with the spec)."""
    cache = spec._far_fields
    hit = cache.get(id(pair))
    if hit is not None and hit[0] is pair:
        return hit[1], hit[2]
    R = pair.T_rig_rect[pair.left][:3, :3]
    q, ok = pair.camera.project(spec.rays_rig @ R, in_image=False)
    c = pair.camera
    inside = ok & (q[:, 0] > -1.0) & (q[:, 0] < c.width) & (q[:, 1] > -1.0) & (q[:, 1] < c.height)
    index = np.flatnonzero(inside)
    pixels = q[index]
    if len(cache) >= 16:  # designs replaced by a correction: keep the newest
        cache.clear()
    cache[id(pair)] = (pair, index, pixels)
    return index, pixels


def _pull(
    spec: PanoramaSpec, p: PairOutput, default_sigma_px: float, iterations: int
) -> tuple[NDArray[np.intp], F64, F64]:
    """Pair ``p``'s range along every panorama ray (:attr:`PanoramaSpec.rays_rig`, from the
    origin) and its relative predicted error: the point ``origin + r·ray`` that the pair ranges,
    found by a few fixed-point steps from the direction seen from the pair's camera (exact where
    they converge; NaN where they do not, or the pair has no range there). A ray whose first
    step finds no range keeps none (the next step would start from the same pixel), so the
    later steps run on the rays the first one ranged. Returns the indices of those rays into
    :attr:`PanoramaSpec.rays_rig`, and their range and relative error."""
    pair = p.pair
    T = pair.T_rig_rect[pair.left]
    centre, R = T[:3, 3], T[:3, :3]
    rng = p.range.astype(np.float64)
    shape = (rng.shape[0], rng.shape[1])
    offset = spec.origin - centre
    index, far = _far_field(spec, pair)
    keep = _near_valid(np.isfinite(rng), far)
    index, rays, far = index[keep], spec.rays_rig[index[keep]], far[keep]
    r = np.full(index.shape[0], np.inf)
    surface = padded_surface(rng)  # once: every step reads the same map
    for step in range(iterations):
        q, ok = far, np.ones(far.shape[0], bool)  # the first step: the rays seen from infinity
        if step:
            seen_from_pair = np.where(np.isfinite(r)[:, None], offset + r[:, None] * rays, rays)
            q, ok = pair.camera.project(seen_from_pair @ R, in_image=False)
        corners = corners_at(shape, q)
        r_pair = np.where(ok, sample_padded(surface, corners), np.nan)
        pix_rays, _ = pair.camera.unproject(q, in_image=False)
        point = (pix_rays @ R.T) * r_pair[:, None] - offset  # from the origin
        r_before, r = r, np.einsum("nk,nk->n", point, rays)
        with np.errstate(invalid="ignore"):
            moved = np.abs(r - r_before) > 1e-7 * np.abs(r)
        if not moved.any():
            break  # every ray converged (or has no range)
    # Converged: the pair's point lies on the panorama ray (within a thousandth of its range).
    miss = np.linalg.norm(point - r[:, None] * rays, axis=1)
    r = np.where(np.isfinite(r) & (miss <= 1e-3 * np.abs(r)) & (r > 0), r, np.nan)
    # The disparity and the confidence at the last step's pixels: its corners.
    disparity = sample_padded(padded_surface(p.disparity.astype(np.float64)), corners)
    if p.confidence is not None:
        conf = np.clip(sample_padded(padded_surface(p.confidence.astype(np.float64)), corners), 1e-12, 1.0)
        sigma_px = np.maximum(-p.confidence_sigma_px * np.log(conf), 0.05)
    else:
        sigma_px = np.full(r.shape, default_sigma_px)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(disparity > 0, sigma_px / disparity, np.nan)
    r[~np.isfinite(rel)] = np.nan
    return index, r, rel


def _near_valid(valid: NDArray[np.bool_], q: F64) -> NDArray[np.bool_]:
    """Where :func:`rig.resample.sample_surface` of a map whose finite pixels are ``valid``
    gives a value at pixels ``q`` (N, 2, finite): some pixel of the 2×2 around each is valid."""
    h, w = valid.shape
    padded = np.zeros((h + 2, w + 2), bool)  # a row and column either side: q may lie in (-1, 0)
    padded[1:-1, 1:-1] = valid
    any4 = padded[:-1, :-1] | padded[:-1, 1:] | padded[1:, :-1] | padded[1:, 1:]  # (h+1, w+1)
    u = np.floor(q[:, 0]).astype(np.intp) + 1
    v = np.floor(q[:, 1]).astype(np.intp) + 1
    inside = (u >= 0) & (u <= w) & (v >= 0) & (v <= h)
    out = np.zeros(q.shape[0], bool)
    out[inside] = any4[v[inside], u[inside]]
    return out


def fuse_panorama(
    spec: PanoramaSpec,
    pairs: Sequence[PairOutput],
    *,
    agree_sigmas: float = 3.0,
    default_sigma_px: float = 0.25,
    iterations: int = 3,
) -> PanoramaFrame:
    """The panorama of ``pairs``' ranges (see the module doc)."""
    if not pairs:
        raise ConfigError("panorama: no pair to fuse")
    cam = spec.camera
    pulled = [_pull(spec, p, default_sigma_px, iterations) for p in pairs]
    # The fusion runs on the pixels some pair ranges (K of them); the others stay empty.
    size = cam.height * cam.width
    ranged = np.zeros(size, bool)
    for index, r_pair, _ in pulled:
        ranged[index[np.isfinite(r_pair)]] = True
    pixels = np.flatnonzero(ranged)
    position = np.full(size, -1, np.intp)
    position[pixels] = np.arange(pixels.size)
    shape = (len(pairs), pixels.size)
    r, rel = np.full(shape, np.nan), np.full(shape, np.nan)
    for k, (index, r_pair, rel_pair) in enumerate(pulled):
        hit = np.isfinite(r_pair)
        r[k, position[index[hit]]], rel[k, position[index[hit]]] = r_pair[hit], rel_pair[hit]
    have = np.isfinite(r)
    sigma = np.where(have, rel * r, np.inf)
    best = np.argmin(sigma, axis=0)
    r_best = np.take_along_axis(r, best[None], axis=0)[0]
    s_best = np.take_along_axis(sigma, best[None], axis=0)[0]
    with np.errstate(invalid="ignore"):
        agree = have & (np.abs(r - r_best) <= agree_sigmas * np.sqrt(sigma**2 + s_best**2))
    weights = np.where(agree, 1.0 / np.maximum(sigma, 1e-9) ** 2, 0.0)
    total = weights.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = np.where(total > 0, np.sum(np.where(agree, r, 0.0) * weights, axis=0) / total, np.nan)
        fused_sigma = np.where(total > 0, 1.0 / np.sqrt(total), np.nan)
    flags = np.zeros(pixels.size, np.uint8)
    flags[agree.sum(axis=0) > 1] |= FUSED
    flags[(have & ~agree).any(axis=0)] |= DISAGREE

    def full(values: NDArray[Any], empty: float, dtype: type[np.generic]) -> NDArray[Any]:
        out = np.full(size, empty, dtype)
        out[pixels] = values
        return out.reshape(cam.height, cam.width)

    return PanoramaFrame(
        range=full(fused, np.nan, np.float32),
        sigma=full(fused_sigma, np.nan, np.float32),
        source=full(best, -1, np.int8),
        flags=full(flags, 0, np.uint8),
        samples=full(have.sum(axis=0), 0, np.uint8),
    )


def lenses_seeing(rig: Rig, spec: PanoramaSpec) -> NDArray[np.uint8]:
    """How many of ``rig``'s lenses see each panorama direction (H, W), the direction taken from
    each camera's own centre (far surfaces: parallax left out)."""
    cam = spec.camera
    in_rig = spec.rays_rig
    count = np.zeros(in_rig.shape[0], np.uint8)
    for name in rig.names:
        in_cam = in_rig @ rig.T_rig_cam[name][:3, :3]
        count += rig.cameras[name].project(in_cam)[1].astype(np.uint8)
    return count.reshape(cam.height, cam.width)
