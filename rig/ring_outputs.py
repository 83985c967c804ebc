"""What ``rig process`` writes for one recording of a rig of N cameras (docs/design.md, "rig
process output")::

    <A>-<B>/                 each stereo pair: exactly the two-camera layout (rig.outputs): range/,
                             left/, right/ (depth/ for the pinhole pair, preview/ with --preview),
                             vpc.json, run.json
    panorama/NNNNNN.png      uint16 range in mm from the panorama's origin along each pixel's ray,
                             0 = invalid (rig.depth.depth_to_png_mm, the one uint16 rule)
    panorama.json            the panorama: size, resolution, R_rig_pano, origin, the pairs
                             (rig.panorama.PanoramaSpec.as_json)
    cloud/NNNNNN.ply         with --ply: the fused cloud, the panorama's points in the rig frame
    run.json                 what made the panorama and the cloud: the recording, every pair's
                             settings (each pair's run.json's), the panorama's, the products

Every file is written atomically; a set is complete when every pair's files and the panorama's
exist, and ``--resume`` trusts them only when every ``run.json`` names the same settings and
recording (:class:`rig.outputs.OutputLayout`'s rules, per directory).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from rig.depth import depth_to_png_mm, ply_bytes
from rig.outputs import RUN_FORMAT, OutputLayout, Product, png_bytes, run_settings
from rig.rig_depth import RecordedSet
from rig.rig_pipeline import RigFrame, RigPipeline

__all__ = ["PANORAMA_FILE", "RING_PRODUCTS", "RingLayout", "panorama_png", "ring_settings"]

PANORAMA_FILE = "panorama.json"


def panorama_png(frame: RigFrame) -> bytes:
    """The panorama as ``panorama/NNNNNN.png``: uint16 mm, 0 = invalid."""
    return png_bytes(depth_to_png_mm(frame.panorama.range))


def _cloud(rig: RigPipeline, frame: RigFrame) -> bytes:
    return ply_bytes(*rig.point_cloud(frame))


#: The ring's own products, beside its pairs' directories.
RING_PRODUCTS: dict[str, Product] = {
    p.name: p
    for p in (
        Product("panorama", ".png", lambda _, f: panorama_png(f)),
        Product("cloud", ".ply", _cloud),
    )
}


def ring_settings(rig: RigPipeline, pair_products: Sequence[str], products: Sequence[str]) -> dict[str, Any]:
    """The ring's ``run.json`` without the recording: every pair's settings, the panorama's and
    the ring's products."""
    return {
        "format": RUN_FORMAT,
        "pairs": {label: run_settings(p, pair_products) for label, p in rig.pipelines.items()},
        "panorama": {"px_per_deg": rig.panorama.px_per_deg},
        "products": list(products),
    }


class RingLayout:
    """The output directory ``root`` of one recording of ``rig``'s cameras: a pair's
    :class:`~rig.outputs.OutputLayout` per pair with ``products`` (all but ``cloud``), and the
    panorama (and with ``cloud`` among ``products``, the fused cloud) beside them."""

    def __init__(self, root: str | Path, rig: RigPipeline, products: Sequence[str], *, fsync: bool = True):
        self.root = Path(root)
        self.rig = rig
        pair_products = [p for p in products if p != "cloud"]
        own = ["panorama", *(["cloud"] if "cloud" in products else [])]
        self.pairs = {
            label: OutputLayout(self.root / label, pair_products, fsync=fsync) for label in rig.labels
        }
        self.own = OutputLayout(self.root, own, fsync=fsync, catalog=RING_PRODUCTS)
        self._settings = ring_settings(rig, pair_products, own)

    def prepare(
        self, recording: Path, seqs: Iterable[int], *, resume: bool, recording_id: str | None = None
    ) -> set[int]:
        """Every directory made ready (:meth:`OutputLayout.prepare`); the sets of ``seqs``
        complete in all of them."""
        seqs = list(seqs)
        complete = set(seqs)
        for label, layout in self.pairs.items():
            pipeline = self.rig.pipelines[label]
            complete &= layout.prepare(pipeline, recording, seqs, resume=resume, recording_id=recording_id)
        documents = {PANORAMA_FILE: self.rig.panorama.as_json(self.rig.labels)}
        complete &= self.own.prepare_files(
            self._settings, documents, recording, seqs, resume=resume, recording_id=recording_id
        )
        return complete

    def write(self, frame: RigFrame) -> None:
        """Every file of one set: each pair's, then the panorama's."""
        for label, layout in self.pairs.items():
            layout.write(self.rig.pipelines[label], frame.pairs[label])
        self.own.write(self.rig, frame)

    def sink(self) -> Callable[[RecordedSet, RigFrame], None]:
        """This directory as the sink of :func:`rig.rig_depth.process_sets`."""
        return lambda _set, frame: self.write(frame)

    def sync(self) -> None:
        for layout in [*self.pairs.values(), self.own]:
            layout.sync()

    def close(self) -> None:
        for layout in [*self.pairs.values(), self.own]:
            layout.close()
