"""Property: whatever a corrupted calibration file contains, the loaders either return a model /
rig or raise CalibrationFileError — never another exception type."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calibration import CalibrationFileError, Rig, load_camera, load_rig
from calibration.formats import dump_rig_yaml
from calibration.models import CameraModel
from tests.calibration.test_formats_samples import (
    CAMODOCAL_MEI,
    CAMODOCAL_SCARAMUZZA,
    OCAMCALIB_TEXT,
    basalt_doc,
    kalibr_doc,
    opencv_fisheye_entries,
    rig_doc,
    write_filestorage,
)
from tests.calibration.test_formats_shared_data import SHARED_SAMPLES
from tests.conftest import shared_file

SAMPLE_NAMES = [
    "rig.yaml",
    "kalibr",
    "basalt",
    "ocamcalib",
    "camodocal-mei",
    "camodocal-ocam",
    "opencv-xml",
    *SHARED_SAMPLES,
]


@pytest.fixture(scope="module")
def samples(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("samples")
    out = {
        "rig.yaml": dump_rig_yaml(Rig.from_dict(rig_doc())),
        "kalibr": yaml.safe_dump(kalibr_doc()),
        "basalt": json.dumps(basalt_doc(), indent=1),
        "ocamcalib": OCAMCALIB_TEXT,
        "camodocal-mei": write_filestorage(tmp / "m.yaml", CAMODOCAL_MEI).read_text(),
        "camodocal-ocam": write_filestorage(tmp / "s.yaml", CAMODOCAL_SCARAMUZZA).read_text(),
        "opencv-xml": write_filestorage(tmp / "o.xml", opencv_fisheye_entries()).read_text(),
    }
    for name, path in SHARED_SAMPLES.items():
        if path.is_file():
            out[name] = path.read_text()
    return out


# One edit: delete a span, insert junk, or swap a span for another sample's text.
edits = st.lists(
    st.tuples(
        st.sampled_from(["delete", "insert", "replace", "truncate"]),
        st.floats(0.0, 1.0),
        st.integers(1, 40),
        st.text(alphabet=st.sampled_from(list("0123456789.-+eE:[]{},\n #\"'abxyzNnaI<>/")), max_size=12),
    ),
    min_size=1,
    max_size=4,
)


def corrupt(text: str, ops: list[tuple[str, float, int, str]]) -> str:
    for op, where, length, junk in ops:
        i = int(where * len(text))
        if op == "delete":
            text = text[:i] + text[i + length :]
        elif op == "insert":
            text = text[:i] + junk + text[i:]
        elif op == "replace":
            text = text[:i] + junk + text[i + length :]
        else:
            text = text[:i]
    return text


@pytest.mark.filterwarnings("ignore::hypothesis.errors.HypothesisWarning")  # large sample reprs
@pytest.mark.parametrize("name", SAMPLE_NAMES)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=edits)
def test_corrupted_files_raise_only_calibration_file_errors(
    tmp_path: Path, samples: dict[str, str], name: str, ops: list[tuple[str, float, int, str]]
) -> None:
    if name not in samples:
        shared_file(name)  # skips (fails in CI) saying it is missing
    path = tmp_path / "calib"
    path.write_text(corrupt(samples[name], ops))
    try:
        assert isinstance(load_camera(path), CameraModel)
    except CalibrationFileError as err:
        assert str(err).startswith(f"{path}: ")
    try:
        assert isinstance(load_rig(path), Rig)
    except CalibrationFileError as err:
        assert str(err).startswith(f"{path}: ")
