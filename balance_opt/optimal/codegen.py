"""Compiling the planner's CasADi kernels to C, with an on-disk cache shared by processes.

:func:`compile_functions` generates the C code of a list of CasADi functions, compiles it into
one shared library named by the hash of that code (and of the compiler, its flags, CasADi's
version and the platform), and loads the functions back as ``casadi.external``. The library is
kept in the cache folder (:func:`default_cache_dir`), so a robot's kernels are compiled once per
machine. A file lock makes concurrent processes (the sweep's workers) wait for one compilation
instead of each compiling; the library is renamed into place atomically, so no process ever
loads a partial file.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as cs

from balance_opt.cache import default_cache_dir, file_lock

log = logging.getLogger(__name__)

#: C compiler flags of the compiled kernels. -O1: on the paper robot the kernels run as fast as
#: with -O2 or -O3 (the differences measured were within the timing noise) and compile faster
#: than with -O2 (19 s against 24 s, gcc); no -march=native or -ffast-math, so that results do
#: not depend on the machine.
COMPILER_FLAGS = ("-O1", "-shared", "-fPIC")
#: Environment variable naming the folder of compiled kernels (default: the user cache folder).


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
    elapsed = 0.0
    folder.mkdir(parents=True, exist_ok=True)
    with file_lock(folder / f"{library.name}.lock"):  # one process compiles, the others wait
        if not library.is_file():
            elapsed = _compile(compiler, source, library)
    # finite differences only let CasADi build (never evaluate) derivative graphs it asks for
    return (
        [cs.external(f.name(), str(library), {"enable_fd": True}) for f in functions],
        elapsed,
        str(library),
    )


def _compile(compiler: str, source: str, library: Path) -> float:
    """Compile C ``source`` to the shared ``library``; returns the wall time [s]."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
        c_file = Path(tmp) / "balance_kernels.c"
        c_file.write_text(source)
        out = Path(tmp) / library.name
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
