"""USB identity against a fake sysfs/dev tree and a fake pyusb backend (real pyusb code path),
bandwidth arithmetic, and the udev rules file (`rig devices`: tests/cli/test_devices.py)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import usb.backend
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
import usb.core

from rig.errors import UsbError
from rig.usb import (
    bus_budget_mbps,
    format_bandwidth_mbps,
    list_uvc_cameras,
    reset_video_device,
    shared_bus_warnings,
    sysfs_usb_device_of_video,
)

REPO = Path(__file__).resolve().parents[2]
PCI = "devices/pci0000:00/0000:00:14.0"


# ----- fake pyusb backend ------------------------------------------------------------------------
class FakeUsbDevice(SimpleNamespace):
    pass


def usb_device(
    bus: int, address: int, ports: tuple[int, ...], vid: int, pid: int, classes: list[int], **kw: Any
) -> FakeUsbDevice:
    return FakeUsbDevice(
        bus=bus, address=address, ports=ports, vid=vid, pid=pid, classes=classes,
        speed=kw.get("speed", 3), iserial=kw.get("iserial", 3), deny_open=kw.get("deny_open", False),
    )  # fmt: skip


class FakeBackend(usb.backend.IBackend):
    """Answers pyusb's backend calls from FakeUsbDevice records; records resets."""

    def __init__(self, devices: list[FakeUsbDevice]) -> None:
        super().__init__()
        self.devices = devices
        self.resets: list[tuple[int, int]] = []

    def enumerate_devices(self) -> Any:
        return iter(self.devices)

    def get_device_descriptor(self, dev: Any) -> Any:
        return SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x200, bDeviceClass=0xEF, bDeviceSubClass=2,
            bDeviceProtocol=1, bMaxPacketSize0=64, idVendor=dev.vid, idProduct=dev.pid, bcdDevice=0x100,
            iManufacturer=0, iProduct=0, iSerialNumber=dev.iserial, bNumConfigurations=1,
            address=dev.address, bus=dev.bus, port_number=dev.ports[-1], port_numbers=dev.ports,
            speed=dev.speed,
        )  # fmt: skip

    def get_configuration_descriptor(self, dev: Any, config: int) -> Any:
        if config != 0:
            raise IndexError(config)
        return SimpleNamespace(
            bLength=9, bDescriptorType=2, wTotalLength=0, bNumInterfaces=len(dev.classes),
            bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=250, extra_descriptors=b"",
        )  # fmt: skip

    def get_interface_descriptor(self, dev: Any, intf: int, alt: int, config: int) -> Any:
        if alt != 0 or intf >= len(dev.classes):
            raise IndexError(intf)
        return SimpleNamespace(
            bLength=9, bDescriptorType=4, bInterfaceNumber=intf, bAlternateSetting=0, bNumEndpoints=0,
            bInterfaceClass=dev.classes[intf], bInterfaceSubClass=1, bInterfaceProtocol=0, iInterface=0,
            extra_descriptors=b"",
        )  # fmt: skip

    def open_device(self, dev: Any) -> Any:
        if dev.deny_open:
            raise usb.core.USBError("Access denied (insufficient permissions)", error_code=-3, errno=13)
        return dev

    def close_device(self, dev_handle: Any) -> None:
        pass

    def reset_device(self, dev_handle: Any) -> None:
        self.resets.append((dev_handle.bus, dev_handle.address))


# ----- fake sysfs and /dev ---------------------------------------------------------------------
def add_usb_device(sys_root: Path, sysname: str, bus: int, devnum: int, attrs: dict[str, str]) -> Path:
    parent = "/".join(sysname.split(".")[0].split("-")[:1])  # bus number
    d = sys_root / PCI / f"usb{parent}" / sysname.rsplit(".", 1)[0] / sysname
    d.mkdir(parents=True)
    files = {"busnum": str(bus), "devnum": str(devnum), "devpath": sysname.split("-", 1)[1], **attrs}
    for k, v in files.items():
        (d / k).write_text(v + "\n")
    link = sys_root / "bus/usb/devices" / sysname
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(Path("../../..") / d.relative_to(sys_root))
    return d


def add_video_node(
    sys_root: Path, dev_root: Path, parent_dir: Path, name: str, index: int, by_path: str | None
) -> None:
    node = parent_dir / "video4linux" / name
    node.mkdir(parents=True)
    (node / "index").write_text(f"{index}\n")
    (node / "device").symlink_to(Path("../.."))  # videoN/device → the USB interface (or platform dev)
    cls = sys_root / "class/video4linux" / name
    cls.parent.mkdir(parents=True, exist_ok=True)
    cls.symlink_to(Path("../..") / node.relative_to(sys_root))
    dev_root.mkdir(parents=True, exist_ok=True)
    (dev_root / name).touch()
    if by_path:
        bp = dev_root / "v4l/by-path" / by_path
        bp.parent.mkdir(parents=True, exist_ok=True)
        bp.symlink_to(Path("../..") / name)


@pytest.fixture
def machine(tmp_path: Path) -> SimpleNamespace:
    """Two UVC cameras on bus 1 (ports 1.2 and 1.3), a USB keyboard, and a platform video device."""
    sys_root, dev_root = tmp_path / "sys", tmp_path / "dev"
    cams = []
    for sysname, devnum, serial, video in (("1-1.2", 5, "SN-LEFT", 0), ("1-1.3", 6, None, 2)):
        attrs = {"speed": "480", "idVendor": "32e4", "idProduct": "9230", "product": "USB Camera"}
        if serial:
            attrs["serial"] = serial
        d = add_usb_device(sys_root, sysname, 1, devnum, attrs)
        intf = d / f"{sysname}:1.0"
        intf.mkdir()
        port = sysname.split("-", 1)[1]
        add_video_node(
            sys_root, dev_root, intf, f"video{video}", 0, f"pci-0000:00:14.0-usb-0:{port}:1.0-video-index0"
        )
        add_video_node(
            sys_root,
            dev_root,
            intf,
            f"video{video + 1}",
            1,
            f"pci-0000:00:14.0-usb-0:{port}:1.0-video-index1",
        )
        cams.append(d)
    kbd = add_usb_device(sys_root, "1-4", 1, 7, {"speed": "12", "idVendor": "046d", "idProduct": "c31c"})
    platform = sys_root / "devices/platform/vivid.0"
    platform.mkdir(parents=True)
    add_video_node(sys_root, dev_root, platform, "video9", 0, None)
    backend = FakeBackend(
        [
            usb_device(1, 5, (1, 2), 0x32E4, 0x9230, [14, 14, 1]),
            usb_device(1, 6, (1, 3), 0x32E4, 0x9230, [14, 14], deny_open=True),
            usb_device(1, 7, (4,), 0x046D, 0xC31C, [3], speed=2),
        ]
    )
    return SimpleNamespace(sys=sys_root, dev=dev_root, backend=backend, kbd=kbd)


# ----- enumeration and mapping -----------------------------------------------------------------
def test_uvc_cameras_are_mapped_to_their_video_nodes(machine: SimpleNamespace) -> None:
    cams = list_uvc_cameras(backend=machine.backend, sysfs_root=machine.sys, dev_root=machine.dev)
    assert [c.port_path for c in cams] == ["1-1.2", "1-1.3"]  # the keyboard is not a camera
    left, right = cams
    assert left.vid_pid == "32e4:9230" and left.serial == "SN-LEFT" and left.serial_note is None
    assert (left.bus, left.address, left.speed, left.speed_mbps) == (1, 5, "high", 480.0)
    assert [v.name for v in left.video] == ["video0", "video1"]
    assert [v.dev for v in left.capture_nodes] == [str(machine.dev / "video0")]
    assert left.capture_nodes[0].by_path == (
        str(machine.dev / "v4l/by-path/pci-0000:00:14.0-usb-0:1.2:1.0-video-index0"),
    )
    assert [v.name for v in right.capture_nodes] == ["video2"] and right.product == "USB Camera"


def test_unreadable_serial_names_the_fix(machine: SimpleNamespace) -> None:
    right = list_uvc_cameras(backend=machine.backend, sysfs_root=machine.sys, dev_root=machine.dev)[1]
    assert right.serial is None
    assert "permission denied" in (right.serial_note or "") and "99-rig-cameras.rules" in (
        right.serial_note or ""
    )


def test_video_node_to_usb_device(machine: SimpleNamespace) -> None:
    by_path = machine.dev / "v4l/by-path/pci-0000:00:14.0-usb-0:1.3:1.0-video-index0"
    for ref in (2, "video2", str(by_path)):
        sd = sysfs_usb_device_of_video(ref, machine.sys)
        assert sd is not None and (sd.sysname, sd.busnum, sd.devnum, sd.devpath) == ("1-1.3", 1, 6, "1.3")
    assert sysfs_usb_device_of_video("video9", machine.sys) is None  # platform device, not USB
    assert sysfs_usb_device_of_video("video42", machine.sys) is None


def test_missing_libusb_is_one_clear_message(
    monkeypatch: pytest.MonkeyPatch, machine: SimpleNamespace
) -> None:
    for mod in (usb.backend.libusb1, usb.backend.libusb0, usb.backend.openusb):
        monkeypatch.setattr(mod, "get_backend", lambda *a, **k: None)
    with pytest.raises(UsbError, match=r"apt install libusb-1\.0-0"):
        list_uvc_cameras(sysfs_root=machine.sys, dev_root=machine.dev)


def test_usb_reset_goes_to_the_right_device(machine: SimpleNamespace) -> None:
    msg = reset_video_device(str(machine.dev / "video0"), backend=machine.backend, sysfs_root=machine.sys)
    assert machine.backend.resets == [(1, 5)] and "1-1.2" in msg
    with pytest.raises(UsbError, match=r"permission denied.*99-rig-cameras\.rules"):
        reset_video_device("video2", backend=machine.backend, sysfs_root=machine.sys)
    with pytest.raises(UsbError, match="no USB device"):
        reset_video_device("video9", backend=machine.backend, sysfs_root=machine.sys)


# ----- bandwidth ---------------------------------------------------------------------------------
def test_bandwidth_numbers() -> None:
    assert format_bandwidth_mbps("YUYV", 640, 480, 30) == pytest.approx(640 * 480 * 2 * 8 * 30 / 1e6)
    assert format_bandwidth_mbps("MJPG", 1280, 960, 30) == pytest.approx(1280 * 960 * 30 * 3.2 / 1e6)
    assert bus_budget_mbps(480) == pytest.approx(384.0) and bus_budget_mbps(5000) == pytest.approx(4500.0)


def test_shared_bus_warning(machine: SimpleNamespace) -> None:
    def req(fourcc: str, w: int, h: int) -> dict[str, tuple[str | int, str, int, int, float]]:
        return {"left": ("video0", fourcc, w, h, 30.0), "right": (2, fourcc, w, h, 30.0)}

    assert shared_bus_warnings(req("MJPG", 1280, 960), sysfs_root=machine.sys) == []
    assert shared_bus_warnings(req("YUYV", 640, 480), sysfs_root=machine.sys) == []  # 295 of 384 Mb/s
    (warning,) = shared_bus_warnings(req("YUYV", 800, 600), sysfs_root=machine.sys)  # 2 × 230 Mb/s
    assert "cameras left, right share USB bus 1" in warning and "461 Mb/s" in warning and "384" in warning


# ----- udev rules ----------------------------------------------------------------------------------
_MATCH_KEYS = {"SUBSYSTEM", "KERNEL", "KERNELS", "ATTR", "ATTRS", "ENV", "SUBSYSTEMS", "DRIVERS", "ACTION"}
_ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "OWNER", "TAG", "RUN", "ENV"}
_TOKEN = re.compile(
    r'^(?P<key>[A-Z]+)(\{(?P<attr>[^}]+)\})?\s*(?P<op>==|!=|\+=|-=|:=|=)\s*"(?P<value>[^"]*)"$'
)


def parse_rules(text: str) -> list[dict[str, tuple[str, str]]]:
    rules = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        rule: dict[str, tuple[str, str]] = {}
        for token in re.split(r",\s*(?=[A-Z])", line):
            m = _TOKEN.match(token.strip())
            assert m, f"line {n}: bad token {token!r}"
            key, op = m["key"], m["op"]
            assert (key in _MATCH_KEYS and op in ("==", "!=")) or (
                key in _ASSIGN_KEYS and op in ("=", "+=", ":=")
            ), f"line {n}: {key}{op}"
            rule[key + (f"{{{m['attr']}}}" if m["attr"] else "")] = (op, m["value"])
        rules.append(rule)
    return rules


def test_udev_rules_give_stable_names_by_port_and_pyusb_access() -> None:
    path = REPO / "deploy/99-rig-cameras.rules"
    rules = parse_rules(path.read_text())
    video = {r["SYMLINK"][1]: r for r in rules if "SYMLINK" in r}
    assert set(video) == {"rig/left", "rig/right"}
    ports = set()
    for r in video.values():
        assert r["SUBSYSTEM"] == ("==", "video4linux") and r["ATTR{index}"] == ("==", "0")
        assert r["GROUP"] == ("=", "video") and r["MODE"] == ("=", "0660") and r["SYMLINK"][0] == "+="
        assert re.fullmatch(r"\d+-\d+(\.\d+)*", r["KERNELS"][1])
        ports.add(r["KERNELS"][1])
    assert len(ports) == 2
    usb_rules = [r for r in rules if r.get("SUBSYSTEM") == ("==", "usb")]
    assert {r["KERNEL"][1] for r in usb_rules} == ports  # pyusb access for the same two ports
    for r in usb_rules:
        assert r["ENV{DEVTYPE}"] == ("==", "usb_device")
        assert r["GROUP"] == ("=", "plugdev") and r["MODE"] == ("=", "0660")
    udevadm = shutil.which("udevadm")
    if udevadm and subprocess.run([udevadm, "verify", "--help"], capture_output=True).returncode == 0:
        # Newer systemd can check the syntax itself as well.
        res = subprocess.run(
            [udevadm, "verify", "--resolve-names=never", str(path)], capture_output=True, text=True
        )
        assert res.returncode == 0, res.stdout + res.stderr
