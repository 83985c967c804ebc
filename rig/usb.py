"""USB identity of the rig's UVC cameras: pyusb enumeration, sysfs mapping, bandwidth, reset.

pyusb lists the devices with a video-class interface (class 14) — VID:PID, bus, port path
(``bus-port.port``, the name the kernel and udev's ``KERNELS==`` use), link speed. sysfs maps each
to its ``/dev/videoN`` nodes: ``/sys/class/video4linux/videoN/device`` is the USB *interface*
(``1-1.2:1.0``), whose parent directory is the USB device (``busnum``, ``devnum``, ``devpath``,
``serial``); udev's ``/dev/v4l/by-path/*`` links give the stable names. The serial string is read
from sysfs (world-readable); only if sysfs lacks it is the device opened through pyusb.

Bandwidth (documented numbers, used for the shared-bus warning): YUYV is 16 bit/px; MJPEG from
a UVC camera at its default quality is typically 2–4 bit/px, estimated at 3.2 bit/px. A USB 2.0
high-speed bus (480 Mb/s) may give at most 80% of each microframe to periodic (isochronous)
transfers, i.e. 384 Mb/s shared by every camera on the bus (USB 2.0 §5.6.4); SuperSpeed allows
90% of 5 Gb/s. Note that many cameras reserve their largest isochronous packet size for MJPEG
whatever the resolution (up to 3 × 1024 B per microframe = 196.6 Mb/s), so two such cameras can
exhaust a USB 2.0 bus even when the estimate fits: the kernel then fails VIDIOC_STREAMON with
"No space left on device". Put the cameras on different buses (root ports) if that happens.

The sysfs/dev roots and the pyusb backend are parameters so tests run against fake trees.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import usb.core
import usb.util

from rig.errors import UsbError

__all__ = [
    "NO_LIBUSB_MESSAGE",
    "UVC_INTERFACE_CLASS",
    "SysfsUsbDevice",
    "UsbCamera",
    "VideoNode",
    "bus_budget_mbps",
    "format_bandwidth_mbps",
    "list_uvc_cameras",
    "permission_message",
    "reset_video_device",
    "shared_bus_warnings",
    "sysfs_usb_device_of_video",
    "sysfs_video_nodes",
]

UVC_INTERFACE_CLASS = 0x0E
RULES_FILE = "deploy/99-rig-cameras.rules"
NO_LIBUSB_MESSAGE = (
    "no libusb backend for pyusb: install libusb (Debian/Ubuntu: sudo apt install libusb-1.0-0)"
)
# pyusb / libusb speed codes → (name, link Mb/s)
_SPEEDS = {
    1: ("low", 1.5),
    2: ("full", 12.0),
    3: ("high", 480.0),
    4: ("super", 5000.0),
    5: ("super+", 10000.0),
}
MJPEG_BITS_PER_PIXEL = 3.2
YUYV_BITS_PER_PIXEL = 16.0


def permission_message(what: str) -> str:
    return (
        f"permission denied on {what}: install the udev rule ({RULES_FILE} → /etc/udev/rules.d/, then "
        "`sudo udevadm control --reload && sudo udevadm trigger` and re-plug), and add the user to "
        "groups video and plugdev"
    )


@dataclass(frozen=True)
class VideoNode:
    """One ``/dev/videoN`` of a camera; ``index`` 0 is the capture node (1 = uvcvideo metadata)."""

    name: str
    dev: str
    index: int | None
    by_path: tuple[str, ...]


@dataclass(frozen=True)
class SysfsUsbDevice:
    """The USB device directory a video node hangs off (``/sys/bus/usb/devices/<sysname>``)."""

    sysname: str
    busnum: int
    devnum: int
    devpath: str
    speed_mbps: float | None
    vid: int | None
    pid: int | None
    serial: str | None
    product: str | None


@dataclass(frozen=True)
class UsbCamera:
    vid: int
    pid: int
    serial: str | None
    serial_note: str | None
    product: str | None
    bus: int
    address: int
    port_path: str
    speed: str
    speed_mbps: float | None
    video: tuple[VideoNode, ...]

    @property
    def vid_pid(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}"

    @property
    def capture_nodes(self) -> tuple[VideoNode, ...]:
        nodes = tuple(v for v in self.video if v.index in (0, None))
        return nodes or self.video


# ----- sysfs ---------------------------------------------------------------------------------------
def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def _read_int(path: Path, base: int = 10) -> int | None:
    text = _read(path)
    try:
        return int(text, base) if text else None
    except ValueError:
        return None


def _usb_device_dir(start: Path) -> Path | None:
    # From the interface dir (1-1.2:1.0) up to the first dir that is a USB device (has busnum).
    p = start
    for _ in range(4):
        if (p / "busnum").is_file() and (p / "devnum").is_file():
            return p
        p = p.parent
    return None


def _sysfs_device(d: Path) -> SysfsUsbDevice | None:
    bus, dev = _read_int(d / "busnum"), _read_int(d / "devnum")
    if bus is None or dev is None:
        return None
    speed = _read(d / "speed")
    try:
        speed_mbps = float(speed) if speed else None
    except ValueError:
        speed_mbps = None
    return SysfsUsbDevice(
        sysname=d.name,
        busnum=bus,
        devnum=dev,
        devpath=_read(d / "devpath") or "",
        speed_mbps=speed_mbps,
        vid=_read_int(d / "idVendor", 16),
        pid=_read_int(d / "idProduct", 16),
        serial=_read(d / "serial"),
        product=_read(d / "product"),
    )


def _video_name(video: str | int) -> str:
    if isinstance(video, int) or str(video).isdigit():
        return f"video{int(video)}"
    return os.path.basename(os.path.realpath(str(video)))


def sysfs_usb_device_of_video(video: str | int, sysfs_root: str | Path = "/sys") -> SysfsUsbDevice | None:
    """The USB device behind ``/dev/videoN`` (or a link to it, or an index); None if not USB."""
    link = Path(sysfs_root) / "class" / "video4linux" / _video_name(video) / "device"
    if not link.exists():
        return None
    d = _usb_device_dir(link.resolve())
    return _sysfs_device(d) if d is not None else None


def _by_path_links(dev_root: Path) -> dict[str, list[str]]:
    links: dict[str, list[str]] = {}
    folder = dev_root / "v4l" / "by-path"
    if folder.is_dir():
        for entry in sorted(folder.iterdir()):
            links.setdefault(os.path.realpath(entry), []).append(str(entry))
    return links


def sysfs_video_nodes(
    sysfs_root: str | Path = "/sys", dev_root: str | Path = "/dev"
) -> dict[tuple[int, int], list[VideoNode]]:
    """(busnum, devnum) → the video nodes of that USB device, with their by-path links."""
    root, dev = Path(sysfs_root), Path(dev_root)
    by_path = _by_path_links(dev)
    out: dict[tuple[int, int], list[VideoNode]] = {}
    folder = root / "class" / "video4linux"
    if not folder.is_dir():
        return out
    for entry in sorted(folder.iterdir(), key=lambda p: (len(p.name), p.name)):
        usbdev = sysfs_usb_device_of_video(entry.name, root)
        if usbdev is None:
            continue
        node = dev / entry.name
        out.setdefault((usbdev.busnum, usbdev.devnum), []).append(
            VideoNode(
                name=entry.name,
                dev=str(node),
                index=_read_int(entry / "index"),
                by_path=tuple(by_path.get(os.path.realpath(node), [])),
            )
        )
    return out


# ----- pyusb ---------------------------------------------------------------------------------------
def _is_uvc(dev: Any) -> bool:
    try:
        return any(intf.bInterfaceClass == UVC_INTERFACE_CLASS for cfg in dev for intf in cfg)
    except (usb.core.USBError, ValueError):
        return False


def _translate(err: Exception, what: str) -> UsbError:
    if isinstance(err, usb.core.NoBackendError):
        return UsbError(NO_LIBUSB_MESSAGE)
    code = getattr(err, "errno", None)
    if code in (errno.EACCES, errno.EPERM) or "Access denied" in str(err):
        return UsbError(permission_message(what))
    return UsbError(f"USB error on {what}: {err}")


def _find(backend: Any, **match: Any) -> list[Any]:
    try:
        return list(usb.core.find(find_all=True, backend=backend, **match))
    except (usb.core.NoBackendError, usb.core.USBError) as err:
        raise _translate(err, "the USB bus") from err


def _serial(dev: Any, sysfs: SysfsUsbDevice | None) -> tuple[str | None, str | None]:
    if sysfs is not None and sysfs.serial:
        return sysfs.serial, None
    if not getattr(dev, "iSerialNumber", 0):
        return None, "the device reports no serial number"
    try:
        return usb.util.get_string(dev, dev.iSerialNumber), None
    except (usb.core.USBError, ValueError) as err:
        # pyusb's ValueError "no langid" is how a permission problem shows up on some systems.
        if isinstance(err, ValueError) or getattr(err, "errno", None) in (errno.EACCES, errno.EPERM):
            return None, permission_message("the serial number")
        return None, f"serial unreadable ({err})"


def list_uvc_cameras(
    *, backend: Any = None, sysfs_root: str | Path = "/sys", dev_root: str | Path = "/dev"
) -> list[UsbCamera]:
    """Every UVC device, with its video nodes; UsbError (one clear line) without libusb."""
    sysfs_devices: dict[tuple[int, int], SysfsUsbDevice] = {}
    devices_dir = Path(sysfs_root) / "bus" / "usb" / "devices"
    if devices_dir.is_dir():
        for d in devices_dir.iterdir():
            sd = _sysfs_device(d.resolve())
            if sd is not None:
                sysfs_devices[(sd.busnum, sd.devnum)] = sd
    nodes = sysfs_video_nodes(sysfs_root, dev_root)
    cams = []
    for dev in _find(backend, custom_match=_is_uvc):
        bus, addr = int(dev.bus or 0), int(dev.address or 0)
        sd = sysfs_devices.get((bus, addr))
        ports = getattr(dev, "port_numbers", None)
        port_path = (
            f"{bus}-{'.'.join(str(p) for p in ports)}" if ports else (sd.sysname if sd else f"{bus}-?")
        )
        speed, mbps = _SPEEDS.get(int(dev.speed or 0), ("unknown", None))
        serial, note = _serial(dev, sd)
        cams.append(
            UsbCamera(
                vid=int(dev.idVendor),
                pid=int(dev.idProduct),
                serial=serial,
                serial_note=note,
                product=sd.product if sd else None,
                bus=bus,
                address=addr,
                port_path=port_path,
                speed=speed,
                speed_mbps=mbps if mbps is not None else (sd.speed_mbps if sd else None),
                video=tuple(nodes.get((bus, addr), [])),
            )
        )
    return sorted(cams, key=lambda c: (c.bus, c.port_path))


def reset_video_device(video: str, *, backend: Any = None, sysfs_root: str | Path = "/sys") -> str:
    """USB-reset the camera behind ``/dev/videoN`` (the supervisor's last resort)."""
    sd = sysfs_usb_device_of_video(video, sysfs_root)
    if sd is None:
        raise UsbError(f"{video}: no USB device behind it in {sysfs_root} (unplugged?)")
    what = f"USB device {sd.sysname} ({video})"
    found = _find(backend, bus=sd.busnum, address=sd.devnum)
    if not found:
        raise UsbError(f"{what}: not found by pyusb (bus {sd.busnum}, address {sd.devnum})")
    try:
        found[0].reset()
    except usb.core.USBError as err:
        raise _translate(err, what) from err
    return f"USB reset of {what}"


# ----- bandwidth -----------------------------------------------------------------------------------
def format_bandwidth_mbps(fourcc: str, width: int, height: int, fps: float) -> float:
    """Estimated payload of one stream (see module docstring for the numbers)."""
    bpp = YUYV_BITS_PER_PIXEL if fourcc.upper() == "YUYV" else MJPEG_BITS_PER_PIXEL
    return width * height * fps * bpp / 1e6


def bus_budget_mbps(link_mbps: float) -> float:
    """Periodic (isochronous) share of a bus: 80% up to high speed, 90% for SuperSpeed."""
    return link_mbps * (0.9 if link_mbps >= 5000 else 0.8)


def shared_bus_warnings(
    requests: Mapping[str, tuple[str | int, str, int, int, float]], *, sysfs_root: str | Path = "/sys"
) -> list[str]:
    """Warnings for cameras whose requested formats exceed their USB bus's periodic budget.

    ``requests``: camera name → (device, fourcc, width, height, fps). Devices not found in sysfs
    are ignored (nothing to say about them).
    """
    buses: dict[int, list[tuple[str, float, float]]] = {}
    for name, (device, fourcc, w, h, fps) in requests.items():
        sd = sysfs_usb_device_of_video(device, sysfs_root)
        if sd is None:
            continue
        buses.setdefault(sd.busnum, []).append(
            (name, format_bandwidth_mbps(fourcc, w, h, fps), sd.speed_mbps or 480.0)
        )
    out = []
    for bus, cams in sorted(buses.items()):
        total = sum(c[1] for c in cams)
        budget = bus_budget_mbps(min(c[2] for c in cams))
        if total > budget:
            names = " + ".join(f"{n} {mb:.0f} Mb/s" for n, mb, _ in cams)
            shared = "share" if len(cams) > 1 else "is on"
            out.append(
                f"cameras {', '.join(c[0] for c in cams)} {shared} USB bus {bus}: {names} = {total:.0f} Mb/s "
                f"exceeds its ~{budget:.0f} Mb/s isochronous budget; use MJPG, a lower size/fps, "
                "or plug them into different root ports"
            )
    return out
