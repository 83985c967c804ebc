"""The one nonlinear least-squares core behind every calibration (mono and stereo, all models).

Unknowns: the free parameters of each camera model, the pose of each extra camera relative to
the reference camera 0 (stereo), and one board pose per view in the reference frame. Residuals:
projection − detection (px) of every observed corner. Poses are parameterised as local
perturbations ``T = T0 · Exp(δ)`` (δ = rotation vector, translation) so every unknown starts
at 0 and there is no rotation-vector singularity. The Jacobian is taken by central finite
differences over column groups: each view's pose touches only that view's rows, so all views'
pose columns share six groups and a Jacobian costs ``2 (P + 6 + 6)`` residual evaluations.

Shapes: object points (N, 3), image points (N, 2), poses 4x4, parameter vectors (P,).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from calibration.errors import CalibrationFailed, ModelError
from calibration.lm import NormalEquations, levenberg_marquardt
from calibration.models.base import CameraModel
from calibration.models.scaramuzza import ScaramuzzaModel

__all__ = [
    "BundleResult",
    "CameraBlock",
    "Observation",
    "param_bounds",
    "param_scales",
    "refine_bundle",
    "se3_exp",
    "with_params_keep_derived",
]

F64 = NDArray[np.float64]
Mask = NDArray[np.bool_]

# Central-difference step relative to max(1, |x|): cube root of machine epsilon.
_FD_STEP = float(np.finfo(np.float64).eps ** (1.0 / 3.0))
# Smallest typical magnitude of a parameter (distortion coefficients that start at 0).
_MIN_SCALE = 1e-2
# Residual for a model/parameter combination the model rejects: large, finite, constant.
_REJECTED_RESIDUAL = 1e4

# Parameter ranges the models themselves require (ModelError outside). Keyed by (model, name),
# then by name alone. Positive focal lengths everywhere.
_BOUNDS: dict[tuple[str, str] | str, tuple[float, float]] = {
    "fx": (1e-6, np.inf),
    "fy": (1e-6, np.inf),
    "gamma1": (1e-6, np.inf),
    "gamma2": (1e-6, np.inf),
    ("mei", "xi"): (0.0, np.inf),
    ("double_sphere", "alpha"): (0.0, 1.0),
    ("double_sphere", "xi"): (-1.0, 1.0),
    ("eucm", "alpha"): (0.0, 1.0),
    ("eucm", "beta"): (1e-9, np.inf),
    ("scaramuzza", "c"): (1e-6, ScaramuzzaModel.MAX_STRETCH),
    ("scaramuzza", "d"): (-ScaramuzzaModel.MAX_STRETCH, ScaramuzzaModel.MAX_STRETCH),
    ("scaramuzza", "e"): (-ScaramuzzaModel.MAX_STRETCH, ScaramuzzaModel.MAX_STRETCH),
}


def param_bounds(model: CameraModel) -> tuple[F64, F64]:
    """Lower and upper bounds (P,) for the flat parameter vector of ``model``."""
    names = model.param_layout
    lo = np.full(len(names), -np.inf)
    hi = np.full(len(names), np.inf)
    for i, n in enumerate(names):
        b = _BOUNDS.get((model.name, n), _BOUNDS.get(n))
        if b is not None:
            lo[i], hi[i] = b
    if isinstance(model, ScaramuzzaModel):  # its centre's range depends on the image size
        for n, size in (("cx", model.width), ("cy", model.height)):
            i = names.index(n)
            lo[i], hi[i] = -size, 2 * size
    return lo, hi


def param_scales(model: CameraModel) -> F64:
    """Typical magnitude (P,) of each parameter: the solver works in units of these so that
    finite-difference steps and bounds are sensible for parameters spanning many orders of
    magnitude (a Scaramuzza ``poly[i]`` scales as ``a0 / R^i`` with R the image half-diagonal)."""
    x = model.params
    scales = np.maximum(np.abs(x), _MIN_SCALE)
    half_diag = 0.5 * float(np.hypot(model.width, model.height))
    for i, n in enumerate(model.param_layout):
        if n.startswith("poly[") and n != "poly[0]":
            power = int(n[5:-1])
            scales[i] = max(abs(float(x[0])), 1.0) / half_diag**power
    return scales


def se3_exp(delta: F64) -> tuple[F64, F64]:
    """(K, 6) perturbations [rotation vector, translation] -> rotations (K, 3, 3), translations (K, 3)."""
    d = np.asarray(delta, dtype=np.float64).reshape(-1, 6)
    return Rotation.from_rotvec(d[:, :3]).as_matrix(), d[:, 3:].copy()


@dataclass
class CameraBlock:
    """One camera in the problem: its model, which parameters are free and its pose.

    ``T_cam_ref`` maps reference-camera points into this camera (identity for camera 0);
    ``pose_free`` says whether it is refined (never for camera 0).
    """

    model: CameraModel
    free: Mask | None = None  # (P,); None = all free
    T_cam_ref: F64 = field(default_factory=lambda: np.eye(4))
    pose_free: bool = False


@dataclass
class Observation:
    """Corners of view ``view`` seen by camera ``camera``; rows with NaN pixels are ignored."""

    camera: int
    view: int
    object_points: F64  # (N, 3) board frame
    image_points: F64  # (N, 2)


@dataclass
class BundleResult:
    """Refined cameras and poses, per-observation residuals and parameter uncertainties."""

    cameras: list[CameraModel]
    T_cam_ref: list[F64]
    T_ref_board: list[F64]
    residuals: list[F64]  # per observation (N_kept, 2): projection − detection
    kept: list[Mask]  # per observation (N,): which input rows were used (finite detections)
    param_std: list[F64]  # per camera (P,), NaN for fixed parameters
    pose_std: list[F64]  # per camera (6,): [rotation (rad) xyz, translation (m) xyz]; NaN if fixed
    rms: float
    success: bool
    message: str
    nfev: int


@dataclass
class _CameraPoints:
    """All corners one camera observes, concatenated over views, and their residual rows."""

    X: F64  # (N, 3) board frame
    u: F64  # (N, 2) detections
    view: NDArray[np.int_]  # (N,) view of each corner
    rows: NDArray[np.int_]  # (2N,) residual rows, u then v per corner


class _Problem:
    def __init__(
        self, blocks: Sequence[CameraBlock], T_ref_board: Sequence[F64], observations: Sequence[Observation]
    ) -> None:
        self.blocks = list(blocks)
        self.T0_views = [np.asarray(T, dtype=np.float64) for T in T_ref_board]
        self.V = len(self.T0_views)
        self.free = [
            np.ones(len(b.model.params), bool) if b.free is None else np.asarray(b.free, bool)
            for b in self.blocks
        ]
        # Column layout: [intrinsics cam0 | cam1 | ... | extrinsics of free cams | views × 6].
        self.intr_slices, self.ext_slices, self.view_col0 = _camera_columns(self.blocks, self.free)
        self.n_params = self.view_col0 + 6 * self.V
        # Unknowns are solved for in units of their typical magnitude (poses: rad and m).
        self.scale = np.ones(self.n_params)
        for c, b in enumerate(self.blocks):
            self.scale[self.intr_slices[c]] = param_scales(b.model)[self.free[c]]

        # Rows: each observation's detected corners, u then v.
        self.obs = list(observations)
        self.kept, self.obs_rows, self.n_res = _observation_rows(self.obs)
        self.row_view = np.zeros(self.n_res, dtype=int)
        for k, o in enumerate(self.obs):
            self.row_view[self.obs_rows[k]] = o.view
        # Rows sorted by view and where each view's run starts (for per-view sums).
        self.row_order = np.argsort(self.row_view, kind="stable")
        counts = np.bincount(self.row_view, minlength=self.V)
        self.view_starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
        self.per_cam = [self._camera_points(c) for c in range(len(self.blocks))]

    def _camera_points(self, c: int) -> _CameraPoints:
        """Camera ``c``'s concatenated points, their view index, and where their rows go."""
        idx = [k for k, o in enumerate(self.obs) if o.camera == c]
        X = [np.asarray(self.obs[k].object_points, np.float64)[self.kept[k]] for k in idx]
        u = [np.asarray(self.obs[k].image_points, np.float64)[self.kept[k]] for k in idx]
        views = [np.full(len(x), self.obs[k].view) for k, x in zip(idx, X, strict=True)]
        r = [np.arange(self.obs_rows[k].start, self.obs_rows[k].stop) for k in idx]
        return _CameraPoints(
            X=np.concatenate(X) if X else np.zeros((0, 3)),
            u=np.concatenate(u) if u else np.zeros((0, 2)),
            view=np.concatenate(views).astype(int) if views else np.zeros(0, int),
            rows=np.concatenate(r).astype(int) if r else np.zeros(0, int),
        )

    # ----- parameter vector <-> models and poses ------------------------------------------------
    def x0(self) -> F64:
        """Initial unknowns (scaled)."""
        x = np.zeros(self.n_params)
        for c, b in enumerate(self.blocks):
            x[self.intr_slices[c]] = b.model.params[self.free[c]]
        return x / self.scale

    def bounds(self) -> tuple[F64, F64]:
        lo = np.full(self.n_params, -np.inf)
        hi = np.full(self.n_params, np.inf)
        for c, b in enumerate(self.blocks):
            blo, bhi = param_bounds(b.model)
            lo[self.intr_slices[c]] = blo[self.free[c]]
            hi[self.intr_slices[c]] = bhi[self.free[c]]
        return lo / self.scale, hi / self.scale

    def models(self, x: F64, final: bool = False) -> list[CameraModel]:
        """Camera models at ``x``. While iterating, derived parameters (Scaramuzza's invpol, a
        Newton seed only) keep their initial values; ``final`` recomputes them."""
        x = x * self.scale
        out = []
        for c, b in enumerate(self.blocks):
            p = b.model.params.copy()
            p[self.free[c]] = x[self.intr_slices[c]]
            out.append(b.model.with_params(p) if final else with_params_keep_derived(b.model, p))
        return out

    def cam_poses(self, x: F64) -> list[F64]:
        x = x * self.scale
        out = []
        for c, b in enumerate(self.blocks):
            s = self.ext_slices[c]
            T = np.asarray(b.T_cam_ref, np.float64).copy()
            if s is not None:
                R, t = se3_exp(x[s])
                T = _compose(T, R[0], t[0])
            out.append(T)
        return out

    def view_poses(self, x: F64) -> tuple[F64, F64]:
        """Board poses in the reference frame: rotations (V, 3, 3), translations (V, 3)."""
        d = (x * self.scale)[self.view_col0 :].reshape(self.V, 6)
        dR, dt = se3_exp(d)
        R0 = np.stack([T[:3, :3] for T in self.T0_views]) if self.V else np.zeros((0, 3, 3))
        t0 = np.stack([T[:3, 3] for T in self.T0_views]) if self.V else np.zeros((0, 3))
        return R0 @ dR, t0 + np.einsum("vij,vj->vi", R0, dt)

    # ----- residuals and Jacobian --------------------------------------------------------------
    def residuals(self, x: F64) -> F64:
        res = np.empty(self.n_res)
        try:
            models = self.models(x)
        except ModelError:
            res.fill(_REJECTED_RESIDUAL)
            return res
        poses = self.cam_poses(x)
        Rv, tv = self.view_poses(x)
        for c, pc in enumerate(self.per_cam):
            if len(pc.X) == 0:
                continue
            p_ref = np.einsum("nij,nj->ni", Rv[pc.view], pc.X) + tv[pc.view]
            p_cam = p_ref @ poses[c][:3, :3].T + poses[c][:3, 3]
            pix, _ = models[c].project(p_cam, in_image=False)
            res[pc.rows] = (pix - pc.u).reshape(-1)
        return res

    def jacobian(self, x: F64) -> tuple[F64, F64]:
        """Central-difference Jacobian in its compact form: ``Jc`` (M, n_cam) over the camera
        unknowns (intrinsics, extrinsics) and ``Jp`` (M, 6) where row i holds the derivatives
        with respect to the pose of the view that row belongs to (the only pose it depends on,
        so all views' k-th pose unknowns are differenced together)."""
        nc = self.view_col0
        Jc = np.zeros((self.n_res, nc))
        Jp = np.zeros((self.n_res, 6))
        lo, hi = self.bounds()
        groups: list[NDArray[np.int_]] = [np.array([j]) for j in range(nc)]
        groups += [np.arange(nc + k, self.n_params, 6) for k in range(6)]
        for k, cols in enumerate(groups):
            h = _FD_STEP * np.maximum(1.0, np.abs(x[cols]))
            xp, xm = x.copy(), x.copy()
            xp[cols] = np.minimum(x[cols] + h, hi[cols])
            xm[cols] = np.maximum(x[cols] - h, lo[cols])
            diff = self.residuals(xp) - self.residuals(xm)
            step = xp[cols] - xm[cols]
            if k < nc:
                Jc[:, k] = diff / step[0]
            else:
                Jp[:, k - nc] = diff / step[self.row_view]
        return Jc, Jp


def refine_bundle(
    blocks: Sequence[CameraBlock],
    T_ref_board: Sequence[F64],
    observations: Sequence[Observation],
    *,
    loss: str = "linear",
    f_scale: float = 1.0,
    max_iter: int = 100,
    tol: float = 1e-12,
) -> BundleResult:
    """Jointly refine the free camera parameters, camera poses and board poses.

    ``T_ref_board[v]`` (4x4) is the initial pose of view v's board in the reference camera;
    every view must be observed at least once. ``loss`` is "linear" (least squares), "huber" or
    "soft_l1" (robust, on each corner's error in px, scale ``f_scale``). Stops when the cost
    changes by less than ``tol`` relative, or after ``max_iter`` iterations. Raises
    CalibrationFailed when there are fewer residuals than unknowns.
    """
    prob = _Problem(blocks, T_ref_board, observations)
    seen = {o.view for o, k in zip(prob.obs, prob.kept, strict=True) if k.any()}
    missing = sorted(set(range(prob.V)) - seen)
    if missing:
        raise CalibrationFailed(f"views {missing} have no observed corners")
    if prob.n_res <= prob.n_params:
        raise CalibrationFailed(
            f"{prob.n_res // 2} observed corners cannot determine {prob.n_params} unknowns"
        )
    lo, hi = prob.bounds()
    x, nfev, converged, message = levenberg_marquardt(
        prob, np.clip(prob.x0(), lo, hi), lo, hi, loss, f_scale, max_iter, tol
    )
    r = prob.residuals(x)
    param_std, pose_std = _camera_std(prob, x, r)
    Rv, tv = prob.view_poses(x)
    T_views = []
    for R, t in zip(Rv, tv, strict=True):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        T_views.append(T)
    residuals = [r[rows].reshape(-1, 2) for rows in prob.obs_rows]
    n_pts = prob.n_res // 2
    return BundleResult(
        cameras=prob.models(x, final=True),
        T_cam_ref=prob.cam_poses(x),
        T_ref_board=T_views,
        residuals=residuals,
        kept=prob.kept,
        param_std=param_std,
        pose_std=pose_std,
        rms=float(np.sqrt((r @ r) / max(n_pts, 1))),
        success=converged,
        message=message,
        nfev=nfev,
    )


def _camera_columns(
    blocks: Sequence[CameraBlock], free: Sequence[Mask]
) -> tuple[list[slice], list[slice | None], int]:
    """The unknowns' columns of each camera's free intrinsics, then of each free camera pose
    (None: fixed); and the first column of the views' poses."""
    intr_slices: list[slice] = []
    col = 0
    for f in free:
        intr_slices.append(slice(col, col + int(f.sum())))
        col += int(f.sum())
    ext_slices: list[slice | None] = []
    for c, b in enumerate(blocks):
        if b.pose_free and c > 0:
            ext_slices.append(slice(col, col + 6))
            col += 6
        else:
            ext_slices.append(None)
    return intr_slices, ext_slices, col


def _observation_rows(observations: Sequence[Observation]) -> tuple[list[Mask], list[slice], int]:
    """Each observation's detected corners (finite image points), its residual rows (two per
    corner) and the number of rows."""
    kept: list[Mask] = []
    obs_rows: list[slice] = []
    rows = 0
    for o in observations:
        keep = np.asarray(np.isfinite(np.asarray(o.image_points, dtype=np.float64)).all(axis=1), dtype=bool)
        kept.append(keep)
        obs_rows.append(slice(rows, rows + 2 * int(keep.sum())))
        rows += 2 * int(keep.sum())
    return kept, obs_rows, rows


def _camera_std(prob: _Problem, x: F64, r: F64) -> tuple[list[F64], list[F64]]:
    """1-σ of each camera's parameters (NaN where fixed) and of its pose (NaN where fixed) at
    the solution ``x`` with residuals ``r``."""
    # Marginal covariance of the camera unknowns: σ² times the inverse Schur complement.
    normal = NormalEquations(prob, *prob.jacobian(x), np.ones(prob.n_res), r)
    dof = max(prob.n_res - prob.n_params, 1)
    sigma2 = float(r @ r) / dof
    std = np.full(prob.n_params, np.nan)
    if prob.view_col0:
        # Not a pseudo-inverse: that would report ~0 variance along an unobservable direction
        # (e.g. double sphere ξ vs α over a narrow field); a true inverse reports it as huge.
        lam, vec = np.linalg.eigh(normal.schur(0.0))
        lam = np.maximum(lam, max(float(lam.max()), 1e-300) * 1e-300)
        std[: prob.view_col0] = np.sqrt(sigma2 * (vec**2 / lam).sum(axis=1))
    std *= prob.scale

    param_std = []
    pose_std = []
    for c, b in enumerate(prob.blocks):
        ps = np.full(len(b.model.params), np.nan)
        ps[prob.free[c]] = std[prob.intr_slices[c]]
        param_std.append(ps)
        s_ = prob.ext_slices[c]
        pose_std.append(std[s_] if s_ is not None else np.full(6, np.nan))
    return param_std, pose_std


def with_params_keep_derived(model: CameraModel, vector: F64) -> CameraModel:
    """Like ``model.with_params(vector)`` but passing the model's current derived parameters
    instead of recomputing them (which can cost far more than a projection)."""
    if not model.derived_params:
        return model.with_params(vector)
    values = model.param_dict
    kwargs: dict[str, float | tuple[float, ...]] = {}
    i = 0
    for n in model.all_param_names():
        if n in model.derived_params:
            kwargs[n] = tuple(values[n])
        elif n in model.list_params:
            k = len(values[n])
            kwargs[n] = tuple(float(v) for v in vector[i : i + k])
            i += k
        else:
            kwargs[n] = float(vector[i])
            i += 1
    return type(model)(model.width, model.height, model.fov_deg, **kwargs)


def _compose(T: F64, dR: F64, dt: F64) -> F64:
    """T · Exp(δ) for a 4x4 T and a perturbation (dR, dt) in T's source frame."""
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ dR
    out[:3, 3] = T[:3, 3] + T[:3, :3] @ dt
    return out
