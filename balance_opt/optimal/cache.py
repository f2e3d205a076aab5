"""Where balance-opt keeps what it computes once per machine: the compiled planner kernels, the
Pinocchio-CasADi bridge and Ipopt's option list.

A module of its own, importing nothing heavy, so that validating a task finds the cached option
list without importing CasADi.
"""

from __future__ import annotations

import os
from pathlib import Path

#: Environment variable naming the cache folder (default: the user cache folder).
CACHE_ENV = "BALANCE_OPT_CACHE"


def default_cache_dir() -> Path:
    """The cache folder: ``$BALANCE_OPT_CACHE``, else ``$XDG_CACHE_HOME/balance-opt``
    (``~/.cache/balance-opt``)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "balance-opt"
