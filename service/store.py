"""The latest depth result and its encodings, shared by every HTTP client.

The worker publishes one immutable :class:`PublishedResult` per processed pair (a reference swap
under a lock: it never waits for clients). Each response body (PNG, npy, JPEG, PLY …) is made
lazily the first time a client asks for it and cached on that result, so N clients asking for
the same frame cost one encode: a lock per key makes the others wait for the first one's bytes
instead of encoding again. A new frame brings a new, empty cache; old ones die with their result.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from rig.capture.frame import Frame, FrameSet
from rig.panorama import PanoramaFrame
from rig.pipeline import DepthFrame
from rig.rig_pipeline import RigFrame, RigPipeline
from service.errors import ConfidenceOff

__all__ = [
    "EncodeCache",
    "EncodeCounter",
    "PublishedResult",
    "RectifiedRenderer",
    "ResultStore",
    "RingResult",
]


class EncodeCounter:
    """Counts encodes per kind (the part of the key before ``:``); thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}

    def add(self, key: str) -> None:
        kind = key.split(":", 1)[0]
        with self._lock:
            self._counts[kind] = self._counts.get(kind, 0) + 1

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)


class EncodeCache:
    """Bytes per key, each produced at most once (a lock per key; see module doc)."""

    def __init__(self, counter: EncodeCounter | None = None) -> None:
        self._counter = counter
        self._guard = threading.Lock()
        self._locks: dict[str, threading.Lock] = {}
        self._bytes: dict[str, bytes] = {}

    def peek(self, key: str) -> bytes | None:
        """The cached bytes, or None (lock-free read: dict lookups are atomic)."""
        return self._bytes.get(key)

    def get(self, key: str, produce: Callable[[], bytes]) -> bytes:
        cached = self._bytes.get(key)
        if cached is not None:
            return cached
        with self._guard:
            lock = self._locks.setdefault(key, threading.Lock())
        with lock:
            cached = self._bytes.get(key)
            if cached is None:
                cached = produce()
                self._bytes[key] = cached
                if self._counter is not None:
                    self._counter.add(key)
            return cached


class RingResult:
    """What a rig of N cameras adds to a published result: every pair's depth by its name
    (``"A-B"``), the set's raw frames, and the panorama, fused from the pairs the first time it is
    asked for (once per result, whoever asks: the fusion costs more than the pairs' matching, so
    the worker never waits for it)."""

    def __init__(self, pipeline: RigPipeline, frames: FrameSet, pairs: dict[str, DepthFrame]) -> None:
        self.pipeline = pipeline
        self.frames = frames
        self.pairs = pairs
        self._panorama: PanoramaFrame | None = None
        self._lock = threading.Lock()

    def panorama(self) -> PanoramaFrame:
        if self._panorama is None:
            with self._lock:
                if self._panorama is None:
                    self._panorama = self.pipeline.fuse(self.pairs)
        return self._panorama

    def rig_frame(self) -> RigFrame:
        """The set as :class:`~rig.rig_pipeline.RigFrame` (the panorama fused if not yet)."""
        first = next(iter(self.pairs.values()))
        return RigFrame(first.seq, first.ts_ns, self.pairs, self.panorama())


RectifiedRenderer = Callable[[str, Frame], NDArray[np.uint8]]
"""``(camera, raw frame) → that camera's VPC image`` from the frame's full (colour) image."""


@dataclass(frozen=True, eq=False)
class PublishedResult:
    """One processed pair. ``index`` counts published results (1, 2, …); ``seq``/``ts_ns`` are
    the pair's (left camera's); ``left``/``right`` the raw frames as the cameras delivered them;
    ``published_ns`` when the worker published it (time.monotonic_ns), ``age_ms`` the time from the
    later frame's arrival to then. ``render_rectified`` makes the
    colour VPC images on request (:meth:`rect_image`). A rig of N cameras: ``frame``, ``left``
    and ``right`` are its first pair's, and ``ring`` holds every pair and the panorama."""

    index: int
    frame: DepthFrame
    left: Frame
    right: Frame
    published_ns: int
    age_ms: float
    cache: EncodeCache = field(default_factory=EncodeCache)
    render_rectified: RectifiedRenderer | None = None
    ring: RingResult | None = None
    # Made on request and kept with the result (carried over by dataclasses.replace).
    _rect_images: dict[str, NDArray[np.uint8]] = field(default_factory=dict, repr=False)
    _rect_locks: dict[str, threading.Lock] = field(
        default_factory=lambda: {"left": threading.Lock(), "right": threading.Lock()}, repr=False
    )

    def __post_init__(self) -> None:
        # Shared read-only by every client thread: make accidental writes fail loudly. (Not the
        # disparity: the pipeline's temporal filter keeps it as its state.)
        for arr in (self.frame.depth, self.frame.valid, self.frame.left_rect, self.frame.right_rect):
            arr.setflags(write=False)

    @property
    def seq(self) -> int:
        return self.frame.seq

    @property
    def ts_ns(self) -> int:
        return self.frame.ts_ns

    def raw_frame(self, camera: str) -> Frame:
        return self.left if camera == "left" else self.right

    def confidence(self) -> NDArray[np.float32]:
        """The frame's confidence map (H, W) float32 in [0, 1], 0 where invalid; raises
        :class:`ConfidenceOff` when the frame was made without one."""
        if self.frame.confidence is None:
            raise ConfidenceOff(
                'confidence is off: PATCH /config {"stereo": {"confidence": true}} turns it on'
            )
        return self.frame.confidence

    def rect_image(self, camera: str) -> NDArray[np.uint8]:
        """``camera``'s (``left``/``right``) VPC image as the camera sees it: colour for colour
        cameras. The worker computes depth from luma only (``frame.left_rect`` is gray); this
        image is made from the raw frame by ``render_rectified`` when first asked for, once per
        result whoever asks, and read-only. Without a renderer, the frame's own VPC image."""
        if self.render_rectified is None:
            return self.frame.left_rect if camera == "left" else self.frame.right_rect
        image = self._rect_images.get(camera)
        if image is not None:
            return image
        with self._rect_locks[camera]:
            image = self._rect_images.get(camera)
            if image is None:
                image = self.render_rectified(camera, self.raw_frame(camera))
                image.setflags(write=False)
                self._rect_images[camera] = image
            return image

    def valid_fraction(self) -> float:
        return float(np.count_nonzero(self.frame.valid)) / max(1, self.frame.valid.size)


class ResultStore:
    """Holds the newest :class:`PublishedResult`; readers never block the publisher for long."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._latest: PublishedResult | None = None
        self.counter = EncodeCounter()

    def new_cache(self) -> EncodeCache:
        return EncodeCache(self.counter)

    def publish(self, result: PublishedResult) -> None:
        with self._cond:
            self._latest = result
            self._cond.notify_all()

    @property
    def latest(self) -> PublishedResult | None:
        return self._latest

    def wait_newer(self, index: int, timeout_s: float) -> PublishedResult | None:
        """The latest result if its index is above ``index``, waiting up to ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._latest is None or self._latest.index <= index:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return self._latest
