"""The speed work's fast paths give what the reference paths give: component-wise
projection against ``project``, Scaramuzza's table seed against its invpol seed, the cache's
zero-copy load, the pipeline's stages against ``process``, and the pipelined worker."""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

import rig.lut_cache as lut_cache
import rig.postprocess as finish_module
from calibration.geometry import rot_x, rot_y
from calibration.models import ScaramuzzaModel, create
from rig.capture.frame import Frame, FramePair
from rig.lut_cache import LutCache
from rig.pipeline import DepthFrame, DepthPipeline, tune_allocator
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from service.store import ResultStore
from service.worker import DepthWorker
from tests.calibration.model_cases import ModelCase, model_cases
from tests.helpers.recordings import encode
from tests.helpers.shots import StereoShot, plane_shot
from tests.helpers.waiting import wait_for

CASES = model_cases()


def _rays(n: int, seed: int) -> np.ndarray:
    """Unit rays over the whole sphere, plus a few points on and near the axis."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    extra = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1e-9, 0.0, 1.0], [0.0, 0.0, 0.0]])
    return np.vstack([v * rng.uniform(0.2, 5.0, size=(n, 1)), extra])


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_project_xyz_is_project_on_components(case: ModelCase) -> None:
    model = case.model
    pts = _rays(20000, 1)
    pix, ok = model.project(pts)
    shape = (len(pts) // 4, 4) if len(pts) % 4 == 0 else (len(pts), 1)
    u, v, ok_xyz = model.project_xyz(*(pts[:, i].reshape(shape) for i in range(3)))
    assert u.shape == shape and ok_xyz.shape == shape and ok_xyz.dtype == bool
    u, v, ok_xyz = u.ravel(), v.ravel(), ok_xyz.ravel()
    # Identical validity except within round-off of the field limit or the image border.
    norm = np.linalg.norm(pts, axis=1)
    theta = np.arccos(np.clip(pts[:, 2] / np.where(norm > 0, norm, 1.0), -1.0, 1.0))
    edge = np.abs(theta - model.max_theta) < 1e-9
    edge |= (np.abs(pix[:, 0] + 0.5) < 1e-6) | (np.abs(pix[:, 0] - model.width + 0.5) < 1e-6)
    edge |= (np.abs(pix[:, 1] + 0.5) < 1e-6) | (np.abs(pix[:, 1] - model.height + 0.5) < 1e-6)
    assert np.array_equal(ok[~edge], ok_xyz[~edge])
    assert ok.sum() > 1000
    err = np.hypot(u[ok] - pix[ok, 0], v[ok] - pix[ok, 1])
    assert err.max() < 1e-9 * max(model.width, model.height)


def test_project_xyz_checks_shapes() -> None:
    from calibration.errors import ModelError

    with pytest.raises(ModelError, match="one shape"):
        CASES[0].model.project_xyz(np.zeros(3), np.zeros(3), np.zeros(4))


@pytest.mark.parametrize("case", [c for c in CASES if c.model.name == "scaramuzza"], ids=lambda c: c.id)
def test_scaramuzza_table_seed_converges_to_the_invpol_seeded_root(case: ModelCase) -> None:
    model = case.model
    assert isinstance(model, ScaramuzzaModel)
    pts = _rays(3 * model.SEED_TABLE_MIN_POINTS, 2)
    many, ok_many = model.project(pts)  # one call: table seed
    step = model.SEED_TABLE_MIN_POINTS // 2
    parts = [model.project(pts[i : i + step]) for i in range(0, len(pts), step)]  # invpol seed
    few = np.vstack([p for p, _ in parts])
    ok_few = np.concatenate([k for _, k in parts])
    assert np.array_equal(ok_many, ok_few) and ok_many.sum() > 1000
    assert np.abs(many[ok_many] - few[ok_few]).max() < 1e-8
    # The table is a good seed: after it one Newton step confirms almost every point.
    per_rad, coeffs = model._seed_table()
    assert all(c.shape == (model.SEED_TABLE_NODES,) for c in coeffs) and per_rad > 0


def test_cache_load_is_zero_copy_aligned_and_writable(tmp_path: Path) -> None:
    fisheye = create(
        "kannala_brandt", 320, 240, fx=72.0, fy=71.8, cx=160.2, cy=119.6,
        k1=0.02, k2=-0.01, k3=0.003, k4=-0.0005, fov_deg=190.0,
    )  # fmt: skip
    vpc = create("pinhole", 160, 120, fx=80.0, fy=80.0, cx=79.5, cy=59.5)
    R = rot_y(math.radians(40)) @ rot_x(math.radians(3))
    cache = LutCache(tmp_path)
    built = cache.get(fisheye, R, vpc)  # type: ignore[arg-type]
    data = built.path.read_bytes()
    (n,) = lut_cache._LEN.unpack_from(data, len(lut_cache.MAGIC))
    assert (len(lut_cache.MAGIC) + lut_cache._LEN.size + n) % 64 == 0, "payload starts aligned"
    lut = cache.load(built.key, (120, 160))
    assert lut is not None
    arrays = (lut.map_x, lut.map_y, lut.map1, lut.map2)
    base = lut.map_x.base
    assert all(a.base is base for a in arrays), "views into one read buffer"
    assert all(a.flags.aligned and a.flags.writeable and a.flags.c_contiguous for a in arrays)
    for name in ("map_x", "map_y", "map1", "map2", "valid"):
        assert np.array_equal(getattr(lut, name), getattr(built.lut, name)), name
    # The remap with loaded maps is the remap with built maps.
    img = (np.arange(240 * 320) % 251).astype(np.uint8).reshape(240, 320)
    assert np.array_equal(lut.remap(img), built.lut.remap(img))


@pytest.mark.parametrize("where", [0.0, 0.37, 0.999])
def test_cache_checksum_catches_one_flipped_bit_anywhere(tmp_path: Path, where: float) -> None:
    fisheye = create("equidistant", 200, 200, fx=60.0, fy=60.0, cx=99.5, cy=99.5, fov_deg=180.0)
    vpc = create("pinhole", 64, 48, fx=40.0, fy=40.0, cx=31.5, cy=23.5)
    cache = LutCache(tmp_path)
    first = cache.get(fisheye, np.eye(3), vpc)  # type: ignore[arg-type]
    data = bytearray(first.path.read_bytes())
    (n,) = lut_cache._LEN.unpack_from(data, len(lut_cache.MAGIC))
    start = len(lut_cache.MAGIC) + lut_cache._LEN.size + n
    pos = start + int(where * (len(data) - start - 1))
    data[pos] ^= 0x01
    first.path.write_bytes(bytes(data))
    assert cache.load(first.key) is None
    assert not first.path.exists()


def test_tune_allocator_is_idempotent() -> None:
    first = tune_allocator()
    assert isinstance(first, bool)
    assert tune_allocator() is first


@pytest.fixture(scope="module")
def shot() -> StereoShot:
    return plane_shot(5.0, scale=0.5, vpc=RectifiedPairConfig(width=320, height=240))


@pytest.fixture(scope="module")
def pipe(shot: StereoShot, lut_cache: Path) -> DepthPipeline:
    return DepthPipeline(
        shot.rig,
        RectifiedPairConfig(width=320, height=240),
        StereoParams(disparity_range=64),
        cache_dir=lut_cache,
    )


def test_pipeline_stages_are_process(pipe: DepthPipeline, shot: StereoShot) -> None:
    whole = pipe.process(shot.left, shot.right, seq=3, ts_ns=9)
    rect = pipe.rectify(shot.left, shot.right)
    staged = pipe.postprocess(pipe.match(rect), 3, 9)
    for name in ("depth", "disparity", "valid", "confidence", "left_rect", "right_rect"):
        assert np.array_equal(getattr(whole, name), getattr(staged, name), equal_nan=name != "valid"), name
    assert staged.timings_ms["total"] == pytest.approx(
        sum(v for k, v in staged.timings_ms.items() if k != "total")
    )
    vpc, gray = pipe.rectify_camera("left", cv2.cvtColor(shot.left, cv2.COLOR_GRAY2BGR))
    assert vpc.shape == (240, 320, 3) and gray.shape == (240, 320)


@pytest.mark.parametrize("stereo", [{}, {"temporal_alpha": 0.5}, {"subpixel": False, "median": 3}])
def test_banded_finish_is_one_pass(
    shot: StereoShot, lut_cache: Path, monkeypatch: pytest.MonkeyPatch, stereo: dict[str, float]
) -> None:
    """The finish stage in row bands across threads (refinement, median, confidence and depth
    with margins) gives what one pass over the whole frame gives, up to the box filters'
    summation order."""
    params = StereoParams(disparity_range=64, **stereo)  # type: ignore[arg-type]

    def finish(pool: bool) -> list[DepthFrame]:
        if not pool:
            monkeypatch.setattr(finish_module, "refine_pool", lambda: None)
        pipe = DepthPipeline(
            shot.rig, RectifiedPairConfig(width=320, height=240), params, cache_dir=lut_cache
        )
        rect = pipe.rectify(shot.left, shot.right)
        # Two frames: the second one through the temporal filter's history when it is on.
        return [pipe.postprocess(pipe.match(rect), i, 0) for i in range(2)]

    banded, whole = finish(True), finish(False)
    assert finish_module._REFINE_THREADS >= 2, "this machine has one core: nothing is banded"
    for b, w in zip(banded, whole, strict=True):
        assert np.array_equal(b.valid, w.valid)
        assert b.valid.mean() > 0.5
        for name in ("disparity", "depth", "confidence"):
            got, want = getattr(b, name), getattr(w, name)
            assert (got is None) == (want is None), name
            if want is not None:
                assert np.array_equal(np.isnan(got), np.isnan(want)), name
                err = np.abs(got - want)
                if name == "confidence":  # σ from float32 running sums of tiny residuals
                    assert np.nanmax(err) < 0.01 and np.nanmean(err) < 1e-4
                else:
                    assert np.nanmax(err) < 1e-4 * max(1.0, float(np.nanmax(np.abs(want)))), name
        assert set(b.timings_ms) == set(w.timings_ms)


class _ListSource:
    """Pairs from a list, then nothing (a PairSource for the worker)."""

    def __init__(self, pairs: list[FramePair]) -> None:
        self._pairs = list(pairs)
        self._lock = threading.Lock()
        self.undecodable: list[tuple[str, int, str]] = []

    def report_undecodable(self, frame: Frame, err: Exception) -> None:
        self.undecodable.append((frame.camera, frame.seq, str(err)))

    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None:
        with self._lock:
            if self._pairs:
                return self._pairs.pop(0)
        time.sleep(min(timeout_s, 0.01))
        return None


def _jpeg_pair(shot: StereoShot, seq: int, corrupt: bool = False) -> FramePair:
    frames = []
    for cam, img in (("left", shot.left), ("right", shot.right)):
        data = encode(img, ".jpg", 95)
        if corrupt and cam == "right":
            data = data[: len(data) // 3]
        frames.append(Frame(cam, seq, seq * 1000, "jpeg", time.monotonic_ns(), raw=data))
    return FramePair(frames[0], frames[1])


def test_pipelined_worker_publishes_every_pair_in_order_and_survives_a_bad_one(
    pipe: DepthPipeline, shot: StereoShot
) -> None:
    pairs = [_jpeg_pair(shot, k, corrupt=k == 2) for k in range(6)]
    store = ResultStore()
    seen: list[int] = []
    source = _ListSource(pairs)
    worker = DepthWorker(source, pipe, store, on_result=lambda r, t: seen.append(r.seq), poll_s=0.02)
    worker.start()
    try:
        wait_for(lambda: len(seen) >= 5, 60.0, "five published pairs")
        stats = worker.stats()
        assert worker.is_alive()
    finally:
        worker.stop()
    assert not worker.is_alive()
    assert seen == [0, 1, 3, 4, 5], "in order, the corrupt pair dropped"
    # The frame that did not decode is the camera's fault, reported to the source, not the worker's.
    assert [(cam, seq) for cam, seq, _ in source.undecodable] == [("right", 2)]
    assert "frame 2" in source.undecodable[0][2] and "truncated" in source.undecodable[0][2]
    assert stats.counters["errors"] == 0 and stats.last_error is None
    assert set(stats.stage_ms) >= {"decode", "remap", "match", "refine", "filters", "depth", "total"}
    assert stats.stage_ms["decode"] > 0  # the worker decoded (the frames came undecoded)
    latest = store.latest
    assert latest is not None and latest.seq == 5
    # The worker's result is the pipeline's result for that pair.
    direct = pipe.process(pairs[5].left.image, pairs[5].right.image)
    assert np.array_equal(latest.frame.depth, direct.depth, equal_nan=True)


class _GatedSource(_ListSource):
    """One pair per ``allow()``."""

    def __init__(self, pairs: list[FramePair]) -> None:
        super().__init__(pairs)
        self._gate = threading.Semaphore(0)

    def allow(self) -> None:
        self._gate.release()

    def next_pair(self, timeout_s: float, *, newest: bool = True) -> FramePair | None:
        if not self._gate.acquire(timeout=timeout_s):
            return None
        return super().next_pair(timeout_s, newest=newest)


def test_worker_prefetches_only_the_encodings_clients_asked_for(
    pipe: DepthPipeline, shot: StereoShot
) -> None:
    source = _GatedSource([_jpeg_pair(shot, k) for k in range(4)])
    store = ResultStore()
    made: list[tuple[str, int]] = []

    def producer(key: str):  # type: ignore[no-untyped-def]
        def produce(result) -> bytes:  # type: ignore[no-untyped-def]
            made.append((key, result.index))
            return f"{key}:{result.index}".encode()

        return produce

    worker = DepthWorker(
        source, pipe, store, prefetch={"asked": producer("asked"), "never": producer("never")}, poll_s=0.02
    )

    def publish_next(index: int) -> None:
        source.allow()
        assert store.wait_newer(index - 1, 60.0) is not None

    worker.start()
    try:
        publish_next(1)
        first = store.latest
        assert first is not None and first.index == 1
        assert made == []  # nothing asked yet: nothing made
        # A client asks for "asked" on result 1 (made on its request path).
        assert first.cache.get("asked", lambda: b"client") == b"client"
        publish_next(2)
        second = store.latest
        assert second is not None and second.index == 2
        wait_for(
            lambda: second.cache.peek("asked") is not None, 30, "the prefetch"
        )  # follows the publication
        assert second.cache.peek("asked") == b"asked:2"
        assert second.cache.peek("never") is None
        publish_next(3)
        wait_for(lambda: len(made) == 2, 30, "the second prefetch")
        assert made == [("asked", 2), ("asked", 3)]
    finally:
        worker.stop()
