"""What the cache holds, its size bound, and clearing it (``balance-opt cache``, ``docs/cache.md``).

The size bound deletes the least recently used planner kernels, planner models and bridge
functions, never the bridge program, whose build takes minutes."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from balance_opt.cache import _LEGACY_TMP, _TMP_MARK, file_lock, is_stale, record_path

log = logging.getLogger(__name__)

#: Environment variable bounding the cache size: bytes, or a number with K, M, G (powers of 1024).
LIMIT_ENV = "BALANCE_OPT_CACHE_LIMIT"
#: The default bound [bytes].
DEFAULT_LIMIT = 2 * 1024**3
KINDS = ("planner kernels", "planner models", "bridge", "Ipopt options", "temporary", "other")
BRIDGE_FOLDER = "pinocchio-bridge"
MODELS_FOLDER = "planner-models"
#: Kinds whose records (``.json`` beside the artefact) are listed with their artefact.
_RECORDED = ("planner kernels", "planner models", "bridge")
_UNITS = {"": 1, "K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}


@dataclass
class Entry:
    """One artefact of the cache with its record (if any); ``name`` is its path relative to the
    cache folder, ``last_used`` the latest modification of its files (POSIX time).
    """

    kind: str
    name: str
    files: list[Path] = field(default_factory=list)
    size: int = 0
    last_used: float = 0.0

    @property
    def evictable(self) -> bool:
        """Planner kernels and models, bridge functions (rebuilt in seconds to minutes when
        needed)."""
        return self.kind in ("planner kernels", "planner models") or (
            self.kind == "bridge" and self.name.endswith(".casadi")
        )

    @property
    def lock(self) -> Path:
        return self.files[0].parent / f"{self.files[0].name}.lock"


def size_limit() -> int:
    """The cache's size bound [bytes]: ``$BALANCE_OPT_CACHE_LIMIT`` or :data:`DEFAULT_LIMIT`."""
    text = os.environ.get(LIMIT_ENV, "").strip()
    if not text:
        return DEFAULT_LIMIT
    match = re.fullmatch(r"(\d+(?:\.\d*)?)\s*([KMGT]?)i?B?", text, re.IGNORECASE)
    if match is None:
        log.warning("%s=%r is not a size (e.g. 500M, 2G); using 2G", LIMIT_ENV, text)
        return DEFAULT_LIMIT
    return int(float(match[1]) * _UNITS[match[2].upper()])


def _kind(relative: Path) -> str:
    if any(_TMP_MARK in part or _LEGACY_TMP.match(part) for part in relative.parts):
        return "temporary"
    if relative.parts[0] == BRIDGE_FOLDER:
        return "bridge"
    if relative.parts[0] == MODELS_FOLDER:
        return "planner models"
    if relative.name.startswith("balance_kernels_"):
        return "planner kernels"
    if relative.name.startswith("ipopt-options-"):
        return "Ipopt options"
    return "other"


def _walk(folder: Path) -> Iterable[Path]:
    """Files and temporary folders under ``folder`` (a temporary folder counts as one item)."""
    for root, dirs, files in os.walk(folder):
        temporary = [d for d in dirs if _TMP_MARK in d or _LEGACY_TMP.match(d)]
        dirs[:] = [d for d in dirs if d not in temporary]
        yield from (Path(root) / name for name in [*temporary, *files])


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def entries(folder: Path) -> list[Entry]:
    """The artefacts in ``folder`` (lock files left out), each with its record."""
    found: dict[Path, Entry] = {}
    for path in _walk(folder):
        relative = path.relative_to(folder)
        kind = _kind(relative)
        if path.name.endswith(".lock") and kind != "temporary":
            continue
        # a record is listed with its artefact (same name, suffix .json)
        key = path
        if path.suffix == ".json" and kind in _RECORDED:
            siblings = [p for p in path.parent.glob(f"{path.stem}*") if p != path]
            artefacts = [
                p
                for p in siblings
                if record_path(p) == path and p.is_file() and not p.name.endswith(".lock")
            ]
            key = artefacts[0] if artefacts else path
        with contextlib.suppress(OSError):
            entry = found.setdefault(key, Entry(kind, str(key.relative_to(folder))))
            entry.files.insert(0, path) if path == key else entry.files.append(path)
            entry.size += _size(path)
            entry.last_used = max(entry.last_used, path.stat().st_mtime)
    return sorted(found.values(), key=lambda e: (KINDS.index(e.kind), e.name))


def _remove(entry: Entry) -> None:
    for path in entry.files:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()


def enforce_limit(folder: Path, keep: Iterable[Path] = (), limit: int | None = None) -> list[Entry]:
    """Delete least recently used evictable entries while ``folder`` exceeds ``limit`` [bytes].

    Entries in use (their lock held by another process) and the files in ``keep`` stay.

    Returns:
        The entries deleted.
    """
    limit = size_limit() if limit is None else limit
    all_entries = entries(folder)
    total = sum(e.size for e in all_entries)
    keep = {Path(p) for p in keep}
    evicted = []
    candidates = [e for e in all_entries if e.evictable and not keep & set(e.files)]
    for entry in sorted(candidates, key=lambda e: e.last_used):
        if total <= limit:
            break
        try:
            with file_lock(entry.lock, blocking=False):
                _remove(entry)
        except BlockingIOError:  # being built or loaded by another process
            continue
        total -= entry.size
        evicted.append(entry)
        log.info(
            "cache over %.0f MB: evicted %s (%.1f MB)", limit / 1e6, entry.name, entry.size / 1e6
        )
    return evicted


def clear(folder: Path) -> tuple[list[Entry], list[Entry]]:
    """Delete every entry of the cache, each under its lock (waiting for a build under way).

    Temporary builds of live processes are left alone. Lock files no process holds are removed.

    Returns:
        ``(entries deleted, entries kept because in use)``.
    """
    deleted, kept = [], []
    for entry in entries(folder):
        if entry.kind == "temporary":
            if not is_stale(entry.files[0]):
                kept.append(entry)
                continue
            _remove(entry)
        else:
            with file_lock(entry.lock):
                _remove(entry)
        deleted.append(entry)
    for lock in folder.rglob("*.lock"):
        with contextlib.suppress(BlockingIOError, OSError), file_lock(lock, blocking=False):
            lock.unlink()
    for sub in sorted(folder.rglob("*"), reverse=True):  # empty sub-folders, deepest first
        if (
            sub.is_dir()
            and _kind(sub.relative_to(folder)) != "temporary"
            and not any(sub.iterdir())
        ):
            sub.rmdir()
    return deleted, kept


def format_size(size: float) -> str:
    """``size`` [bytes] in B, kB, MB or GB (powers of 1000)."""
    for unit in ("B", "kB", "MB"):
        if size < 1000:
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1000
    return f"{size:.2f} GB"
