"""The one on-disk cache of balance-opt: compiled planner kernels, the Pinocchio-CasADi bridge and
Ipopt's option catalog, in ``$BALANCE_OPT_CACHE``, else ``$XDG_CACHE_HOME/balance-opt``
(``~/.cache/balance-opt``), with the file lock its builders share."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

#: Environment variable that moves the cache folder.
CACHE_ENV = "BALANCE_OPT_CACHE"


def default_cache_dir() -> Path:
    """The cache folder: ``$BALANCE_OPT_CACHE``, else ``$XDG_CACHE_HOME/balance-opt``
    (``~/.cache/balance-opt``)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "balance-opt"


@contextlib.contextmanager
def file_lock(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` (POSIX ``flock``; no lock where ``fcntl`` is missing), so
    that one process builds a cached artefact while the others wait for it."""
    try:
        import fcntl
    except ImportError:  # Windows: concurrent builds stay correct (atomic rename)
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
