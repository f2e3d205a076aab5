"""Ipopt options checked against Ipopt's own option list, before any planning; the version of
the Ipopt library the planner solves with, for the record of a run; one thread for its linear
algebra."""

from __future__ import annotations

import contextlib
import ctypes
import difflib
import glob
import html
import importlib.metadata
import json
import logging
import math
import os
import re
import sys
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from balance_opt.cache import atomic_write_text, default_cache_dir
from balance_opt.errors import InputError

log = logging.getLogger(__name__)

#: Ipopt option types, as its documentation names them.
INTEGER, REAL, STRING = "integer", "real", "string"

#: Options Ipopt accepts but does not document (``sb``: suppress the banner).
UNDOCUMENTED = {"sb": ("yes", "no")}

_BLOCK = re.compile(r"<strong>(\w+)</strong>(.*?)</blockquote>", re.DOTALL)
_TYPE = re.compile(r"this (integer|real|string) option")
_RANGE = re.compile(
    r"valid range for this (?:integer|real) option is (.*?) and its default", re.DOTALL
)
#: A range ``lo < name <= hi``, either side optional (``unrestricted``: neither).
_BOUNDS = re.compile(r"(?:(\S+) (<=?) )?\w+(?: (<=?) (\S+))?")
_VALUE = re.compile(r"^ - ([^:\s]+):", re.MULTILINE)


@dataclass(frozen=True)
class IpoptOption:
    """One Ipopt option: its type, its range (numbers) or its possible values (strings)."""

    name: str
    type: str
    lower: float | None = None
    lower_strict: bool = False
    upper: float | None = None
    upper_strict: bool = False
    values: tuple[str, ...] = ()

    def describe(self) -> str:
        """The expected value in words, e.g. ``an integer >= 0`` or ``one of 'yes', 'no'``."""
        if self.type == STRING:
            return (
                "one of " + ", ".join(repr(v) for v in self.values) if self.values else "a string"
            )
        what = "an integer" if self.type == INTEGER else "a finite number"
        parts = []
        if self.lower is not None:
            parts.append(f"{'>' if self.lower_strict else '>='} {self.lower:g}")
        if self.upper is not None:
            parts.append(f"{'<' if self.upper_strict else '<='} {self.upper:g}")
        return what + (" " + " and ".join(parts) if parts else "")


def parse_documentation(text: str) -> dict[str, IpoptOption]:
    """Options from Ipopt's Doxygen-mode option documentation."""
    catalog = {}
    for name, body in _BLOCK.findall(text):
        kind = _TYPE.search(body)
        if kind is None:
            continue
        fields: dict[str, Any] = {}
        span = _RANGE.search(body)
        span = " ".join(html.unescape(span.group(1)).replace("≤", "<=").split()) if span else ""
        lower, lower_op, upper_op, upper = _BOUNDS.fullmatch(span).groups() if span else [None] * 4
        if lower is not None:
            fields.update(lower=float(lower), lower_strict=lower_op == "<")
        if upper is not None:
            fields.update(upper=float(upper), upper_strict=upper_op == "<")
        if kind.group(1) == STRING:
            fields["values"] = tuple(_VALUE.findall(body))
        catalog[name] = IpoptOption(name=name, type=kind.group(1), **fields)
    for name, values in UNDOCUMENTED.items():
        catalog.setdefault(name, IpoptOption(name=name, type=STRING, values=values))
    return catalog


def _documentation_from_ipopt() -> str:
    """Ipopt's option documentation, written to a file by a solver of a one-variable problem
    (a file: Ipopt's console output goes to Python's or to the C stdout, by build)."""
    import casadi as cs

    x = cs.SX.sym("x")
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "options.txt")
        opts = {
            "ipopt.print_options_documentation": "yes",
            "ipopt.print_advanced_options": "yes",
            "ipopt.print_options_mode": "doxygen",
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.output_file": path,
            "ipopt.file_print_level": 5,
            "ipopt.max_iter": 0,
            "print_time": False,
        }
        cs.nlpsol("options_doc", "ipopt", {"x": x, "f": x**2}, opts)(x0=1.0)
        return Path(path).read_text()


def option_catalog() -> dict[str, IpoptOption]:
    """Every Ipopt option of the installed CasADi's Ipopt, by name (cached on disk)."""
    path = default_cache_dir() / f"ipopt-options-casadi-{importlib.metadata.version('casadi')}.json"
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        data = json.loads(path.read_text())
        catalog = {k: IpoptOption(**{**v, "values": tuple(v["values"])}) for k, v in data.items()}
        if catalog:
            return catalog
    catalog = parse_documentation(_documentation_from_ipopt())
    if len(catalog) <= len(UNDOCUMENTED):
        raise RuntimeError("Ipopt printed no option documentation")
    with contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps({k: asdict(v) for k, v in catalog.items()}))
    return catalog


#: The file name suffix of the libraries Ipopt loads linear solvers from (``hsllib``,
#: ``pardisolib``: ``libhsl.so``, ``libpardiso.so`` on Linux).
_LIBRARY_SUFFIX = {"darwin": ".dylib", "win32": ".dll"}.get(sys.platform, ".so")
#: The library option of each solver Ipopt loads at run time, and functions Ipopt takes from it.
_LOADED_SOLVERS = {
    "ma27": ("hsllib", ("ma27ad", "ma27bd", "ma27cd", "ma27id")),
    "ma57": ("hsllib", ("ma57ad", "ma57bd", "ma57cd", "ma57id")),
    "ma77": ("hsllib", ("ma77_default_control_d", "ma77_analyse_d", "ma77_factor_d")),
    "ma86": ("hsllib", ("ma86_default_control_d", "ma86_analyse_d", "ma86_factor_d")),
    "ma97": ("hsllib", ("ma97_default_control_d", "ma97_analyse_d", "ma97_factor_d")),
    "pardiso": ("pardisolib", ("pardisoinit", "pardiso")),
}


def _exports(library: ctypes.CDLL, function: str) -> bool:
    """Whether ``library`` has ``function`` under one of the names a Fortran or C build gives."""
    names = (function, function + "_", function.upper(), function.upper() + "_")
    return any(hasattr(library, name) for name in names)


def linear_solver_loads(name: str, libraries: Mapping[str, Any] = MappingProxyType({})) -> bool:
    """Whether Ipopt can load linear solver ``name`` (with the ``hsllib``/``pardisolib`` of
    ``libraries``, else Ipopt's default library): a one-variable solve with it. An HSL or
    Pardiso solver is tried only when its library loads and has the solver's functions: Ipopt
    refuses one whose library is missing, but a refused ``ma97`` crashes the next solve of the
    process, and one whose functions are missing crashes at once."""
    import casadi as cs

    opts = {"ipopt.linear_solver": name, "ipopt.print_level": 0, "ipopt.sb": "yes"}
    if name in _LOADED_SOLVERS:
        option, functions = _LOADED_SOLVERS[name]
        path = libraries.get(option)
        if path:
            opts[f"ipopt.{option}"] = path
        try:
            library = ctypes.CDLL(path or f"lib{option[: -len('lib')]}{_LIBRARY_SUFFIX}")
        except OSError:
            return False
        if not all(_exports(library, f) for f in functions):
            return False
    x = cs.SX.sym("x")
    solver = cs.nlpsol("probe", "ipopt", {"x": x, "f": (x - 1) ** 2}, {**opts, "print_time": 0})
    solver(x0=0.0)
    return solver.stats()["return_status"] not in ("Invalid_Option", "Invalid_Problem_Definition")


def option_problem(
    name: str,
    value: Any,
    catalog: Mapping[str, IpoptOption],
    libraries: Mapping[str, Any] = MappingProxyType({}),
) -> str | None:
    """What is wrong with Ipopt option ``name = value`` (given the other options ``libraries``,
    which may name the linear solvers' libraries), or ``None`` when Ipopt accepts it."""
    option = catalog.get(name)
    if option is None:
        close = difflib.get_close_matches(name, list(catalog), n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        return f"unknown Ipopt option '{name}'{hint}"
    expected = f"expected {option.describe()}"
    if option.type == STRING:
        if not isinstance(value, str):
            return f"Ipopt option '{name}' takes a string, got {value!r}; {expected}"
        if option.values and value not in option.values:
            return f"Ipopt option '{name}' does not accept {value!r}; {expected}"
        if name == "linear_solver" and not linear_solver_loads(value, libraries):
            return (
                f"Ipopt cannot load linear solver {value!r} (not in this installation: the HSL "
                "solvers need a separately installed library); 'mumps' is always available"
            )
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"Ipopt option '{name}' takes a number, got {value!r}; {expected}"
    if not math.isfinite(value):
        return f"Ipopt option '{name}' must be finite, got {value!r}; {expected}"
    if option.type == INTEGER and value != int(value):
        return f"Ipopt option '{name}' takes an integer, got {value!r}; {expected}"
    low, high = option.lower, option.upper
    if (low is not None and (value < low or (option.lower_strict and value == low))) or (
        high is not None and (value > high or (option.upper_strict and value == high))
    ):
        return f"Ipopt option '{name}' is out of range, got {value!r}; {expected}"
    return None


def _solver_option_error(name: str, problem: str) -> InputError:
    return InputError(f"--solver-option {name}: {problem}")


def check_ipopt_options(
    options: Mapping[str, Any],
    error: Callable[[str, str], Exception] = _solver_option_error,
) -> dict[str, Any]:
    """``options`` checked against Ipopt's own option list (:func:`option_catalog`; unchecked,
    with a warning, when it cannot be had), an integer option given as ``500.0`` as ``500``."""
    if not options:
        return {}
    try:
        catalog = option_catalog()
    except (ImportError, RuntimeError, OSError) as exc:  # no CasADi, Ipopt fails, no temp file
        log.warning("Ipopt options not checked: cannot read Ipopt's option list (%s)", exc)
        return dict(options)
    out = {}
    for name, value in options.items():
        problem = option_problem(name, value, catalog, options)
        if problem is not None:
            raise error(name, problem)
        out[name] = int(value) if catalog[name].type == INTEGER else value
    return out


def ipopt_version() -> str:
    """Version of the Ipopt library bundled with CasADi (e.g. ``"3.14.19"``), or ``"unknown"``."""
    import casadi

    folder = os.path.dirname(casadi.__file__)
    for path in sorted(glob.glob(os.path.join(folder, "*ipopt*")), key=len):  # libipopt first
        try:
            lib = ctypes.CDLL(path)
            getter = lib.GetIpoptVersion
        except (OSError, AttributeError):
            continue
        major, minor, release = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        getter(ctypes.byref(major), ctypes.byref(minor), ctypes.byref(release))
        return f"{major.value}.{minor.value}.{release.value}"
    log.debug("no Ipopt library with GetIpoptVersion in %s", folder)
    return "unknown"


#: The environment variables OpenBLAS reads its number of threads from: one set overrides
#: the choice.
THREADS_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def casadi_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS that CasADi's Ipopt plugin loaded, or ``None`` when none is loaded (before
    the first ``nlpsol``, or another build of CasADi). The wheel holds several copies of the
    file under different names: opening one by its path could load a second, unused instance,
    so it is looked up by name among the loaded libraries only (``RTLD_NOLOAD``)."""
    import casadi as cs  # loaded already: it built the solver

    if not hasattr(os, "RTLD_NOLOAD"):
        return None  # no way to find the loaded one without loading another
    mode = os.RTLD_NOLOAD | os.RTLD_LAZY
    for path in sorted(Path(cs.__file__).parent.glob("libcasadi-tp-openblas*")):
        try:
            lib = ctypes.CDLL(path.name, mode=mode)
            lib.openblas_get_num_threads  # noqa: B018 (raises AttributeError without it)
        except (OSError, AttributeError):
            continue
        return lib
    return None


def one_thread_for_ipopt() -> None:
    """Set CasADi's OpenBLAS to one thread for Ipopt's linear algebra (each time an NLP is
    built: cheap), unless one of :data:`THREADS_VARIABLES` is set."""
    if any(os.environ.get(name) for name in THREADS_VARIABLES):
        return
    lib = casadi_openblas()
    if lib is None:
        log.debug("CasADi's Ipopt loaded no OpenBLAS of its own: its threads are left alone")
        return
    lib.openblas_set_num_threads(ctypes.c_int(1))
