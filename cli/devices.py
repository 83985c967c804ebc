"""`rig devices`: the UVC cameras on this machine and how to name them stably (see docs/cameras.md)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from cli.console import console, warn
from rig.capture.config import V4L2CameraConfig, load_capture_config
from rig.usb import UsbCamera, list_uvc_cameras, shared_bus_warnings

__all__ = ["register"]


def _roles(cams: list[UsbCamera], config: Path | None, sysfs_root: Path) -> tuple[dict[str, str], list[str]]:
    """Which listed camera the config calls left/right (by video node), and bandwidth warnings."""
    if config is None:
        return {}, []
    cfg = load_capture_config(config)
    roles: dict[str, str] = {}
    requests = {}
    for name in ("left", "right"):
        cam = cfg.camera(name)
        if not isinstance(cam, V4L2CameraConfig):
            continue
        dev = cam.device
        node = (
            f"video{dev}"
            if isinstance(dev, int) or dev.isdigit()
            else os.path.basename(os.path.realpath(dev))
        )
        for c in cams:
            if any(v.name == node for v in c.video):
                roles[c.port_path] = f"{roles[c.port_path]}+{name}" if c.port_path in roles else name
        requests[name] = (dev, cam.fourcc, cam.width, cam.height, cam.fps)
    return roles, shared_bus_warnings(requests, sysfs_root=sysfs_root) if len(requests) == 2 else []


def register(app: typer.Typer) -> None:
    @app.command(
        "devices",
        help="List UVC cameras: VID:PID, serial, USB bus-port path (for the udev rule), speed, "
        "/dev/videoN and /dev/v4l/by-path names. With --config, mark left/right and check USB bandwidth.",
    )
    def devices(
        config: Annotated[
            Path | None,
            typer.Option("--config", metavar="FILE", help="YAML file with a 'cameras:' section."),
        ] = None,
        sysfs_root: Annotated[Path, typer.Option("--sysfs-root", metavar="DIR", hidden=True)] = Path("/sys"),
        dev_root: Annotated[Path, typer.Option("--dev-root", metavar="DIR", hidden=True)] = Path("/dev"),
    ) -> None:
        cams = list_uvc_cameras(sysfs_root=sysfs_root, dev_root=dev_root)
        if not cams:
            console.print("no UVC cameras found (plugged in? `lsusb` lists every USB device)")
            return
        roles, warnings = _roles(cams, config, sysfs_root)
        table = Table(title="UVC cameras", title_justify="left")
        for col in ("camera", "VID:PID", "product", "serial", "bus-port", "speed", "/dev/videoN", "by-path"):
            table.add_column(col, overflow="fold")
        for c in cams:
            serial = c.serial or (f"[yellow]{c.serial_note}[/yellow]" if c.serial_note else "")
            speed = f"{c.speed} ({c.speed_mbps:g} Mb/s)" if c.speed_mbps else c.speed
            table.add_row(
                roles.get(c.port_path, ""),
                c.vid_pid,
                c.product or "",
                serial,
                c.port_path,
                speed,
                " ".join(v.dev for v in c.capture_nodes),
                " ".join(p for v in c.capture_nodes for p in v.by_path),
            )
        console.print(table)
        console.print(
            "Stable names: put each camera's bus-port into deploy/99-rig-cameras.rules "
            '(KERNELS=="<bus-port>") for /dev/rig/left and /dev/rig/right.',
            highlight=False,
        )
        for w in warnings:
            warn(w)
