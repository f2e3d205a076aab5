"""Types of a file format in words: what a setting expects ("a list of numbers") and what a
file gave ("a string"), for validation messages and the reference table."""

from __future__ import annotations

import dataclasses
import difflib
import functools
import types
import typing
from typing import Any, Literal, Union


@functools.cache
def type_hints(cls) -> dict:
    return typing.get_type_hints(cls)


def is_union(tp) -> bool:
    return typing.get_origin(tp) in (Union, types.UnionType)


def union_args(tp) -> tuple:
    return typing.get_args(tp) if is_union(tp) else (tp,)


def tag_of(cls) -> str | None:
    """The ``type`` literal of a tagged-union member, or None."""
    if not dataclasses.is_dataclass(cls):
        return None
    tp = type_hints(cls).get("type")
    if typing.get_origin(tp) is Literal and len(typing.get_args(tp)) == 1:
        return typing.get_args(tp)[0]
    return None


def describe(tp) -> str:
    """Human name of a type, as used in 'expected ...' messages and the reference."""
    if tp is type(None):
        return "null"
    if is_union(tp):
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if all(tag_of(a) for a in members):
            return "a mapping with type: " + " | ".join(tag_of(a) for a in members)
        return " or ".join(describe(a) for a in members)
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"a list of {plural(typing.get_args(tp)[0])}"
    if origin is dict:
        return f"a mapping of names to {plural(typing.get_args(tp)[1])}"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        tp, str(tp)
    )


def plural(tp) -> str:
    if is_union(tp):
        return " or ".join(plural(a) for a in typing.get_args(tp) if a is not type(None))
    origin = typing.get_origin(tp)
    if origin is tuple:
        return f"lists of {plural(typing.get_args(tp)[0])}"
    if origin is dict or dataclasses.is_dataclass(tp):
        return "mappings"
    if origin is Literal:
        return "names (" + ", ".join(repr(a) for a in typing.get_args(tp)) + ")"
    return {bool: "booleans", int: "integers", float: "numbers", str: "strings"}.get(tp, str(tp))


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
