"""The one on-disk cache of balance-opt: compiled planner kernels, the Pinocchio-CasADi bridge and
Ipopt's option catalog, in ``$BALANCE_OPT_CACHE``, else ``$XDG_CACHE_HOME/balance-opt``
(``~/.cache/balance-opt``).

The rules that keep it harmless, shared by every builder:

* a file lock per artefact (:func:`file_lock`): one process builds, the others wait;
* builds happen in a temporary folder named after the host and the process
  (:func:`build_dir`), and the result is renamed into place atomically; a build killed part-way
  leaves that folder behind, and :func:`clean_stale` removes it once its process is gone (or
  after :data:`STALE_SECONDS` when the process cannot be checked);
* a record beside each artefact holds its SHA-256 and size (:func:`write_record`), checked
  before the artefact is used (:func:`check_record`): a truncated or foreign file is rebuilt,
  never loaded.

The inventory and the size bound (``balance-opt cache``) are in :mod:`balance_opt.cache_admin`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import socket
import tempfile
import time
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
def file_lock(path: Path, blocking: bool = True) -> Iterator[None]:
    """An exclusive lock on ``path`` (POSIX ``flock``; no lock where ``fcntl`` is missing), so
    that one process builds a cached artefact while the others wait for it.

    Raises:
        BlockingIOError: ``blocking`` is false and another process holds the lock.
    """
    try:
        import fcntl
    except ImportError:  # Windows: concurrent builds stay correct (atomic rename)
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


# ----------------------------------------------------------------------------- temporary builds
#: Age [s] after which a temporary build whose process cannot be checked (another host, or a
#: name without a process id) is deemed abandoned: longer than the slowest build.
STALE_SECONDS = 3600.0
_TMP_MARK = ".tmp-"
_TMP_NAME = re.compile(r"\.tmp-(?P<host>.+)-(?P<pid>\d+)-[^-]*$")
#: Names ``tempfile`` gives without a prefix (left by builds of earlier versions).
_LEGACY_TMP = re.compile(r"^tmp[a-z0-9_]{8}$")


def _tmp_prefix(stem: str) -> str:
    return f"{stem}{_TMP_MARK}{socket.gethostname()}-{os.getpid()}-"


@contextlib.contextmanager
def build_dir(folder: Path, stem: str) -> Iterator[Path]:
    """A temporary folder in ``folder`` for building ``stem``, removed on exit; its name holds
    the host and process id, so that :func:`clean_stale` can tell a killed build from a live one.
    """
    with tempfile.TemporaryDirectory(prefix=_tmp_prefix(stem), dir=folder) as tmp:
        yield Path(tmp)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``path`` through a temporary file and an atomic rename (readers see the old or the
    new content, never a part)."""
    fd, tmp = tempfile.mkstemp(prefix=_tmp_prefix(path.name), dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; the cache may be shared
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def is_stale(path: Path, now: float | None = None) -> bool:
    """Whether ``path`` is the leftover of a killed build: its process (on this host) is gone,
    or it is older than :data:`STALE_SECONDS` when that cannot be checked."""
    match = _TMP_NAME.search(path.name)
    if match is None and not _LEGACY_TMP.match(path.name):
        return False
    if match is not None and match["host"] == socket.gethostname():
        pid = int(match["pid"])
        return pid != os.getpid() and not pid_alive(pid)
    try:
        age = (time.time() if now is None else now) - path.lstat().st_mtime
    except OSError:
        return False
    return age > STALE_SECONDS


def clean_stale(folder: Path) -> list[Path]:
    """Remove the leftovers of killed builds in ``folder`` and its sub-folders; returns them."""
    removed = []
    for root, dirs, files in os.walk(folder):
        for name in [*dirs, *files]:
            path = Path(root) / name
            if is_stale(path):
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    with contextlib.suppress(OSError):
                        path.unlink()
                removed.append(path)
        dirs[:] = [d for d in dirs if _TMP_MARK not in d and not _LEGACY_TMP.match(d)]
    return removed


# ----------------------------------------------------------------------------- integrity records
def record_path(artefact: Path) -> Path:
    """The record beside ``artefact``: its name with the suffix replaced by ``.json``."""
    return artefact.with_suffix(".json")


def sha256_of(path: Path) -> str:
    """The SHA-256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_record(artefact: Path, **extra) -> dict:
    """Record the SHA-256 and size [bytes] of ``artefact`` (plus ``extra``) beside it."""
    record = {"sha256": sha256_of(artefact), "size": artefact.stat().st_size, **extra}
    atomic_write_text(record_path(artefact), json.dumps(record))
    return record


def check_record(artefact: Path) -> tuple[dict | None, str]:
    """``(record, "")`` when ``artefact`` matches its record, else ``(None, why not)``."""
    try:
        size = artefact.stat().st_size
    except OSError:
        return None, "missing"
    try:
        record = json.loads(record_path(artefact).read_text())
    except FileNotFoundError:
        return None, "no record of its SHA-256"
    except (OSError, ValueError) as exc:
        return None, f"unreadable record ({exc})"
    if not isinstance(record, dict) or "sha256" not in record:
        return None, "unreadable record"
    if record.get("size", size) != size:
        return None, f"size {size} bytes, {record['size']} recorded"
    if sha256_of(artefact) != record["sha256"]:
        return None, "SHA-256 differs from the recorded one"
    return record, ""


def touch(path: Path) -> None:
    """Mark ``path`` as just used (its modification time orders the size bound's eviction)."""
    with contextlib.suppress(OSError):
        os.utime(path)
