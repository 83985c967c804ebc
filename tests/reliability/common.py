"""Helpers shared by the reliability suite: the ``rig`` console script in subprocesses, service
settings for a replayed JPEG recording, and Prometheus text parsing."""

from __future__ import annotations

import os
import re
import selectors
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import yaml
from prometheus_client.parser import text_string_to_metric_families

from rig.recording import Recording, RecordingWriter
from service.settings import Settings, load_settings
from tests.service.conftest import FAST_SUPERVISOR, REPLAY_FPS, TOKEN, service_overrides

__all__ = [
    "AUTH",
    "FAST_SUPERVISOR",
    "REPLAY_FPS",
    "RIG",
    "TOKEN",
    "Served",
    "assert_one_line_error",
    "clean_env",
    "jpeg_copy",
    "metric_values",
    "run_rig",
    "service_settings",
    "start_serve",
    "write_serve_config",
]

RIG = Path(sys.executable).with_name("rig")
AUTH = {"Authorization": f"Bearer {TOKEN}"}
JPEG_QUALITY = 90


def clean_env(tmp: Path, **extra: str) -> dict[str, str]:
    """The environment without any RIG_* variable, caches and data under ``tmp``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RIG_")}
    env.update(
        PYTHONUNBUFFERED="1",
        XDG_CACHE_HOME=str(tmp / "cache"),
        XDG_DATA_HOME=str(tmp / "data"),
        COLUMNS="200",
        **extra,
    )
    return env


def run_rig(
    args: list[str], env: dict[str, str] | None = None, timeout: float = 120, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(RIG), *args], env=env, capture_output=True, text=True, timeout=timeout, cwd=cwd
    )


def assert_one_line_error(result: subprocess.CompletedProcess[str], *needles: str) -> str:
    """Exit status 2, exactly one non-empty line on stderr starting with ``error:``, no traceback;
    returns that line."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    context = f"args={result.args!r}\nstdout={result.stdout!r}\nstderr={result.stderr!r}"
    assert result.returncode == 2, context
    assert len(lines) == 1 and lines[0].startswith("error:"), context
    assert "Traceback" not in result.stderr + result.stdout, context
    for needle in needles:
        assert needle in lines[0], (needle, context)
    return lines[0]


def metric_values(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """``{(sample name, sorted labels): value}`` of a Prometheus text exposition."""
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def jpeg_copy(source: Path, out: Path, quality: int = JPEG_QUALITY) -> Path:
    """``source`` (a rendered PNG recording) re-encoded as JPEG frames, same seqs and timestamps,
    with its calibration.yaml: what an MJPEG camera recording looks like."""
    src = Recording(source)
    params = [cv2.IMWRITE_JPEG_QUALITY, quality]
    with RecordingWriter(out, meta={"source": f"jpeg copy of {source}"}) as writer:
        for pair in src.pairs:
            ok_left, left = cv2.imencode(".jpg", src.read_image(pair, "left"), params)
            ok_right, right = cv2.imencode(".jpg", src.read_image(pair, "right"), params)
            assert ok_left and ok_right
            writer.write_pair(
                pair.seq, pair.left_ts_ns, pair.right_ts_ns, left.tobytes(), right.tobytes(), ext=".jpg"
            )
    if src.calibration_path is not None:
        shutil.copyfile(src.calibration_path, out / "calibration.yaml")
    return out


def write_serve_config(path: Path, recording: Path, tmp: Path, lut_cache: Path, **kw: Any) -> Path:
    """:func:`service_overrides` as a YAML config file for ``rig serve --config``."""
    path.write_text(yaml.safe_dump(service_overrides(recording, tmp, lut_cache, **kw)))
    return path


def service_settings(recording: Path, tmp: Path, lut_cache: Path, **kw: Any) -> Settings:
    """:func:`service_overrides` as validated Settings (for an in-process LiveServer)."""
    return load_settings(None, service_overrides(recording, tmp, lut_cache, **kw))


URL_RE = re.compile(r"depth service: (http://(\S+?):(\d+)/)")


@dataclass
class Served:
    """A ``rig serve`` subprocess and what it printed up to its URL line."""

    proc: subprocess.Popen[str]
    url: str
    host: str
    port: int
    output: list[str]

    def stop(self) -> str:
        """SIGTERM (graceful) and the rest of its output; kills it if it does not stop in 60 s."""
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            out, _ = self.proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate()
        return "".join(self.output) + (out or "")


def start_serve(args: list[str], env: dict[str, str], timeout: float = 120) -> Served:
    """``rig serve ARGS`` until it prints its URL (stdout and stderr merged)."""
    proc = subprocess.Popen(
        [str(RIG), "serve", *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    output: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not sel.select(timeout=1.0):
            if proc.poll() is not None:
                break
            continue
        line = proc.stdout.readline()
        if not line:
            break
        output.append(line)
        m = URL_RE.search(line)
        if m:
            return Served(proc, m.group(1), m.group(2), int(m.group(3)), output)
    proc.kill()
    proc.communicate()
    raise AssertionError("rig serve printed no URL:\n" + "".join(output))
