"""rig.yaml's optional ``pairs:``: exact round trip, one-line errors naming the file and the
entry, and the rig's pairs chosen in one place (rig.ring.stereo_pairs)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from calibration import CalibrationFileError, Rig, load_rig, save_rig
from calibration.errors import ModelError
from rig.ring import adjacent_pairs, stereo_pairs
from rig.sim.presets import get_ring_preset


def _ring(pairs: list[tuple[str, str]] | None) -> Rig:
    rig = get_ring_preset("ring4").rig
    return Rig(rig.cameras, rig.T_rig_cam, pairs)


def test_pairs_round_trip_exactly_and_override_the_geometry(tmp_path: Path) -> None:
    explicit = [("cam2", "cam1"), ("cam1", "cam3")]
    save_rig(_ring(explicit), tmp_path / "rig.yaml")
    text = (tmp_path / "rig.yaml").read_text()
    assert "pairs:\n- [cam2, cam1]\n- [cam1, cam3]\n" in text
    back = load_rig(tmp_path / "rig.yaml")
    assert back.pairs == explicit
    assert stereo_pairs(back) == explicit
    save_rig(back, tmp_path / "again.yaml")
    assert (tmp_path / "again.yaml").read_text() == text
    # Without the field the geometry chooses, and the file has no 'pairs' key.
    save_rig(_ring(None), tmp_path / "plain.yaml")
    assert "pairs" not in yaml.safe_load((tmp_path / "plain.yaml").read_text())
    plain = load_rig(tmp_path / "plain.yaml")
    assert plain.pairs is None
    assert stereo_pairs(plain) == adjacent_pairs(plain)


@pytest.mark.parametrize(
    ("pairs", "field", "message"),
    [
        ([["cam1", "cam9"]], "pairs[0]", "the rig has no camera 'cam9'"),
        ([["cam1", "cam2"], ["cam3", "cam3"]], "pairs[1]", "cannot pair with itself"),
        ([["cam1", "cam2"], ["cam1", "cam2"]], "pairs[1]", "cam1|cam2 is listed twice"),
        ([["cam1", "cam2", "cam3"]], "pairs[0]", "must have 2 entries"),
        ([["cam1", 2]], "pairs[0][1]", "must be a string"),
        ("cam1-cam2", "pairs", "must be a list"),
        ([], "pairs", "the list is empty"),
    ],
)
def test_bad_pairs_are_one_line_naming_the_file_and_entry(
    tmp_path: Path, pairs: object, field: str, message: str
) -> None:
    save_rig(_ring(None), tmp_path / "rig.yaml")
    doc = yaml.safe_load((tmp_path / "rig.yaml").read_text())
    doc["pairs"] = pairs
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(CalibrationFileError) as caught:
        load_rig(tmp_path / "rig.yaml")
    text = str(caught.value)
    assert "\n" not in text
    assert text.startswith(f"{tmp_path / 'rig.yaml'}: field '{field}': ")
    assert message in text


def test_a_rig_checks_its_own_pairs() -> None:
    with pytest.raises(ModelError, match=r"pairs\[0\]: the rig has no camera 'left'"):
        _ring([("left", "right")])
    assert Rig.from_dict(_ring([("cam1", "cam2")]).to_dict()).pairs == [("cam1", "cam2")]
    with pytest.raises(ModelError, match=r"pairs\[0\]: a pair is \[left, right\]"):
        Rig.from_dict({**_ring(None).to_dict(), "pairs": [["cam1"]]})
