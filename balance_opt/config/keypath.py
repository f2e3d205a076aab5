"""Key paths: where a value sits in a nested mapping, e.g. ``("mission", "goal", 2)``.

Shared by the YAML reader (:mod:`balance_opt.config.yaml_lines`, which records the line of every
path) and the typed configuration (:mod:`balance_opt.config.typed_config`, which names the path of
a bad value), so that both print a path the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

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
