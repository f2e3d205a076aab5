"""Typed configuration: frozen dataclasses are the single source of truth for a file format.

A format is a tree of frozen dataclasses whose fields are declared with :func:`setting` (a
``dataclasses.field`` that also carries a description, a unit and value constraints). From that
one declaration this module derives

* the validator, :func:`from_data`: plain data (from :mod:`balance_opt.io.yaml_lines`) to typed
  objects, every error naming the file, the line and the key path and what was expected;
* the JSON Schema, :func:`json_schema`, for editors;
* the reference table of the README, :func:`reference_rows`.

Supported field types: ``bool``, ``int``, ``float`` (an int is accepted), ``str``,
``Literal[...]``, ``tuple[T, ...]`` (a YAML list), ``dict[str, T]`` (a mapping with free keys),
``T | None``, unions of those, nested dataclasses, and *tagged unions*: a union of dataclasses
that each have a ``type: Literal["..."]`` field, chosen by the ``type`` key.

A dataclass may set ``__exactly_one__ = ("a", "b", ...)``: exactly one of these keys must be
given.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Sequence
from typing import Any, Literal, Union

from balance_opt.io.yaml_lines import YamlDocument

_MISSING = dataclasses.MISSING


def setting(
    default: Any = _MISSING,
    *,
    doc: str,
    unit: str | None = None,
    factory=None,
    minimum: float | None = None,
    exclusive_minimum: float | None = None,
    maximum: float | None = None,
    min_items: int | None = None,
    max_items: int | None = None,
):
    """A dataclass field of a typed configuration.

    Args:
        default: the value when the key is left out; leave out for a required key.
        doc: one sentence: what the value means.
        unit: unit of the number(s), e.g. ``"rad/s"``.
        factory: a default factory instead of ``default`` (for dicts and dataclasses).
        minimum, exclusive_minimum, maximum: bounds of a number (of each number in a list).
        min_items, max_items: bounds on the length of a list.
    """
    meta = {
        "doc": doc,
        "unit": unit,
        "minimum": minimum,
        "exclusive_minimum": exclusive_minimum,
        "maximum": maximum,
        "min_items": min_items,
        "max_items": max_items,
    }
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


# ----------------------------------------------------------------------------------- type helpers
def _is_union(tp) -> bool:
    return typing.get_origin(tp) in (Union, types.UnionType)


def _union_args(tp) -> tuple:
    return typing.get_args(tp) if _is_union(tp) else (tp,)


def _tag_of(cls) -> str | None:
    """The ``type`` literal of a tagged-union member, or None."""
    if not dataclasses.is_dataclass(cls):
        return None
    tp = typing.get_type_hints(cls).get("type")
    if typing.get_origin(tp) is Literal and len(typing.get_args(tp)) == 1:
        return typing.get_args(tp)[0]
    return None


def _describe(tp) -> str:
    """Human name of a type, as used in 'expected ...' messages and the reference."""
    if tp is type(None):
        return "null"
    if _is_union(tp):
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if all(_tag_of(a) for a in members):
            return "a mapping with type: " + " | ".join(_tag_of(a) for a in members)
        return " or ".join(_describe(a) for a in members)
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"a list of {_plural(typing.get_args(tp)[0])}"
    if origin is dict:
        return f"a mapping of names to {_plural(typing.get_args(tp)[1])}"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        tp, str(tp)
    )


def _plural(tp) -> str:
    if _is_union(tp):
        return " or ".join(_plural(a) for a in typing.get_args(tp) if a is not type(None))
    origin = typing.get_origin(tp)
    if origin is tuple:
        return f"lists of {_plural(typing.get_args(tp)[0])}"
    if origin is dict or dataclasses.is_dataclass(tp):
        return "mappings"
    if origin is Literal:
        return "names (" + ", ".join(repr(a) for a in typing.get_args(tp)) + ")"
    return {bool: "booleans", int: "integers", float: "numbers", str: "strings"}.get(tp, str(tp))


def _got(value) -> str:
    kind = {
        dict: "a mapping",
        list: "a list",
        str: "a string",
        bool: "a boolean",
        int: "an integer",
        float: "a number",
        type(None): "nothing (null)",
    }.get(type(value), type(value).__name__)
    if isinstance(value, (dict, list)):
        return kind
    if isinstance(value, bool):
        return f"{str(value).lower()} ({kind})"
    return f"{value!r} ({kind})"


def suggest(name: Any, candidates) -> str:
    """``"; did you mean 'x'?"`` for close matches, else ``""``."""
    names = [str(c) for c in candidates]
    close = difflib.get_close_matches(str(name), names, n=3)
    if not close and len(str(name)) >= 3:  # an abbreviation: 'accel' for 'acceleration'
        close = [c for c in names if c.startswith(str(name))][:3]
    return f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""


# ----------------------------------------------------------------------------------- validation
class _Invalid(Exception):
    """Internal: a value at ``path`` does not fit; turned into a TaskFileError by from_data."""

    def __init__(self, path: tuple, reason: str):
        self.path = path
        self.reason = reason


def _check_number(value: float, meta: dict, path: tuple) -> None:
    lo, xlo, hi = meta.get("minimum"), meta.get("exclusive_minimum"), meta.get("maximum")
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if math.isnan(value):
        raise _Invalid(path, "expected a number, got NaN")
    if xlo is not None and not value > xlo:
        raise _Invalid(path, f"must be greater than {xlo:g}{unit}, got {value:g}")
    if lo is not None and not value >= lo:
        raise _Invalid(path, f"must be at least {lo:g}{unit}, got {value:g}")
    if hi is not None and not value <= hi:
        raise _Invalid(path, f"must be at most {hi:g}{unit}, got {value:g}")


def _convert(value: Any, tp, meta: dict, path: tuple) -> Any:
    if _is_union(tp):
        return _convert_union(value, tp, meta, path)
    origin = typing.get_origin(tp)
    if origin is Literal:
        options = typing.get_args(tp)
        if value not in options or isinstance(value, bool) != isinstance(options[0], bool):
            raise _Invalid(
                path,
                f"expected one of {', '.join(repr(o) for o in options)}, got {_got(value)}"
                + (suggest(value, options) if isinstance(value, str) else ""),
            )
        return value
    if origin is tuple:
        if not isinstance(value, list):
            raise _Invalid(path, f"expected {_describe(tp)}, got {_got(value)}")
        n_lo, n_hi = meta.get("min_items"), meta.get("max_items")
        if n_lo is not None and n_lo == n_hi and len(value) != n_lo:
            raise _Invalid(
                path,
                f"expected a list of {n_lo} {_plural(typing.get_args(tp)[0])}, got {len(value)}",
            )
        if n_lo is not None and len(value) < n_lo:
            raise _Invalid(path, f"expected at least {n_lo} items, got {len(value)}")
        if n_hi is not None and len(value) > n_hi:
            raise _Invalid(path, f"expected at most {n_hi} items, got {len(value)}")
        item_meta = {k: meta.get(k) for k in ("minimum", "exclusive_minimum", "maximum", "unit")}
        return tuple(
            _convert(v, typing.get_args(tp)[0], item_meta, (*path, i)) for i, v in enumerate(value)
        )
    if origin is dict:
        if not isinstance(value, dict):
            raise _Invalid(path, f"expected {_describe(tp)}, got {_got(value)}")
        value_tp = typing.get_args(tp)[1]
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise _Invalid((*path, k), f"expected a name as key, got {_got(k)}")
            out[k] = _convert(v, value_tp, meta, (*path, k))
        return out
    if dataclasses.is_dataclass(tp):
        return _convert_dataclass(value, tp, path)
    if tp is bool:
        if not isinstance(value, bool):
            raise _Invalid(path, f"expected true or false, got {_got(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _Invalid(path, f"expected an integer, got {_got(value)}")
        _check_number(value, meta, path)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _Invalid(path, f"expected a number, got {_got(value)}")
        _check_number(float(value), meta, path)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise _Invalid(path, f"expected a string, got {_got(value)}")
        if not value.strip():
            raise _Invalid(path, "expected a non-empty string")
        return value
    if tp is Any:
        return value
    raise TypeError(f"typed_config: unsupported field type {tp!r} at {path}")


def _convert_union(value, tp, meta, path):
    members = typing.get_args(tp)
    if value is None:
        if type(None) in members:
            return None
        raise _Invalid(path, f"expected {_describe(tp)}, got nothing (null)")
    members = [m for m in members if m is not type(None)]
    tags = {_tag_of(m): m for m in members}
    if None not in tags:  # tagged union: dispatch on 'type'
        if not isinstance(value, dict):
            raise _Invalid(
                path, f"expected a mapping with a 'type' key ({', '.join(tags)}), got {_got(value)}"
            )
        if "type" not in value:
            raise _Invalid(path, f"missing key 'type'; expected one of {', '.join(tags)}")
        tag = value["type"]
        if tag not in tags:
            raise _Invalid(
                (*path, "type"),
                f"expected one of {', '.join(repr(t) for t in tags)}, got {_got(tag)}"
                + suggest(tag, tags),
            )
        return _convert(value, tags[tag], meta, path)
    if len(members) == 1:
        return _convert(value, members[0], meta, path)
    first_error = None
    for m in members:
        try:
            return _convert(value, m, meta, path)
        except _Invalid as exc:
            # prefer an error found deeper inside the value (it fit the member's shape)
            if first_error is None or len(exc.path) > len(first_error.path):
                first_error = exc
    if first_error is not None and len(first_error.path) > len(path):
        raise first_error
    raise _Invalid(path, f"expected {_describe(tp)}, got {_got(value)}")


def _convert_dataclass(value, cls, path):
    if not isinstance(value, dict):
        raise _Invalid(path, f"expected a mapping, got {_got(value)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    for key in value:
        if key not in fields:
            raise _Invalid(
                (*path, key),
                f"unknown key '{key}'; expected one of {', '.join(fields)}" + suggest(key, fields),
            )
    one_of = getattr(cls, "__exactly_one__", ())
    if one_of:
        given = [k for k in one_of if value.get(k) is not None]
        if len(given) != 1:
            what = "none" if not given else ", ".join(given)
            raise _Invalid(path, f"expected exactly one of {', '.join(one_of)}; got {what}")
    kwargs = {}
    for name, f in fields.items():
        if name in value:
            kwargs[name] = _convert(value[name], hints[name], dict(f.metadata), (*path, name))
        elif f.default is _MISSING and f.default_factory is _MISSING:
            raise _Invalid(
                path,
                f"missing required key '{name}' ({_describe(hints[name])}: {f.metadata.get('doc', '')})",
            )
    return cls(**kwargs)


def from_data(cls, doc: YamlDocument, path: Sequence[Any] = ()):
    """Typed ``cls`` instance from the plain data of ``doc`` (at ``path`` inside it).

    Raises:
        TaskFileError: naming the file, the line and the key path of the first bad value, and what
            was expected there.
    """
    value = doc.data
    for part in path:
        value = value[part]
    try:
        return _convert(value, cls, {}, tuple(path))
    except _Invalid as exc:
        raise doc.error(exc.path, exc.reason) from None


# ----------------------------------------------------------------------------------- JSON Schema
def _schema(tp, meta: dict, defs: dict) -> dict:
    if _is_union(tp):
        members = typing.get_args(tp)
        if all(_tag_of(m) for m in members if m is not type(None)):
            return {"oneOf": [_schema(m, meta, defs) for m in members]}
        return {"anyOf": [_schema(m, meta, defs) for m in members]}
    origin = typing.get_origin(tp)
    if tp is type(None):
        return {"type": "null"}
    if origin is Literal:
        return {"enum": list(typing.get_args(tp))}
    if origin is tuple:
        out = {"type": "array", "items": _schema(typing.get_args(tp)[0], _number_meta(meta), defs)}
        if meta.get("min_items") is not None:
            out["minItems"] = meta["min_items"]
        if meta.get("max_items") is not None:
            out["maxItems"] = meta["max_items"]
        return out
    if origin is dict:
        return {
            "type": "object",
            "additionalProperties": _schema(typing.get_args(tp)[1], meta, defs),
        }
    if dataclasses.is_dataclass(tp):
        name = tp.__name__
        if name not in defs:
            defs[name] = None  # placeholder against recursion
            defs[name] = dataclass_schema(tp, defs)
        return {"$ref": f"#/$defs/{name}"}
    if tp in (int, float):
        out = {"type": "integer" if tp is int else "number"}
        if meta.get("minimum") is not None:
            out["minimum"] = meta["minimum"]
        if meta.get("exclusive_minimum") is not None:
            out["exclusiveMinimum"] = meta["exclusive_minimum"]
        if meta.get("maximum") is not None:
            out["maximum"] = meta["maximum"]
        return out
    if tp is bool:
        return {"type": "boolean"}
    if tp is str:
        return {"type": "string", "minLength": 1}
    if tp is Any:
        return {}
    raise TypeError(f"typed_config: unsupported field type {tp!r}")


def _number_meta(meta: dict) -> dict:
    return {k: meta.get(k) for k in ("minimum", "exclusive_minimum", "maximum")}


def _json_default(value):
    if dataclasses.is_dataclass(value):
        return {f.name: _json_default(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple):
        return [_json_default(v) for v in value]
    if isinstance(value, dict):
        return {k: _json_default(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _field_default(f):
    if f.default is not _MISSING:
        return f.default
    if f.default_factory is not _MISSING:
        return f.default_factory()
    return _MISSING


def dataclass_schema(cls, defs: dict) -> dict:
    """JSON Schema object of one dataclass (nested dataclasses go to ``defs``)."""
    hints = typing.get_type_hints(cls)
    props, required = {}, []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        meta = dict(f.metadata)
        prop = _schema(hints[f.name], meta, defs)
        doc = meta.get("doc", "")
        if meta.get("unit"):
            doc = f"{doc} [{meta['unit']}]"
        if "$ref" in prop:
            prop = {"allOf": [prop]}
        prop["description"] = doc
        default = _field_default(f)
        if default is _MISSING:
            required.append(f.name)
        elif default is not None:
            prop["default"] = _json_default(default)
        props[f.name] = prop
    out = {
        "type": "object",
        "description": (cls.__doc__ or "").strip().split("\n\n")[0],
        "properties": props,
        "additionalProperties": False,
    }
    if _tag_of(cls) and "type" not in required:
        required.insert(0, "type")  # the tag selects the member: always given
    if required:
        out["required"] = required
    one_of = getattr(cls, "__exactly_one__", ())
    if one_of:
        out["oneOf"] = [{"required": [k]} for k in one_of]
    return out


def json_schema(cls, title: str, schema_id: str | None = None) -> dict:
    """JSON Schema (draft 2020-12) of the format whose root is the dataclass ``cls``."""
    defs: dict = {}
    root = dataclass_schema(cls, defs)
    out = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title}
    if schema_id:
        out["$id"] = schema_id
    out.update(root)
    if defs:
        out["$defs"] = defs
    return out


# ----------------------------------------------------------------------------------- reference
def _default_text(f) -> str:
    default = _field_default(f)
    if default is _MISSING:
        return "required"
    if dataclasses.is_dataclass(default):
        return "see below"
    if default is None:
        return "none"
    if isinstance(default, bool):
        return str(default).lower()
    if isinstance(default, float) and math.isinf(default):
        return "inf" if default > 0 else "-inf"
    if isinstance(default, (tuple, dict)) and not default:
        return "[]" if isinstance(default, tuple) else "{}"
    return repr(default) if isinstance(default, str) else str(_json_default(default))


def reference_rows(cls, prefix: str = "") -> list[tuple[str, str, str, str]]:
    """Rows ``(key path, type, default, meaning)`` of every key of the format, depth first.

    Tagged-union members are listed under ``prefix (type: tag)``.
    """
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp, meta = hints[f.name], dict(f.metadata)
        key = f"{prefix}{f.name}"
        doc = meta.get("doc", "")
        if meta.get("unit"):
            doc = f"{doc} [{meta['unit']}]"
        members = [m for m in _union_args(tp) if m is not type(None)]
        if len(members) > 1 and all(_tag_of(m) for m in members):
            rows.append((key, _describe(tp), _default_text(f), doc))
            for m in members:
                for sub in reference_rows(m, f"{key}."):
                    if sub[0] == f"{key}.type":
                        continue
                    rows.append((f"{sub[0]} (type: {_tag_of(m)})", *sub[1:]))
            continue
        if len(members) == 1 and dataclasses.is_dataclass(members[0]):
            rows.append((key, "mapping", _default_text(f), doc))
            rows.extend(reference_rows(members[0], f"{key}."))
            continue
        if typing.get_origin(tp) is dict and dataclasses.is_dataclass(typing.get_args(tp)[1]):
            rows.append((key, "mapping of names to mappings", _default_text(f), doc))
            rows.extend(reference_rows(typing.get_args(tp)[1], f"{key}.NAME."))
            continue
        rows.append((key, _describe(tp), _default_text(f), doc))
    return rows


def reference_markdown(cls) -> str:
    """The reference table of the format as Markdown (key, type, default, meaning)."""
    lines = ["| key | type | default | meaning |", "| --- | --- | --- | --- |"]
    for key, tp, default, doc in reference_rows(cls):
        cells = (
            f"`{key}`",
            tp,
            f"`{default}`" if default not in ("required", "see below", "none") else default,
            doc,
        )
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)
