"""The base of the configuration models (VPC, stereo, cameras, faults, server settings), and the
one reader of the YAML config file they come from (:func:`read_config_file`: ``rig serve``'s
settings and the ``cameras:`` section ``rig record`` and ``rig devices`` take from the same file),
whose relative paths are relative to the file (:func:`path_in_config`).

Numbers in a configuration are numbers and finite: YAML's ``true`` and JSON's ``true`` equal 1 in
Python, and ``.nan``, ``.inf`` or ``1e400`` parse as floats, but none of them is a port, a
window size or a duration. :class:`SettingsModel` refuses a boolean wherever a field expects a
number (or a tuple of numbers), and NaN and ±infinity in every float field, each as an error of
that field, listed with the model's other errors.
"""

from __future__ import annotations

import types
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin

import yaml
from pydantic import BaseModel, ConfigDict, ModelWrapValidatorHandler, ValidationError, model_validator
from pydantic_core import ErrorDetails, InitErrorDetails, PydanticCustomError

from rig.errors import ConfigError

__all__ = [
    "SettingsModel",
    "describe_field_errors",
    "expects_number",
    "field_errors",
    "path_in_config",
    "read_config_file",
]

_BOOLEAN = PydanticCustomError("boolean_number", "must be a number, not a boolean")


def expects_number(annotation: Any) -> bool:
    """Whether a field of this type takes a number: int, float, a Literal of numbers, or an
    optional or a tuple of those (not bool, which is a number to Python)."""
    if annotation in (int, float):
        return True
    origin = get_origin(annotation)
    args = get_args(annotation)
    if origin is Literal:
        return bool(args) and all(type(a) in (int, float) for a in args)
    if origin in (Union, types.UnionType, tuple):
        return any(a is not type(None) and a is not Ellipsis and expects_number(a) for a in args)
    return False


def _holds_boolean(value: Any) -> bool:
    items = value if isinstance(value, list | tuple) else (value,)
    return any(isinstance(v, bool) for v in items)


class SettingsModel(BaseModel):
    """A configuration model: booleans are no numbers, numbers are finite (see module doc)."""

    model_config = ConfigDict(allow_inf_nan=False)

    # A wrap validator of the model, not a field validator on "*": that would also wrap the
    # discriminator of the camera and fault kinds, which pydantic refuses.
    @model_validator(mode="wrap")
    @classmethod
    def _no_boolean_numbers(cls, data: Any, handler: ModelWrapValidatorHandler[Any]) -> Any:
        flagged = set()
        if isinstance(data, dict):
            flagged = {
                name
                for name, field in cls.model_fields.items()
                if name in data and expects_number(field.annotation) and _holds_boolean(data[name])
            }
        if not flagged:
            return handler(data)
        errors = [InitErrorDetails(type=_BOOLEAN, loc=(name,), input=data[name]) for name in sorted(flagged)]
        try:  # the other fields' errors too, so that one answer lists every mistake
            handler({k: v for k, v in data.items() if k not in flagged})
        except ValidationError as err:
            errors += [
                InitErrorDetails(type=e["type"], loc=e["loc"], input=e["input"], ctx=e.get("ctx", {}))
                for e in err.errors(include_url=False)
                if not (e["loc"] and e["loc"][0] in flagged)
            ]
        raise ValidationError.from_exception_data(cls.__name__, errors)


def field_errors(
    err: ValidationError | Sequence[ErrorDetails], *, prefix: tuple[str, ...] = (), hide: tuple[str, ...] = ()
) -> list[tuple[str, str]]:
    """``(field, message)`` of every error in ``err`` (or in a list of its errors), in order: the
    field as a dotted path after ``prefix``, without the parts in ``hide`` (union tags such as a
    camera's kind, which the config file does not spell); the message without pydantic's
    "Value error, "."""
    out = []
    for e in err.errors(include_url=False) if isinstance(err, ValidationError) else err:
        path = ".".join(str(p) for p in (*prefix, *e["loc"]) if p not in hide)
        out.append((path, e["msg"].removeprefix("Value error, ")))
    return out


def describe_field_errors(errors: list[tuple[str, str]]) -> str:
    """``field 'a': message; field 'b': message`` (one line for any number of mistakes)."""
    return "; ".join(f"field '{path or '<root>'}': {msg}" for path, msg in errors)


def read_config_file(path: Path) -> dict[str, Any]:
    """The mapping a YAML config file holds (``{}`` for an empty file); ConfigError naming the
    file when it is missing, unreadable, not YAML or not a mapping."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: config file unreadable ({err})") from err
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML ({' '.join(str(err).split())})") from err
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: the config file must hold a mapping (server, cameras, ...)")
    return doc


def path_in_config(value: Any, base: Path) -> Any:
    """A path value of a config file in directory ``base``: a relative one is relative to the
    file, as most tools read them; anything else is returned as it is (validation names it)."""
    if isinstance(value, str) and value and not Path(value).expanduser().is_absolute():
        return str(base / value)
    return value
