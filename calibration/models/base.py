"""The one surface every camera model has (docs/design.md, "Camera models"), in the style of basalt-headers.

Shapes: points (N, 3) float64 in the camera frame (x right, y down, z forward); pixels (N, 2)
float64 (u, v) with (0, 0) the centre of the top-left pixel; rays (N, 3) unit vectors; masks (N,).
Entries whose mask is False are finite but meaningless: never NaN, inf or a sentinel value.

Parameters are numbers, or lists of numbers for the names a model lists in ``list_params``
(e.g. Scaramuzza's polynomials). The flat parameter vector :attr:`CameraModel.params` holds every
scalar as one entry and every list as its entries in order (:attr:`CameraModel.param_layout`
names each entry, e.g. ``"poly[2]"``); ``derived_params`` (lists the model recomputes from the
others, e.g. Scaramuzza's fitted ``invpol``) are not in the vector.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Self, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.errors import ModelError

__all__ = [
    "MAX_IMAGE_SIZE_PX",
    "MODELS",
    "CameraModel",
    "Mask",
    "create",
    "pixels_from_ratio",
    "register",
    "smallest_positive_root",
]

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]

# Relative slack on the field-angle limit so a ray unprojected exactly at the limit projects back.
_THETA_SLACK = 1e-12
# Pixels on the image border survive a round trip's round-off.
_EDGE_SLACK = 1e-9
# Largest image width or height accepted (pixels): far beyond any real sensor (~15000 px), small
# enough that image coordinates, their squares and the models' polynomials in them stay far from
# float64 overflow (a 1e200-pixel "image" would load with infinite radii).
MAX_IMAGE_SIZE_PX = 100_000


class CameraModel(ABC):
    """A calibrated central camera: ``project`` and ``unproject`` with validity masks.

    Subclasses declare ``name``, ``param_names`` (required, in file order) and
    ``optional_params`` (name -> default), and implement ``_project``/``_unproject`` for their
    own domain; this base adds the checks every model shares: finite output, the field-angle
    limit (``max_theta``, which includes an optional lens ``fov_deg``) and the image bounds.
    """

    name: ClassVar[str]
    param_names: ClassVar[tuple[str, ...]]
    optional_params: ClassVar[Mapping[str, float | tuple[float, ...]]] = {}
    # Names whose value is a list of numbers (stored as tuples, written to files as lists).
    list_params: ClassVar[tuple[str, ...]] = ()
    # List parameters the model derives from the others when absent (empty); kept out of the
    # flat vector and recomputed when other parameters change (with_params, replace).
    derived_params: ClassVar[tuple[str, ...]] = ()

    def __init__(self, width: int, height: int, fov_deg: float | None = None, **params: Any) -> None:
        self.width = self._image_extent("width", width)
        self.height = self._image_extent("height", height)
        unknown = sorted(set(params) - set(self.all_param_names()))
        if unknown:
            raise ModelError(f"{self.name}: unknown parameter(s) {', '.join(unknown)}")
        missing = [n for n in self.param_names if n not in params]
        if missing:
            raise ModelError(f"{self.name}: missing parameter(s) {', '.join(missing)}")
        values: dict[str, float] = {}
        lists: dict[str, tuple[float, ...]] = {}
        for n in self.all_param_names():
            raw = params.get(n, self.optional_params.get(n))
            if n in self.list_params:
                lists[n] = self._number_list(n, raw)
                continue
            try:
                value = float(raw)  # type: ignore[arg-type]
            except (TypeError, ValueError) as err:
                raise ModelError(
                    f"{self.name}: parameter {n} must be a number, got {raw!r}", param=n
                ) from err
            if not math.isfinite(value):
                raise ModelError(f"{self.name}: parameter {n} must be finite, got {value}", param=n)
            values[n] = value
        self._values = values
        self._lists = lists
        if fov_deg is not None:
            fov = float(fov_deg)
            if not (0.0 < fov <= 360.0):
                raise ModelError(f"{self.name}: fov_deg must be in (0, 360], got {fov_deg!r}")
            self.fov_deg: float | None = fov
        else:
            self.fov_deg = None
        self._setup()
        model_limit = float(self._model_max_theta())
        lens_limit = math.radians(self.fov_deg) / 2.0 if self.fov_deg is not None else math.pi
        self.max_theta = min(model_limit, lens_limit, math.pi)

    # ----- what subclasses provide -------------------------------------------------------------
    @abstractmethod
    def _setup(self) -> None:
        """Read ``self._values`` (and ``self._lists``) into attributes, validate them (raise
        ModelError), precompute; fill in empty ``derived_params`` entries of ``self._lists``."""

    @abstractmethod
    def _model_max_theta(self) -> float:
        """Largest angle off the optical axis (radians) where the model is valid and invertible."""

    @abstractmethod
    def _project(self, points: F64) -> tuple[F64, Mask]:
        """Project (N, 3) points; mask False outside the model's own domain."""

    # Set by models whose _project_components mask already holds the field-angle limit.
    _components_check_field: ClassVar[bool] = False

    def _project_components(self, x: F64, y: F64, z: F64) -> tuple[F64, F64, Mask]:
        """Hook of :meth:`project_xyz`: ``_project`` on coordinate arrays of any one shape.
        Models override it with the same formula written on the components (no stacking, few
        temporaries) and let ``_project`` call it. Outputs must be new arrays."""
        pix, ok = self._project(np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1))
        return pix[:, 0].reshape(x.shape), pix[:, 1].reshape(x.shape), ok.reshape(x.shape)

    @abstractmethod
    def _unproject(self, pixels: F64) -> tuple[F64, Mask]:
        """Unproject (N, 2) pixels to (N, 3) rays (any length); mask False where impossible."""

    # ----- the shared surface ------------------------------------------------------------------
    @classmethod
    def all_param_names(cls) -> tuple[str, ...]:
        """Required then optional parameter names: the order of :attr:`params`."""
        return tuple(cls.param_names) + tuple(cls.optional_params)

    @property
    def param_layout(self) -> tuple[str, ...]:
        """Name of each entry of :attr:`params` (P,): scalars by name, list entries as ``name[i]``."""
        out: list[str] = []
        for n in self.all_param_names():
            if n in self.derived_params:
                continue
            if n in self.list_params:
                out.extend(f"{n}[{i}]" for i in range(len(self._lists[n])))
            else:
                out.append(n)
        return tuple(out)

    @property
    def params(self) -> F64:
        """Flat parameter vector (P,): :meth:`all_param_names` order, lists expanded in place,
        ``derived_params`` left out (see :attr:`param_layout`)."""
        out: list[float] = []
        for n in self.all_param_names():
            if n in self.derived_params:
                continue
            if n in self.list_params:
                out.extend(self._lists[n])
            else:
                out.append(self._values[n])
        return np.array(out, dtype=np.float64)

    @property
    def param_dict(self) -> dict[str, Any]:
        """Name -> value: floats, and tuples of floats for ``list_params``."""
        return {**self._values, **self._lists}

    def with_params(self, vector: ArrayLike) -> Self:
        """Same model type, size, lens limit and list lengths with a new flat vector (P,).

        Derived parameters are recomputed, unless the vector equals :attr:`params` (then the
        copy keeps them, so ``m.with_params(m.params) == m``).
        """
        v = np.asarray(vector, dtype=np.float64).reshape(-1)
        layout = self.param_layout
        if v.shape[0] != len(layout):
            raise ModelError(f"{self.name}: expected {len(layout)} parameters, got {v.shape[0]}")
        if np.array_equal(v, self.params):
            return type(self)(self.width, self.height, self.fov_deg, **self.param_dict)
        kwargs: dict[str, float | tuple[float, ...]] = {}
        i = 0
        for n in self.all_param_names():
            if n in self.derived_params:
                continue
            if n in self.list_params:
                k = len(self._lists[n])
                kwargs[n] = tuple(float(x) for x in v[i : i + k])
                i += k
            else:
                kwargs[n] = float(v[i])
                i += 1
        return type(self)(self.width, self.height, self.fov_deg, **kwargs)

    def replace(self, **changes: Any) -> Self:
        """Copy with some of width, height, fov_deg or parameters changed (derived parameters
        not named in ``changes`` are recomputed when anything changes)."""
        width = changes.pop("width", self.width)
        height = changes.pop("height", self.height)
        fov = changes.pop("fov_deg", self.fov_deg)
        values = self.param_dict
        if changes or (width, height, fov) != (self.width, self.height, self.fov_deg):
            for n in self.derived_params:
                if n not in changes:
                    del values[n]
        return type(self)(width, height, fov, **{**values, **changes})

    def project(self, points: ArrayLike, *, in_image: bool = True) -> tuple[F64, Mask]:
        """Points (N, 3) -> pixels (N, 2), valid (N,).

        Invalid: zero-length point, beyond ``max_theta`` off axis, outside the model's domain,
        or (with ``in_image``) outside the image ``[-0.5, W-0.5] x [-0.5, H-0.5]``.
        """
        pts = _as_array(points, 3, "points")
        norm = np.linalg.norm(pts, axis=1)
        ok = norm > 0.0
        cos_theta = np.divide(pts[:, 2], norm, out=np.ones_like(norm), where=ok)
        ok &= np.arccos(np.clip(cos_theta, -1.0, 1.0)) <= self.max_theta * (1.0 + _THETA_SLACK)
        with np.errstate(all="ignore"):
            pix, valid = self._project(pts)
        valid = valid & ok & np.isfinite(pix).all(axis=1)
        if in_image:
            valid &= self.in_image(pix)
        return np.where(np.isfinite(pix), pix, 0.0), valid

    def project_xyz(self, x: ArrayLike, y: ArrayLike, z: ArrayLike) -> tuple[F64, F64, Mask]:
        """``project(stack([x, y, z]))`` for coordinate arrays of one shape (any), returned as
        (u, v, valid) of that shape: the hot path of lookup-table builds (no (N, 3) stacking,
        the field limit as ``z >= |p| cos(max_theta)`` instead of an arccos per point).

        Valid exactly where :meth:`project` says valid (in-image), up to round-off at the very
        edge of the field or image. Unlike :meth:`project`, invalid entries may hold NaN.
        """
        xa, ya, za = (np.asarray(a, dtype=np.float64) for a in (x, y, z))
        if not (xa.shape == ya.shape == za.shape):
            raise ModelError(f"x, y, z must have one shape, got {xa.shape}, {ya.shape}, {za.shape}")
        with np.errstate(all="ignore"):
            u, v, ok = self._project_components(xa, ya, za)
            if not self._components_check_field:
                ok &= self._within_field(xa, ya, za)
        lo, w, h = -0.5 - _EDGE_SLACK, self.width - 0.5 + _EDGE_SLACK, self.height - 0.5 + _EDGE_SLACK
        # Comparisons are False for NaN and fail for inf: these bounds also reject non-finite.
        ok &= u >= lo
        ok &= u <= w
        ok &= v >= lo
        ok &= v <= h
        return u, v, ok

    def _within_field(self, x: F64, y: F64, z: F64) -> Mask:
        """Non-zero points within ``max_theta`` of the axis (the checks :meth:`project` adds)."""
        n2 = x * x
        n2 += y * y
        n2 += z * z
        limit = self.max_theta * (1.0 + _THETA_SLACK)
        if limit >= math.pi:
            out: Mask = n2 > 0.0
            return out
        ok = z >= math.cos(limit) * np.sqrt(n2, out=n2)
        ok &= n2 > 0.0
        return ok

    def unproject(self, pixels: ArrayLike, *, in_image: bool = True) -> tuple[F64, Mask]:
        """Pixels (N, 2) -> unit rays (N, 3), valid (N,).

        Invalid: outside the image (with ``in_image``), outside the lens circle/model domain,
        a ray beyond ``max_theta``, or an iterative inversion that did not converge.
        """
        pix = _as_array(pixels, 2, "pixels")
        with np.errstate(all="ignore"):
            rays, valid = self._unproject(pix)
            norm = np.linalg.norm(rays, axis=1)
            rays = rays / norm[:, None]
        valid = valid & np.isfinite(rays).all(axis=1) & (norm > 0.0)
        rays = np.where(valid[:, None], rays, np.array([0.0, 0.0, 1.0]))
        theta = np.arccos(np.clip(rays[:, 2], -1.0, 1.0))
        valid &= theta <= self.max_theta * (1.0 + _THETA_SLACK)
        if in_image:
            valid &= self.in_image(pix)
        return rays, valid

    def in_image(self, pixels: ArrayLike) -> Mask:
        """(N, 2) -> (N,) whether each pixel lies inside the image area."""
        pix = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        u, v = pix[:, 0], pix[:, 1]
        lo, w, h = -0.5 - _EDGE_SLACK, self.width - 0.5 + _EDGE_SLACK, self.height - 0.5 + _EDGE_SLACK
        return (u >= lo) & (u <= w) & (v >= lo) & (v <= h)

    def to_dict(self) -> dict[str, Any]:
        """``{"model", "width", "height", "params": {...}}`` (+ ``fov_deg`` when set): rig.yaml."""
        d: dict[str, Any] = {
            "model": self.name,
            "width": self.width,
            "height": self.height,
            "params": {
                n: ([float(x) for x in self._lists[n]] if n in self._lists else float(self._values[n]))
                for n in self.all_param_names()
            },
        }
        if self.fov_deg is not None:
            d["fov_deg"] = self.fov_deg
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CameraModel:
        """Inverse of :meth:`to_dict`. On the base class the ``model`` key picks the type."""
        if not isinstance(d, Mapping):
            raise ModelError("camera entry must be a mapping")
        name = d.get("model", getattr(cls, "name", None))
        target = MODELS.get(str(name)) if cls is CameraModel else cls
        if target is None:
            raise ModelError(f"unknown camera model {name!r}; known: {', '.join(sorted(MODELS))}")
        if cls is not CameraModel and name != cls.name:
            raise ModelError(f"expected model {cls.name!r}, got {name!r}")
        for key in ("width", "height", "params"):
            if key not in d:
                raise ModelError(f"{target.name}: missing field '{key}'")
        params = d["params"]
        if not isinstance(params, Mapping):
            raise ModelError(f"{target.name}: field 'params' must be a mapping")
        return target(d["width"], d["height"], d.get("fov_deg"), **dict(params))

    def __repr__(self) -> str:
        vals = [f"{k}={v:.6g}" for k, v in self._values.items()]
        vals += [f"{k}=[{', '.join(f'{x:.6g}' for x in v)}]" for k, v in self._lists.items()]
        return f"{type(self).__name__}({self.width}x{self.height}, {', '.join(vals)})"

    def __eq__(self, other: object) -> bool:
        return (
            type(other) is type(self)
            and isinstance(other, CameraModel)
            and (self.width, self.height, self.fov_deg) == (other.width, other.height, other.fov_deg)
            and self._values == other._values
            and self._lists == other._lists
        )

    def _image_extent(self, what: str, value: Any) -> int:
        """``value`` as an image width/height in [1, MAX_IMAGE_SIZE_PX]; ModelError otherwise."""
        try:
            ok = not isinstance(value, bool) and int(value) == value
        except (TypeError, ValueError, OverflowError):  # None, text, NaN, inf
            ok = False
        if not ok or int(value) <= 0:
            raise ModelError(f"{self.name}: {what} must be a positive integer, got {value!r}", param=what)
        if int(value) > MAX_IMAGE_SIZE_PX:
            raise ModelError(
                f"{self.name}: {what} must be at most {MAX_IMAGE_SIZE_PX} px, got {_short(value)}",
                param=what,
            )
        return int(value)

    def _number_list(self, n: str, raw: object) -> tuple[float, ...]:
        """A list parameter as a tuple of finite floats (None -> empty); ModelError otherwise."""
        if raw is None:
            return ()
        bad_array = isinstance(raw, np.ndarray) and raw.ndim != 1
        if bad_array or isinstance(raw, str | bytes | Mapping) or not isinstance(raw, Sequence | np.ndarray):
            raise ModelError(f"{self.name}: parameter {n} must be a list of numbers, got {raw!r}", param=n)
        out: list[float] = []
        for i, x in enumerate(raw):
            try:
                value = float(x)
            except (TypeError, ValueError) as err:
                raise ModelError(
                    f"{self.name}: parameter {n}[{i}] must be a number, got {x!r}", param=n
                ) from err
            if not math.isfinite(value):
                raise ModelError(f"{self.name}: parameter {n}[{i}] must be finite, got {value}", param=n)
            out.append(value)
        return tuple(out)

    __hash__ = None  # type: ignore[assignment]


MODELS: dict[str, type[CameraModel]] = {}
_M = TypeVar("_M", bound=type[CameraModel])


def register(cls: _M) -> _M:
    """Class decorator adding a model to :data:`MODELS` under its ``name``."""
    MODELS[cls.name] = cls
    return cls


def create(name: str, width: int, height: int, **params: Any) -> CameraModel:
    """Build a model by name: ``create("kannala_brandt", 1280, 960, fx=..., ..., fov_deg=190)``."""
    try:
        cls = MODELS[name]
    except KeyError:
        raise ModelError(f"unknown camera model {name!r}; known: {', '.join(sorted(MODELS))}") from None
    fov = params.pop("fov_deg", None)
    return cls(width, height, fov, **params)


def pixels_from_ratio(
    x: F64, y: F64, den: F64, fx: float, fy: float, cx: float, cy: float
) -> tuple[F64, F64]:
    """``(fx·x/den + cx, fy·y/den + cy)`` for arrays of one shape, with two temporaries."""
    u = x * fx
    u /= den
    u += cx
    v = y * fy
    v /= den
    v += cy
    return u, v


def smallest_positive_root(coeffs_ascending: Sequence[float], what: str = "polynomial") -> float:
    """Smallest real root > 0 of ``c0 + c1 s + c2 s^2 + ...``; ``inf`` if there is none.

    When the companion matrix's ratios ``c_i / c_n`` would overflow, solves for ``s = 2^q t``
    instead (see :func:`_scaled_for_roots`); when even that cannot hold the polynomial, raises
    ModelError naming ``what``. Never a RuntimeWarning.
    """
    c = np.asarray(coeffs_ascending, dtype=np.float64).reshape(-1)
    if not np.isfinite(c).all():
        raise ModelError(f"{what}: coefficients must be finite, got {_short_list(c)}")
    # Trailing zeros lower the degree; leading zeros are roots at 0, which are not positive.
    c = np.trim_zeros(np.trim_zeros(c, "b"), "f")
    if c.size <= 1:
        return math.inf
    with np.errstate(over="ignore", under="ignore"):
        overflows = not np.isfinite(c[:-1] / c[-1]).all()
    q, scaled = _scaled_for_roots(c, what) if overflows else (0, c)
    t = np.roots(scaled[::-1])
    with np.errstate(over="ignore", under="ignore"):  # a root beyond float64 is no root in range
        re, im = np.ldexp(t.real, q), np.ldexp(t.imag, q)
    real = re[np.abs(im) <= 1e-9 * np.maximum(1.0, np.abs(re))]
    pos = real[real > 0]
    return float(pos.min()) if pos.size else math.inf


def _scaled_for_roots(c: F64, what: str) -> tuple[int, F64]:
    """(q, coefficients (n+1,) of ``Σ c_i (2^q t)^i / (2^(q n) c_n)`` up to a power of two) for
    c_0, c_n non-zero: q from the Fujiwara bound puts every root at |t| <= 2 and makes every
    coefficient smaller than the leading one. Middle ones that underflow are negligible next to
    the solver's round-off, the constant term is not (it places the roots near 0): ModelError."""
    n = c.size - 1
    _, e = np.frexp(c)  # c_i = m_i 2^e_i exactly, 0.5 <= |m_i| < 1
    q = int(np.ceil(max((e[i] - e[n]) / (n - i) for i in range(n) if c[i] != 0.0))) + 1
    with np.errstate(under="ignore"):
        scaled = np.ldexp(c, q * (np.arange(n + 1) - n) - e[n])
    if abs(scaled[0]) < np.finfo(np.float64).tiny:
        nz = np.abs(c[c != 0.0])
        raise ModelError(
            f"{what}: coefficients from {nz.min():.3g} to {nz.max():.3g} in magnitude are too far apart "
            "to find its roots in float64"
        )
    return q, scaled


def _short(x: Any) -> str:
    """A number for a message: whole numbers below 1e15 in full, else 6 significant digits."""
    try:
        f = float(x)
    except OverflowError:  # an integer beyond float range: no 400-digit messages
        return f"~1e+{len(str(abs(int(x)))) - 1}"
    return f"{f:.15g}" if abs(f) < 1e15 and f.is_integer() else f"{f:.6g}"


def _short_list(values: NDArray[np.float64]) -> str:
    """(N,) numbers for a message, 6 significant digits each."""
    return "[" + ", ".join(f"{float(v):.6g}" for v in values) + "]"


def _as_array(x: ArrayLike, cols: int, what: str) -> F64:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1 and a.shape[0] == cols:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != cols:
        raise ModelError(f"{what} must have shape (N, {cols}), got {np.shape(x)}")
    return a
