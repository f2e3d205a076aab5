"""Typed configuration: one declaration per setting (:func:`setting`), for files and Python.

From a tree of frozen dataclasses come the file validator (:func:`from_data`, errors naming
file, line and key path), the check of Python calls (:func:`check_settings`),
:func:`walk_settings`, and in :mod:`balance_opt.config.schema` the JSON Schema and the reference
table. Field types: ``bool``, ``int``, ``float``,
``str``, ``Literal``, ``tuple[T, ...]``, ``dict[str, T]``, optionals, unions, nested dataclasses
and tagged unions (a ``type: Literal[...]`` field). A class may set ``__exactly_one__``.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import re
import types
import typing
from collections.abc import Iterator, Mapping
from typing import Any, Literal, Union

from balance_opt.config.yaml_lines import format_path
from balance_opt.errors import InputError

_MISSING = dataclasses.MISSING


# ------------------------------------------------------------------------------ types in words
@functools.cache
def type_hints(cls) -> dict:
    return typing.get_type_hints(cls)


def is_union(tp) -> bool:
    return typing.get_origin(tp) in (Union, types.UnionType)


def tag_of(cls) -> str | None:
    """The ``type`` literal of a tagged-union member, or None."""
    tp = type_hints(cls).get("type") if dataclasses.is_dataclass(cls) else None
    args = typing.get_args(tp)
    return args[0] if typing.get_origin(tp) is Literal and len(args) == 1 else None


#: Scalar field types: the Python types of their values in files (a bool is no number), their
#: JSON Schema type, and their names for one value and for several.
SCALARS = {
    bool: ((bool,), "boolean", "true or false", "booleans"),
    int: ((int,), "integer", "an integer", "integers"),
    float: ((int, float), "number", "a number", "numbers"),
    str: ((str,), "string", "a string", "strings"),
}


def describe(tp, plural: bool = False) -> str:
    """Human name of a type (of several values of it: ``plural``), as used in 'expected ...'
    messages and the reference."""
    if tp is type(None):
        return "null"
    if is_union(tp):
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if not plural and all(tag_of(a) for a in members):
            return "a mapping with type: " + " | ".join(tag_of(a) for a in members)
        return " or ".join(describe(a, plural) for a in members)
    origin = typing.get_origin(tp)
    if origin is Literal:
        names = ", ".join(repr(a) for a in typing.get_args(tp))
        return f"names ({names})" if plural else f"one of {names}"
    if origin is tuple:
        return ("lists of " if plural else "a list of ") + describe(typing.get_args(tp)[0], True)
    if origin is dict:
        value = describe(typing.get_args(tp)[1], True)
        return "mappings" if plural else f"a mapping of names to {value}"
    if dataclasses.is_dataclass(tp):
        return "mappings" if plural else "a mapping"
    return SCALARS[tp][2 + plural] if tp in SCALARS else str(tp)


def value_words(value) -> str:
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


# ----------------------------------------------------------------------------------- settings
def setting(
    default: Any = _MISSING,
    *,
    doc: str,
    unit: str | None = None,
    factory=None,
    minimum: float | None = None,
    exclusive_minimum: float | None = None,
    finite: bool = True,
    min_items: int | None = None,
    max_items: int | None = None,
    item: str | None = None,
    pattern: tuple[str, str] | None = None,
    per: str | None = None,
    key: str | None = None,
    section: str | None = None,
    inline: bool = False,
    after: str | None = None,
    in_file: bool = True,
):
    """A dataclass field of a typed configuration.

    Args:
        default: the value when the key is left out; leave out for a required key.
        doc: one sentence: what the value means.
        unit: unit of the number(s), e.g. ``"rad/s"``.
        factory: a default factory instead of ``default`` (for dicts and dataclasses).
        minimum, exclusive_minimum: bounds of a number (of each number in a list).
        finite: reject ``inf`` (NaN is always rejected).
        min_items, max_items: bounds on the length of a list.
        item: what the list's items name, for messages (``"joint"``: ``"must name at least
            one joint"``).
        pattern: ``(regular expression, the rule in words)`` a string must match in full.
        per: the list holds one value per item of this kind (e.g. ``"balance joint"``); checked
            by the user of :func:`walk_settings`, who knows how many there are.
        key, section, inline, after, in_file: the key's name in files, the mapping it sits in
            (described in the class's ``__sections__``), a nested dataclass's keys written
            in the parent's mapping, the key it is listed after, whether files have it.
    """
    meta = {k: v for k, v in locals().items() if k not in ("default", "factory")}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def field_default(f):
    if f.default is not _MISSING:
        return f.default
    if f.default_factory is not _MISSING:
        return f.default_factory()
    return _MISSING


# ----------------------------------------------------------------------------------- file layout
@dataclasses.dataclass(frozen=True)
class Leaf:
    """A key of the file bound to a field: ``attrs`` is the attribute path from the class whose
    layout holds it (more than one name through ``inline`` fields)."""

    key: str
    attrs: tuple[str, ...]
    field: dataclasses.Field
    tp: Any

    @property
    def meta(self) -> dict:
        return dict(self.field.metadata)


@dataclasses.dataclass(frozen=True)
class Section:
    """A mapping of the file whose keys are fields of the enclosing class (``section=``)."""

    key: str
    doc: str
    name: str
    entries: tuple


def _prefixed(entry, name: str):
    """``entry`` of an inline field ``name``: its attribute paths start with ``name``."""
    if isinstance(entry, Section):
        return dataclasses.replace(entry, entries=tuple(_prefixed(e, name) for e in entry.entries))
    return dataclasses.replace(entry, attrs=(name, *entry.attrs))


@functools.cache
def file_layout(cls) -> tuple:
    """The keys of ``cls``'s mapping in the file, in order: leaves and sections."""
    hints = type_hints(cls)
    entries: list = []
    sections: dict[str, list] = {}
    late: list[Leaf] = []
    for f in dataclasses.fields(cls):
        meta = f.metadata
        if not f.init or not meta.get("in_file", True):
            continue
        if meta.get("inline"):
            entries.extend(_prefixed(e, f.name) for e in file_layout(hints[f.name]))
            continue
        leaf = Leaf(meta.get("key") or f.name, (f.name,), f, hints[f.name])
        if meta.get("section"):
            if meta["section"] not in sections:
                sections[meta["section"]] = []
                entries.append(meta["section"])  # placeholder, filled below
            sections[meta["section"]].append(leaf)
        elif meta.get("after"):
            late.append(leaf)
        else:
            entries.append(leaf)
    docs = getattr(cls, "__sections__", {})
    entries = [
        Section(e, docs[e], f"{cls.__name__}.{e}", tuple(sections[e])) if isinstance(e, str) else e
        for e in entries
    ]
    for leaf in late:
        keys = [e.key for e in entries]
        entries.insert(keys.index(leaf.field.metadata["after"]) + 1, leaf)
    keys = [e.key for e in entries]
    assert len(keys) == len(set(keys)), f"{cls.__name__}: a key is declared twice: {keys}"
    return tuple(entries)


def get_attr(obj, attrs: tuple[str, ...]):
    return functools.reduce(getattr, attrs, obj)


# ----------------------------------------------------------------------------------- validation
@dataclasses.dataclass(eq=False)  # hashable by identity, as exceptions are
class _Invalid(Exception):
    """Internal: a value at ``path`` does not fit; turned into an InputError by the callers."""

    path: tuple
    reason: str


NUMBER_META = ("minimum", "exclusive_minimum", "finite", "unit")


def _check_number(value: float, meta: dict, path: tuple) -> None:
    lo, xlo = meta.get("minimum"), meta.get("exclusive_minimum")
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if math.isnan(value):
        raise _Invalid(path, "expected a number, got NaN")
    if math.isinf(value) and meta.get("finite", True):
        raise _Invalid(path, f"expected a finite number, got {value:g}")
    if xlo is not None and not value > xlo:
        raise _Invalid(path, f"must be greater than {xlo:g}{unit}, got {value:g}")
    if lo is not None and not value >= lo:
        raise _Invalid(path, f"must be at least {lo:g}{unit}, got {value:g}")


def _convert_list(value: list, tp, meta: dict, path: tuple) -> tuple:
    n_lo, n_hi = meta.get("min_items"), meta.get("max_items")
    if n_lo is not None and len(value) < n_lo and meta.get("item"):
        got = f"got {len(value)}" if value else "got an empty list"
        items = f"one {meta['item']}" if n_lo == 1 else f"{n_lo} {meta['item']}s"
        raise _Invalid(path, f"must name at least {items}, {got}")
    if n_lo is not None and n_lo == n_hi and len(value) != n_lo:
        raise _Invalid(
            path,
            f"expected a list of {n_lo} {describe(typing.get_args(tp)[0], True)}, got {len(value)}",
        )
    if n_lo is not None and len(value) < n_lo:
        raise _Invalid(path, f"expected at least {n_lo} items, got {len(value)}")
    if n_hi is not None and len(value) > n_hi:
        raise _Invalid(path, f"expected at most {n_hi} items, got {len(value)}")
    item_meta = {k: meta.get(k) for k in NUMBER_META}
    return tuple(
        _convert(v, typing.get_args(tp)[0], item_meta, (*path, i)) for i, v in enumerate(value)
    )


def _convert(value: Any, tp, meta: dict, path: tuple) -> Any:
    if is_union(tp):
        return _convert_union(value, tp, meta, path)
    origin = typing.get_origin(tp)
    if origin is Literal:
        options = typing.get_args(tp)
        if value not in options or isinstance(value, bool) != isinstance(options[0], bool):
            raise _Invalid(
                path,
                f"expected one of {', '.join(repr(o) for o in options)}, got {value_words(value)}"
                + (suggest(value, options) if isinstance(value, str) else ""),
            )
        return value
    if tp is Any or (dataclasses.is_dataclass(tp) and isinstance(value, tp)):
        return value  # a dataclass built in Python checked itself
    if not _same_kind(value, tp):
        raise _Invalid(path, f"expected {describe(tp)}, got {value_words(value)}")
    if origin is tuple:
        return _convert_list(value, tp, meta, path)
    if origin is dict:
        value_tp = typing.get_args(tp)[1]
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise _Invalid((*path, k), f"expected a name as key, got {value_words(k)}")
            out[k] = _convert(v, value_tp, meta, (*path, k))
        return out
    if dataclasses.is_dataclass(tp):
        tree: dict = {}
        _read_mapping(value, file_layout(tp), path, tree, getattr(tp, "__exactly_one__", ()))
        return _build(tp, tree, path)
    if tp in (int, float):
        _check_number(value, meta, path)
        return tp(value)
    if tp is str and not value.strip():
        raise _Invalid(path, "expected a non-empty string")
    if tp is str and meta.get("pattern") and not re.fullmatch(meta["pattern"][0], value):
        raise _Invalid(path, f"{value!r} is not allowed here: use {meta['pattern'][1]}")
    return value


def _convert_union(value, tp, meta, path):
    members = typing.get_args(tp)
    if value is None:
        if type(None) in members:
            return None
        raise _Invalid(path, f"expected {describe(tp)}, got nothing (null)")
    members = [m for m in members if m is not type(None)]
    if any(dataclasses.is_dataclass(m) and isinstance(value, m) for m in members):
        return value  # built in Python: it checked itself
    tags = {tag_of(m): m for m in members}
    if None not in tags:  # tagged union: dispatch on 'type'
        if not isinstance(value, dict):
            raise _Invalid(
                path,
                f"expected a mapping with a 'type' key ({', '.join(tags)}), got {value_words(value)}",
            )
        if "type" not in value:
            raise _Invalid(path, f"missing key 'type'; expected one of {', '.join(tags)}")
        tag = value["type"]
        if tag not in tags:
            raise _Invalid(
                (*path, "type"),
                f"expected one of {', '.join(repr(t) for t in tags)}, got {value_words(tag)}"
                + suggest(tag, tags),
            )
        return _convert(value, tags[tag], meta, path)
    if len(members) == 1:
        return _convert(value, members[0], meta, path)
    errors = []
    for m in members:
        try:
            return _convert(value, m, meta, path)
        except _Invalid as exc:
            errors.append(exc)
    # The most telling error: one found deeper inside the value (it fit the member's shape),
    # the one reason every member gave (an empty list where each member wants items), or that
    # of the only member of the value's kind (inf for a number or a list of numbers).
    deepest = max(errors, key=lambda e: len(e.path))
    fitting = [e for m, e in zip(members, errors) if _same_kind(value, m)]
    if len(deepest.path) > len(path) or len({e.reason for e in errors}) == 1:
        raise deepest
    if len(fitting) == 1:
        raise fitting[0]
    raise _Invalid(path, f"expected {describe(tp)}, got {value_words(value)}")


def _same_kind(value, tp) -> bool:
    """Whether ``value`` is of the kind of ``tp`` (a list for a tuple...), whatever its content."""
    origin = typing.get_origin(tp)
    if origin is tuple:
        return isinstance(value, list)
    if origin is dict or dataclasses.is_dataclass(tp):
        return isinstance(value, dict)
    if origin is Literal:
        return isinstance(value, str)
    if tp in SCALARS:
        return isinstance(value, SCALARS[tp][0]) and (tp is bool or not isinstance(value, bool))
    raise TypeError(f"typed_config: unsupported field type {tp!r}")


def _read_mapping(value: dict, entries: tuple, path: tuple, tree: dict, one_of=()) -> None:
    """Convert the keys of mapping ``value`` into ``tree``, keyword arguments by attribute path."""
    keys = {e.key: e for e in entries}
    for key in value:
        if key not in keys:
            raise _Invalid(
                (*path, key),
                f"unknown key '{key}'; expected one of {', '.join(keys)}" + suggest(key, keys),
            )
    if one_of:
        given = [k for k in one_of if value.get(k) is not None]
        if len(given) != 1:
            what = "none" if not given else ", ".join(given)
            raise _Invalid(path, f"expected exactly one of {', '.join(one_of)}; got {what}")
    for e in entries:
        if isinstance(e, Section):
            if e.key in value:
                sub = value[e.key]
                if not isinstance(sub, dict):
                    raise _Invalid((*path, e.key), f"expected a mapping, got {value_words(sub)}")
                _read_mapping(sub, e.entries, (*path, e.key), tree)
        elif e.key in value:
            node = tree
            for name in e.attrs[:-1]:
                node = node.setdefault(name, {})
            node[e.attrs[-1]] = _convert(value[e.key], e.tp, e.meta, (*path, e.key))
        elif field_default(e.field) is _MISSING:
            raise _Invalid(
                path,
                f"missing required key '{e.key}' ({describe(e.tp)}: {e.meta.get('doc', '')})",
            )


def _build(cls, tree: dict, path: tuple):
    """``cls`` from the keyword arguments ``tree``, its own checks' errors located at ``path``."""
    inline = {f.name for f in dataclasses.fields(cls) if f.metadata.get("inline")}
    kwargs = {
        name: _build(type_hints(cls)[name], value, path) if name in inline else value
        for name, value in tree.items()
    }
    try:
        return cls(**kwargs)
    except InputError as exc:
        raise _Invalid(path, str(exc)) from None


def from_data(cls, doc):
    """The dataclass ``cls`` (the root of a format) from the plain data of ``doc``; the first
    bad value raises a TaskFileError naming file, line, key path and what was expected."""
    try:
        return _convert(doc.data, cls, {}, ())
    except _Invalid as exc:
        raise doc.error(exc.path, exc.reason) from None


def _plain(value):
    """A Python value as the plain data of a file: sequences and arrays as lists, NumPy scalars
    as Python numbers, mappings as dicts; dataclasses are kept."""
    if (
        value is None
        or isinstance(value, (str, bool, int, float))
        or dataclasses.is_dataclass(value)
    ):
        return value
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist"):  # NumPy arrays and scalars
        return _plain(value.tolist())
    return value


def check_settings(obj, what: str) -> None:
    """Check and normalise the fields of the frozen dataclass ``obj`` against their
    :func:`setting` declarations (for its ``__post_init__``): lists and arrays become tuples of
    Python numbers, mappings dicts, ints given for floats floats.

    Raises:
        InputError: ``"<what> '<name>': <problem>"`` for the first field that does not fit
            (``what``: e.g. ``"planner option"``).
    """
    hints = type_hints(type(obj))
    for f in dataclasses.fields(obj):
        if "doc" not in f.metadata:
            continue
        value = getattr(obj, f.name)
        try:
            converted = _convert(_plain(value), hints[f.name], dict(f.metadata), (f.name,))
        except _Invalid as exc:
            raise InputError(f"{what} '{format_path(exc.path)}': {exc.reason}") from None
        if converted is not value:
            object.__setattr__(obj, f.name, converted)


def walk_settings(obj, path: tuple = (), entries=None) -> Iterator[tuple[tuple, Any, dict]]:
    """Every value of the typed tree ``obj``: ``(key path in the file, value, declaration)``,
    depth first (the values of nested dataclasses, not the dataclasses)."""
    for e in file_layout(type(obj)) if entries is None else entries:
        if isinstance(e, Section):
            yield from walk_settings(obj, (*path, e.key), e.entries)
            continue
        value = get_attr(obj, e.attrs)
        if dataclasses.is_dataclass(value):
            yield from walk_settings(value, (*path, e.key))
        else:
            yield (*path, e.key), value, e.meta
