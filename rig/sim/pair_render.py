"""One rendered pair of a recording: the rig's two fisheye views (rendered side by side on two
threads: numpy and OpenCV release the GIL in the work that matters), the exact range of the
rectified pair's left view and, when asked for, the Reference pair (ideal rectified views).

The fisheye cameras' sub-pixel rays are kept between frames (:class:`RayGrid` with its cache)
when a recording has more than one frame and they fit :data:`RAY_CACHE_BYTES`; they do not
change with the rig's pose, and the lens model's unprojection is a third of a fisheye view's work.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calibration.models import CameraModel
from calibration.rig import Rig
from rig.rectified import RectifiedPair
from rig.sim.lens_effects import LensEffects
from rig.sim.render import Geometry, RayGrid, Render, render, render_geometry
from rig.sim.scene import Scene

__all__ = ["RAY_CACHE_BYTES", "PairRenderer", "RenderedPair"]

F64 = NDArray[np.float64]

#: The most memory the cached rays of a recording's fisheye cameras may take (a prototype
#: camera at 3×3 supersampling needs ~170 MB).
RAY_CACHE_BYTES = 512 << 20
# Bytes a cached sub-pixel sample takes at most: its ray (3 float64) and its validity flag.
_BYTES_PER_SAMPLE = 25


@dataclass(frozen=True)
class RenderedPair:
    """The fisheye ``views`` (left, right), the ``truth`` of the left rectified view and the
    Reference ``references`` (left, right) when asked for."""

    views: tuple[Render, Render]
    truth: Geometry
    references: tuple[Render, Render] | None


class PairRenderer:
    """Renders the fisheye pair ``pair.left``/``pair.right`` of ``rig`` and the rectified pair's
    ground truth, shot after shot. ``lens``: the fisheyes' lens effects (None: ideal);
    ``noise_std`` and ``vignetting``: the simple sensor model added on top (see
    :func:`rig.sim.render.render`); ``frames``: how many shots will be rendered (rays are cached
    for more than one)."""

    def __init__(
        self,
        rig: Rig,
        pair: RectifiedPair,
        *,
        supersample: int,
        color: bool,
        lens: LensEffects | None,
        noise_std: float,
        vignetting: float,
        reference: bool,
        frames: int,
    ) -> None:
        self.rig, self.pair = rig, pair
        self.names = (pair.left, pair.right)
        self.supersample, self.color, self.lens = supersample, color, lens
        self.noise_std, self.vignetting, self.reference = noise_std, vignetting, reference
        cams = [rig.cameras[n] for n in self.names]
        need = sum(c.width * c.height for c in cams) * supersample**2 * _BYTES_PER_SAMPLE
        cache = frames > 1 and need <= RAY_CACHE_BYTES
        self.grids = {n: RayGrid(c, supersample, cache=cache) for n, c in zip(self.names, cams, strict=True)}
        self.truth_grid = RayGrid(pair.camera, 1, cache=frames > 1)
        # Work per view in rays, for the progress fraction of a pair.
        weights = [self._rays(c, supersample) for c in cams]
        if reference:
            weights += [self._rays(pair.camera, supersample)] * 2
        self.weights = np.array([*weights, self._rays(pair.camera, 1)], dtype=np.float64)

    @staticmethod
    def _rays(camera: CameraModel, supersample: int) -> float:
        return float(camera.width * camera.height * supersample**2)

    def render(
        self, scene: Scene, T_world_rig: F64, seeds: tuple[int, int], progress: Callable[[float], None] | None
    ) -> RenderedPair:
        """The pair seen from ``T_world_rig``; the fisheyes' noise seeded by ``seeds``;
        ``progress(fraction)`` of the pair's work done, from any thread."""
        done = np.zeros(self.weights.size)
        lock = threading.Lock()

        def report(view: int) -> Callable[[float], None] | None:
            if progress is None:
                return None

            def step(fraction: float) -> None:
                with lock:  # one report at a time, so they never go backwards
                    done[view] = fraction
                    progress(float(done @ self.weights / self.weights.sum()))

            return step

        def fisheye(i: int) -> Render:
            name = self.names[i]
            return render(
                scene, self.rig.cameras[name], T_world_rig @ self.rig.T_rig_cam[name],
                supersample=self.supersample, color=self.color, noise_std=self.noise_std,
                vignetting=self.vignetting, seed=seeds[i], rays=self.grids[name], progress=report(i),
                lens=self.lens, camera_index=list(self.rig.cameras).index(name),
            )  # fmt: skip

        def rectified(i: int) -> Render:
            pose = T_world_rig @ self.pair.T_rig_rect[self.names[i]]
            return render(
                scene, self.pair.camera, pose, supersample=self.supersample, color=self.color,
                progress=report(2 + i),
            )  # fmt: skip

        with ThreadPoolExecutor(max_workers=2) as pool:
            views = [pool.submit(fisheye, i) for i in (0, 1)]
            if self.reference:
                jobs = [pool.submit(rectified, i) for i in (0, 1)]
                refs = (jobs[0].result(), jobs[1].result())
                references: tuple[Render, Render] | None = refs
                truth = Geometry(refs[0].depth, refs[0].distance, refs[0].valid)
            else:
                pose = T_world_rig @ self.pair.T_rig_rect[self.names[0]]
                truth_job = pool.submit(render_geometry, scene, self.pair.camera, pose, rays=self.truth_grid)
                references, truth = None, truth_job.result()
            left, right = views[0].result(), views[1].result()
        if progress is not None:
            progress(1.0)
        return RenderedPair((left, right), truth, references)
