"""Hypothesis strategies that build malformed inputs from valid ones, structurally: calibration
files of every supported format (the parsed tree, the OpenCV FileStorage entries or the
OCamCalib lines are edited, then written the way their tools write them) and recording
directories (recording.json, frames.csv and the frame files).

Text-level corruption (cut, spliced, junk bytes) is covered by tests/calibration/test_formats_fuzz;
these edits keep the syntax valid so the readers' field checks are what gets exercised.
"""

from __future__ import annotations

import contextlib
import copy
import json
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from hypothesis import strategies as st

from calibration import Rig
from calibration.formats import dump_rig_yaml
from tests.calibration.test_formats_samples import (
    CAMODOCAL_KB,
    CAMODOCAL_MEI,
    CAMODOCAL_SCARAMUZZA,
    OCAMCALIB_TEXT,
    T_C1_C0,
    basalt_doc,
    kalibr_doc,
    opencv_fisheye_entries,
    rig_doc,
    write_filestorage,
)

__all__ = [
    "CALIBRATION_SAMPLES",
    "RIG_FORMATS",
    "CalibrationSample",
    "malformed_calibration",
    "malformed_recording",
]

Path_ = tuple[Any, ...]


# ----- valid samples ------------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationSample:
    """A valid file of one format: ``kind`` says how it is represented and written."""

    kind: str  # "yaml", "json" (a tree), "fs-yaml", "fs-xml" (FileStorage entries), "text"
    build: Callable[[], Any]
    suffix: str


def _rig_yaml_tree() -> Any:
    return yaml.safe_load(dump_rig_yaml(Rig.from_dict(rig_doc())))


def _opencv_stereo() -> dict[str, Any]:
    fish = opencv_fisheye_entries()
    return {
        "K1": fish["K"],
        "D1": fish["D"],
        "K2": fish["K"],
        "D2": fish["D"],
        "R": T_C1_C0[:3, :3].copy(),
        "T": T_C1_C0[:3, 3].reshape(3, 1).copy(),
        "imageSize": np.array([512, 512]),
    }


def _opencv_omnidir() -> dict[str, Any]:
    K = np.array([[758.355, 0.0, 646.72], [0.0, 757.615, 395.001], [0.0, 0.0, 1.0]])
    D = np.array([[-0.344504, 0.0984552, -0.00403995, 0.00610364]])
    return {"K": K, "D": D, "xi": np.array([[0.894975]]), "imageSize": np.array([1280, 800])}


CALIBRATION_SAMPLES: dict[str, CalibrationSample] = {
    "rig.yaml": CalibrationSample("yaml", _rig_yaml_tree, ".yaml"),
    "kalibr": CalibrationSample("yaml", kalibr_doc, ".yaml"),
    "basalt": CalibrationSample("json", basalt_doc, ".json"),
    "camodocal-kb": CalibrationSample("fs-yaml", lambda: copy.deepcopy(CAMODOCAL_KB), ".yaml"),
    "camodocal-mei": CalibrationSample("fs-yaml", lambda: copy.deepcopy(CAMODOCAL_MEI), ".yaml"),
    "camodocal-scaramuzza": CalibrationSample(
        "fs-yaml", lambda: copy.deepcopy(CAMODOCAL_SCARAMUZZA), ".yaml"
    ),
    "ocamcalib": CalibrationSample("text", lambda: OCAMCALIB_TEXT.splitlines(), ".txt"),
    "opencv-fisheye-yaml": CalibrationSample("fs-yaml", opencv_fisheye_entries, ".yaml"),
    "opencv-omnidir-xml": CalibrationSample("fs-xml", _opencv_omnidir, ".xml"),
    "opencv-stereo-yaml": CalibrationSample("fs-yaml", _opencv_stereo, ".yaml"),
    "opencv-stereo-xml": CalibrationSample("fs-xml", _opencv_stereo, ".xml"),
}
#: Formats that hold a rig (two cameras and their pose); the others hold one camera.
RIG_FORMATS = ("rig.yaml", "kalibr", "basalt", "opencv-stereo-yaml", "opencv-stereo-xml")


# ----- tree edits (YAML/JSON documents) ---------------------------------------------------------
_NUMBERS = st.one_of(
    st.integers(-(10**20), 10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1e-300, 1e300, 0.5, 65536, 2**31, -(2**63)]),
)
_SCALARS = st.one_of(st.none(), st.booleans(), _NUMBERS, st.text(max_size=8))
_VALUES = st.one_of(
    _SCALARS,
    st.lists(_NUMBERS, max_size=5),
    st.lists(st.lists(_NUMBERS, max_size=5), max_size=5),
    st.dictionaries(st.text(max_size=6), _SCALARS, max_size=3),
)
_TREE_OPS = ("delete", "replace", "replace", "scale", "shorten", "lengthen", "wrap", "swap")


def _paths(tree: Any, prefix: Path_ = ()) -> list[Path_]:
    out: list[Path_] = []
    items: Any = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else ()
    for key, value in items:
        out.append((*prefix, key))
        out.extend(_paths(value, (*prefix, key)))
    return out


def _parent(tree: Any, path: Path_) -> Any:
    for key in path[:-1]:
        tree = tree[key]
    return tree


def _edit_tree(draw: st.DrawFn, tree: Any) -> Any:
    paths = _paths(tree)
    if not paths:
        return draw(_VALUES)
    path = draw(st.sampled_from(paths))
    parent, key = _parent(tree, path), path[-1]
    value = parent[key]
    op = draw(st.sampled_from(_TREE_OPS))
    if op == "delete":
        del parent[key]
    elif op == "replace":
        parent[key] = draw(_VALUES)
    elif op == "scale":  # keeps the type, breaks the meaning (negative focal, huge distortion, ...)
        factor = draw(st.sampled_from([-1.0, 0.0, 1e9, 1e-9, 1.5, float("nan")]))
        parent[key] = _scaled(value, factor)
    elif op == "shorten" and isinstance(value, (list, dict)) and value:
        if isinstance(value, list):
            value.pop(draw(st.integers(0, len(value) - 1)))
        else:
            del value[draw(st.sampled_from(sorted(value, key=str)))]
    elif op == "lengthen" and isinstance(value, list):
        value.append(copy.deepcopy(value[-1]) if value else draw(_SCALARS))
    elif op == "wrap":
        parent[key] = [value]
    elif op == "swap":
        other = draw(st.sampled_from(paths))
        with contextlib.suppress(KeyError, IndexError, TypeError):  # the other was inside this one
            parent[key] = copy.deepcopy(_parent(tree, other)[other[-1]])
    else:
        parent[key] = draw(_VALUES)
    return tree


def _scaled(value: Any, factor: float) -> Any:
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value * factor
    if isinstance(value, list):
        return [_scaled(v, factor) for v in value]
    if isinstance(value, dict):
        return {k: _scaled(v, factor) for k, v in value.items()}
    return value


# ----- FileStorage entries ----------------------------------------------------------------------
_FS_VALUES = st.one_of(
    _NUMBERS.filter(lambda v: not isinstance(v, int) or abs(v) < 2**31),
    st.text(alphabet=st.characters(min_codepoint=48, max_codepoint=122), min_size=1, max_size=8),
    st.builds(
        lambda shape, fill: np.full(shape, fill, dtype=np.float64),
        st.tuples(st.integers(1, 4), st.integers(1, 4)),
        st.floats(allow_nan=True, allow_infinity=True),
    ),
    st.builds(
        lambda shape, seed: np.random.default_rng(seed).normal(0.0, 100.0, shape),
        st.tuples(st.integers(1, 4), st.integers(1, 4)),
        st.integers(0, 2**32 - 1),
    ),
    st.builds(lambda n: np.arange(n, dtype=np.int32).reshape(1, n), st.integers(1, 5)),
)


def _edit_entries(draw: st.DrawFn, entries: dict[str, Any]) -> dict[str, Any]:
    paths = _paths_fs(entries)
    path = draw(st.sampled_from(paths))
    parent, key = _parent(entries, path), path[-1]
    value = parent[key]
    op = draw(st.sampled_from(("delete", "replace", "replace", "scale", "reshape", "rename")))
    if op == "delete":
        del parent[key]
    elif op == "replace":
        parent[key] = draw(_FS_VALUES)
    elif op == "scale" and isinstance(value, (int, float, np.ndarray)) and not isinstance(value, bool):
        factor = draw(st.sampled_from([-1.0, 0.0, 1e9, 1e-9, float("nan")]))
        parent[key] = (
            np.asarray(value, dtype=np.float64) * factor if isinstance(value, np.ndarray) else value * factor
        )
    elif op == "reshape" and isinstance(value, np.ndarray) and value.size > 1:
        flat = value.reshape(-1)
        parent[key] = flat[: draw(st.integers(1, flat.size - 1))].reshape(1, -1)
    elif op == "rename":
        parent[draw(st.sampled_from(["k", "K_", "fx", "data", "D1", "xi"]))] = parent.pop(key)
    else:
        parent[key] = draw(_FS_VALUES)
    return entries


def _paths_fs(entries: dict[str, Any], prefix: Path_ = ()) -> list[Path_]:
    out: list[Path_] = []
    for k, v in entries.items():
        out.append((*prefix, k))
        if isinstance(v, dict):
            out.extend(_paths_fs(v, (*prefix, k)))
    return out


def _storable(entries: dict[str, Any]) -> dict[str, Any]:
    """What cv2.FileStorage can hold of a mutated document: maps, numbers (bools as ints),
    strings and arrays; other values (None, lists) are left out."""
    out: dict[str, Any] = {}
    for k, v in entries.items():
        if isinstance(v, dict):
            out[k] = _storable(v)
        elif isinstance(v, bool):
            out[k] = int(v)
        elif isinstance(v, (int, float, str, np.ndarray)):
            out[k] = v
    return out


# ----- OCamCalib text lines -----------------------------------------------------------------------
_TOKENS = st.sampled_from(["nan", "inf", "-inf", "1e999", "abc", "0", "-1", "99999999999", ".", "--", "1,5"])


def _edit_lines(draw: st.DrawFn, lines: list[str]) -> list[str]:
    data = [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]
    i = draw(st.sampled_from(data))
    tokens = lines[i].split()
    op = draw(st.sampled_from(("delete-line", "duplicate-line", "token", "drop-token", "add-token", "count")))
    if op == "delete-line":
        del lines[i]
    elif op == "duplicate-line":
        lines.insert(i, lines[i])
    elif op == "token" and tokens:
        tokens[draw(st.integers(0, len(tokens) - 1))] = draw(_TOKENS)
        lines[i] = " ".join(tokens)
    elif op == "drop-token" and tokens:
        tokens.pop(draw(st.integers(0, len(tokens) - 1)))
        lines[i] = " ".join(tokens)
    elif op == "count" and tokens:  # the leading coefficient count no longer matches
        tokens[0] = str(draw(st.integers(-3, 40)))
        lines[i] = " ".join(tokens)
    else:
        lines[i] = lines[i] + " " + draw(_TOKENS)
    return lines


# ----- calibration strategy ---------------------------------------------------------------------
@st.composite
def malformed_calibration(draw: st.DrawFn, name: str, into: Path) -> Path:
    """A file of format ``name`` after 1-3 structural edits, written under ``into``."""
    sample = CALIBRATION_SAMPLES[name]
    content = sample.build()
    for _ in range(draw(st.integers(1, 3))):
        if sample.kind in ("yaml", "json"):
            content = _edit_tree(draw, content)
        elif sample.kind == "text":
            content = _edit_lines(draw, content)
        elif _paths_fs(content):
            content = _edit_entries(draw, content)
    path = into / f"calibration{sample.suffix}"
    path.unlink(missing_ok=True)
    if sample.kind == "yaml":
        path.write_text(yaml.safe_dump(content, allow_unicode=True))
    elif sample.kind == "json":
        path.write_text(json.dumps(content))
    elif sample.kind == "text":
        path.write_text("\n".join(content) + "\n")
    else:
        write_filestorage(path, _storable(content))
    return path


# ----- recordings -------------------------------------------------------------------------------
_CSV_FIELDS = st.one_of(
    st.text(max_size=10),
    st.integers(-(10**20), 10**20).map(str),
    st.sampled_from(
        [
            "",
            "-1",
            "1e3",
            "0x10",
            "../../etc/passwd",
            "/etc/passwd",
            "left",
            "left/",
            "a\x00b",
            "left/../../x.jpg",
        ]
    ),
)
_RECORDING_META = st.one_of(
    st.just("{not json"),
    st.just("[]"),
    st.just('"a string"'),
    st.builds(
        lambda version, cameras: json.dumps({"version": version, "cameras": cameras}),
        st.one_of(st.just(1), st.none(), st.integers(-3, 3), st.text(max_size=3)),
        st.one_of(st.just(["left", "right"]), st.none(), st.text(max_size=5), st.lists(_SCALARS, max_size=3)),
    ),
)


def _edit_recording(draw: st.DrawFn, root: Path) -> str:
    """One edit of the recording at ``root``: its metadata, a removed part, a frame file or
    its index; returns what was done."""
    target = draw(st.sampled_from(("meta", "index", "index", "index", "frame", "remove")))
    if target == "meta":
        (root / "recording.json").write_text(draw(_RECORDING_META))
        return "recording.json"
    if target == "remove":
        return _remove_part(draw, root)
    if target == "frame":
        return _edit_frame(draw, root)
    return _edit_index(draw, root / "frames.csv")


def _remove_part(draw: st.DrawFn, root: Path) -> str:
    victim = draw(st.sampled_from(["recording.json", "frames.csv", "left"]))
    p = root / victim
    if p.is_dir():
        shutil.rmtree(p)
    else:
        p.unlink(missing_ok=True)
    return f"removed {victim}"


def _edit_frame(draw: st.DrawFn, root: Path) -> str:
    frames = (
        sorted((root / "left").glob("*")) + sorted((root / "right").glob("*"))
        if (root / "left").is_dir()
        else []
    )
    if not frames:
        return "no frame to edit"
    frame = draw(st.sampled_from(frames))
    op = draw(st.sampled_from(("empty", "truncate", "garbage", "directory", "delete")))
    if frame.is_dir():  # made a directory by an earlier edit
        frame.rmdir()
        return f"frame {frame.name}: removed"
    data = frame.read_bytes()
    if op == "directory":
        frame.unlink()
        frame.mkdir()
    elif op == "delete":
        frame.unlink()
    else:
        frame.write_bytes(
            b""
            if op == "empty"
            else data[: len(data) // 2]
            if op == "truncate"
            else draw(st.binary(max_size=64))
        )
    return f"frame {frame.name}: {op}"


def _edit_index(draw: st.DrawFn, index: Path) -> str:
    if not index.is_file():
        return "no index"
    raw = index.read_bytes()
    lines = raw.decode("utf-8", "replace").split("\n")
    op = draw(
        st.sampled_from(("field", "field", "drop-field", "add-field", "header", "duplicate", "cut", "bytes"))
    )
    row = draw(st.integers(0, max(0, len(lines) - 2)))
    fields = lines[row].split(",")
    if op == "field":
        fields[draw(st.integers(0, len(fields) - 1))] = draw(_CSV_FIELDS)
        lines[row] = ",".join(fields)
    elif op == "drop-field":
        fields.pop(draw(st.integers(0, len(fields) - 1)))
        lines[row] = ",".join(fields)
    elif op == "add-field":
        lines[row] = ",".join([*fields, draw(_CSV_FIELDS)])
    elif op == "header":
        lines[0] = draw(
            st.sampled_from(["", "seq,left_ts_ns,right_ts_ns,left_file", "a,b,c,d,e", "seq;left"])
        )
    elif op == "duplicate":
        lines.insert(row, lines[row])
    elif op == "cut":
        index.write_bytes(raw[: draw(st.integers(0, len(raw)))])
        return "frames.csv cut"
    else:
        index.write_bytes(raw + draw(st.binary(min_size=1, max_size=16)))
        return "frames.csv junk bytes"
    index.write_text("\n".join(lines))
    return f"frames.csv {op}"


@st.composite
def malformed_recording(draw: st.DrawFn, good: Path, into: Path) -> tuple[Path, list[str]]:
    """A copy of the recording ``good`` at ``into`` after 1-3 edits; returns it and the edits."""
    if into.exists():
        shutil.rmtree(into)
    shutil.copytree(good, into)
    edits = [_edit_recording(draw, into) for _ in range(draw(st.integers(1, 3)))]
    return into, edits
