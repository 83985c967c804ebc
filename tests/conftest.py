"""Shared fixtures (the helpers they use are in :mod:`tests.helpers`). Real third-party data
lives in ../shared/data (never copied into the repo); tests that need it, or a tool .ci/run
installs (the ``needs_tool`` marker), skip with the reason when it is absent, and fail instead
under ``RIG_REQUIRE_TEST_INPUTS=1`` (:mod:`tests.helpers.inputs`)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest

from tests.helpers.inputs import missing_input, missing_inputs_line, require_tool, skip_reason
from tests.helpers.recordings import jpeg_copy
from tests.helpers.service import (
    InProcessServer,
    LiveServer,
    SmallRecording,
    StartApp,
    StartServer,
    render_small_recording,
    service_settings,
    small_recording_at,
)
from tests.helpers.shared import made_once, run_root, share_under

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("RIG_SHARED_DATA", REPO.parent / "shared" / "data"))
REAL_DATA = "the real third-party data"


def shared_file(relative: str) -> Path:
    """Path of one shared data file; skips the calling test if it is missing (fails it under
    ``RIG_REQUIRE_TEST_INPUTS=1``)."""
    p = SHARED_DATA / relative
    if not SHARED_DATA.is_dir():
        missing_input(REAL_DATA, f"no directory {SHARED_DATA} (set RIG_SHARED_DATA)")
    if not p.exists():
        missing_input(REAL_DATA, f"{p} not present")
    return p


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "needs_tool(tool, install): needs a program .ci/run installs (skip or fail if absent)"
    )


#: The modules that take longest under ``make test`` (seconds of wall time per module, summed
#: per test: 76 down to 22), longest first. A scheduling hint, nothing more: a module missing here
#: only starts later. ``make test`` keeps this order (``--no-loadscope-reorder``: xdist would
#: otherwise hand out the modules with the most tests first).
LONGEST_MODULES = (
    "tests/bench/test_bench_quick.py",
    "tests/cli/test_ring.py",
    "tests/calibration/test_stereo_calibrate.py",
    "tests/cli/test_calibrate_ring.py",
    "tests/bench/test_lens_fit.py",
    "tests/reliability/test_camera_faults.py",
    "tests/calibration/test_corner_refine.py",
    "tests/calibration/test_calibrate_renders.py",
    "tests/rig/test_ring_render.py",
    "tests/reliability/test_hostile_clients.py",
    "tests/calibration/test_calibrate.py",
    "tests/cli/test_calibrate.py",
    "tests/cli/test_check.py",
    "tests/cli/test_bad_input.py",
    "tests/cli/test_serve.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest modules first (:data:`LONGEST_MODULES`), then the other modules with slow
    tests, then the rest; each module's tests kept together and in order. The workers
    (``--dist loadscope``, a module at a time) then start the long modules early and end on
    short ones, instead of one worker finishing a long module while the others idle."""
    slow = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow")}
    rank = {module: k for k, module in enumerate(LONGEST_MODULES)}

    def order(item: pytest.Item) -> tuple[int, bool]:
        module = item.nodeid.split("::")[0]
        return rank.get(module, len(rank)), module not in slow

    items.sort(key=order)


def pytest_runtest_setup(item: pytest.Item) -> None:
    for mark in item.iter_markers("needs_tool"):
        require_tool(*mark.args)


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """One line counting the tests skipped for a missing input, and how to fail them instead."""
    line = missing_inputs_line(skip_reason(r) for r in terminalreporter.stats.get("skipped", []))
    if line is not None:
        terminalreporter.write_line(line, yellow=True, bold=True)


@pytest.fixture(scope="session", autouse=True)
def _renders_shared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Renders several modules ask for (the calibration tests' boards, the stereo shots) made
    once for the run, whichever worker asks first (:func:`tests.helpers.shared.once_per_run`)."""
    share_under(run_root(tmp_path_factory))
    yield
    share_under(None)


@pytest.fixture(scope="session")
def lut_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One LUT cache directory for the whole session: a table is built once, then loaded."""
    return tmp_path_factory.mktemp("lut-cache")


@pytest.fixture(scope="session")
def bench_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The benchmarks' generated inputs (recordings) for the session, where tests that use the
    same recordings find them too."""
    return tmp_path_factory.mktemp("bench-cache")


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory: pytest.TempPathFactory) -> SmallRecording:
    """The demo room at half the prototype's size: 3 noisy pairs, 320x240 VPC, ground truth
    (rendered once for the whole run)."""
    return small_recording_at(made_once(run_root(tmp_path_factory), "demo-small", render_small_recording))


@pytest.fixture(scope="session")
def jpeg_recording(small_recording: SmallRecording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small recording's 3 pairs re-encoded as JPEG, with the rig's calibration.yaml: what an
    MJPEG camera records (corrupt and truncated frames mean what they mean on a UVC camera)."""
    return made_once(
        run_root(tmp_path_factory), "jpeg-small", lambda out: jpeg_copy(small_recording.loop, out)
    )


@pytest.fixture(scope="session")
def replayed_recording(small_recording: SmallRecording) -> Path:
    """What :func:`start_server` replays (the reliability suite overrides it with the JPEG copy)."""
    return small_recording.loop


Served = TypeVar("Served", LiveServer, InProcessServer)


def _served(
    kind: type[Served], recording: Path, lut_cache: Path, tmp_path: Path
) -> Iterator[Callable[..., Served]]:
    servers: list[Served] = []

    def start(ready: bool = True, **kw: Any) -> Served:
        served = kind(service_settings(recording, tmp_path, lut_cache, **kw)).start()
        servers.append(served)
        if ready:
            served.wait_ready()
        return served

    yield start
    for served in servers:
        served.stop()


@pytest.fixture
def start_server(replayed_recording: Path, lut_cache: Path, tmp_path: Path) -> Iterator[StartServer]:
    """Factory: a fresh real server (uvicorn on loopback) replaying :func:`replayed_recording`
    (keyword arguments as for ``service_settings``: ``server:`` fields, ``camera_faults``, ...),
    waited for until it serves depth unless ``ready=False``; stopped at teardown. For tests of
    what needs the socket; the others use :func:`start_app`."""
    yield from _served(LiveServer, replayed_recording, lut_cache, tmp_path)


@pytest.fixture
def start_app(replayed_recording: Path, lut_cache: Path, tmp_path: Path) -> Iterator[StartApp]:
    """Factory: as :func:`start_server`, the app run in process (``InProcessServer``)."""
    yield from _served(InProcessServer, replayed_recording, lut_cache, tmp_path)
