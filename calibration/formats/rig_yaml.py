"""Our ``rig.yaml`` (docs/design.md, "rig.yaml"), read and written.

``{version: 1, cameras: {name: {model, width, height, params: {...}, [fov_deg], T_rig_cam: 4x4}},
[pairs: [[left, right], ...]]}``: ``pairs`` lists the stereo pairs where the geometry's choice
(``rig.ring.adjacent_pairs``) is not wanted.
Floats are written with ``repr`` precision so a save/load round trip is exact.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from calibration.atomic import write_atomic
from calibration.errors import CalibrationFileError
from calibration.formats.content import CalibrationContent, build_model
from calibration.formats.document import Document, Field
from calibration.models import MODELS, CameraModel
from calibration.rig import Rig, pairs_problem

__all__ = [
    "RIG_YAML_VERSION",
    "atomic_write_bytes",
    "dump_rig_yaml",
    "is_rig_yaml",
    "read_rig_yaml",
    "write_rig_yaml",
]

RIG_YAML_VERSION = 1


def is_rig_yaml(tree: Any) -> bool:
    return isinstance(tree, Mapping) and isinstance(tree.get("cameras"), Mapping)


def read_rig_yaml(doc: Document) -> CalibrationContent:
    root = Field(doc.path, doc.tree)
    version = root.get("version")
    if version is not None and version.integer() != RIG_YAML_VERSION:
        raise version.error(
            f"unsupported version {version.value!r}; this software reads version {RIG_YAML_VERSION}"
        )
    cams = root["cameras"]
    names = cams.members()
    if not names:
        raise cams.error("must name at least one camera")
    cameras: dict[str, CameraModel] = {}
    poses = {}
    for name in names:
        entry = cams[name]
        cameras[name] = _read_camera(entry)
        poses[name] = entry["T_rig_cam"].transform()
    pairs = _read_pairs(root.get("pairs"), names)
    return CalibrationContent(doc.path, "rig.yaml", cameras, T_rig_cam=poses, pairs=pairs)


def _read_pairs(pairs_field: Field | None, cameras: list[str]) -> list[tuple[str, str]] | None:
    """``pairs: [[left, right], ...]`` (None when absent), each name a camera of the file; the
    error names the entry at fault."""
    if pairs_field is None:
        return None
    entries = pairs_field.items()
    pairs = []
    for entry in entries:
        left, right = (name.string() for name in entry.items(length=2))
        pairs.append((left, right))
    problem = pairs_problem(pairs, cameras)
    if problem is not None:
        at = pairs_field if problem[0] < 0 else entries[problem[0]]
        raise at.error(problem[1])
    return pairs


def _read_camera(entry: Field) -> CameraModel:
    model_field = entry["model"]
    model = model_field.string()
    cls = MODELS.get(model)
    if cls is None:
        raise model_field.error(f"unknown camera model {model!r}; known: {', '.join(sorted(MODELS))}")
    width = entry["width"].image_extent()
    height = entry["height"].image_extent()
    fov = entry.get("fov_deg")
    params_field = entry["params"]
    known = cls.all_param_names()
    params: dict[str, Any] = {}
    for pname in params_field.members():
        value = params_field[pname]
        if pname not in known:
            raise value.error(f"unknown parameter of model {model!r}; known: {', '.join(known)}")
        params[pname] = value.numbers() if pname in cls.list_params else value.number()
    for required in cls.param_names:
        if required not in params:
            raise CalibrationFileError(params_field.path, "missing", f"{params_field.name}.{required}")
    if fov is not None:
        params["fov_deg"] = fov.number()
    return build_model(params_field, model, width, height, **params)


def dump_rig_yaml(rig: Rig) -> str:
    """The rig.yaml text of ``rig``: ``version`` first, then :meth:`Rig.to_dict`."""
    doc = {"version": RIG_YAML_VERSION, **_plain(rig.to_dict())}
    header = (
        "# Rig calibration (odfc-rig rig.yaml, docs/design.md): T_rig_cam maps camera points into the rig.\n"
    )
    return header + yaml.dump(doc, Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=110)


class _Dumper(yaml.SafeDumper):
    """Mappings one key per line; lists of numbers (matrix rows, polynomials) on one line."""


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(not isinstance(x, list | dict) for x in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


def _represent_dict(dumper: yaml.SafeDumper, data: dict[str, Any]) -> yaml.Node:
    return dumper.represent_mapping("tag:yaml.org,2002:map", data, flow_style=False)


_Dumper.add_representer(list, _represent_list)
_Dumper.add_representer(dict, _represent_dict)


def write_rig_yaml(rig: Rig, path: str | Path) -> None:
    """Write ``rig`` to ``path`` atomically (:func:`atomic_write_bytes`)."""
    atomic_write_bytes(Path(path), dump_rig_yaml(rig).encode("utf-8"))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` through :func:`calibration.atomic.write_atomic` (readers see
    the old or the new file, never a part; the old file's permissions are kept);
    CalibrationFileError naming ``path`` if it cannot be written."""
    try:
        write_atomic(path, data)
    except OSError as err:
        raise CalibrationFileError(path, f"cannot write: {err.strerror or err}") from err


def _plain(obj: Any) -> Any:
    """Numpy scalars/arrays -> Python floats/lists so safe_dump writes plain YAML."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, bool | str) or obj is None:
        return obj
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj)
    return obj
