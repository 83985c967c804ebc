"""Bring-up check of a rig's two cameras: what ``rig check`` measures and judges.

:func:`run_bringup` opens both cameras for a few seconds through the service's own capture path
(:class:`~rig.capture.capture.StereoCapture`: the same camera factory, supervisors and pairing),
takes pairs like the depth worker does, and judges what a technician can act on, one
:class:`CheckRow` per check and camera:

* **camera** — it opened and delivered frames (else the supervisor's reason);
* **format** — what the camera negotiated (format, size), against the config;
* **frame rate** — achieved frames per second (over the supervisor's fps window) against the
  nominal rate: at least :data:`MIN_FPS_SHARE` of it;
* **timestamps** — their source: V4L2 buffer timestamps, or the host clock fallback (a warning:
  pairing then sees USB and driver jitter);
* **pairing** — pairs formed, capture-time skew p50/p95 against the skew gate;
* **dropped**, **corrupt** — shares of the camera's frames against the supervisor's
  ``max_dropped_fraction`` / ``max_broken_fraction``;
* **USB** — bus, port, link speed and the estimated bandwidth against the bus's isochronous
  budget (:mod:`rig.usb`; V4L2 cameras only);
* **exposure** — exposure, gain and white balance as the camera read them back
  (:meth:`~rig.capture.v4l2.V4L2Camera.controls`); automatic exposure is a warning (the two
  cameras may expose differently);
* **calibration** — the frames' size against the calibration's;
* **rectified rows** — a sample pair rectified and its matched features' vertical disparity
  (:mod:`rig.calibration_check`; swapped cameras are named).

A row is ``pass``, ``warn`` (works, but worth a look), ``fail`` (with what to do), ``n/a`` (does
not apply: a file camera has no USB link) or ``not measured`` (no frame came to measure it on: a
camera that delivered nothing has its losses, exposure and frame size unknown, never passed).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from calibration.rig import Rig
from rig.calibration_check import VERTICAL_WARN_PX, check_calibration, check_frame_sizes
from rig.capture.capture import CAMERA_NAMES, StereoCapture
from rig.capture.config import CaptureConfig, V4L2CameraConfig
from rig.capture.frame import FramePair
from rig.capture.health import CameraHealth, CaptureHealth
from rig.capture.protocol import Camera, CameraInfo
from rig.capture.v4l2 import V4L2Camera
from rig.errors import RigError
from rig.pipeline import DepthPipeline
from rig.rectified import RectifiedPairConfig
from rig.stereo import StereoParams
from rig.usb import bus_budget_mbps, format_bandwidth_mbps, sysfs_usb_device_of_video

__all__ = ["MIN_FPS_SHARE", "NOT_MEASURED", "BringupReport", "CheckRow", "Result", "run_bringup"]

Result = Literal["pass", "warn", "fail", "n/a", "not measured"]
NOT_MEASURED: Result = "not measured"
#: A camera delivering less than this share of its nominal frame rate fails.
MIN_FPS_SHARE = 0.9
# V4L2 auto exposure modes (CAP_PROP_AUTO_EXPOSURE in raw V4L2 units).
_EXPOSURE_MODES = {0: "auto", 1: "manual", 2: "shutter priority", 3: "aperture priority (auto)"}


@dataclass(frozen=True)
class CheckRow:
    check: str
    camera: str  # "left", "right", or "" for the pair
    value: str  # what was measured
    expected: str  # the limit it is judged against
    result: Result
    action: str = ""  # what to do when it is not a pass


@dataclass(frozen=True)
class BringupReport:
    rows: list[CheckRow]
    seconds: float
    pairs: int

    @property
    def failed(self) -> list[CheckRow]:
        return [r for r in self.rows if r.result == "fail"]

    @property
    def not_measured(self) -> list[CheckRow]:
        return [r for r in self.rows if r.result == NOT_MEASURED]


def _unmeasured(check: str, camera: str, expected: str, why: str = "no frame arrived") -> CheckRow:
    return CheckRow(check, camera, why, expected, NOT_MEASURED)


def run_bringup(
    config: CaptureConfig,
    rig: Rig,
    *,
    vpc: RectifiedPairConfig | None = None,
    stereo: StereoParams | None = None,
    cache_dir: str | Path | None = None,
    seconds: float = 5.0,
    cameras: Mapping[str, Camera] | None = None,
    on_tick: Callable[[float], None] | None = None,
    sysfs_root: str | Path = "/sys",
) -> BringupReport:
    """Open both cameras of ``config`` for ``seconds`` and judge them (see module doc).
    ``cameras`` replaces the cameras the config describes and ``sysfs_root`` the system's
    ``/sys`` (tests); ``on_tick(elapsed_s)`` is called about ten times a second."""
    pipeline = DepthPipeline(rig, vpc, stereo, cache_dir=cache_dir)
    capture = StereoCapture(config, cameras=cameras)
    sample: FramePair | None = None
    pairs = 0
    start = time.monotonic()
    with capture:
        while (elapsed := time.monotonic() - start) < seconds:
            pair = capture.next_pair(min(0.1, max(0.0, seconds - elapsed)))
            if pair is not None:
                pairs += 1
                sample = pair
            if on_tick is not None:
                on_tick(min(elapsed, seconds))
        health = capture.health()
        infos = {n: capture.camera(n).info() for n in CAMERA_NAMES}
        controls = {
            n: cam.controls() for n in CAMERA_NAMES if isinstance(cam := capture.camera(n), V4L2Camera)
        }
    rows: list[CheckRow] = []
    for name in CAMERA_NAMES:
        rows += _camera_rows(
            name, health.cameras[name], infos[name], config, capture.camera(name).nominal_fps
        )
    rows.append(_pairing_row(health, pairs))
    delivered = {n: int(health.cameras[n].counters["frames_received"] or 0) > 0 for n in CAMERA_NAMES}
    for name in CAMERA_NAMES:
        rows += _loss_rows(name, health.cameras[name], config, delivered[name])
    rows += _usb_rows(config, infos, sysfs_root)
    rows += [
        _exposure_row(n, config, controls.get(n))
        if delivered[n]
        else _unmeasured("exposure", n, "read back from the camera")
        for n in CAMERA_NAMES
    ]
    size_rows = _size_rows(rig, infos, delivered)
    rows += size_rows
    rows.append(_rows_row(pipeline, sample, ok_sizes=all(r.result == "pass" for r in size_rows)))
    return BringupReport(rows, seconds, pairs)


def _camera_rows(
    name: str, cam: CameraHealth, info: CameraInfo, config: CaptureConfig, nominal: float | None
) -> list[CheckRow]:
    received = int(cam.counters["frames_received"] or 0)
    if received == 0:
        why = cam.reason or cam.last_error or "no frame arrived"
        return [
            CheckRow(
                "camera",
                name,
                f"no frames: {why}",
                "frames arrive",
                "fail",
                "check the cable and the device path (`rig devices`), and that nothing else uses the camera",
            )
        ]
    rows = [CheckRow("camera", name, f"{received} frames from {info.device}", "frames arrive", "pass")]
    wanted = config.camera(name)
    fmt = f"{info.format} {info.width}x{info.height}"
    if isinstance(wanted, V4L2CameraConfig):
        expect = f"{wanted.fourcc} {wanted.width}x{wanted.height}"
        ok = (info.format, info.width, info.height) == (wanted.fourcc, wanted.width, wanted.height)
        rows.append(
            CheckRow("format", name, fmt, expect, "pass" if ok else "fail", "" if ok else "see v4l2-ctl")
        )
    else:
        rows.append(CheckRow("format", name, fmt, "as recorded", "pass"))
    fps = float(cam.counters["fps"] or 0.0)
    if nominal:
        ok = fps >= MIN_FPS_SHARE * nominal
        rows.append(
            CheckRow(
                "frame rate",
                name,
                f"{fps:.1f} fps",
                f"≥ {MIN_FPS_SHARE * nominal:.1f} ({MIN_FPS_SHARE:.0%} of {nominal:g})",
                "pass" if ok else "fail",
                ""
                if ok
                else "more light (auto exposure lowers the rate in the dark), a lower size or rate, "
                "MJPG, or its own USB port",
            )
        )
    source = info.timestamp_source or "?"
    if source == "host":
        rows.append(
            CheckRow(
                "timestamps",
                name,
                f"host clock: {info.timestamp_note or 'fallback'}",
                "V4L2 buffer timestamps",
                "warn",
                "pairing sees USB and driver jitter; a UVC camera with buffer timestamps pairs tighter",
            )
        )
    else:
        what = {"v4l2": "V4L2 buffer (CLOCK_MONOTONIC)", "live": "replayed, rebased to the host clock"}
        rows.append(CheckRow("timestamps", name, what.get(source, source), "V4L2 buffer timestamps", "pass"))
    return rows


def _pairing_row(health: CaptureHealth, pairs: int) -> CheckRow:
    p = health.pairing
    p50, p95 = p.counters["skew_ms"], p.counters["skew_ms_p95"]
    formed = int(p.counters["pairs_formed"] or 0)
    if not formed or p50 is None or p95 is None:
        return CheckRow(
            "pairing",
            "",
            "no pair formed",
            f"skew ≤ {p.skew_gate_ms:.1f} ms",
            "fail",
            "both cameras must deliver",
        )
    ok = float(p95) <= p.skew_gate_ms
    return CheckRow(
        "pairing",
        "",
        f"{formed} pairs, skew p50 {float(p50):.1f} ms, p95 {float(p95):.1f} ms",
        f"p95 ≤ {p.skew_gate_ms:.1f} ms (the skew gate)",
        "pass" if ok else "fail",
        "" if ok else "the cameras run at different rates or drift: same fps for both, or hardware sync",
    )


def _loss_rows(name: str, cam: CameraHealth, config: CaptureConfig, delivered: bool) -> list[CheckRow]:
    sup = config.supervisor
    if not delivered:
        return [
            _unmeasured("dropped", name, f"≤ {sup.max_dropped_fraction:.0%}"),
            _unmeasured("corrupt", name, f"≤ {sup.max_broken_fraction:.0%}"),
        ]
    c = {k: int(v or 0) for k, v in cam.counters.items() if isinstance(v, int) and not isinstance(v, bool)}
    arrived = c["frames_received"] + c["frames_corrupt"] + c["timestamp_errors"]
    dropped_share = c["frames_dropped"] / max(1, arrived + c["frames_lost"])
    broken = c["frames_corrupt"] + c["frames_undecodable"]
    broken_share = broken / max(1, arrived)
    ok_drop = dropped_share <= sup.max_dropped_fraction
    ok_broken = broken_share <= sup.max_broken_fraction
    return [
        CheckRow(
            "dropped",
            name,
            f"{c['frames_dropped']} ({dropped_share:.0%}: lost {c['frames_lost']}, unpaired "
            f"{c['frames_unpaired']}, evicted {c['frames_evicted']})",
            f"≤ {sup.max_dropped_fraction:.0%}",
            "pass" if ok_drop else "fail",
            "" if ok_drop else "lost: USB bandwidth or a slow host; unpaired: its partner camera is slower",
        ),
        CheckRow(
            "corrupt",
            name,
            f"{broken} ({broken_share:.0%}: corrupt {c['frames_corrupt']}, "
            f"undecodable {c['frames_undecodable']})",
            f"≤ {sup.max_broken_fraction:.0%}",
            "pass" if ok_broken else "fail",
            "" if ok_broken else "a bad cable or hub, or a USB bus at its limit (lower the size or rate)",
        ),
    ]


def _usb_rows(
    config: CaptureConfig, infos: Mapping[str, CameraInfo], sysfs_root: str | Path
) -> list[CheckRow]:
    rows: dict[str, CheckRow] = {}
    found = {}
    for name in CAMERA_NAMES:
        cam = config.camera(name)
        if not isinstance(cam, V4L2CameraConfig):
            rows[name] = CheckRow("USB", name, "file camera", "", "n/a")
            continue
        usb = sysfs_usb_device_of_video(cam.device, sysfs_root)
        if usb is None:
            rows[name] = CheckRow("USB", name, f"{cam.device}: no USB device behind it in sysfs", "", "n/a")
            continue
        info = infos[name]
        found[name] = (usb, format_bandwidth_mbps(info.format, info.width, info.height, info.fps or cam.fps))
    for name, (usb, need) in found.items():
        link = usb.speed_mbps or 480.0
        sharing = [n for n, (u, _) in found.items() if u.busnum == usb.busnum]
        total = sum(found[n][1] for n in sharing)
        budget = bus_budget_mbps(min((found[n][0].speed_mbps or 480.0) for n in sharing))
        shared = (
            f" (bus total ~{total:.0f} with {' and '.join(n for n in sharing if n != name)})"
            if len(sharing) > 1
            else ""
        )
        ok = total <= budget
        rows[name] = CheckRow(
            "USB",
            name,
            f"bus {usb.busnum} port {usb.sysname}, {link:g} Mb/s link, ~{need:.0f} Mb/s{shared}",
            f"≤ {budget:.0f} Mb/s per bus",
            "pass" if ok else "fail",
            "" if ok else "MJPG, a lower size or rate, or the cameras on different root ports",
        )
    return [rows[n] for n in CAMERA_NAMES]


def _exposure_row(name: str, config: CaptureConfig, controls: Mapping[str, float] | None) -> CheckRow:
    cam = config.camera(name)
    if not isinstance(cam, V4L2CameraConfig) or controls is None:
        return CheckRow("exposure", name, "file camera" if controls is None else "not read", "", "n/a")
    mode = int(controls.get("auto_exposure", -1))
    parts = [f"mode {_EXPOSURE_MODES.get(mode, mode)}"]
    parts += [f"{k.replace('_', ' ')} {v:g}" for k, v in controls.items() if k != "auto_exposure" and v >= 0]
    value = ", ".join(parts)
    if cam.exposure is None:
        return CheckRow(
            "exposure",
            name,
            value,
            "manual (cameras.*.exposure)",
            "warn",
            "automatic exposure: the two cameras may expose (and time frames) differently; set "
            "cameras.left/right.exposure to one value",
        )
    return CheckRow("exposure", name, value, f"exposure {cam.exposure:g}", "pass")


def _size_rows(rig: Rig, infos: Mapping[str, CameraInfo], delivered: Mapping[str, bool]) -> list[CheckRow]:
    rows = []
    for name in CAMERA_NAMES:
        info, model = infos[name], rig.cameras[name]
        value = f"frames {info.width}x{info.height}"
        expect = f"calibration {model.width}x{model.height}"
        if not delivered[name]:
            rows.append(_unmeasured("calibration", name, expect))
            continue
        problems = check_frame_sizes(rig, {name: (info.width, info.height)})
        if problems:
            rows.append(CheckRow("calibration", name, value, expect, "fail", problems[0].message))
        else:
            rows.append(CheckRow("calibration", name, value, expect, "pass"))
    return rows


def _rows_row(pipeline: DepthPipeline, sample: FramePair | None, *, ok_sizes: bool) -> CheckRow:
    expect = f"≤ {VERTICAL_WARN_PX:g} px"
    if sample is None:
        return _unmeasured("rectified rows", "", expect, "no pair to rectify")
    if not ok_sizes:
        return CheckRow("rectified rows", "", "the frames do not fit the calibration", expect, "n/a")
    try:
        left, right = sample.left.gray, sample.right.gray
        check = check_calibration(pipeline, left, right)
    except RigError as err:
        return CheckRow("rectified rows", "", f"sample pair unusable: {err}", expect, "fail", "")
    value = (
        f"{check.vertical_px:.2f} px over {check.matches} matched features"
        if check.vertical_px is not None
        else f"{check.matches} matched features"
    )
    if check.errors:
        return CheckRow("rectified rows", "", value, expect, "fail", check.errors[0].message)
    if check.warnings:
        return CheckRow("rectified rows", "", value, expect, "warn", check.warnings[0].message)
    return CheckRow("rectified rows", "", value, expect, "pass")
