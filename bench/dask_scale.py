"""``rig process`` over several recordings: in this process against a Dask LocalCluster of 1 and
of 2 worker processes on this machine.

Input: ``--recordings`` copies (symbolic links) of the MJPEG recording of :mod:`bench.process`,
each processed into its own output directory as ``rig process 'recs/*' --out DIR`` does.

Each mode runs :func:`rig.process.process_recordings` over all of them: **here** (no scheduler:
one recording after another through the staged pipeline), and on a LocalCluster of **1** and of
**2** workers (one thread each; each task a chunk of ``--chunk-pairs`` pairs running the same
staged pipeline in the worker). Both clusters are started once, before the windows (their start
time is reported apart), and stay up; a run's wall time includes connecting, planning, shipping
the lookup tables to the workers (once per run), the tasks and their results. Pairs per second =
pairs written / wall time. The modes run in rotating order, round after round (``--rounds``), and
each cluster run is compared with the in-process run of its round.

Run: ``flock /tmp/rig-bench.lock .venv/bin/python -m bench.dask_scale`` (``--quick``: seconds).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import pickle
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from rich.table import Table

from bench.common import (
    add_common_arguments,
    console,
    finish,
    machine_info,
    median,
    percentile,
    print_machine,
)
from bench.process import bench_input, run_ours
from bench.recordings import MjpegSpec
from rig.cluster import local_cluster
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams

__all__ = ["main"]

MODES = ("here", "1 worker", "2 workers")


def _local_cluster(workers: int) -> tuple[Any, float]:
    """``rig process --scheduler local``'s cluster of ``workers`` workers; its start time (s)."""
    t0 = time.perf_counter()
    cluster = local_cluster(workers)
    return cluster, time.perf_counter() - t0


def _bytes_under(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _close(cluster: Any) -> None:
    """Close ``cluster`` without its closing messages (workers retired, comms closed): the
    cluster restores the loggers' levels it silenced before it logs them."""
    for name in list(logging.root.manager.loggerDict):
        if name.startswith("distributed"):
            logging.getLogger(name).setLevel(logging.ERROR)
    cluster.close()


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.dask_scale", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--pairs", type=int, default=None, help="pairs per recording")
    parser.add_argument("--recordings", type=int, default=None, help="recordings processed per run")
    parser.add_argument("--rounds", type=int, default=None, help="rounds of the three modes")
    parser.add_argument("--chunk-pairs", type=int, default=None, help="pairs per task")
    args = parser.parse_args(argv)
    quick = args.quick
    spec = MjpegSpec(frames=4, views=1, scale=0.25) if quick else MjpegSpec(frames=args.pairs or 24)
    w, h, disp = (160, 120, 32) if quick else (640, 480, 128)
    n_recordings = args.recordings or (2 if quick else 4)
    rounds = args.rounds or args.repeat or (1 if quick else 4)
    chunk = args.chunk_pairs or (2 if quick else 12)
    info = machine_info()
    print_machine(info, "rig process over recordings: this process vs a Dask LocalCluster")
    runs: dict[str, list[float]] = {m: [] for m in MODES}
    out_bytes = math.nan
    with tempfile.TemporaryDirectory(
        prefix="rig-bench-dask-", dir=os.environ.get("RIG_BENCH_SCRATCH")
    ) as tmp:
        data = bench_input(
            spec, RectifiedPairConfig(width=w, height=h), StereoParams(disparity_range=disp), Path(tmp)
        )
        recs = Path(tmp) / "recs"
        recs.mkdir()
        recordings = []
        for k in range(n_recordings):
            (recs / f"rec{k}").symlink_to(data.recording, target_is_directory=True)
            recordings.append(recs / f"rec{k}")
        total = n_recordings * data.pairs
        in_bytes = sum(_bytes_under(data.recording / cam) for cam in ("left", "right")) / data.pairs
        lut_bytes = len(pickle.dumps(data.pipeline.lut_info))  # as scattered to the workers
        console.print(
            f"input: {n_recordings} × {data.recording} ({data.pairs} pairs each, {total} in all); "
            f"VPC {w}×{h}, {disp} disparities; {chunk} pairs per task; {rounds} round(s) of the modes, "
            "in rotating order"
        )
        (c1, start1), (c2, start2) = _local_cluster(1), _local_cluster(2)
        schedulers = {"here": None, "1 worker": c1.scheduler_address, "2 workers": c2.scheduler_address}
        try:
            run_ours(data, recordings[:1], Path(tmp) / "warm")  # page cache and pipeline warm
            for r in range(rounds):
                for i in range(len(MODES)):
                    mode = MODES[(r + i) % len(MODES)]
                    out = Path(tmp) / f"out-{r}-{i}"
                    run = run_ours(data, recordings, out, schedulers[mode], chunk)
                    if run.written != total or run.failures:
                        raise SystemExit(
                            f"{mode}: {run.written} of {total} pairs written, {run.failures} failed"
                        )
                    runs[mode].append(run.written / run.wall_s)
                    out_bytes = _bytes_under(out) / total
                    shutil.rmtree(out)
        finally:
            _close(c1)
            _close(c2)
    ratios = {m: [runs[m][k] / runs["here"][k] for k in range(rounds)] for m in MODES[1:]}
    table = Table(title=f"rig process over {n_recordings} recordings ({total} pairs): pairs/s")
    for col in ("mode", "pairs/s (median)", "× this process (IQR)", "cluster start s"):
        table.add_column(col, justify="right")
    table.add_row("this process", f"{median(runs['here']):.2f}", "1", "")
    for mode, start in (("1 worker", start1), ("2 workers", start2)):
        rr = ratios[mode]
        iqr = f"({percentile(rr, 25):.2f}–{percentile(rr, 75):.2f})"
        table.add_row(mode, f"{median(runs[mode]):.2f}", f"{median(rr):.2f} {iqr}", f"{start:.1f}")
    console.print(
        f"per pair: {in_bytes / 1e6:.2f} MB read (two JPEG frames), {out_bytes / 1e6:.2f} MB written; "
        f"lookup tables shipped once per worker: {lut_bytes / 1e6:.1f} MB"
    )
    console.print(
        "pairs/s = pairs written / wall time of a whole run (connecting, planning, shipping the tables, "
        "the tasks); × this process = against the in-process run of the same round"
    )
    return finish(
        "dask_scale",
        info,
        {
            "spec": spec.__dict__,
            "vpc": [w, h],
            "disparities": disp,
            "recordings": n_recordings,
            "pairs": total,
            "chunk_pairs": chunk,
            "rounds": rounds,
            "pairs_per_s": {m: median(v) for m, v in runs.items()},
            "ratio": {m: median(v) for m, v in ratios.items()},
            "cluster_start_s": {"1 worker": start1, "2 workers": start2},
            "bytes_per_pair": {"read": in_bytes, "written": out_bytes},
            "lut_bytes": lut_bytes,
            "runs": {"pairs_per_s": runs, "ratio": ratios},
        },
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
