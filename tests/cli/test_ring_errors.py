"""Bad input around rings of N cameras, through the console script: one line naming the file and
field, exit status 2 (a ring's calibration where a command takes two cameras, a recording without
a camera of the calibration, unknown cameras in ``pairs:``, bad ``rig sim --rig`` and ``rig
evaluate --study consistency`` options)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from calibration import save_rig
from calibration.rig import Rig
from rig.sim.presets import get_ring_preset
from tests.helpers.command import assert_one_line_error, clean_env, run_rig
from tests.helpers.recordings import write_recording
from tests.helpers.shots import prototype_rig


@pytest.fixture(scope="module")
def ring_yaml(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A quarter-size ring4 (small lookup tables)."""
    path = tmp_path_factory.mktemp("ring-cal") / "ring.yaml"
    save_rig(get_ring_preset("ring4").scaled(0.25).rig, path)
    return path


def test_a_ring_where_a_command_takes_two_cameras(ring_yaml: Path, tmp_path: Path) -> None:
    result = run_rig(["lut", "build", "--calibration", ring_yaml], clean_env(tmp_path))
    assert_one_line_error(
        result, str(ring_yaml), "field 'cameras'", "a rig of 4 cameras (cam1, cam2, cam3, cam4)"
    )


def test_a_recording_without_the_calibrations_cameras(ring_yaml: Path, tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "pair", 2, width=320, height=240)
    result = run_rig(
        ["process", rec, "--calibration", ring_yaml, "--out", tmp_path / "out", "--px-per-deg", "2"],
        clean_env(tmp_path),
    )
    assert_one_line_error(
        result, str(rec / "recording.json"), "field 'cameras'", "no camera 'cam1', 'cam2', 'cam3', 'cam4'"
    )


def test_pairs_naming_an_unknown_camera(ring_yaml: Path, tmp_path: Path) -> None:
    doc = yaml.safe_load(ring_yaml.read_text())
    doc["pairs"] = [["cam1", "cam2"], ["cam2", "left"]]
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc))
    rec = write_recording(tmp_path / "pair", 1)
    result = run_rig(["process", rec, "--calibration", bad, "--out", tmp_path / "out"], clean_env(tmp_path))
    assert_one_line_error(result, str(bad), "field 'pairs[1]'", "the rig has no camera 'left'")


def test_pairs_of_a_rig_must_be_two_cameras_each() -> None:
    rig = get_ring_preset("ring4").rig
    with pytest.raises(ValueError, match=r"pairs\[0\]"):
        Rig(rig.cameras, rig.T_rig_cam, [("cam1", "cam1")])


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["sim", "--rig", "ring9"], ["unknown --rig 'ring9'", "ring4"]),
        (["sim", "--rig", "ring4", "--scene", "plane"], ["--rig renders --scene room"]),
        (["sim", "--panorama-px-per-deg", "3"], ["--panorama-px-per-deg applies to --rig"]),
        (["evaluate", "--study", "consistency"], ["needs a recording"]),
        (["evaluate", "--study", "consistency", "rec", "--out", "x"], ["--out applies to --study paper"]),
        (["evaluate", "--study", "paper", "rec"], ["REC apply to --study consistency"]),
    ],
)
def test_ring_options(tmp_path: Path, args: list[str], needles: list[str]) -> None:
    extra = ["--out", str(tmp_path / "o")] if args[0] == "sim" else []
    assert_one_line_error(run_rig([*args, *extra], clean_env(tmp_path)), *needles)


def test_consistency_of_a_rig_whose_pairs_share_no_camera(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "pair", 1, width=1280, height=960)
    save_rig(prototype_rig(), rec / "calibration.yaml")
    result = run_rig(["evaluate", "--study", "consistency", rec], clean_env(tmp_path))
    assert_one_line_error(result, "calibration.yaml", "(left|right) share no camera")
