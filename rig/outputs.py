"""What ``rig process`` writes for one recording, and which of its pairs are complete.

Layout of an output directory::

    vpc.json              the rectified pair: projection, width, height, fx, fy, cx, cy,
                          baseline_m, R_rig_rect
    run.json              what made the files: the recording, the lookup tables' content keys,
                          the rectified pair's and stereo settings and the products written
    range/NNNNNN.png      uint16 range in mm along each left pixel's ray, 0 = invalid
    depth/NNNNNN.png      the pinhole pair's product: uint16 depth in mm along its z, 0 = invalid
    left/NNNNNN.png       the left and right rectified images (gray or BGR like the recording)
    right/NNNNNN.png
    cloud/NNNNNN.ply      with ``ply``: the points in the rig frame, coloured from the left view
    preview/NNNNNN.png    with ``preview``: the left view beside colour depth (lat-lon: range)
                          and its colour bar in metres (rig.colormap)

Every file is written atomically (:func:`calibration.atomic.write_atomic`: a temporary, fsynced, renamed
into place), so a file that exists is complete, and a pair is complete when every product of it
exists. ``--resume`` (:meth:`OutputLayout.prepare` with ``resume``) trusts those files only when
``run.json`` names the same settings and the same recording (:func:`recording_identity`: its
pair index and its first and last frames, wherever it lies now); a run without it first removes
what an earlier run wrote for the pairs it is about to process, so a crashed run never leaves two
runs' files mixed.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import struct
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from calibration.atomic import fsync_directory, is_temporary, sweep_temporaries, write_atomic
from rig.capture.recorded import RecordedPairs
from rig.colormap import DepthColors
from rig.depth import depth_to_png_mm, ply_bytes
from rig.errors import ConfigError, OutputError, PipelineError, RigError
from rig.pipeline import DepthFrame, DepthPipeline

__all__ = [
    "BASE_PRODUCTS",
    "PRODUCTS",
    "RUN_FILE",
    "VPC_FILE",
    "OutputLayout",
    "Product",
    "depth_preview",
    "png_bytes",
    "recording_identity",
    "run_settings",
]

RUN_FILE = "run.json"
VPC_FILE = "vpc.json"
RUN_FORMAT = 1
_NO_SPACE = {errno.ENOSPC, errno.EDQUOT}


def png_bytes(image: NDArray[Any]) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise PipelineError(f"PNG encoding failed for an image of shape {image.shape}")
    return bytes(buf.tobytes())


@dataclass(frozen=True)
class Product:
    """One kind of output file: its directory, file suffix and encoder (of a pair's
    ``(pipeline, frame)``; a ring's products, :mod:`rig.ring_outputs`, of its
    ``(rig pipeline, rig frame)``)."""

    name: str
    suffix: str
    encode: Callable[[Any, Any], bytes]

    def file_name(self, seq: int) -> str:
        return f"{seq:06d}{self.suffix}"


def _cloud(pipeline: DepthPipeline, frame: DepthFrame) -> bytes:
    return ply_bytes(*pipeline.point_cloud(frame))


PRODUCTS: dict[str, Product] = {
    p.name: p
    for p in (
        Product("range", ".png", lambda _, f: png_bytes(depth_to_png_mm(f.range))),
        Product("depth", ".png", lambda _, f: png_bytes(depth_to_png_mm(f.depth))),
        Product("left", ".png", lambda _, f: png_bytes(f.left_rect)),
        Product("right", ".png", lambda _, f: png_bytes(f.right_rect)),
        Product("cloud", ".ply", _cloud),
        Product("preview", ".png", lambda _, f: png_bytes(depth_preview(f.left_rect, f.depth))),
    )
}
BASE_PRODUCTS = ("range", "left", "right")


def run_settings(pipeline: DepthPipeline, products: Sequence[str]) -> dict[str, Any]:
    """Everything that decides the bytes of the output files (``run.json`` without the
    recording): the tables' content keys (calibration and VPC), VPC, stereo, products."""
    return {
        "format": RUN_FORMAT,
        "luts": {name: pipeline.lut_info[name].key for name in pipeline.names},
        "vpc": pipeline.pair_config.model_dump(mode="json"),
        "stereo": pipeline.stereo.model_dump(mode="json"),
        "products": list(products),
    }


def recording_identity(recording: RecordedPairs) -> str:
    """What tells a recording from another, wherever it lies: a SHA-256 of its index (each
    set's seq and every camera's capture time) and of the bytes of its first and last pairs' frames (two
    renders of one scene can share the index)."""
    digest = hashlib.sha256()
    for pair in recording.pairs:
        digest.update(struct.pack(f"<q{len(pair.stamps)}q", pair.seq, *pair.stamps))
    for pair in {id(p): p for p in (recording.pairs[:1] + recording.pairs[-1:])}.values():
        for camera in recording.cameras:
            try:
                stored = recording.read_frame(pair, camera)
            except RigError:
                digest.update(b"unreadable")
                continue
            data = stored.raw if stored.raw is not None else stored.image
            digest.update(b"" if data is None else bytes(data))
    return digest.hexdigest()


def _differing_key(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> str | None:
    """The first key (dotted) whose value differs between two documents, or None."""
    for key in sorted(set(a) | set(b)):
        va, vb = a.get(key), b.get(key)
        if isinstance(va, dict) and isinstance(vb, dict):
            inner = _differing_key(va, vb, f"{prefix}{key}.")
            if inner is not None:
                return inner
        elif va != vb:
            return f"{prefix}{key}"
    return None


class OutputLayout:
    """The output directory ``root`` of one recording with ``products`` (names of ``catalog``,
    by default a pair's :data:`PRODUCTS`); ``fsync`` forces each file to the disk before it is
    named."""

    def __init__(
        self,
        root: str | Path,
        products: Sequence[str] = BASE_PRODUCTS,
        *,
        fsync: bool = True,
        catalog: Mapping[str, Product] = PRODUCTS,
    ):
        unknown = [p for p in products if p not in catalog]
        if unknown:
            known = ", ".join(catalog)
            raise ConfigError(f"unknown output product(s) {', '.join(unknown)} (known: {known})")
        self.root = Path(root)
        self.catalog = dict(catalog)
        self.products = [catalog[p] for p in products]
        self.fsync = fsync

    def path(self, product: str, seq: int) -> Path:
        return self.root / product / self.catalog[product].file_name(seq)

    # ----- before a run ------------------------------------------------------------------------
    def prepare(
        self,
        pipeline: DepthPipeline,
        recording: Path,
        seqs: Iterable[int],
        *,
        resume: bool,
        recording_id: str | None = None,
    ) -> set[int]:
        """Make the directories and write ``vpc.json`` and ``run.json``; returns the pairs of
        ``seqs`` already complete (``resume`` with the same settings and recording:
        ``recording_id`` is its :func:`recording_identity`), after removing what an earlier run
        left for the others (see the module doc). ConfigError when ``resume`` meets a
        ``run.json`` of other settings or another recording; OutputError/DiskFullError when the
        directory cannot be written."""
        settings = run_settings(pipeline, [p.name for p in self.products])
        return self.prepare_files(
            settings,
            {VPC_FILE: pipeline.pair.as_json()},
            recording,
            seqs,
            resume=resume,
            recording_id=recording_id,
        )

    def prepare_files(
        self,
        settings: dict[str, Any],
        documents: Mapping[str, dict[str, Any]],
        recording: Path,
        seqs: Iterable[int],
        *,
        resume: bool,
        recording_id: str | None = None,
    ) -> set[int]:
        """:meth:`prepare` with the run's ``settings`` (``run.json`` without the recording)
        and the JSON ``documents`` to write beside it (file name → content) given."""
        seqs = list(seqs)
        source = {"recording": str(recording.resolve())}
        if recording_id is not None:
            source["recording_id"] = recording_id
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            trusted = resume and self._same_run(settings, source)
            names = self._present()
            complete = self._complete(seqs, names) if trusted else set()
            self._remove(set(seqs) - complete, names)
            for product in self.products:
                (self.root / product.name).mkdir(exist_ok=True)
            run = {**source, **settings}
            for name, doc in documents.items():
                self._write_json(name, doc)
            self._write_json(RUN_FILE, run)
            fsync_directory(self.root)
        except OSError as err:
            raise self.write_error(err, self.root) from err
        return complete

    def _same_run(self, settings: dict[str, Any], source: dict[str, str]) -> bool:
        """Whether the existing ``run.json`` names ``settings`` and the recording of ``source``
        (False when there is none); ConfigError when it names others."""
        path = self.root / RUN_FILE
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return False
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise ConfigError(f"{path}: unreadable ({err}); rerun without --resume to start over") from err
        doc = doc if isinstance(doc, dict) else {}
        # An earlier run.json without the identity (older versions) is judged by the path.
        key = "recording_id" if "recording_id" in doc and "recording_id" in source else "recording"
        if doc.get(key) != source[key]:
            raise ConfigError(
                f"{path}: the files there were made from another recording ({doc.get('recording')}); "
                "rerun without --resume to replace them, or write to another --out"
            )
        earlier = {k: v for k, v in doc.items() if k not in ("recording", "recording_id")}
        differing = _differing_key(earlier, settings)
        if differing is not None:
            raise ConfigError(
                f"{path}: the files there were made with other settings ({differing} differs); rerun "
                "without --resume to replace them, or write to another --out"
            )
        return True

    def _present(self) -> dict[str, set[str]]:
        """The finished file names in each product directory (every product: a run without
        ``--ply`` still removes an earlier run's clouds of the pairs it redoes)."""
        names: dict[str, set[str]] = {}
        for name in self.catalog:
            directory = self.root / name
            sweep_temporaries(directory)
            try:
                names[name] = {e.name for e in os.scandir(directory) if not is_temporary(e.name)}
            except FileNotFoundError:
                names[name] = set()
        return names

    def _complete(self, seqs: Sequence[int], names: dict[str, set[str]]) -> set[int]:
        return {s for s in seqs if all(p.file_name(s) in names[p.name] for p in self.products)}

    def _remove(self, seqs: set[int], names: dict[str, set[str]]) -> None:
        for name, present in names.items():
            product = self.catalog[name]
            for seq in seqs:
                if product.file_name(seq) in present:
                    (self.root / name / product.file_name(seq)).unlink(missing_ok=True)

    def _write_json(self, name: str, doc: dict[str, Any]) -> None:
        write_atomic(self.root / name, json.dumps(doc, indent=2).encode() + b"\n", fsync=self.fsync)

    # ----- during and after a run --------------------------------------------------------------
    def write(self, pipeline: Any, frame: Any) -> None:
        """Every product of one processed pair (``pipeline``, ``frame``: what the products
        encode, :class:`Product`), each file atomically."""
        for product in self.products:
            data = product.encode(pipeline, frame)
            path = self.root / product.name / product.file_name(frame.seq)
            try:
                write_atomic(path, data, fsync=self.fsync)
            except OSError as err:
                raise self.write_error(err, path) from err

    def sink(self, pipeline: DepthPipeline) -> Callable[[object, DepthFrame], None]:
        """This directory as a sink of the staged executor (:data:`rig.staged.Sink`): each pair's
        products, made with ``pipeline``'s geometry, written by :meth:`write`."""
        return lambda _pair, frame: self.write(pipeline, frame)

    def sync(self) -> None:
        """Make the renames of the files written so far durable (once per batch of pairs)."""
        for product in self.products:
            fsync_directory(self.root / product.name)

    def close(self) -> None:
        """After the last writer is done: remove any temporary a crashed writer left, sync."""
        for product in self.products:
            sweep_temporaries(self.root / product.name)
        self.sync()

    def write_error(self, err: OSError, where: Path) -> OutputError:
        if err.errno in _NO_SPACE:
            return OutputError(
                f"{self.root}: disk full (writing {where.name}); every pair written so far is complete: "
                "free some space and rerun with --resume"
            )
        return OutputError(f"{where}: cannot write output ({err.strerror or err})")


def depth_preview(left_rect: NDArray[Any], depth: NDArray[Any]) -> NDArray[np.uint8]:
    """Left rectified image beside its depth (lat-lon: range) in colour and a colour bar in metres:
    the service's colour scale (:class:`rig.colormap.DepthColors`, log between its default near and
    far, the same colours on every frame; black = no depth). (H, 2W + legend, 3) uint8 BGR."""
    colors = DepthColors()
    left = left_rect if left_rect.ndim == 3 else cv2.cvtColor(left_rect, cv2.COLOR_GRAY2BGR)
    return np.hstack([left, colors.colorize(depth), colors.legend(depth.shape[0])])
