"""`rig lut build|show` through the installed console script."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from calibration import save_rig
from rig.lut_cache import LutCache, lut_key
from rig.rectified import RectifiedPairConfig, design_rectified_pair
from tests.helpers.command import clean_env, run_rig
from tests.helpers.shots import prototype_rig


def run(*args: str | Path, env_cache: Path | None = None) -> subprocess.CompletedProcess[str]:
    env = clean_env() if env_cache is None else clean_env(RIG_CACHE_DIR=env_cache)
    return run_rig(args, env, timeout=120)


@pytest.fixture(scope="module")
def calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cal") / "rig.yaml"
    save_rig(prototype_rig(1.0), path)
    return path


def test_build_reports_path_key_valid_fraction_and_time_then_hits(calibration: Path, tmp_path: Path) -> None:
    cache = tmp_path / "lut"
    res = run("lut", "build", "--calibration", calibration, "--cache-dir", cache, "--projection", "pinhole")
    assert res.returncode == 0, res.stderr
    pair = design_rectified_pair(prototype_rig(1.0), RectifiedPairConfig(projection="pinhole"))
    for name in ("left", "right"):
        key = lut_key(prototype_rig(1.0).cameras[name], pair.R_cam_rect[name], pair.camera)
        assert (cache / f"{key}.lut").is_file()
        assert key[:16] in res.stdout
    assert res.stdout.count("100.0%") == 2 and res.stdout.count("built") == 2
    assert "pinhole 640x480, hfov 90.0°" in res.stdout
    again = run("lut", "build", "-c", calibration, "--cache-dir", cache, "--projection", "pinhole")
    assert again.returncode == 0 and again.stdout.count("cache (load)") == 2
    forced = run(
        "lut", "build", "-c", calibration, "--cache-dir", cache, "--rebuild", "--projection", "pinhole"
    )
    assert forced.returncode == 0 and forced.stdout.count("built") == 2


def test_build_warns_when_the_vpc_leaves_the_lens(calibration: Path, tmp_path: Path) -> None:
    res = run(
        "lut", "build", "-c", calibration, "--vpc-hfov", "150", "--vpc-size", "320x240", env_cache=tmp_path
    )
    assert res.returncode == 0, res.stderr
    assert "warning" in res.stderr and "of its pixels are valid" in res.stderr
    assert "pinhole 320x240, hfov 150.0°" in res.stdout
    assert len(list(tmp_path.glob("*.lut"))) == 2, "RIG_CACHE_DIR is honoured"


def test_show_lists_and_clears_the_cache(calibration: Path, tmp_path: Path) -> None:
    cache = tmp_path / "lut"
    empty = run("lut", "show", "--cache-dir", cache)
    assert empty.returncode == 0 and "no cached tables" in empty.stdout
    assert (
        run("lut", "build", "-c", calibration, "--cache-dir", cache, "--vpc-size", "320x240").returncode == 0
    )
    (cache / ("f" * 64 + ".lut")).write_bytes(b"broken")
    res = run("lut", "show", "--cache-dir", cache)
    assert res.returncode == 0, res.stderr
    entries = {e.path.name for e in LutCache(cache).entries()}
    for name in entries:
        assert name[:16] in res.stdout
    assert res.stdout.count("kannala_brandt 1280x960 -> vpc 320x240") == 2
    assert "bad" in res.stdout
    cleared = run("lut", "show", "--cache-dir", cache, "--clear")
    assert cleared.returncode == 0 and "removed 3 table(s)" in cleared.stdout
    assert list(cache.glob("*.lut")) == []


def test_build_errors_are_one_line_exit_2(calibration: Path, tmp_path: Path) -> None:
    for args, needle in (
        ((), "--calibration"),
        (("-c", tmp_path / "nope.yaml"), "nope.yaml"),
        (("-c", calibration, "--vpc-size", "big"), "--vpc-size"),
        (("-c", calibration, "--pitch", "95"), "--pitch"),
    ):
        res = run("lut", "build", *args, "--cache-dir", tmp_path)
        assert res.returncode == 2, (args, res.stderr)
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and needle in lines[0], res.stderr


def test_hostile_cache_entries_never_stop_the_command(calibration: Path, tmp_path: Path) -> None:
    # Before: a non-finite image size in a header ended with "internal error", a FIFO hung it.
    cache = tmp_path / "lut"
    cache.mkdir()
    pair = design_rectified_pair(prototype_rig(1.0), RectifiedPairConfig(width=320, height=240))
    keys = [
        lut_key(prototype_rig(1.0).cameras[n], pair.R_cam_rect[n], pair.camera) for n in ("left", "right")
    ]
    (cache / f"{keys[0]}.lut").write_bytes(
        b"ODFCLUT\n" + len(h := b'{"version": 2, "height": Infinity}').to_bytes(4, "little") + h
    )
    os.mkfifo(cache / f"{keys[1]}.lut")
    shown = run("lut", "show", "--cache-dir", cache)
    assert shown.returncode == 0, shown.stderr
    assert "FIFO" in shown.stdout and "Infinity" in shown.stdout
    built = run("lut", "build", "-c", calibration, "--cache-dir", cache, "--vpc-size", "320x240")
    assert built.returncode == 0, built.stderr
    assert built.stdout.count("built") == 2
    warnings = [ln for ln in built.stderr.splitlines() if "LUT cache file" in ln]
    assert len(warnings) == 2 and all("rebuilding" in w for w in warnings), built.stderr
    assert (
        run("lut", "build", "-c", calibration, "--cache-dir", cache, "--vpc-size", "320x240").stdout.count(
            "cache (load)"
        )
        == 2
    )
