"""The one on-disk cache of balance-opt (planner kernels, the Pinocchio-CasADi bridge, Ipopt's
option catalog) in ``$BALANCE_OPT_CACHE``, else ``$XDG_CACHE_HOME/balance-opt``.

Shared rules (``docs/cache.md``): a file lock per artefact; builds in a temporary folder named
after host and process, renamed into place (leftovers of killed builds removed by
:func:`clean_stale`); a record of SHA-256 and size checked before use. The size bound evicts
the least recently used kernels, models and bridge functions, never the bridge program. The
compilers that build them run through :func:`run_commands`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

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
    """An exclusive lock on ``path`` (``filelock``: ``flock`` on POSIX, ``msvcrt`` on Windows), a
    new one per call (a second call waits, in this process too); BlockingIOError when not
    ``blocking`` and it is held."""
    import filelock

    # no soft-lock fallback: a soft lock left by a killed process would block every later wait
    lock = filelock.FileLock(path, blocking=blocking, fallback_to_soft=False)
    try:
        lock.acquire()
    except filelock.Timeout as exc:
        raise BlockingIOError(f"{path}: locked (by another process, or another thread)") from exc
    try:
        yield
    finally:
        lock.release()


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
    the host and process id for :func:`clean_stale`."""
    with tempfile.TemporaryDirectory(prefix=_tmp_prefix(stem), dir=folder) as tmp:
        yield Path(tmp)


def atomic_write_text(path: Path, text: str) -> None:
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
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        pass
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


def _is_temporary(name: str) -> bool:
    return _TMP_MARK in name or bool(_LEGACY_TMP.match(name))


def _walk(folder: Path) -> list[Path]:
    """Files and temporary folders under ``folder`` (a temporary folder counts as one item)."""
    found = []
    for root, dirs, files in os.walk(folder):
        temporary = [d for d in dirs if _is_temporary(d)]
        dirs[:] = [d for d in dirs if d not in temporary]
        found += [Path(root) / name for name in [*temporary, *files]]
    return found


def _delete(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _remove(entry) -> None:
    for path in entry.files:
        _delete(path)


def clean_stale(folder: Path) -> list[Path]:
    """Remove the leftovers of killed builds in ``folder`` and its sub-folders; returns them."""
    removed = [path for path in _walk(folder) if is_stale(path)]
    for path in removed:
        _delete(path)
    return removed


# ----------------------------------------------------------------------------- compilers
def first_error(output: str) -> str:
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or ["no message"])[0][:300]


def run_commands(
    commands: list[list[str]],
    stop: threading.Event | None = None,
    tick: Callable[[int], None] | None = None,
    every: float = 30.0,
    timeout: float | None = None,
) -> list[str]:
    """Run ``commands`` (compilers, the bridge program) at once as children of this process and
    wait for all of them; returns the output (stdout and stderr) of each.

    Each runs in a process group of its own, ended whole (a compiler driver and the ``cc1`` it
    started) when this call ends first: interrupted, ``stop`` set (OSError ``stopped``), or
    ``timeout`` [s] past.
    ``tick(group)`` is called every ``every`` [s] with the first command's group. Raises
    OSError with the first error line (:func:`first_error`) of a command that failed."""
    stop = stop if stop is not None else threading.Event()
    procs = []
    with contextlib.ExitStack() as files:
        outputs = [files.enter_context(tempfile.TemporaryFile()) for _ in commands]
        try:
            for command, out in zip(commands, outputs):
                procs.append(
                    subprocess.Popen(
                        command,
                        stdin=subprocess.DEVNULL,
                        stdout=out,
                        stderr=subprocess.STDOUT,
                        start_new_session=os.name == "posix",
                    )
                )
            start, ticks = time.monotonic(), 1
            while running := [proc for proc in procs if proc.poll() is None]:
                if stop.is_set():
                    raise OSError("stopped")
                if timeout is not None and time.monotonic() - start > timeout:
                    raise OSError(f"no answer in {timeout:g} s")
                if tick is not None and time.monotonic() - start >= ticks * every:
                    tick(procs[0].pid)
                    ticks += 1
                # back at once when it ends (a short command takes milliseconds, not a poll)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    running[0].wait(0.05)
        finally:
            for proc in procs:
                if proc.poll() is None:
                    if os.name == "posix":
                        with contextlib.suppress(OSError):
                            os.killpg(proc.pid, signal.SIGKILL)
                    proc.kill()
                    proc.wait()
        texts = []
        for out in outputs:
            out.seek(0)
            texts.append(out.read().decode(errors="replace"))
    for proc, text in zip(procs, texts):
        if proc.returncode != 0:
            raise OSError(first_error(text))
    return texts


# ----------------------------------------------------------------------------- integrity records
def record_path(artefact: Path) -> Path:
    return artefact.with_suffix(".json")


def sha256_of(path: Path) -> str:
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


def kinematics_key(robot) -> str:
    """SHA-256 of what a planner model depends on: the locked URDF (links, joints, inertia,
    locked positions), the arm joints in order and the end-effector frames."""
    content = {
        "urdf": robot.locked_urdf,
        "joints": list(robot.joint_names),
        "arms": [[arm.name, list(arm.joints), arm.ee_frame] for arm in robot.arms],
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def lock_path(artefact: Path) -> Path:
    """The lock file of ``artefact``, held while it is built, checked and loaded, or evicted."""
    return artefact.parent / f"{artefact.name}.lock"


def load_checked(artefact: Path, load: Callable, what: str, then: str, blocking: bool = True):
    """``load(artefact)`` if it matches its record (then touched), under its lock so that no
    other process evicts it meanwhile; else ``None``, a damaged artefact deleted with a warning
    (``cached <what>: <what is wrong>; <then>``)."""
    if not artefact.exists():
        return None
    with file_lock(lock_path(artefact), blocking):
        record, problem = check_record(artefact)
        if record is not None:
            try:
                value = load(artefact)
            except RuntimeError as exc:  # CasADi's, on a file it cannot read
                problem = f"unreadable ({str(exc).strip().splitlines()[-1][:200]})"
            else:
                touch(record_path(artefact))
                return value
        log.warning("cached %s: %s; %s", what, problem, then)
        for path in (artefact, record_path(artefact)):
            path.unlink(missing_ok=True)
    return None


# ----------------------------------------------------------------------------- inventory, bound

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
    """One artefact of the cache with its record (if any); ``name`` relative to the cache
    folder, ``last_used`` the latest modification of its files (POSIX time)."""

    kind: str
    name: str
    files: list[Path] = field(default_factory=list)
    size: int = 0
    last_used: float = 0.0

    @property
    def evictable(self) -> bool:
        """Planner kernels and models, bridge functions (rebuilt when needed)."""
        return self.kind in ("planner kernels", "planner models") or (
            self.kind == "bridge" and self.name.endswith(".casadi")
        )

    @property
    def lock(self) -> Path:
        return lock_path(self.files[0])


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
    if any(_is_temporary(part) for part in relative.parts):
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


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def entries(folder: Path) -> list[Entry]:
    """The artefacts in ``folder`` (lock files left out), each with its record."""
    found: dict[Path, Entry] = {}
    paths = {path: _kind(path.relative_to(folder)) for path in _walk(folder)}
    owners = {record_path(p): p for p in paths if p.suffix not in (".json", ".lock", ".failed")}
    for path, kind in paths.items():
        if path.name.endswith(".lock") and kind != "temporary":
            continue
        key = owners.get(path, path) if kind in _RECORDED else path  # a record: its artefact's
        with contextlib.suppress(OSError):
            entry = found.setdefault(key, Entry(kind, str(key.relative_to(folder))))
            entry.files.insert(0, path) if path == key else entry.files.append(path)
            entry.size += _size(path)
            entry.last_used = max(entry.last_used, path.stat().st_mtime)
    return sorted(found.values(), key=lambda e: (KINDS.index(e.kind), e.name))


def enforce_limit(folder: Path, keep: Iterable[Path] = (), limit: int | None = None) -> list[Entry]:
    """Delete least recently used evictable entries while ``folder`` exceeds ``limit`` [bytes],
    but those in use (lock held elsewhere) or in ``keep``; returns the entries deleted."""
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
    """Delete every entry, each under its lock, but live processes' temporary builds, and the
    lock files no process holds; returns ``(deleted, kept because in use)``."""
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
        if sub.is_dir() and _kind(sub.relative_to(folder)) != "temporary":
            with contextlib.suppress(OSError):  # not empty
                sub.rmdir()
    return deleted, kept


def format_size(size: float) -> str:
    """``size`` [bytes] in B, kB, MB or GB (powers of 1000)."""
    for unit in ("B", "kB", "MB"):
        if size < 1000:
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1000
    return f"{size:.2f} GB"
