"""Start-up time of ``rig serve``: launch → first depth frame (docs/performance.md, "Start-up").

Launches the real command in a child process and polls ``/readyz`` (200 once a depth frame has
been published) from the moment of launch. Cases:

* **warm** — LUT cache and demo recording cached (the usual restart);
* **cold LUTs** — a fresh ``RIG_CACHE_DIR``: both tables are built;
* **cold, with render** — a fresh user cache dir (``XDG_CACHE_HOME``) as well: the demo room is
  rendered first (once per machine in real life; ``--demo`` only).

For reference, ``imports`` is the time for ``python -c 'import cli.main, service.serve'`` (the Python
start-up and the import of numpy, OpenCV, FastAPI, uvicorn... that every launch pays).
Each case's figure is the median of ``--repeat`` launches (the render case: ``--render-repeat``).

Run: ``.venv/bin/python -m bench.startup`` (``--quick``: a small recording, no render).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rich.table import Table

from bench.common import add_common_arguments, console, finish, machine_info, median, print_machine
from bench.service_proc import REPO, ServiceProcess, serve_args_for

__all__ = ["main", "time_imports", "time_to_first_frame"]


def time_imports() -> float:
    """Seconds for a fresh interpreter to import the service."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-c", "import cli.main, service.serve"], cwd=REPO, env=env, check=True)
    return time.monotonic() - t0


def time_to_first_frame(serve_args: list[str], env: dict[str, str], timeout_s: float) -> float:
    with ServiceProcess([*serve_args, "--log-level", "warning"], env) as svc:
        return svc.wait_ready(timeout_s)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m bench.startup", description=__doc__.split("\n\n")[0])
    add_common_arguments(parser)
    parser.add_argument("--recording", type=Path, default=None, help="serve a recording instead of --demo")
    parser.add_argument("--render-repeat", type=int, default=1, help="launches of the render case")
    args = parser.parse_args(argv)
    repeat = args.repeat or (1 if args.quick else 5)
    info = machine_info()
    print_machine(info, "rig serve: launch → first depth frame")
    demo = not args.quick and args.recording is None
    serve_args = serve_args_for(args.quick, args.recording)
    console.print(f"command: rig serve {' '.join(serve_args)}; {repeat} launch(es) per case")
    results: dict[str, list[float]] = {"imports": [time_imports() for _ in range(repeat)]}
    with tempfile.TemporaryDirectory(prefix="rig-bench-startup-") as tmp_name:
        tmp = Path(tmp_name)
        timeout = 1800.0
        if demo:
            results["cold, with render"] = []
            for k in range(max(1, args.render_repeat)):
                fresh = {"XDG_CACHE_HOME": str(tmp / f"xdg-{k}"), "RIG_CACHE_DIR": str(tmp / f"lut-{k}")}
                results["cold, with render"].append(time_to_first_frame(serve_args, fresh, timeout))
            # The first render's caches are the warm ones from now on.
            base_env = {"XDG_CACHE_HOME": str(tmp / "xdg-0"), "RIG_CACHE_DIR": str(tmp / "lut-0")}
        else:
            base_env = {"XDG_CACHE_HOME": str(tmp / "xdg"), "RIG_CACHE_DIR": str(tmp / "lut-warm")}
            time_to_first_frame(serve_args, base_env, timeout)  # fills the caches (not timed)
        results["cold LUTs"] = []
        results["warm"] = []
        for k in range(repeat):
            cold = {**base_env, "RIG_CACHE_DIR": str(tmp / f"lut-cold-{k}")}
            results["cold LUTs"].append(time_to_first_frame(serve_args, cold, timeout))
            results["warm"].append(time_to_first_frame(serve_args, base_env, timeout))
    table = Table(title="time from launching rig serve to the first depth frame (/readyz 200)")
    for col in ("case", "median s", "runs s"):
        table.add_column(col, justify="right")
    order = ["imports", "warm", "cold LUTs", "cold, with render"]
    for case in [c for c in order if c in results]:
        runs = results[case]
        table.add_row(case, f"{median(runs):.2f}", ", ".join(f"{r:.2f}" for r in runs))
    return finish(
        "startup",
        info,
        {
            "serve_args": serve_args,
            "repeat": repeat,
            "runs_s": results,
            "median_s": {k: median(v) for k, v in results.items()},
        },
        args.json,
        table,
    )


if __name__ == "__main__":
    main()
