"""deploy/: the systemd unit (systemd-analyze verify), the udev rules (parsed; udevadm verify
where this systemd has it), install.sh (run twice into a staging PREFIX) and the example config
(loads with the service's Settings)."""

from __future__ import annotations

import configparser
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from rig.capture.config import V4L2CameraConfig
from rig.stereo import StereoParams
from service.settings import load_settings

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
UNIT = DEPLOY / "rig.service"
RULES = DEPLOY / "99-rig-cameras.rules"
INSTALL = DEPLOY / "install.sh"


def unit_sections(text: str) -> dict[str, dict[str, list[str]]]:
    """systemd unit as section → key → values (keys may repeat)."""
    out: dict[str, dict[str, list[str]]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            out.setdefault(section, {})
            continue
        key, _, value = line.partition("=")
        out[section].setdefault(key.strip(), []).append(value.strip())
    return out


def test_unit_contents() -> None:
    u = unit_sections(UNIT.read_text())
    s = u["Service"]
    assert s["User"] == ["rig"]
    assert set(s["SupplementaryGroups"][0].split()) == {"video", "plugdev"}
    assert s["EnvironmentFile"] == ["/etc/rig/rig.env"]
    assert s["ExecStart"] == ["/opt/rig/venv/bin/rig serve --config /etc/rig/rig.yaml"]
    assert s["Restart"] == ["on-failure"]
    # Hardened, but the cameras stay reachable.
    assert s["NoNewPrivileges"] == ["yes"] and s["ProtectSystem"] == ["strict"]
    assert s["PrivateDevices"] == ["no"]
    assert set(s["DeviceAllow"]) == {"char-video4linux rw", "char-usb_device rw"}
    assert u["Install"]["WantedBy"] == ["multi-user.target"]


@pytest.mark.needs_tool("systemd-analyze", "apt-get install systemd; .ci/run does")
def test_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    # As shipped, the only complaint here is the not-yet-installed venv executable.
    r = subprocess.run(["systemd-analyze", "verify", str(UNIT)], capture_output=True, text=True)
    problems = [line for line in (r.stdout + r.stderr).splitlines() if line.strip()]
    assert problems == [
        "rig.service: Command /opt/rig/venv/bin/rig is not executable: No such file or directory"
    ]
    # With an executable that exists, the unit verifies with no output at all (unknown keys,
    # bad values and bad sections would all be reported).
    copy = tmp_path / "rig.service"
    copy.write_text(
        UNIT.read_text().replace("/opt/rig/venv/bin/rig", str(Path(sys.executable).with_name("rig")))
    )
    r = subprocess.run(["systemd-analyze", "verify", str(copy)], capture_output=True, text=True)
    assert r.returncode == 0 and (r.stdout + r.stderr).strip() == "", r.stdout + r.stderr


_MATCH_KEYS = {
    "SUBSYSTEM",
    "KERNEL",
    "KERNELS",
    "ATTR",
    "ATTRS",
    "ENV",
    "SUBSYSTEMS",
    "DRIVER",
    "DRIVERS",
    "ACTION",
}
_ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "OWNER", "TAG", "ENV", "RUN", "NAME"}
_TOKEN = re.compile(r'\s*([A-Z_]+)(?:\{([^}]+)\})?\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*(?:,|$)')


def parse_udev_rules(text: str) -> list[list[tuple[str, str | None, str, str]]]:
    """Rules as lists of (key, attribute, operator, value); AssertionError on a malformed line."""
    rules = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        pos, tokens = 0, []
        while pos < len(line):
            m = _TOKEN.match(line, pos)
            assert m, f"{RULES.name}:{n}: cannot parse at column {pos}: {line[pos:]!r}"
            key, attr, op, value = m.groups()
            if op in ("==", "!="):
                assert key in _MATCH_KEYS, f"line {n}: {key} is not a match key"
            else:
                assert key in _ASSIGN_KEYS, f"line {n}: {key} is not an assignment key"
            tokens.append((key, attr, op, value))
            pos = m.end()
        rules.append(tokens)
    return rules


def test_udev_rules_give_stable_names_and_usb_access() -> None:
    rules = parse_udev_rules(RULES.read_text())
    symlinks = {}
    for rule in rules:
        d = {(k, a): (op, v) for k, a, op, v in rule}
        if ("SYMLINK", None) in d:
            assert d[("SUBSYSTEM", None)] == ("==", "video4linux")
            assert ("KERNELS", None) in d or ("ENV", "ID_PATH") in d  # by USB port path
            assert d[("GROUP", None)] == ("=", "video")
            symlinks[d[("SYMLINK", None)][1]] = d
    assert set(symlinks) == {"rig/left", "rig/right"}
    port = {name: d.get(("KERNELS", None), ("", ""))[1] for name, d in symlinks.items()}
    assert port["rig/left"] != port["rig/right"]
    usb = [r for r in rules if ("SUBSYSTEM", None, "==", "usb") in r]
    assert usb and all(("GROUP", None, "=", "plugdev") in r and ("MODE", None, "=", "0660") in r for r in usb)


def test_udev_parser_rejects_broken_lines(tmp_path: Path) -> None:
    for bad in ('SUBSYSTEM=="video4linux" SYMLINK+="x"', 'SUBSYSTEM=="usb", FOO=="1"', 'MODE=="0660"x'):
        with pytest.raises(AssertionError):
            parse_udev_rules(bad)


def test_install_script_syntax() -> None:
    assert subprocess.run(["bash", "-n", str(INSTALL)], capture_output=True).returncode == 0
    assert os.access(INSTALL, os.X_OK)
    assert "set -euo pipefail" in INSTALL.read_text()


@pytest.mark.needs_tool("shellcheck", "apt-get install shellcheck; .ci/run does")
def test_install_script_shellcheck() -> None:
    r = subprocess.run(["shellcheck", str(INSTALL)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout


def run_install(prefix: Path, **env: str) -> subprocess.CompletedProcess[str]:
    full = {**os.environ, "PREFIX": str(prefix), "SKIP_PIP": "1", "PYTHON": sys.executable, **env}
    return subprocess.run(["bash", str(INSTALL)], env=full, capture_output=True, text=True, timeout=300)


@pytest.mark.timeout(300)
def test_install_into_prefix_is_idempotent_and_keeps_local_config(tmp_path: Path) -> None:
    root = tmp_path / "root"
    first = run_install(root)
    assert first.returncode == 0, first.stderr
    files = {
        "opt/rig/venv/bin/python": None,
        "etc/rig/rig.yaml": (DEPLOY / "rig.example.yaml", 0o640),
        "etc/rig/rig.env": (DEPLOY / "rig.env.example", 0o640),
        "etc/systemd/system/rig.service": (UNIT, 0o644),
        "etc/udev/rules.d/99-rig-cameras.rules": (RULES, 0o644),
    }
    for rel, expect in files.items():
        p = root / rel
        assert p.exists(), rel
        if expect is not None:
            assert p.read_bytes() == expect[0].read_bytes() and (p.stat().st_mode & 0o777) == expect[1], rel
    assert (root / "var/lib/rig/recordings").is_dir()
    assert "created   venv" in first.stdout

    (root / "etc/rig/rig.yaml").write_text("server: {port: 9999}\n")  # the operator's edit
    second = run_install(root)
    assert second.returncode == 0, second.stderr
    assert "installed" not in second.stdout.replace("installed odfc-rig", "")  # nothing re-copied
    assert "unchanged venv" in second.stdout and "kept      " in second.stdout
    assert (root / "etc/rig/rig.yaml").read_text() == "server: {port: 9999}\n"


def test_install_dry_run_changes_nothing(tmp_path: Path) -> None:
    root = tmp_path / "dry"
    r = run_install(root, DRY_RUN="1", SKIP_PIP="0")
    assert r.returncode == 0, r.stderr
    assert "would run: " in r.stdout and "-m venv" in r.stdout and "pip install" in r.stdout
    assert not root.exists()


def test_example_config_loads_with_the_service_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in list(os.environ):
        if name.startswith("RIG_"):
            monkeypatch.delenv(name)
    s = load_settings(DEPLOY / "rig.example.yaml")
    assert s.server.host == "127.0.0.1" and s.server.recordings_dir == Path("/var/lib/rig/recordings")
    assert s.cameras is not None
    for name in ("left", "right"):
        cam = s.cameras.camera(name)
        assert isinstance(cam, V4L2CameraConfig) and cam.device == f"/dev/rig/{name}"
    assert s.calibration.path == DEPLOY / "calibration.yaml"  # relative to the config file
    # The robot's config keeps the stereo defaults chosen against phantom obstacles (docs/stereo.md).
    assert s.stereo == StereoParams()
    env = configparser.ConfigParser()
    env.read_string("[env]\n" + (DEPLOY / "rig.env.example").read_text())
    assert "rig_api_token" in env["env"]
