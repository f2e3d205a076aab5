"""Compiling the planner's CasADi kernels to C, with an on-disk cache shared by processes.

:func:`compile_functions` generates the C code of a list of CasADi functions, compiles it into
one shared library named by the hash of that code (and of the compiler, its flags, CasADi's
version and the platform), and loads the functions back as ``casadi.external``. The library is
kept in the cache folder (:func:`default_cache_dir`), so a robot's kernels are compiled once per
machine. Loading a damaged library would crash the process (a truncated one: bus error), so the
cache's rules apply (:mod:`balance_opt.cache`): a file lock makes concurrent processes wait for
one compilation; the library is built in a temporary folder and renamed into place; its SHA-256
and size are recorded beside it and checked before every load, and a library that does not match
is deleted and rebuilt. After a build the cache is trimmed to its size bound
(:func:`balance_opt.cache_admin.enforce_limit`).
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import time
from pathlib import Path

import casadi as cs

from balance_opt.cache import (
    build_dir,
    check_record,
    clean_stale,
    default_cache_dir,
    file_lock,
    record_path,
    touch,
    write_record,
)
from balance_opt.cache_admin import enforce_limit

log = logging.getLogger(__name__)

#: C compiler flags of the compiled kernels. -O1: on the paper robot the kernels run as fast as
#: with -O2 or -O3 (the differences measured were within the timing noise) and compile faster
#: than with -O2 (19 s against 24 s, gcc); no -march=native or -ffast-math, so that results do
#: not depend on the machine.
COMPILER_FLAGS = ("-O1", "-shared", "-fPIC")


def find_compiler() -> str | None:
    """A C compiler on the PATH (``$CC``, ``cc``, ``gcc``, ``clang``), or ``None``."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def compile_functions(
    functions: list[cs.Function], cache_dir: Path | None = None
) -> tuple[list[cs.Function], float, str]:
    """Compile CasADi functions to one shared library, cached on disk by the hash of their C code.

    Args:
        functions: SX functions (distinct names).
        cache_dir: folder of the libraries (default :func:`default_cache_dir`).

    Returns:
        ``(external functions, compile time [s] (0 if cached), library path)``.

    Raises:
        OSError: no C compiler, or the compiler failed (the caller falls back to SX).
    """
    generator = cs.CodeGenerator("balance_kernels.c", {"with_header": False})
    for f in functions:
        generator.add(f)
    source = generator.dump()
    compiler = find_compiler()
    if compiler is None:
        raise OSError("no C compiler found (tried $CC, cc, gcc, clang)")
    fingerprint = [
        source,
        compiler,
        " ".join(COMPILER_FLAGS),
        cs.__version__,
        platform.machine(),
        platform.system(),
    ]
    digest = hashlib.sha256("\n".join(fingerprint).encode()).hexdigest()[:20]
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    library = folder / f"balance_kernels_{digest}{'.dll' if os.name == 'nt' else '.so'}"
    folder.mkdir(parents=True, exist_ok=True)
    clean_stale(folder)
    with file_lock(folder / f"{library.name}.lock"):  # one process compiles, the others wait
        elapsed = _ensure_library(compiler, source, library)
        touch(record_path(library))  # most recently used: evicted last
        # loaded under the lock, so that no other process evicts it between check and load;
        # finite differences only let CasADi build (never evaluate) derivative graphs it asks for
        externals = [cs.external(f.name(), str(library), {"enable_fd": True}) for f in functions]
    if elapsed:
        enforce_limit(folder, keep=[library, record_path(library)])
    return externals, elapsed, str(library)


def _ensure_library(compiler: str, source: str, library: Path) -> float:
    """Check the cached ``library`` against its record; build it when missing or damaged.
    Returns the compile time [s] (0 if the cached library was intact)."""
    record, problem = check_record(library)
    if record is not None:
        return 0.0
    if problem != "missing":
        log.warning("cached balance kernels %s: %s; deleting and rebuilding", library, problem)
    for path in (library, record_path(library)):
        path.unlink(missing_ok=True)
    elapsed = _compile(compiler, source, library)
    write_record(library, compile_seconds=round(elapsed, 3))
    return elapsed


def _compile(compiler: str, source: str, library: Path) -> float:
    """Compile C ``source`` to the shared ``library``; returns the wall time [s]."""
    start = time.perf_counter()
    with build_dir(library.parent, library.stem) as tmp:
        c_file = tmp / "balance_kernels.c"
        c_file.write_text(source)
        out = tmp / library.name
        proc = subprocess.run(
            [compiler, *COMPILER_FLAGS, str(c_file), "-o", str(out), "-lm"],
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            raise OSError(f"{compiler} failed on the balance kernels: {proc.stderr.strip()[:500]}")
        os.replace(out, library)  # atomic: a process never loads a partial library
    elapsed = time.perf_counter() - start
    log.info("compiled balance kernels to %s in %.1f s", library, elapsed)
    return elapsed
