"""`rig devices` against the fake sysfs/dev tree and pyusb backend of tests/rig/test_usb.py."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
from typer.testing import CliRunner

from cli.main import build_app
from rig.usb import list_uvc_cameras
from tests.rig.test_usb import FakeBackend, machine

__all__ = ["machine"]


def test_rig_devices_table(monkeypatch: pytest.MonkeyPatch, machine: SimpleNamespace, tmp_path: Path) -> None:
    import cli.devices as devices_cli

    real = devices_cli.list_uvc_cameras
    monkeypatch.setattr(devices_cli, "list_uvc_cameras", lambda **kw: real(backend=machine.backend, **kw))
    cfg = tmp_path / "rig.yaml"
    left_link = machine.dev / "v4l/by-path/pci-0000:00:14.0-usb-0:1.2:1.0-video-index0"
    fmt = "fourcc: YUYV, width: 800, height: 600"
    cfg.write_text(
        "cameras:\n"
        f"  left: {{kind: v4l2, device: '{left_link}', {fmt}}}\n"
        f"  right: {{kind: v4l2, device: '{machine.dev / 'video2'}', {fmt}}}\n"
    )
    args = ["devices", "--sysfs-root", str(machine.sys), "--dev-root", str(machine.dev), "--config", str(cfg)]
    monkeypatch.setattr(devices_cli.console, "width", 400)  # long tmp paths on one line each
    result = CliRunner().invoke(build_app(), args)
    assert result.exit_code == 0, result.output
    out = result.output
    rows = [line for line in out.splitlines() if "32e4:9230" in line]
    assert len(rows) == 2
    assert "left" in rows[0] and "1-1.2" in rows[0] and "SN-LEFT" in rows[0] and "video0" in rows[0]
    assert "right" in rows[1] and "1-1.3" in rows[1] and "high (480 Mb/s)" in rows[1]
    assert "usb-0:1.2:1.0-video-index0" in out
    assert "share USB bus 1" in out


def test_rig_devices_with_no_camera(machine: SimpleNamespace) -> None:
    import cli.devices as devices_cli

    args = ["devices", "--sysfs-root", str(machine.sys), "--dev-root", str(machine.dev)]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(
            devices_cli, "list_uvc_cameras", lambda **kw: list_uvc_cameras(backend=FakeBackend([]), **kw)
        )
        result = CliRunner().invoke(build_app(), args)
    assert result.exit_code == 0 and "no UVC cameras found" in result.output


def test_rig_devices_without_libusb_exits_2_with_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from cli.main import main

    for mod in (usb.backend.libusb1, usb.backend.libusb0, usb.backend.openusb):
        monkeypatch.setattr(mod, "get_backend", lambda *a, **k: None)
    monkeypatch.setattr(sys, "argv", ["rig", "devices"])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "libusb-1.0-0" in err and err.startswith("error:")
