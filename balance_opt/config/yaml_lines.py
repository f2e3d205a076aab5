"""YAML documents that remember the 1-based line of every key path (``("mission", "goal", 2)``,
printed ``mission.goal[2]``), so validation errors can say where the culprit is. Unlike
``yaml.safe_load``, a key given twice is an error and ``1e-3`` is a float.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from balance_opt.errors import InputError

#: A key path: mapping keys (str) and sequence positions (int), outermost first.
KeyPath = tuple[Any, ...]


def format_path(path: Sequence[Any]) -> str:
    """``("mission", "goal", 2)`` -> ``"mission.goal[2]"``; the empty path is ``"(top level)"``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out or "(top level)"


class TaskFileError(InputError):
    """An error in a YAML file: ``FILE:LINE: KEY.PATH: reason`` (so editors can jump to the
    line); ``source`` is ``"<dict>"`` for data built in Python, ``line`` ``None`` when unknown."""

    def __init__(self, source: str, line: int | None, path: Sequence[Any], reason: str):
        self.source = source
        self.line = line
        self.path = tuple(path)
        self.reason = reason
        where = f"{source}:{line}" if line is not None else source
        super().__init__(f"{where}: {format_path(path)}: {reason}")


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e-3`` as a float."""


_FLOAT_TAG = "tag:yaml.org,2002:float"
_FLOAT = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.VERBOSE,
)
_Loader.yaml_implicit_resolvers = {
    k: [r for r in v if r[0] != _FLOAT_TAG]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(_FLOAT_TAG, _FLOAT, list("-+0123456789."))


@dataclass(frozen=True)
class YamlDocument:
    """Plain data read from a YAML file (``source`` names it in errors), with the 1-based line
    of each key path present in the file."""

    data: Any
    source: str
    lines: dict[KeyPath, int] = field(default_factory=dict, repr=False)

    def line_of(self, path: Sequence[Any]) -> int | None:
        """Line of ``path``, or of its nearest ancestor present in the file (``None`` if none)."""
        path = tuple(path)
        while path and path not in self.lines:
            path = path[:-1]
        return self.lines.get(path)

    def error(self, path: Sequence[Any], reason: str, cls=TaskFileError) -> TaskFileError:
        """A :class:`TaskFileError` (or its subclass ``cls``) located at ``path``."""
        return cls(self.source, self.line_of(path), path, reason)


def _build(node: yaml.Node, loader: _Loader, path: KeyPath, lines: dict, source: str) -> Any:
    lines.setdefault(path, node.start_mark.line + 1)  # a mapping value: its key's line
    if isinstance(node, yaml.MappingNode):
        loader.flatten_mapping(node)  # resolve '<<' merge keys
        out: dict = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                raise TaskFileError(
                    source, key_node.start_mark.line + 1, path, "a mapping key must be a plain name"
                )
            key = loader.construct_object(key_node)
            if key in out:
                raise TaskFileError(
                    source,
                    key_node.start_mark.line + 1,
                    (*path, key),
                    f"key '{key}' is given twice (first on line {lines[(*path, key)]})",
                )
            lines[(*path, key)] = key_node.start_mark.line + 1
            out[key] = _build(value_node, loader, (*path, key), lines, source)
        return out
    if isinstance(node, yaml.SequenceNode):
        return [
            _build(item, loader, (*path, i), lines, source) for i, item in enumerate(node.value)
        ]
    return loader.construct_object(node, deep=True)


def parse_yaml(text: str, source: str) -> YamlDocument:
    """Parse YAML ``text``; ``source`` names it in error messages (a syntax error with its line,
    a duplicate key, an empty document)."""
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise TaskFileError(
                source, None, (), "the file is empty; expected a mapping of task keys"
            )
        lines: dict[KeyPath, int] = {}
        data = _build(node, loader, (), lines, source)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        context = exc.context or ""
        if exc.context and exc.context_mark is not None and exc.context_mark.line + 1 != line:
            context = f"{exc.context} that starts on line {exc.context_mark.line + 1}:"
        problem = " ".join(p for p in (context, exc.problem) if p)
        raise TaskFileError(source, line, (), f"YAML syntax error: {problem}") from None
    except yaml.YAMLError as exc:
        raise TaskFileError(source, None, (), f"YAML error: {exc}") from None
    finally:
        loader.dispose()
    return YamlDocument(data, source, lines)


def load_yaml(path: str | Path) -> YamlDocument:
    """Read and parse the YAML file at ``path`` (see :func:`parse_yaml`)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TaskFileError(str(path), None, (), "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise TaskFileError(str(path), None, (), f"cannot read the file: {exc}") from None
    return parse_yaml(text, str(path))
