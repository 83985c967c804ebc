"""The fast renderer against the brute-force one it replaced: every ray tested against every
rectangle in the world frame (``Scene.intersect``), sub-pixel rays from ``camera.unproject``,
shaded per rectangle and box-filtered. Culling, tiling, camera-frame casting and cached rays
must change nothing but rounding."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from calibration.geometry import make_transform, rot_x, rot_y, rot_z
from calibration.models import CameraModel
from rig.sim import Scene, get_preset, render, room_scene
from rig.sim.raycast import CameraScene, ray_cone
from rig.sim.render import RayGrid, render_geometry, subpixel_offsets

F64 = NDArray[np.float64]


def _pose(rng: np.random.Generator) -> F64:
    """A pose inside the room, clear of the boxes, turned anywhere."""
    R = rot_y(rng.uniform(-math.pi, math.pi)) @ rot_x(rng.uniform(-0.6, 0.6)) @ rot_z(rng.uniform(-0.5, 0.5))
    return make_transform(R, [rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.5), rng.uniform(-0.8, 1.2)])


def _cone_of_rays(rng: np.random.Generator, n: int) -> F64:
    """``n`` unit rays within a random cone of 0.1°–60° around a random axis."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    rays = axis + math.tan(math.radians(rng.uniform(0.1, 60.0))) * rng.uniform(-1, 1, (n, 3))
    out: F64 = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    return out


def test_culled_camera_frame_hits_equal_brute_force_world_hits() -> None:
    rng = np.random.default_rng(5)
    scene = room_scene(3)
    culled_away = 0
    for _ in range(40):
        T = _pose(rng)
        view = CameraScene(scene, T)
        rays = _cone_of_rays(rng, 400)
        axis, cos_half = ray_cone(rays)
        rects = view.candidates(axis, cos_half)
        culled_away += len(scene.rects) - rects.size
        fast = view.intersect(rays, rects)
        slow = scene.intersect(T[:3, 3], rays @ T[:3, :3].T)
        np.testing.assert_array_equal(fast.rect_index, slow.rect_index)
        np.testing.assert_allclose(fast.t, slow.t, rtol=1e-12)
        np.testing.assert_allclose(fast.st, slow.st, atol=1e-9)
        # Every rectangle any ray hits (not only the nearest) is a candidate.
        world_rays = rays @ T[:3, :3].T
        for r in range(len(scene.rects)):
            alone = Scene([scene.rects[r]]).intersect(T[:3, 3], world_rays)
            if (alone.rect_index >= 0).any():
                assert r in rects
    # Cones up to 60° wide in a closed room: still over a third of the tests culled.
    assert culled_away > 0.35 * 40 * len(scene.rects)


def _brute_force_render(scene: Scene, camera: CameraModel, T: F64, s: int) -> tuple[NDArray[np.uint8], F64]:
    """The renderer before tiles and culling: grey image and centre distance."""
    h, w = camera.height, camera.width
    du, dv = subpixel_offsets(s)
    v = np.arange(h, dtype=np.float64)[:, None, None, None] + dv[None, :, None, :]
    u = np.arange(w, dtype=np.float64)[None, None, :, None] + du[None, :, None, :]
    u, v = np.broadcast_arrays(u, v)
    rays, ok = camera.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    hits = scene.intersect(T[:3, 3], rays[ok] @ T[:3, :3].T)
    values = np.zeros(ok.size, dtype=np.float32)
    shaded = np.zeros(hits.t.size, dtype=np.float32)
    for r in np.unique(hits.rect_index[hits.rect_index >= 0]):
        sel = hits.rect_index == r
        shaded[sel] = scene.rects[int(r)].texture.sample_as(hits.st[sel], 1)
    values[ok] = shaded
    image = values.reshape(h, s, w, s).mean(axis=(1, 3))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    centre_rays, centre_ok = camera.unproject(np.stack([xx.ravel(), yy.ravel()], axis=1))
    centre = scene.intersect(T[:3, 3], centre_rays[centre_ok] @ T[:3, :3].T)
    distance = np.full(h * w, np.nan)
    distance[centre_ok] = np.where(centre.rect_index >= 0, centre.t, np.nan)
    out = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    out[~centre_ok.reshape(h, w)] = 0
    return out, distance.reshape(h, w)


@pytest.mark.parametrize("supersample", [2, 3])
def test_render_equals_the_brute_force_renderer(supersample: int) -> None:
    preset = get_preset("prototype").scaled(0.125)
    scene = room_scene(1)
    rng = np.random.default_rng(supersample)
    for name in ("left", "right"):
        cam = preset.rig.cameras[name]
        T = _pose(rng) @ preset.rig.T_rig_cam[name]
        fast = render(scene, cam, T, supersample=supersample)
        image, distance = _brute_force_render(scene, cam, T, supersample)
        # Rounding only: a float32 mean landing either side of .5 flips a pixel by one level.
        diff = np.abs(fast.image.astype(int) - image)
        assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
        np.testing.assert_array_equal(np.isnan(fast.distance), np.isnan(distance))
        np.testing.assert_allclose(fast.distance, distance, rtol=1e-6)
        assert np.isfinite(fast.distance[fast.valid]).all()


def test_cached_rays_render_every_pose_the_same_and_geometry_is_the_renders() -> None:
    preset = get_preset("prototype").scaled(0.125)
    cam = preset.rig.cameras["left"]
    scene = room_scene(0)
    grid = RayGrid(cam, 3, cache=True)
    rng = np.random.default_rng(9)
    for _ in range(2):
        T = _pose(rng)
        cached = render(scene, cam, T, rays=grid, noise_std=1.0, seed=4)
        fresh = render(scene, cam, T, noise_std=1.0, seed=4)
        np.testing.assert_array_equal(cached.image, fresh.image)
        np.testing.assert_array_equal(cached.depth, fresh.depth)
        truth = render_geometry(scene, cam, T)
        np.testing.assert_array_equal(truth.distance, fresh.distance)
        np.testing.assert_array_equal(truth.valid, fresh.valid)
