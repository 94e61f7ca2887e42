"""Technique options: one way to declare a knob (default, bounds, choices, help) and one set of validators.

Every technique's ``Options`` is a frozen dataclass whose fields are made by :func:`option`.  The
field's metadata is the single source of

* validation (:func:`check_options`, called from each ``Options.__post_init__``, so a bad value is
  refused the same way from Python, the CLI and the HTTP API),
* parsing of loosely typed input (:func:`options_from_mapping`: JSON bodies, ``--option k=v``),
* the published description (:func:`describe_options`: ``GET /v1/techniques``,
  ``farfield techniques``, the dashboard's job form).

Types are strict: a boolean is not a number, a string is not a number, and numbers are finite.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from typing import Any, Literal, get_args, get_origin

from farfield.core.errors import LayerPlanError

# Fields that describe the output image a job serves; a job gives them at its top level
# ("resolution", "fov_deg"), not among the technique's "options".
IMAGE_FIELDS = ("resolution", "fov_deg")


def option(default: Any, help: str, *, ge: float | None = None, gt: float | None = None, le: float | None = None,
           lt: float | None = None, choices: tuple | None = None, internal: bool = False) -> Any:  # fmt: skip
    """A dataclass field of a technique's ``Options``.

    ``ge``/``gt`` and ``le``/``lt`` bound numbers (``gt``, ``lt``: exclusive); ``choices`` lists the
    allowed values of a string, or of each item of a tuple; ``internal`` hides a field from the
    job API and the published description (e.g. switches that only demonstrate a failure).
    """
    meta = {"help": help, "ge": ge, "gt": gt, "le": le, "lt": lt, "choices": choices, "internal": internal}
    if isinstance(default, (list, dict, set)):
        raise TypeError("option defaults must be immutable")
    return dataclasses.field(default=default, metadata={"farfield": meta})


def _meta(field: dataclasses.Field) -> dict:
    return field.metadata.get(
        "farfield", {"help": "", "ge": None, "gt": None, "le": None, "lt": None, "choices": None, "internal": False}
    )


def _hints(cls: type) -> dict:
    return typing.get_type_hints(cls)


def _base_type(hint: Any) -> tuple[Any, bool]:
    """(the type without ``None``, whether ``None`` is allowed)."""
    origin = get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in get_args(hint) if a is not type(None)]
        return (args[0] if len(args) == 1 else typing.Union[tuple(args)]), len(args) < len(get_args(hint))  # noqa: UP007 - built at run time
    return hint, False


def _kind(hint: Any) -> str:
    """'integer', 'number', 'boolean', 'string' or 'array' (of strings)."""
    if hint is bool:
        return "boolean"
    if hint is int:
        return "integer"
    if hint is float:
        return "number"
    if hint is str or get_origin(hint) is Literal:
        return "string"
    if get_origin(hint) is tuple:
        return "array"
    raise TypeError(f"unsupported option type {hint!r}")


def _choices(hint: Any, meta: dict) -> tuple | None:
    if meta["choices"] is not None:
        return tuple(meta["choices"])
    if get_origin(hint) is Literal:
        return get_args(hint)
    if get_origin(hint) is tuple:
        item = get_args(hint)[0]
        if get_origin(item) is Literal:
            return get_args(item)
    return None


def _range_text(meta: dict) -> str:
    low = "[" if meta.get("ge") is not None else "(" if meta.get("gt") is not None else None
    high = "]" if meta.get("le") is not None else ")" if meta.get("lt") is not None else None
    lo = meta.get("ge") if meta.get("ge") is not None else meta.get("gt")
    hi = meta.get("le") if meta.get("le") is not None else meta.get("lt")
    if low and high:
        return f" in {low}{lo:g}, {hi:g}{high}"
    if low:
        return f" {'>=' if low == '[' else '>'} {lo:g}"
    if high:
        return f" {'<=' if high == ']' else '<'} {hi:g}"
    return ""


def check_value(name: str, value: Any, hint: Any, meta: dict) -> Any:
    """``value`` for the field ``name`` (tuples normalised), or LayerPlanError naming the field.

    >>> check_value("grid_cell", 8, int, {"ge": 1, "gt": None, "le": 256, "choices": None})
    8
    >>> check_value("grid_cell", True, int, {"ge": 1, "gt": None, "le": 256, "choices": None})
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: grid_cell must be an integer in [1, 256], got True
    >>> check_value("enlargement", float("nan"), float, {"ge": 1, "gt": None, "le": 8, "choices": None})
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: enlargement must be a number in [1, 8], got nan
    """
    base, nullable = _base_type(hint)
    if value is None:
        if nullable:
            return None
        raise LayerPlanError(f"{name} must be given (it has no 'none' value)")
    kind = _kind(base)
    choices = _choices(base, meta)
    if kind == "boolean":
        if not isinstance(value, bool):
            raise LayerPlanError(f"{name} must be true or false, got {value!r}")
        return value
    if kind in ("integer", "number"):
        noun = "an integer" if kind == "integer" else "a number"
        message = f"{name} must be {noun}{_range_text(meta)}, got {value!r}"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise LayerPlanError(message)
        if kind == "integer" and (isinstance(value, float) and not value.is_integer()):
            raise LayerPlanError(message)
        if isinstance(value, float) and not math.isfinite(value):
            raise LayerPlanError(message)
        bounds = [(meta.get("ge"), lambda b: value < b), (meta.get("gt"), lambda b: value <= b),
                  (meta.get("le"), lambda b: value > b), (meta.get("lt"), lambda b: value >= b)]  # fmt: skip
        if any(bound is not None and outside(bound) for bound, outside in bounds):
            raise LayerPlanError(message)
        return int(value) if kind == "integer" else float(value)
    if kind == "string":
        if not isinstance(value, str) or (choices is not None and value not in choices):
            allowed = f" out of {list(choices)}" if choices is not None else ""
            raise LayerPlanError(f"{name} must be a string{allowed}, got {value!r}")
        return value
    # array of strings (also one comma-separated string, as on the command line)
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    items = tuple(value) if isinstance(value, (list, tuple)) else None
    if (
        items is None
        or not all(isinstance(v, str) for v in items)
        or (choices is not None and any(v not in choices for v in items))
    ):
        allowed = f" out of {list(choices)}" if choices is not None else ""
        raise LayerPlanError(f"{name} must be a list of strings{allowed}, got {value!r}")
    return items


def check_options(options: Any) -> None:
    """Validate every field of an ``Options`` instance from its metadata (called by ``__post_init__``);
    tuples given as lists are stored as tuples."""
    hints = _hints(type(options))
    for field in dataclasses.fields(options):
        value = check_value(field.name, getattr(options, field.name), hints[field.name], _meta(field))
        if value is not getattr(options, field.name):
            object.__setattr__(options, field.name, value)


def public_fields(cls: type) -> list[dataclasses.Field]:
    """The fields of ``cls`` a job or the CLI may set (not ``internal``)."""
    return [f for f in dataclasses.fields(cls) if not _meta(f)["internal"]]


def options_from_mapping(
    cls: type, values: Mapping[str, Any], what: str = "technique parameters", unlisted: tuple[str, ...] = ()
) -> Any:
    """An ``Options`` instance from a mapping of field names to JSON-like values (unknown names and
    bad values raise LayerPlanError naming them; ``unlisted`` names are accepted but not listed as
    known in that message)."""
    known = [f.name for f in public_fields(cls)]
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise LayerPlanError(f"unknown {what} {unknown}; known: {[k for k in known if k not in unlisted]}")
    try:
        return cls(**values)
    except TypeError as error:  # e.g. a value the dataclass machinery itself refuses
        raise LayerPlanError(f"bad {what} {dict(values)}: {error}") from None


def parse_option_text(cls: type, name: str, text: str) -> Any:
    """The value of ``--option name=text`` for a field of ``cls``: a number, true/false, none, or a
    comma-separated list for list options; strings as given.

    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class O:
    ...     n: int = option(1, "n")
    ...     d: tuple[str, ...] = option(("a",), "d")
    >>> parse_option_text(O, "n", "3"), parse_option_text(O, "d", "a, b")
    (3, ('a', 'b'))
    """
    fields = {f.name: f for f in public_fields(cls)}
    if name not in fields:
        raise LayerPlanError(f"unknown option {name!r}; known: {list(fields)}")
    base, nullable = _base_type(_hints(cls)[name])
    kind = _kind(base)
    text = text.strip()
    if nullable and text.lower() in ("none", "null", ""):
        return None
    if kind == "boolean":
        lowered = text.lower()
        if lowered in ("true", "yes", "on", "1"):
            return True
        if lowered in ("false", "no", "off", "0"):
            return False
        raise LayerPlanError(f"{name} must be true or false, got {text!r}")
    if kind in ("integer", "number"):
        try:
            number = float(text)
        except ValueError:
            raise LayerPlanError(f"{name} must be a number, got {text!r}") from None
        return int(number) if kind == "integer" and number.is_integer() else number
    if kind == "array":
        return tuple(t.strip() for t in text.split(",") if t.strip())
    return text


def describe_options(cls: type) -> list[dict]:
    """One JSON-ready entry per public field: name, type, nullable, default, bounds, choices, help."""
    hints = _hints(cls)
    out = []
    for field in public_fields(cls):
        meta = _meta(field)
        base, nullable = _base_type(hints[field.name])
        default = field.default
        out.append({
            "name": field.name,
            "type": _kind(base),
            "nullable": nullable,
            "default": list(default) if isinstance(default, tuple) else default,
            "minimum": meta["ge"],
            "exclusive_minimum": meta["gt"],
            "maximum": meta["le"],
            "exclusive_maximum": meta["lt"],
            "choices": list(_choices(base, meta)) if _choices(base, meta) is not None else None,
            "help": meta["help"],
        })  # fmt: skip
    return out


def stored_values(options: Any) -> dict:
    """The public fields of an ``Options`` instance but the image fields, JSON-ready (tuples as lists):
    what a job stores, so that equal options are stored alike however they were spelled and a job
    means the same thing if a default changes."""
    out = {}
    for field in public_fields(type(options)):
        if field.name not in IMAGE_FIELDS:
            value = getattr(options, field.name)
            out[field.name] = list(value) if isinstance(value, tuple) else value
    return out


def options_json_schema(cls: type) -> dict:
    """A JSON Schema object of the public fields of ``cls`` but the image fields (what a job's
    ``options`` may hold), each with its type, default, bounds, choices and help as ``description``.

    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class O:
    ...     n: int = option(1, "how many", ge=1, le=9)
    >>> options_json_schema(O)["properties"]["n"]
    {'type': 'integer', 'description': 'how many', 'default': 1, 'minimum': 1, 'maximum': 9}
    """
    properties = {}
    for entry in describe_options(cls):
        if entry["name"] in IMAGE_FIELDS:
            continue
        schema: dict = {"type": entry["type"], "description": entry["help"], "default": entry["default"]}
        for key, name in (
            ("minimum", "minimum"),
            ("exclusive_minimum", "exclusiveMinimum"),
            ("maximum", "maximum"),
            ("exclusive_maximum", "exclusiveMaximum"),
        ):
            if entry[key] is not None:
                schema[name] = entry[key]
        if entry["choices"] is not None:
            if entry["type"] == "array":
                schema["items"] = {"type": "string", "enum": entry["choices"]}
            else:
                schema["enum"] = entry["choices"]
        if entry["nullable"]:
            schema["type"] = [schema["type"], "null"]
        properties[entry["name"]] = schema
    return {"type": "object", "additionalProperties": False, "properties": properties}
