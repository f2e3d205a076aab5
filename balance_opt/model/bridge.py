"""The Pinocchio-CasADi bridge: Pinocchio's own algorithms on ``casadi.SX`` from a pip install.

PyPI's ``pin`` wheels lack ``pinocchio.casadi`` but ship Pinocchio's header-only CasADi scalar
support; with the ``casadi`` and ``cmeel-*`` headers, a small C++ program
(``cpp/pinocchio_casadi_bridge.cpp``) is compiled once per machine. Run on a robot, it saves
the centroidal momentum matrix, the end-effector Jacobians and every joint's placement as a
``casadi.Function`` file, which :func:`bridge_function` loads.

Cached in ``<kernel cache>/pinocchio-bridge/``: the program, keyed by its source, compile
command, compiler and library versions, built under a file lock and checked by SHA-256; and each
robot's function, keyed by the program, the locked URDF, the model joints and the frames.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import platform
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as cs

from balance_opt.cache import (
    build_dir,
    check_record,
    default_cache_dir,
    file_lock,
    kinematics_key,
    lock_path,
    run_commands,
    write_record,
)
from balance_opt.errors import BalanceOptError

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("cpp") / "pinocchio_casadi_bridge.cpp"
#: -O0: the program runs once per robot, briefly, so optimizing it would only lengthen the build
#: (which instantiates Pinocchio's templates on casadi::SX).
CXX_FLAGS = ("-std=c++17", "-O0", "-s")
#: The compile definitions Pinocchio 4.1's CMake targets (pinocchio_headers, pinocchio_parsers)
#: export: Pinocchio's joint variant has more alternatives than Boost.MPL's default limit, and
#: the double-scalar algorithms and the URDF parser come compiled from the pin wheel.
DEFINES = (
    "BOOST_MPL_LIMIT_LIST_SIZE=30",
    "BOOST_MPL_LIMIT_VECTOR_SIZE=30",
    "BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS",
    "BOOST_FUSION_INVOKE_MAX_ARITY=12",
    "PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION",
    "PINOCCHIO_WITH_URDFDOM",
    "PINOCCHIO_URDFDOM_HEADERS_MAJOR_VERSION=3",
    "PINOCCHIO_URDFDOM_HEADERS_MINOR_VERSION=0",
    "PINOCCHIO_URDFDOM_HEADERS_PATCH_VERSION=0",
)
LIBRARIES = ("pinocchio_parsers", "pinocchio_default")
#: What the build notice announces [min]: the wall time stretches when other processes share
#: the cores; the "still building" lines say how much CPU the compiler has had so far.
BUILD_MINUTES = "1-6"
#: Seconds between two "still building" log lines.
PROGRESS_SECONDS = 30
#: Seconds ``$CXX --version`` may take (a wrapper that hangs makes the bridge unavailable).
VERSION_TIMEOUT = 60.0
#: The headers the bridge includes, each with the folders of an install prefix's ``include``
#: that may hold it, in search order (none: CasADi's, in its package folder).
HEADERS = {
    "pinocchio/autodiff/casadi.hpp": ("",),
    "Eigen/Core": ("eigen3", ""),
    "urdf_model/model.h": ("urdfdom_headers", ""),
    "boost/mpl/list.hpp": ("",),
    "casadi/casadi.hpp": (),
}
#: The pip packages that bring the headers, named in the "headers not found" reason.
HEADER_PACKAGES = "pin, casadi, cmeel-eigen, cmeel-urdfdom-headers"
FOLDER = "pinocchio-bridge"


class BridgeUnavailable(BalanceOptError):
    """The bridge cannot be built or run here; ``reason`` says why in a few words."""

    def __init__(self, reason: str):
        self.reason = reason
        super().__init__(f"the Pinocchio-CasADi bridge is unavailable: {reason}")


@dataclass(frozen=True)
class Toolchain:
    """Where the compiler, the headers (in search order) and the libraries of the bridge are."""

    compiler: str
    include_dirs: tuple[str, ...]
    library_dirs: tuple[str, ...]

    def command(self, output: Path) -> list[str]:
        """The one compiler call that builds the bridge into ``output``."""
        rpath = [f"-Wl,-rpath,{d}" for d in self.library_dirs]
        if sys.platform.startswith("linux"):
            # RPATH rather than RUNPATH: a foreign LD_LIBRARY_PATH cannot swap the libraries
            rpath.append("-Wl,--disable-new-dtags")
        return [
            self.compiler,
            *CXX_FLAGS,
            *(f"-D{d}" for d in DEFINES),
            *(f"-I{d}" for d in self.include_dirs),
            str(SOURCE),
            "-o",
            str(output),
            *(f"-L{d}" for d in self.library_dirs),
            *(f"-l{lib}" for lib in LIBRARIES),
            "-lcasadi",
            *rpath,
        ]


@dataclass(frozen=True)
class BuildRecord:
    """How the cached bridge program was built (times in s; ``built_now``: by this process)."""

    path: Path
    wall_seconds: float
    cpu_seconds: float
    built_now: bool


# ----------------------------------------------------------------------------- toolchain
def find_cxx_compiler() -> str | None:
    """A C++ compiler on the PATH (``$CXX``, ``c++``, ``g++``, ``clang++``), or ``None``."""
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _prefixes() -> list[Path]:
    """Install prefixes that may hold the headers: the cmeel prefixes on ``sys.path`` (where
    the ``pin`` and ``cmeel-*`` wheels install), then the environment's and the system's."""
    cmeel = [Path(p) / "cmeel.prefix" for p in sys.path if p]
    return [p for p in [*cmeel, Path(sys.prefix), Path("/usr/local"), Path("/usr")] if p.is_dir()]


def find_toolchain() -> Toolchain:
    """The compiler, headers and libraries the bridge needs, found without building anything
    (BridgeUnavailable when one is missing)."""
    if os.name == "nt":
        raise BridgeUnavailable("not supported on Windows")
    compiler = find_cxx_compiler()
    if compiler is None:
        raise BridgeUnavailable("no C++ compiler found: tried $CXX, c++, g++, clang++")
    casadi_dir, prefixes = Path(cs.__file__).parent, _prefixes()
    found = {}
    for header, subfolders in HEADERS.items():
        folders = [p / "include" / sub for p in prefixes for sub in subfolders]
        folders = folders if subfolders else [casadi_dir / "include"]
        found[header] = next((str(f) for f in folders if (f / header).is_file()), None)
    missing = [h for h, d in found.items() if d is None]
    if missing:
        raise BridgeUnavailable(
            f"C++ headers not found: {', '.join(missing)} (pip packages {HEADER_PACKAGES})"
        )
    libraries = [p / lib for p in prefixes for lib in ("lib", "lib64")]
    pinocchio_lib = next((d for d in libraries if (d / f"lib{LIBRARIES[0]}.so").exists()), None)
    if pinocchio_lib is None or not (casadi_dir / "libcasadi.so").exists():
        raise BridgeUnavailable("Pinocchio's or CasADi's shared libraries not found")
    includes = tuple(dict.fromkeys(found.values()))  # in order, without repeats
    return Toolchain(compiler, includes, (str(pinocchio_lib), str(casadi_dir)))


def _compiler_version(compiler: str) -> str:
    try:
        out = run_commands([[compiler, "--version"]], timeout=VERSION_TIMEOUT)[0]
    except OSError as exc:
        raise BridgeUnavailable(f"{compiler} does not run: {exc}") from exc
    return (out.splitlines() or [""])[0]


def _build_key(toolchain: Toolchain) -> str:
    import pinocchio

    parts = [
        SOURCE.read_text(),
        # the source by content (above), not by where this package is installed
        " ".join(toolchain.command(Path("out"))).replace(str(SOURCE), SOURCE.name),
        _compiler_version(toolchain.compiler),
        str(pinocchio.__version__),
        cs.__version__,
        platform.machine(),
        platform.system(),
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- the program
def _compile(toolchain: Toolchain, program: Path) -> BuildRecord:
    log.info(
        "building the Pinocchio-CasADi bridge (once per machine: about 1.5 min of CPU, %s min "
        "of wall time depending on the load) in %s",
        BUILD_MINUTES,
        program.parent,
    )
    start, cpu0 = time.perf_counter(), _children_cpu()

    def progress(group: int) -> None:
        cpu = _children_cpu() - cpu0 + _group_cpu(group)
        elapsed = time.perf_counter() - start
        log.info(
            "... still building the bridge (%.0f s so far, %.0f s of CPU of about 90)", elapsed, cpu
        )

    with build_dir(program.parent, program.name) as tmp:
        out = tmp / program.name
        run_commands([toolchain.command(out)], tick=progress, every=PROGRESS_SECONDS)
        wall, cpu = time.perf_counter() - start, _children_cpu() - cpu0
        os.replace(out, program)  # atomic: no process ever runs a half-written program
    write_record(program, wall_seconds=wall, cpu_seconds=cpu)
    log.info("built the Pinocchio-CasADi bridge in %.0f s (CPU %.0f s): %s", wall, cpu, program)
    return BuildRecord(program, wall, cpu, True)


def _group_cpu(group: int) -> float:
    """CPU seconds of the running processes of a process group (the compiler driver and the
    compiler it runs, their finished children included), from ``/proc``; 0 without it."""
    ticks = 0
    for entry in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = entry.read_text().rsplit(")", 1)[1].split()
            # after the name: state, ppid, pgrp, ..., utime (12th), stime, cutime, cstime
            if int(fields[2]) == group:
                ticks += sum(map(int, fields[11:15]))
    return ticks / os.sysconf("SC_CLK_TCK")


def _children_cpu() -> float:
    times = os.times()
    return times.children_user + times.children_system


def ensure_bridge(cache_dir: Path | None = None) -> BuildRecord:
    """The bridge program, built first if it is not cached (or if its cached bytes changed).

    Raises:
        BridgeUnavailable: no compiler, missing headers, or the build failed.
    """
    toolchain = find_toolchain()
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir() / FOLDER
    program = folder / f"pinocchio_casadi_bridge_{_build_key(toolchain)}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with file_lock(lock_path(program)):
            saved, _ = check_record(program)
            if saved is not None and {"wall_seconds", "cpu_seconds"} <= saved.keys():
                record = BuildRecord(program, saved["wall_seconds"], saved["cpu_seconds"], False)
            else:
                record = _compile(toolchain, program)
    except OSError as exc:  # unwritable cache folder, compiler gone, disk full, ...
        raise BridgeUnavailable(f"build failed: {exc}") from exc
    return record


# ----------------------------------------------------------------------------- per robot


def function_path(robot, program: Path) -> Path:
    key = hashlib.sha256(f"{program.name}\n{kinematics_key(robot)}".encode()).hexdigest()[:16]
    return program.parent / "functions" / f"{robot.name}_{key}.casadi"


def _load(path: Path, robot) -> cs.Function | None:
    """The saved function at ``path`` if it loads and has the expected shape, else ``None``."""
    try:
        fun = cs.Function.load(str(path))
    except RuntimeError:  # missing, truncated or foreign file
        return None
    n = len(robot.model_joint_names)  # arm joints, then the mimic joints following them
    shape, m = (6, 6 + n), fun.n_out() - 1
    ok = fun.n_in() == 1 and fun.size_in(0) == (n, 1) and m == 1 + len(robot.arms)
    if not ok or any(fun.size_out(i) != shape for i in range(m)):
        return None
    return fun if fun.size_out(m) == (12, robot.model.njoints - 1) else None


def bridge_function(robot, cache_dir: Path | None = None) -> cs.Function:
    """``pinocchio_primitives(q) -> (A_G, J_0, ..., J_m, oMi)`` of ``robot`` (6 x (6+m) each,
    world-aligned axes, base columns first; every joint's placement, 12 x (njoints - 1)), from
    the cache or generated by the bridge program.

    Raises:
        BridgeUnavailable: the program cannot be built, or it failed on this robot.
    """
    program = ensure_bridge(cache_dir).path
    path = function_path(robot, program)
    fun = _load(path, robot)
    if fun is None:  # the program run on the robot, its function renamed into place
        start, joints = time.perf_counter(), robot.model_joint_names
        frames = [arm.ee_frame for arm in robot.arms]
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with build_dir(path.parent, path.stem) as tmp:
                (tmp / "robot.urdf").write_text(robot.locked_urdf)
                files = [str(tmp / "robot.urdf"), str(tmp / path.name)]
                run_commands([[str(program), *files, str(len(joints)), *joints, *frames]])
                os.replace(tmp / path.name, path)
        except OSError as exc:  # also a program replaced by a broken file meanwhile
            raise BridgeUnavailable(f"the bridge failed on {robot.name}: {exc}") from exc
        fun = _load(path, robot)
        if fun is None:
            raise BridgeUnavailable(f"the bridge wrote an unreadable function file {path}")
        elapsed = time.perf_counter() - start
        log.info("Pinocchio primitives of %s generated in %.2f s", robot.name, elapsed)
    return fun


def bridge_centroidal_map(robot, q: cs.SX) -> cs.SX:
    """The centroidal momentum matrix as a ``casadi.SX`` expression of the model joints'
    positions ``q`` (``robot.model_joint_names``: the arm joints, then the mimic joints following
    them; columns: base, then those joints)."""
    return cs.SX(bridge_function(robot)(q)[0])
