"""Our rig.yaml: exact save/load round trips for every model, atomic writes, the public API."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

import calibration
from calibration import CalibrationFileError, Rig, create, load_camera, load_rig, save_rig
from calibration.geometry import make_transform
from calibration.models import CameraModel
from tests.calibration.model_cases import ModelCase, model_cases

CASES = model_cases()


def random_pose(rng: np.random.Generator) -> np.ndarray:
    R = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    return make_transform(R, rng.normal(0.0, 0.1, 3))


def two_camera_rig(left: CameraModel, right: CameraModel, seed: int = 0) -> Rig:
    rng = np.random.default_rng(seed)
    return Rig({"left": left, "right": right}, {"left": random_pose(rng), "right": random_pose(rng)})


def assert_same_rig(a: Rig, b: Rig) -> None:
    assert a.names == b.names
    for name in a.names:
        assert a.cameras[name] == b.cameras[name], name
        assert a.cameras[name].to_dict() == b.cameras[name].to_dict()
        assert np.array_equal(a.T_rig_cam[name], b.T_rig_cam[name]), name


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_save_load_round_trip_is_exact(tmp_path: Path, case: ModelCase) -> None:
    rig = two_camera_rig(case.model, case.model, seed=len(case.id))
    path = tmp_path / "rig.yaml"
    save_rig(rig, path)
    back = load_rig(path)
    assert_same_rig(rig, back)
    # The document is plain YAML: version first, then Rig.to_dict(), readable without our loader.
    doc = yaml.safe_load(path.read_text())
    assert list(doc) == ["version", "cameras"] and doc["version"] == 1
    assert_same_rig(rig, Rig.from_dict(doc))
    assert calibration.detect_format(path) == "rig.yaml"


def test_every_registered_model_has_a_round_trip_case() -> None:
    assert {c.model.name for c in CASES} == set(calibration.MODELS)


def test_awkward_floats_survive_exactly(tmp_path: Path) -> None:
    """repr precision: tiny, huge, subnormal and not-exactly-decimal values come back bit for bit."""
    model = create(
        "kannala_brandt",
        1280,
        960,
        fx=0.1 + 0.2,
        fy=1e16 + 2.0,
        cx=640.0000000000001,
        cy=-0.0,
        k1=5e-324,
        k2=-1.2345678901234567e-300,
        k3=1e-5,
        k4=-3.0e-17,
        fov_deg=190.0000000000001,
    )
    rig = two_camera_rig(model, model.replace(cx=1.0 / 3.0), seed=7)
    save_rig(rig, tmp_path / "r.yaml")
    assert_same_rig(rig, load_rig(tmp_path / "r.yaml"))


def test_rig_with_three_cameras_and_custom_names(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    cams = {name: case.model for name, case in zip(("front", "back", "up"), CASES, strict=False)}
    rig = Rig(cams, {n: random_pose(rng) for n in cams})
    save_rig(rig, tmp_path / "r.yaml")
    back = load_rig(tmp_path / "r.yaml")
    assert_same_rig(rig, back)
    assert load_camera(tmp_path / "r.yaml", "up") == cams["up"]
    assert load_camera(tmp_path / "r.yaml") == cams["front"]


def test_single_camera_file_loads_as_camera_but_not_as_rig(tmp_path: Path) -> None:
    model = CASES[0].model
    save_rig(Rig({"cam0": model}, {"cam0": np.eye(4)}), tmp_path / "intrinsics.yaml")
    assert load_camera(tmp_path / "intrinsics.yaml") == model
    assert load_camera(tmp_path / "intrinsics.yaml", "cam0") == model
    with pytest.raises(CalibrationFileError, match=r"intrinsics\.yaml: holds one camera; a rig needs two"):
        load_rig(tmp_path / "intrinsics.yaml")


def test_unknown_camera_name_lists_the_names(tmp_path: Path) -> None:
    save_rig(two_camera_rig(CASES[0].model, CASES[1].model), tmp_path / "rig.yaml")
    with pytest.raises(
        CalibrationFileError, match=r"rig\.yaml: no camera named 'middle'; the file holds: left, right"
    ):
        load_camera(tmp_path / "rig.yaml", "middle")


def test_rig_yaml_without_version_is_read(tmp_path: Path) -> None:
    """Rig.to_dict() dumped by hand (no version key) is the same document."""
    rig = two_camera_rig(CASES[0].model, CASES[2].model)
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(rig.to_dict()))
    assert_same_rig(rig, load_rig(tmp_path / "rig.yaml"))


# ----- atomic writing ------------------------------------------------------------------------------
def test_save_replaces_an_existing_file_and_leaves_no_temp_files(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    path.write_text("old content\n")
    os.chmod(path, 0o640)
    rig = two_camera_rig(CASES[0].model, CASES[1].model)
    save_rig(rig, path)
    assert_same_rig(rig, load_rig(path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]
    assert path.stat().st_mode & 0o777 == 0o640


def test_failed_save_keeps_the_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "rig.yaml"
    old = two_camera_rig(CASES[0].model, CASES[1].model, seed=1)
    save_rig(old, path)
    before = path.read_bytes()

    def broken_replace(src: object, dst: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(CalibrationFileError, match=r"rig\.yaml: cannot write: No space left on device"):
        save_rig(two_camera_rig(CASES[2].model, CASES[3].model, seed=2), path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]


def test_save_into_a_missing_folder_names_the_file(tmp_path: Path) -> None:
    target = tmp_path / "no" / "such" / "rig.yaml"
    with pytest.raises(CalibrationFileError, match=r"no/such/rig\.yaml: cannot write"):
        save_rig(two_camera_rig(CASES[0].model, CASES[0].model), target)


def test_written_file_is_readable_text(tmp_path: Path) -> None:
    rig = two_camera_rig(CASES[0].model, CASES[0].model)
    save_rig(rig, tmp_path / "rig.yaml")
    text = (tmp_path / "rig.yaml").read_text()
    assert text.startswith("# Rig calibration")
    assert "\nversion: 1\n" in text
    # Matrices as one flow-style row per line, parameters by name.
    row = rig.T_rig_cam["left"][3]
    assert f"  - [{', '.join(repr(float(x)) for x in row)}]" in text
    assert f"    fx: {CASES[0].model.param_dict['fx']!r}" in text


@pytest.mark.parametrize(
    ("poly", "field", "message"),
    [
        ([300.0, "x", -0.001], "cameras.left.params.poly[1]", "must be a number, got text 'x'"),
        (300.0, "cameras.left.params.poly", "must be a list, got float"),
        ([-300.0, 0.0, 0.001], "cameras.left.params", "a0) must be > 0"),
    ],
)
def test_list_parameters_are_checked_entry_by_entry(
    tmp_path: Path, poly: object, field: str, message: str
) -> None:
    scaramuzza = next(c.model for c in CASES if c.model.name == "scaramuzza")
    path = tmp_path / "rig.yaml"
    save_rig(two_camera_rig(scaramuzza, scaramuzza), path)
    doc = yaml.safe_load(path.read_text())
    doc["cameras"]["left"]["params"]["poly"] = poly
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CalibrationFileError) as info:
        load_rig(path)
    assert info.value.field == field and message in str(info.value), str(info.value)
