"""Calibration files that cost too much: a polynomial of thousands of coefficients, nesting
thousands deep, rows of a hundred thousand numbers, a file of megabytes. Each is refused with one
CalibrationFileError naming the file (and the field) from bounds checked before the heavy work
(root finding, building the tree); ``bench.calibration_bombs`` measures what they cost before."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from calibration import CalibrationFileError, load_camera
from calibration.formats.parse import MAX_FILE_BYTES, MAX_NESTING, MAX_VALUES
from calibration.models.scaramuzza import ScaramuzzaModel
from tests.calibration.test_formats_samples import (
    CAMODOCAL_SCARAMUZZA,
    OCAMCALIB_TEXT,
    Broken,
    check_broken,
    rig_doc,
    setter,
    text_file,
    yaml_file,
)

POL = "5 -3.258881e+02 0.000000e+00 8.612196e-04 -3.553896e-08 6.737619e-09 "


def _pol(n: int) -> str:
    """OCAMCALIB_TEXT with a ``pol`` line of ``n`` coefficients (the extra ones tiny)."""
    line = f"{n} " + " ".join(POL.split()[1:] + ["1e-30"] * (n - 5))
    return OCAMCALIB_TEXT.replace(POL, line)


def _invpol(n: int) -> str:
    start = OCAMCALIB_TEXT.index("\n11 407.216320")
    end = OCAMCALIB_TEXT.index("\n", start + 1)
    return OCAMCALIB_TEXT[:start] + f"\n{n} " + " ".join(["1.0"] * n) + OCAMCALIB_TEXT[end:]


def _xml(body: str) -> str:
    return f'<?xml version="1.0"?>\n<opencv_storage>\n{body}\n</opencv_storage>\n'


def _nested_xml(depth: int) -> str:
    return _xml("<a>" * depth + "1" + "</a>" * depth)


def _numbers(n: int, sep: str = ", ") -> str:
    return sep.join(["0.5"] * n)


def _opencv_yaml_matrix(n: int) -> str:
    return f"%YAML:1.0\nK: !!opencv-matrix\n  rows: 1\n  cols: {n}\n  dt: d\n  data: [{_numbers(n)}]\n"


def _scaramuzza_poly(n: int) -> object:
    def edit(doc: dict[str, object]) -> None:
        setter("cameras.left.model", "scaramuzza")(doc)
        params = {"poly": [250.0, 0.0, -1e-3] + [0.0] * (n - 3), "cx": 320.0, "cy": 240.0}
        setter("cameras.left.params", params | {"c": 1.0, "d": 0.0, "e": 0.0})(doc)

    return edit


ROWS = 3 * MAX_VALUES  # numbers in a row beyond the bound, well within the file size
CASES = [
    Broken("ocam-pol-2000", text_file(_pol(2000)), "pol", "line 3: more than 33 numbers"),
    Broken("ocam-pol-40", text_file(_pol(40)), "pol", "more than 33 numbers (the count and at most 32"),
    Broken("ocam-invpol-100", text_file(_invpol(100)), "invpol", "more than 65 numbers"),
    Broken(
        "rig-scaramuzza-poly-40",
        yaml_file(rig_doc, _scaramuzza_poly(40), "rig.yaml"),
        "cameras.left.params",
        "parameter poly may have at most 32 coefficients, got 40",
        loader="rig",
    ),
    Broken(
        "xml-100000-deep",
        text_file(_nested_xml(100_000), "c.xml"),
        None,
        f"nested deeper than {MAX_NESTING} levels",
    ),
    Broken("xml-33-deep", text_file(_nested_xml(MAX_NESTING + 1), "c.xml"), None, "nested deeper than"),
    Broken(
        "yaml-5000-deep",
        text_file("K: " + "[" * 5000 + "1" + "]" * 5000 + "\n", "c.yaml"),
        None,
        f"nested deeper than {MAX_NESTING} levels",
    ),
    Broken(
        "yaml-row",
        text_file("K: [" + ", ".join(["1.5"] * ROWS) + "]\nD: [0, 0, 0, 0]\n", "c.yaml"),
        None,
        f"more than {MAX_VALUES} values",
    ),
    Broken(
        "opencv-yaml-matrix-data",
        text_file(
            _opencv_yaml_matrix(ROWS),
            "c.yaml",
        ),
        None,
        f"more than {MAX_VALUES} values",
    ),
    Broken(
        "json-row",
        text_file(json.dumps({"value0": {"intrinsics": [1.0] * ROWS}}), "c.json"),
        None,
        f"more than {MAX_VALUES} values",
    ),
    Broken(
        "xml-matrix",
        text_file(
            _xml(
                f'<K type_id="opencv-matrix"><rows>1</rows><cols>{ROWS}</cols><dt>d</dt>'
                f"<data>{_numbers(ROWS, ' ')}</data></K>"
            ),
            "c.xml",
        ),
        None,
        f"more than {MAX_VALUES} values",
    ),
    Broken("too-large", text_file("# " + "x" * MAX_FILE_BYTES + "\n", "c.yaml"), None, "is too large"),
]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_a_file_that_costs_too_much_is_one_clear_error(tmp_path: Path, case: Broken) -> None:
    check_broken(tmp_path, case)


def test_the_bounds_leave_real_files_alone(tmp_path: Path) -> None:
    """At the bounds: 32 pol coefficients, 64 invpol ones, 32 levels, 20 000 values load, and the
    CamOdoCal Scaramuzza sample still does."""
    pol = tmp_path / "pol.txt"
    pol.write_text(_pol(ScaramuzzaModel.MAX_POLY_COEFFS))
    assert len(load_camera(pol).param_dict["poly"]) == ScaramuzzaModel.MAX_POLY_COEFFS
    nested = tmp_path / "nested.yaml"
    sample = json.loads(json.dumps(CAMODOCAL_SCARAMUZZA))
    wrapped: object = 1
    for _ in range(MAX_NESTING - 2):
        wrapped = [wrapped]
    sample["notes"] = {"deep": wrapped, "values": [0.5] * (MAX_VALUES - 200)}
    nested.write_text("%YAML:1.0\n" + json.dumps(sample))
    assert load_camera(nested).name == "scaramuzza"
    with pytest.raises(CalibrationFileError, match="nested deeper"):
        sample["notes"]["deep"] = [[wrapped]]
        nested.write_text("%YAML:1.0\n" + json.dumps(sample))
        load_camera(nested)
