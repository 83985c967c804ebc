"""A process out of file descriptors (EMFILE) is reported as such by the camera it stops, never
counted as corrupt frames. The descriptors are really exhausted, in a child process of its own
(a lowered ``RLIMIT_NOFILE`` filled with open files), where a supervised file camera replays a
small recording."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.helpers.recordings import write_recording

REPO = Path(__file__).resolve().parents[2]

CHILD = """
import json, os, resource, sys, time
from rig.capture.config import FileCameraConfig
from rig.capture.file_camera import FileCamera
from rig.capture.supervisor import CameraSupervisor
from tests.helpers.recordings import FAST_SUPERVISOR

camera = FileCamera(FileCameraConfig(recording=sys.argv[1], pace=30.0, loop=True, timestamps="live"), "left")
frames = []
# The failing open must be what stops it: a replay stalled by a busy machine would trip the fast
# watchdog first, and the camera would be unavailable for another reason.
sup = CameraSupervisor(camera, FAST_SUPERVISOR.model_copy(update={"watchdog_s": 5.0}), frames.append)
sup.start()
deadline = time.monotonic() + 10
while len(frames) < 5 and time.monotonic() < deadline:
    time.sleep(0.01)
before = len(frames)
soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
resource.setrlimit(resource.RLIMIT_NOFILE, (256, hard))
held = []
try:
    while True:
        held.append(os.open(os.devnull, os.O_RDONLY))
except OSError:
    pass
# Polled, not slept: a loaded machine may take longer to reach the failing open.
deadline = time.monotonic() + 20
while sup.health().state == "available" and time.monotonic() < deadline:
    time.sleep(0.02)
during = sup.health()
for fd in held:
    os.close(fd)
resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
deadline = time.monotonic() + 10
while sup.health().state != "available" and time.monotonic() < deadline:
    time.sleep(0.02)
after = sup.health()
sup.stop()
print(json.dumps({
    "frames_before": before,
    "state_during": during.state,
    "reason_during": during.reason,
    "corrupt_during": during.counters["frames_corrupt"],
    "state_after": after.state,
    "corrupt_after": after.counters["frames_corrupt"],
}))
"""


def test_running_out_of_file_descriptors_is_named_and_not_counted_as_corrupt(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "rec", n=10)
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(rec)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["frames_before"] >= 5
    assert result["state_during"] == "unavailable", result
    assert "file descriptors" in result["reason_during"] and "EMFILE" in result["reason_during"], result
    assert result["corrupt_during"] == result["corrupt_after"] == 0, result
    assert result["state_after"] == "available", result
