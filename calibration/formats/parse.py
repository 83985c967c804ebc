"""Parsing a calibration file's text into a plain tree, within bounds checked before the heavy work.

:func:`parse_text` reads JSON, YAML (also OpenCV's ``%YAML:1.0`` dialect with ``!!opencv-matrix``
tags) and OpenCV FileStorage XML, and recognises OCamCalib's plain text. Before a tree is built
(YAML: from the parser's events; XML: from its tags) or walked (JSON), its nesting and its number
of values are bounded (:data:`MAX_NESTING`, :data:`MAX_VALUES`); files are at most
:data:`MAX_FILE_BYTES`. Every failure is one :class:`CalibrationFileError` naming the file.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from calibration.errors import CalibrationFileError

__all__ = ["MAX_FILE_BYTES", "MAX_NESTING", "MAX_VALUES", "TaggedMatrix", "parse_text"]

# Calibration files are a few kB (the largest real one we read, OpenCV corner lists, 240 kB);
# anything this big is an image or a recording picked by mistake.
MAX_FILE_BYTES = 4 * 1024 * 1024
# Checked before a file's tree is built (YAML's events, XML's tags) or walked (JSON): calibrations
# nest a few levels and hold at most some thousands of values (corner lists); a million numbers
# in a YAML row cost PyYAML a minute and a gigabyte, 100 000 nested XML tags crash OpenCV's parser.
MAX_NESTING = 32
MAX_VALUES = 20_000


@dataclass(frozen=True)
class TaggedMatrix:
    """An OpenCV ``!!opencv-matrix`` node as parsed, validated later by :meth:`Field.matrix`."""

    content: Any


def parse_text(path: Path, text: str) -> tuple[str, Any]:
    """The kind of ``text`` ("json", "yaml", "xml" or "text" for OCamCalib) and its tree (None
    for text)."""
    head = text.lstrip()
    if head.startswith("{"):
        return "json", _bounded(path, _parse_json(path, text))
    if head.startswith("<"):
        _check_xml_nesting(path, head)
        return "xml", _bounded(path, _parse_opencv_xml(path, head))
    if _looks_like_ocamcalib(text):
        return "text", None
    return "yaml", _parse_yaml(path, text)


# ----- bounds, before the heavy work -------------------------------------------------------------
def _too_much(path: Path, nesting: int, values: int) -> None:
    if nesting > MAX_NESTING:
        raise CalibrationFileError(path, f"not a calibration file: nested deeper than {MAX_NESTING} levels")
    if values > MAX_VALUES:
        raise CalibrationFileError(
            path, f"not a calibration file: more than {MAX_VALUES} values (calibrations hold hundreds)"
        )


def _bounded(path: Path, tree: Any) -> Any:
    """``tree`` after checking its nesting and its number of values (matrices count their
    elements), walked without recursion."""
    values, stack = 0, [(tree, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, TaggedMatrix):
            node = node.content
        if isinstance(node, Mapping):
            stack += [(v, depth + 1) for v in node.values()]
        elif isinstance(node, list | tuple):
            stack += [(v, depth + 1) for v in node]
        else:
            values += int(node.size) if isinstance(node, np.ndarray) else 1
        _too_much(path, depth, values)
    return tree


_XML_TAG = re.compile(r"<(/?)([^>]*?)(/?)>")


def _check_xml_nesting(path: Path, text: str) -> None:
    """The depth of the XML's elements, from its tags alone (OpenCV's parser recurses per level
    and crashes the process on 100 000 of them)."""
    depth = 0
    for tag in _XML_TAG.finditer(text):
        closing, body, empty = tag.groups()
        if body.startswith(("?", "!")) or empty:
            continue
        depth += -1 if closing else 1
        _too_much(path, depth, 0)


# The YAML scan's parsers: libyaml's when PyYAML has it (ten times faster), then PyYAML's own
# (libyaml stops at 1000 levels of nesting with an error of its own, which PyYAML's scan bounds).
_YAML_EVENTS = tuple(dict.fromkeys((getattr(yaml, "CSafeLoader", yaml.SafeLoader), yaml.SafeLoader)))


def _check_yaml_size(path: Path, body: str) -> None:
    """Nesting and values of a YAML document from its parser's events, stopping at the first
    bound crossed, before any node is built (a syntax error is left to the loader to report)."""
    for loader in _YAML_EVENTS:
        depth = values = 0
        try:
            for event in yaml.parse(body, Loader=loader):
                if isinstance(event, yaml.CollectionStartEvent):
                    depth += 1
                elif isinstance(event, yaml.CollectionEndEvent):
                    depth -= 1
                elif isinstance(event, yaml.ScalarEvent):
                    values += 1
                _too_much(path, depth, values)
            return
        except yaml.YAMLError:
            continue


# ----- parsers ------------------------------------------------------------------------------------
def _parse_json(path: Path, text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise CalibrationFileError(path, f"not valid JSON: {err.msg} at line {err.lineno}") from err
    except RecursionError as err:
        raise CalibrationFileError(path, "not a calibration file: nesting too deep") from err


class _Loader(yaml.SafeLoader):
    """SafeLoader plus OpenCV's matrix tags and YAML 1.2 floats such as ``1e-05``."""


# Own copy of the resolver table so the extra float pattern does not leak into yaml.SafeLoader.
_Loader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def _construct_opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> TaggedMatrix:
    if not isinstance(node, yaml.MappingNode):
        return TaggedMatrix(loader.construct_object(node, deep=True))
    return TaggedMatrix(loader.construct_mapping(node, deep=True))


_Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", _construct_opencv_matrix)
_Loader.add_constructor("tag:yaml.org,2002:opencv-nd-matrix", _construct_opencv_matrix)

# OpenCV writes "%YAML:1.0" (not a valid YAML directive) or "%YAML 1.2" on the first line.
_YAML_DIRECTIVE = re.compile(r"\A\s*%YAML[: ][^\n]*")


def _parse_yaml(path: Path, text: str) -> Any:
    # Keep the line count so parser messages point at the right line.
    body = _YAML_DIRECTIVE.sub("", text, count=1)
    _check_yaml_size(path, body)
    try:
        return yaml.load(body, Loader=_Loader)  # _Loader derives from SafeLoader
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise CalibrationFileError(path, f"not valid YAML: {problem}{where}") from err
    except RecursionError as err:
        raise CalibrationFileError(path, "not a calibration file: nesting too deep") from err


def _parse_opencv_xml(path: Path, text: str) -> Any:
    if not text.startswith("<?xml"):
        text = '<?xml version="1.0"?>\n' + text
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as err:
        # OpenCV's Python binding reports parse failures as SystemError wrapping cv2.error.
        cause = err.__cause__ if isinstance(err, SystemError) and err.__cause__ else err
        detail = str(cause).strip().splitlines()[-1] if str(cause).strip() else type(cause).__name__
        raise CalibrationFileError(path, f"not valid OpenCV FileStorage XML: {detail}") from err
    try:
        if not storage.isOpened():
            raise CalibrationFileError(path, "not valid OpenCV FileStorage XML")
        return _filenode_to_tree(storage.root())
    finally:
        storage.release()


def _filenode_to_tree(node: cv2.FileNode) -> Any:
    if node.isMap():
        keys = list(node.keys())
        tree = {k: _filenode_to_tree(node.getNode(k)) for k in keys}
        if {"dt", "data"} <= set(keys) and ({"rows", "cols"} <= set(keys) or "sizes" in keys):
            try:
                return TaggedMatrix(np.asarray(node.mat(), dtype=np.float64))
            except cv2.error:
                return TaggedMatrix(tree)  # inconsistent sizes: Field.matrix names the problem
        return tree
    if node.isSeq():
        return [_filenode_to_tree(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


_NUMBER_LINE = re.compile(r"^[-+0-9.eE\s]+$")


def _looks_like_ocamcalib(text: str) -> bool:
    """OCamCalib's export: its ``#polynomial coefficients`` header, or only ``#`` comments and
    lines of numbers (the header decides even when a number is garbled, for a precise error)."""
    stripped = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if stripped and stripped[0].lower().startswith("#polynomial coefficients"):
        return True
    lines = [ln for ln in stripped if not ln.startswith("#")]
    return len(lines) >= 5 and all(_NUMBER_LINE.match(ln) for ln in lines) and lines[0].split()[0].isdigit()
