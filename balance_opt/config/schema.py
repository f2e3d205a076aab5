"""What a typed configuration (:mod:`balance_opt.config.typed_config`) says of itself: its JSON
Schema (:func:`json_schema`) and its Markdown reference table (:func:`reference_markdown`), both
read from the same declarations as the validator."""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, Literal

from balance_opt.config.typed_config import (
    NUMBER_META,
    SCALARS,
    Section,
    describe,
    field_default,
    file_layout,
    get_attr,
    is_union,
    tag_of,
)


# ----------------------------------------------------------------------------------- JSON Schema
def _schema(tp, meta: dict, defs: dict) -> dict:
    if is_union(tp):
        members = typing.get_args(tp)
        if all(tag_of(m) for m in members if m is not type(None)):
            return {"oneOf": [_schema(m, meta, defs) for m in members]}
        return {"anyOf": [_schema(m, meta, defs) for m in members]}
    origin = typing.get_origin(tp)
    if tp is type(None):
        return {"type": "null"}
    if origin is Literal:
        return {"enum": list(typing.get_args(tp))}
    if origin is tuple:
        item_meta = {k: meta.get(k) for k in NUMBER_META}
        out = {"type": "array", "items": _schema(typing.get_args(tp)[0], item_meta, defs)}
        for name, key in (("min_items", "minItems"), ("max_items", "maxItems")):
            if meta.get(name) is not None:
                out[key] = meta[name]
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
    if tp is str:
        if meta.get("pattern"):
            return {"type": "string", "pattern": f"^(?:{meta['pattern'][0]})$"}
        return {"type": "string", "minLength": 1}
    if tp in SCALARS:
        out = {"type": SCALARS[tp][1]}
        for name, key in (("minimum", "minimum"), ("exclusive_minimum", "exclusiveMinimum")):
            if meta.get(name) is not None:
                out[key] = meta[name]
        return out
    if tp is Any:
        return {}
    raise TypeError(f"typed_config: unsupported field type {tp!r}")


def _json_default(value):
    if dataclasses.is_dataclass(value):
        return _entries_data(value, file_layout(type(value)))
    if isinstance(value, tuple):
        return [_json_default(v) for v in value]
    if isinstance(value, dict):
        return {k: _json_default(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _entries_data(obj, entries: tuple) -> dict:
    """The keys of ``entries`` with their values in ``obj`` (``None``: their defaults), as
    plain data laid out as in a file."""
    out = {}
    for e in entries:
        if isinstance(e, Section):
            out[e.key] = _entries_data(obj, e.entries)
        else:
            out[e.key] = _json_default(
                field_default(e.field) if obj is None else get_attr(obj, e.attrs)
            )
    return out


def _doc(meta: dict) -> str:
    doc = meta.get("doc", "")
    return f"{doc} [{meta['unit']}]" if meta.get("unit") else doc


def _object_schema(entries: tuple, description: str, defs: dict) -> tuple[dict, list]:
    """JSON Schema object of a mapping with the keys ``entries``, and its required keys."""
    props, required = {}, []
    for e in entries:
        if isinstance(e, Section):
            if e.name not in defs:
                schema, _ = _object_schema(e.entries, e.doc[:1].upper() + e.doc[1:] + ".", defs)
                defs[e.name] = schema
            props[e.key] = {
                "allOf": [{"$ref": f"#/$defs/{e.name}"}],
                "description": e.doc,
                "default": _entries_data(None, e.entries),
            }
            continue
        prop = _schema(e.tp, e.meta, defs)
        if "$ref" in prop:
            prop = {"allOf": [prop]}
        prop["description"] = _doc(e.meta)
        default = field_default(e.field)
        if default is dataclasses.MISSING:
            required.append(e.key)
        elif default is not None:
            prop["default"] = _json_default(default)
        props[e.key] = prop
    out = {
        "type": "object",
        "description": description,
        "properties": props,
        "additionalProperties": False,
    }
    return out, required


def dataclass_schema(cls, defs: dict) -> dict:
    """JSON Schema object of one dataclass (nested dataclasses go to ``defs``)."""
    description = (cls.__doc__ or "").strip().split("\n\n")[0]
    out, required = _object_schema(file_layout(cls), description, defs)
    if tag_of(cls) and "type" not in required:
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
    default = field_default(f)
    if default is dataclasses.MISSING:
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


def reference_rows(cls, prefix: str = "", entries=None) -> list[tuple[str, str, str, str]]:
    """Rows ``(key path, type, default, meaning)`` of every key of the format, depth first;
    tagged-union members under ``prefix (type: tag)``."""
    rows = []
    for e in file_layout(cls) if entries is None else entries:
        key = f"{prefix}{e.key}"
        if isinstance(e, Section):
            rows.append((key, "mapping", "see below", e.doc))
            rows.extend(reference_rows(cls, f"{key}.", e.entries))
            continue
        tp, doc, default = e.tp, _doc(e.meta), _default_text(e.field)
        members = [
            m for m in (typing.get_args(tp) if is_union(tp) else (tp,)) if m is not type(None)
        ]
        if len(members) == 1 and dataclasses.is_dataclass(members[0]):
            rows.append((key, "mapping", default, doc))
            rows.extend(reference_rows(members[0], f"{key}."))
        elif typing.get_origin(tp) is dict and dataclasses.is_dataclass(typing.get_args(tp)[1]):
            rows.append((key, "mapping of names to mappings", default, doc))
            rows.extend(reference_rows(typing.get_args(tp)[1], f"{key}.NAME."))
        else:
            rows.append((key, describe(tp), default, doc))
        if len(members) > 1 and all(tag_of(m) for m in members):  # tagged union
            for m in members:
                for sub in reference_rows(m, f"{key}."):
                    if sub[0] != f"{key}.type":
                        rows.append((f"{sub[0]} (type: {tag_of(m)})", *sub[1:]))
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
