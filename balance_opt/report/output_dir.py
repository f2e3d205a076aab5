"""All-or-nothing output folders: a run writes into a staging folder beside its target and moves
it into place only when every file is complete.

The staging folder is created at once so a bad location fails before any work. A ``flock`` on a
file beside the target refuses a second run into the same folder (the kernel releases it even
after ``kill -9``). Success swaps the folders in one ``renameat2`` exchange where the system has
it, so a reader never sees files of two runs side by side. Single files rewritten in place (a
sweep's tables) go through :func:`replaced_atomically`."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from balance_opt.cache import pid_alive
from balance_opt.errors import InputError

if TYPE_CHECKING:  # typing.Self is Python 3.11+; annotations are not evaluated at run time
    from typing_extensions import Self

#: Names of the helper entries kept beside a target folder ``NAME``.
STAGING_PREFIX = ".{name}.partial-"
LOCK_NAME = ".{name}.lock"
_RENAME_EXCHANGE = 2  # renameat2 flag (Linux >= 3.15)
_AT_FDCWD = -100


class OutputFolderError(InputError):
    """The output folder cannot be used (not creatable, not empty, or in use)."""


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths with Linux's ``renameat2(RENAME_EXCHANGE)``; False where it is absent."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    rc = renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    if ctypes.get_errno() in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()), str(a))


def _target_path(target: str | Path) -> Path:
    """The absolute target; a symbolic link is followed (the folder is replaced, the link
    kept)."""
    path = Path(target).absolute()
    return path.resolve() if path.is_symlink() else path


def make_parent(target: Path) -> None:
    """Create the folder that will hold ``target``, or raise :class:`OutputFolderError` naming
    what is in the way."""
    if target.exists() and not target.is_dir():
        raise OutputFolderError(f"output folder {target} exists and is not a folder")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        blocking = next((p for p in target.parents if p.exists() and not p.is_dir()), None)
        reason = f"{blocking} is a file" if blocking else exc.strerror or str(exc)
        raise OutputFolderError(f"cannot create output folder {target}: {reason}") from None


class FolderLock:
    """Exclusive lock of a ``target`` folder (its parent must exist: :func:`make_parent`) while
    a run writes to it: ``flock`` on the file ``.NAME.lock`` beside the folder, holding the
    process id of its holder."""

    def __init__(self, target: str | Path):
        self.target = _target_path(target)
        self.path = self.target.parent / LOCK_NAME.format(name=self.target.name)
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock without waiting; :class:`OutputFolderError` names the process that
        holds it."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise OutputFolderError(
                f"cannot create output folder {self.target}: {exc.strerror or exc}"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise OutputFolderError(
                f"output folder {self.target} is being written by another balance-opt run "
                f"(process {holder}); wait for it to finish or choose another --output"
            ) from None
        try:
            same_file = os.stat(self.path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same_file = False
        if not same_file:  # the previous holder removed the file as we opened it: lock anew
            os.close(fd)
            return self.acquire()
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> Self:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


@contextlib.contextmanager
def replaced_atomically(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; when the block ends without error it is
    flushed to disk and renamed onto ``path`` (which holds its old content or the whole new one,
    never a part); on error it is removed. The suffix is kept (matplotlib reads the format from
    it)."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


class OutputFolder:
    """A target folder written all-or-nothing; use as a context manager around the run.

    ``with`` blocks nest: the outermost one commits, an error in any of them aborts, so a caller
    can check and lock the folder before its own work and hand it to
    :func:`~balance_opt.app.pipeline.run_task`.

    Args:
        force: replace a target that exists and is not empty (only once the new run is
            complete); without it such a target is refused before any work.
    """

    def __init__(self, target: str | Path, force: bool = False):
        self.target = _target_path(target)
        self.force = force
        self.staging: Path | None = None
        self._lock = FolderLock(self.target)
        self._depth = 0  # nested ``with`` blocks: the outermost one commits

    def open(self) -> Path:
        """Check the location, take the lock and create the staging folder; returns it (the
        same one if already open)."""
        if self.staging is not None:
            return self.staging
        target, name = self.target, self.target.name
        make_parent(target)
        self._lock.acquire()  # first: a run that ends meanwhile cannot be replaced unasked
        try:
            self._check_replaceable()
        except BaseException:
            self._lock.release()
            raise
        self._remove_dead_staging()
        staging = target.parent / f"{STAGING_PREFIX.format(name=name)}{os.getpid()}"
        try:
            shutil.rmtree(staging, ignore_errors=True)
            staging.mkdir()
        except OSError as exc:
            self._lock.release()
            raise OutputFolderError(
                f"cannot write in output folder {target.parent}: {exc.strerror or exc}"
            ) from None
        self.staging = staging
        return staging

    def _check_replaceable(self) -> None:
        try:
            not_empty = self.target.is_dir() and any(self.target.iterdir())
        except OSError as exc:
            raise OutputFolderError(
                f"cannot read output folder {self.target}: {exc.strerror or exc}"
            ) from None
        if not_empty and not self.force:
            raise OutputFolderError(
                f"output folder {self.target} exists and is not empty; use --force to replace "
                "it (the old results are kept until the new ones are complete), or choose "
                "another --output"
            )

    def _remove_dead_staging(self) -> None:
        prefix = STAGING_PREFIX.format(name=self.target.name)
        for entry in self.target.parent.glob(f"{prefix}*"):
            pid = entry.name[len(prefix) :].split(".")[0]
            if pid.isdigit() and not pid_alive(int(pid)):
                shutil.rmtree(entry, ignore_errors=True)

    def final(self, path: str | Path) -> Path:
        """Where a file written in the staging folder is once the folder is committed."""
        if self.staging is None:
            raise RuntimeError("OutputFolder.final() outside open() and commit()")
        return self.target / Path(path).relative_to(self.staging)

    def commit(self) -> Path:
        """Move the complete staging folder into place (replacing the old target).

        An interruption before the swap leaves the old target as it was (the staging folder is
        deleted); after it, the target holds the new run."""
        if self.staging is None:
            raise RuntimeError("OutputFolder.commit() before open()")
        target, staging = self.target, self.staging
        try:
            if target.exists():
                if not _exchange(staging, target):
                    old = staging.with_name(staging.name + ".old")
                    os.rename(target, old)
                    os.rename(staging, target)
                    staging = old
                shutil.rmtree(staging, ignore_errors=True)  # the old run, now at that path
            else:
                os.rename(staging, target)
        except BaseException:
            self.abort()
            raise
        self.staging = None
        self._lock.release()
        return target

    def abort(self) -> None:
        """Delete the staging folder; the target stays as it was."""
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None
        self._lock.release()

    def __enter__(self) -> Self:
        self.open()
        self._depth += 1
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_) -> None:
        self._depth -= 1
        if exc_type is not None:
            self.abort()
        elif self._depth == 0 and self.staging is not None:  # None: an inner block aborted
            self.commit()
