"""Textures with a physical size: what a rectangle of the virtual scene looks like.

A texture maps surface coordinates ``(s, t)`` in metres (from the rectangle's top-left corner,
s along its x axis, t along its y axis) to grey levels (M,) or BGR (M, 3), float32 in [0, 255].
:class:`ImageTexture` samples an image bilinearly (tiling it when ``repeat``);
:class:`CheckerTexture` is analytic (exact edges, for calibration targets).
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from rig.errors import ConfigError
from rig.sim.patterns import PATTERNS

__all__ = ["TEXTURES", "CheckerTexture", "ImageTexture", "Texture", "make_texture", "texture_name"]

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: Procedural texture kinds, in the order integer texture ids refer to them.
TEXTURES: list[str] = list(PATTERNS)

# cv2.remap refuses maps with a side >= SHRT_MAX: lookups go through (rows, _REMAP_COLS) maps.
_REMAP_COLS = 4096
# BT.601 luma weights for B, G, R (cv2.cvtColor's BGR2GRAY).
_LUMA_BGR = np.array([0.114, 0.587, 0.299], dtype=np.float32)


class Texture(ABC):
    """Surface appearance: ``sample((M, 2) metres) -> (M,) grey or (M, 3) BGR`` float32."""

    channels: int = 1

    @abstractmethod
    def sample(self, st: F64) -> F32:
        """Values at surface coordinates ``st`` (M, 2) in metres."""

    def sample_as(self, st: F64, channels: int) -> F32:
        """Values with the requested channel count: (M,) for 1, (M, 3) BGR for 3."""
        values = self.sample(st)
        if channels == 1:
            return values if values.ndim == 1 else values @ _LUMA_BGR
        return values if values.ndim == 2 else np.repeat(values[:, None], 3, axis=1)


@dataclass(frozen=True, eq=False)
class ImageTexture(Texture):
    """An image (H, W) grey or (H, W, 3) BGR spanning ``size_m`` = (width, height) metres.

    ``repeat`` tiles it (the procedural patterns are periodic, so tiles join without a seam);
    otherwise the border texels extend outwards. ``offset_m`` shifts the image on the surface.
    """

    image: F32
    size_m: tuple[float, float]
    repeat: bool = True
    offset_m: tuple[float, float] = (0.0, 0.0)
    channels: int = field(init=False)

    def __post_init__(self) -> None:
        img = np.ascontiguousarray(self.image, dtype=np.float32)
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3) or min(img.shape[:2]) < 2:
            raise ConfigError(f"texture image must be (H, W) or (H, W, 3) with H, W >= 2, got {img.shape}")
        if not (self.size_m[0] > 0 and self.size_m[1] > 0):
            raise ConfigError(f"texture size_m must be positive, got {self.size_m}")
        img.setflags(write=False)
        object.__setattr__(self, "image", img)
        object.__setattr__(self, "channels", 1 if img.ndim == 2 else 3)

    def sample(self, st: F64) -> F32:
        h, w = self.image.shape[:2]
        # Texel i covers [i, i+1) * size / n; its centre is remap coordinate i.
        x = (st[:, 0] - self.offset_m[0]) * (w / self.size_m[0]) - 0.5
        y = (st[:, 1] - self.offset_m[1]) * (h / self.size_m[1]) - 0.5
        if self.repeat:
            # Wrap in float64 first: far coordinates would lose precision in remap's float32 maps.
            x, y = np.mod(x + 0.5, w) - 0.5, np.mod(y + 0.5, h) - 0.5
        m = x.shape[0]
        if m == 0:
            return np.zeros((0, *self.image.shape[2:]), dtype=np.float32)
        border = cv2.BORDER_WRAP if self.repeat else cv2.BORDER_REPLICATE
        rows = -(-m // _REMAP_COLS)
        maps = np.zeros((2, rows * _REMAP_COLS), dtype=np.float32)
        maps[0, :m], maps[1, :m] = x, y
        mx, my = maps.reshape(2, rows, _REMAP_COLS)
        out = cv2.remap(self.image, mx, my, cv2.INTER_LINEAR, borderMode=border)
        return out.reshape(rows * _REMAP_COLS, *self.image.shape[2:])[:m]

    def tinted(
        self, dark_bgr: tuple[float, float, float], light_bgr: tuple[float, float, float]
    ) -> ImageTexture:
        """A BGR copy of a grey texture mapping grey 0..255 onto the ramp dark..light."""
        if self.channels != 1:
            raise ConfigError("only a grey texture can be tinted")
        g = self.image[..., None] / 255.0
        lo, hi = np.array(dark_bgr, np.float32), np.array(light_bgr, np.float32)
        return ImageTexture((lo + g * (hi - lo)).astype(np.float32), self.size_m, self.repeat, self.offset_m)


@dataclass(frozen=True, eq=False)
class CheckerTexture(Texture):
    """Analytic chessboard: ``cols × rows`` squares of ``square_m``, black where (i + j) is odd
    (the top-left square is white), inside a white margin of ``margin_m``; (0, 0) of the surface
    is the margin's outer corner. With that parity ``cv2.findChessboardCornersSB`` numbers the
    corners of a board with one odd and one even corner count from the top-left, row-major."""

    cols: int
    rows: int
    square_m: float
    margin_m: float = 0.0
    black: float = 0.0
    white: float = 255.0

    def sample(self, st: F64) -> F32:
        i = np.floor((st[:, 0] - self.margin_m) / self.square_m)
        j = np.floor((st[:, 1] - self.margin_m) / self.square_m)
        inside = (i >= 0) & (i < self.cols) & (j >= 0) & (j < self.rows)
        black = inside & ((i + j) % 2 == 1)
        return np.where(black, self.black, self.white).astype(np.float32)


def texture_name(kind: str | int) -> str:
    """Canonical name of a texture kind given by name or index into :data:`TEXTURES`."""
    if isinstance(kind, bool):
        raise ConfigError(
            f"unknown texture {kind!r}; known: {', '.join(TEXTURES)} (or 0..{len(TEXTURES) - 1})"
        )
    if isinstance(kind, int | np.integer):
        if 0 <= int(kind) < len(TEXTURES):
            return TEXTURES[int(kind)]
    elif isinstance(kind, str):
        if kind in PATTERNS:
            return kind
        if kind.strip().isdigit():
            return texture_name(int(kind))
    raise ConfigError(f"unknown texture {kind!r}; known: {', '.join(TEXTURES)} (or 0..{len(TEXTURES) - 1})")


@functools.lru_cache(maxsize=24)
def _pattern(name: str, seed: int, size_px: int) -> F32:
    rng = np.random.default_rng([seed, TEXTURES.index(name)])
    img = PATTERNS[name](rng, size_px)
    img.setflags(write=False)
    return img


def make_texture(
    kind: str | int = 0,
    seed: int = 0,
    *,
    size_m: float | tuple[float, float] = 1.0,
    size_px: int = 1024,
    repeat: bool = True,
) -> ImageTexture:
    """A seeded procedural texture (deterministic: same kind, seed and size -> same pixels).

    ``kind`` is a name of :data:`TEXTURES` or its index; ``size_m`` the physical width (and
    height) of one tile; ``size_px`` its resolution (a power of two is fastest).
    """
    name = texture_name(kind)
    if not (16 <= int(size_px) <= 8192):
        raise ConfigError(f"texture size_px must be in [16, 8192], got {size_px}")
    sm = (
        (float(size_m), float(size_m))
        if isinstance(size_m, int | float)
        else (float(size_m[0]), float(size_m[1]))
    )
    return ImageTexture(_pattern(name, int(seed), int(size_px)), sm, repeat)
