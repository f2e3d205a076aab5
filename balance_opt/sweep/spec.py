"""Sweep files: a base task and the parameters to vary, expanded into cases.

A sweep file is YAML, read and checked like a task file (every error names the file, the line
and the key path)::

    task: paper_capture.yaml        # a task file, relative to this file, or an inline mapping
    methods: [analytic, optimal]    # every parameter set is planned with each method
    grid:                           # every combination of these values ...
      optimal.intervals: [20, 40]
    cases:                          # ... times each of these parameter sets ...
      - {initial.balance: [0.0, 0.5, -1.0]}
      - {initial.balance: [0.3, 0.8, -1.4]}
    random:                         # ... times each of these seeded random samples
      seed: 7
      samples: 10
      parameters:
        mission.goal: {uniform: [[0.8, 0.5, -1.8], [1.4, 1.1, -1.2]]}

A parameter is a key path of the task file (``mission.goal``, ``limits.balance_joint1.velocity``,
``optimal.weights.omega``, ``mission.goal[2]``), and its value replaces the base task's value
there (missing mappings on the way are created). Anything a task file can say can be varied:
the mission goal in joint or Cartesian space, the balance arm's initial configuration, limits,
weights, horizon and intervals; the planning method is varied with ``methods``.

Each case gets a stable id: a hash of its method, its parameters and the base task, so that the
same case has the same id in every run (this is what ``--resume`` and the comparison of runs
rely on), whatever the order or the number of workers.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import itertools
import json
import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from balance_opt.io.typed_config import from_data, setting
from balance_opt.io.typed_reference import json_schema, reference_markdown
from balance_opt.io.yaml_lines import (
    TaskFileError,
    YamlDocument,
    format_path,
    load_yaml,
    parse_yaml,
)

logger = logging.getLogger(__name__)

#: Planning methods a sweep can run.
METHODS = ("analytic", "optimal")
#: Hex digits of a case id (48 bits: a collision among a million cases has odds ~2e-3).
CASE_ID_DIGITS = 12
SWEEP_SCHEMA_ID = "https://balance-opt.invalid/sweep.schema.json"
#: Largest number of cases a sweep file may expand to (a typo in a grid should not start a
#: year of computation).
MAX_CASES = 1_000_000
_NAME = r"[^.\[\]\s]+"
_KEY_PATH = re.compile(rf"{_NAME}(?:\.{_NAME}|\[\d+\])*")
_SEGMENT = re.compile(rf"({_NAME})|\[(\d+)\]")


# ------------------------------------------------------------------------------ file format
@dataclass(frozen=True)
class Distribution:
    """How one parameter is drawn in ``random`` sampling (exactly one key)."""

    __exactly_one__ = ("uniform", "normal", "choice", "integers")

    uniform: tuple[Any, ...] | None = setting(
        None,
        min_items=2,
        max_items=2,
        doc="[low, high]: uniform between low and high (numbers, or lists of the same length, "
        "drawn element by element)",
    )
    normal: tuple[Any, ...] | None = setting(
        None,
        min_items=2,
        max_items=2,
        doc="[mean, std]: normal distribution (numbers, or lists of the same length)",
    )
    choice: tuple[Any, ...] | None = setting(
        None, min_items=1, doc="values to pick from, each equally likely"
    )
    integers: tuple[int, ...] | None = setting(
        None,
        min_items=2,
        max_items=2,
        doc="[low, high]: an integer from low to high, both included",
    )


@dataclass(frozen=True)
class RandomSamples:
    """Seeded random samples of some parameters."""

    seed: int = setting(doc="seed of the random generator (numpy default_rng)")
    samples: int = setting(doc="number of samples", minimum=1)
    parameters: dict[str, Distribution] = setting(doc="key path of the task -> its distribution")


@dataclass(frozen=True)
class SweepSpec:
    """A sweep: a base task, the methods, and the parameters to vary.

    The cases are the product of the grid, the list of cases and the random samples (each
    defaulting to the base task alone), times the methods.
    """

    task: str | dict[str, Any] = setting(
        doc="the base task: a task file (path relative to the sweep file) or an inline task mapping"
    )
    name: str | None = setting(None, doc="name of the study (for the report)")
    methods: tuple[Literal["analytic", "optimal"], ...] = setting(
        ("analytic", "optimal"), min_items=1, doc="planning methods run on every parameter set"
    )
    simulate: bool = setting(False, doc="also simulate each plan with the free-floating dynamics")
    grid: dict[str, tuple[Any, ...]] = setting(
        factory=dict, doc="key path of the task -> list of values; every combination is a case"
    )
    cases: tuple[dict[str, Any], ...] = setting(
        (), doc="a list of parameter sets (key path -> value), each one a case"
    )
    random: RandomSamples | None = setting(None, doc="seeded random samples of parameters")


def sweep_json_schema() -> dict:
    """JSON Schema (draft 2020-12) of sweep files, for editors (``balance-opt sweep --schema``);
    the inline ``task`` and the parameter values are those of task files."""
    return json_schema(SweepSpec, "balance-opt sweep file", SWEEP_SCHEMA_ID)


def sweep_reference_markdown() -> str:
    """Reference table of every sweep-file key (type, default, meaning)."""
    return reference_markdown(SweepSpec)


# ------------------------------------------------------------------------------ key paths
def parse_key_path(text: str) -> tuple[Any, ...]:
    """``"mission.goal[2]"`` -> ``("mission", "goal", 2)`` (the inverse of ``format_path``).

    Raises:
        ValueError: ``text`` is not a key path.
    """
    if not isinstance(text, str) or not _KEY_PATH.fullmatch(text):
        raise ValueError(
            f"'{text}' is not a key path (expected names joined by '.', and [i] for "
            "list items, like mission.goal[2])"
        )
    return tuple(name if name else int(index) for name, index in _SEGMENT.findall(text))


def apply_overrides(task: dict, parameters: dict[str, Any]) -> dict:
    """A copy of the task data with each parameter's value put at its key path.

    Mappings missing on the way are created; a list item must exist.

    Raises:
        KeyError: a path goes through a value that is not a mapping, or past the end of a list
            (the message names the parameter).
    """
    out = copy.deepcopy(task)
    for text, value in parameters.items():
        path = parse_key_path(text)
        node = out
        for depth, part in enumerate(path):
            last = depth == len(path) - 1
            where = format_path(path[:depth]) or "the task"
            if isinstance(part, int):
                if not isinstance(node, list) or part >= len(node):
                    raise KeyError(f"parameter '{text}': {where} has no item [{part}]")
            elif not isinstance(node, dict):
                raise KeyError(f"parameter '{text}': {where} is not a mapping")
            if last:
                node[part] = copy.deepcopy(value)
            else:
                if isinstance(part, str) and part not in node:
                    node[part] = {}
                node = node[part]
    return out


# ------------------------------------------------------------------------------ case ids
def canonical_json(data: Any) -> str:
    """JSON with sorted keys and no spaces: equal data, equal text (floats as ``repr``)."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)


def case_id_from(method: str, parameters: dict[str, Any], setup_hash: str) -> str:
    """Stable id of a case: a hash of its method, its parameters and what all cases share (the
    base task, ``simulate``, the solver options: ``setup_hash``)."""
    text = canonical_json({"method": method, "parameters": parameters, "setup": setup_hash})
    return hashlib.sha256(text.encode()).hexdigest()[:CASE_ID_DIGITS]


# ------------------------------------------------------------------------------ sampling
def _as_array(value: Any, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number or a list of numbers, got {value!r}") from None
    if arr.ndim > 1:
        raise ValueError(f"{what} must be a number or a list of numbers, got {value!r}")
    return arr


def _plain(value: np.ndarray) -> Any:
    """A float, or a list of floats, from a 0-d or 1-d array."""
    return float(value) if value.ndim == 0 else [float(v) for v in value]


def draw_samples(random: RandomSamples, doc: YamlDocument, at: tuple) -> list[dict[str, Any]]:
    """The parameter sets of a ``random`` block, drawn with ``numpy.random.default_rng(seed)``
    in a fixed order (sample by sample, parameters in file order): the same file gives the same
    samples on every machine.

    Raises:
        TaskFileError: bounds of mismatched shapes, ``low > high`` or a negative ``std``.
    """
    draws = {}
    for name, dist in random.parameters.items():
        where = (*at, "parameters", name)
        try:
            if dist.uniform is not None:
                low, high = (
                    _as_array(v, f"uniform {k}") for k, v in zip(("low", "high"), dist.uniform)
                )
                if low.shape != high.shape:
                    raise ValueError(f"low has shape {low.shape} but high has {high.shape}")
                if np.any(low > high):
                    raise ValueError(
                        f"low must not exceed high, got low={_plain(low)}, high={_plain(high)}"
                    )
                draws[name] = ("uniform", low, high)
            elif dist.normal is not None:
                mean, std = (
                    _as_array(v, f"normal {k}") for k, v in zip(("mean", "std"), dist.normal)
                )
                if mean.shape != std.shape and std.ndim != 0:
                    raise ValueError(f"mean has shape {mean.shape} but std has {std.shape}")
                if np.any(std < 0):
                    raise ValueError(f"std must not be negative, got {_plain(std)}")
                draws[name] = ("normal", mean, np.broadcast_to(std, mean.shape))
            elif dist.integers is not None:
                low, high = dist.integers
                if low > high:
                    raise ValueError(f"low must not exceed high, got [{low}, {high}]")
                draws[name] = ("integers", low, high)
            else:
                draws[name] = ("choice", list(dist.choice), None)
        except ValueError as exc:
            raise doc.error(where, str(exc)) from None
    rng = np.random.default_rng(random.seed)
    samples = []
    for _ in range(random.samples):
        sample = {}
        for name, (kind, a, b) in draws.items():
            if kind == "uniform":
                sample[name] = _plain(rng.uniform(a, b))
            elif kind == "normal":
                sample[name] = _plain(rng.normal(a, b))
            elif kind == "integers":
                sample[name] = int(rng.integers(a, b, endpoint=True))
            else:
                sample[name] = copy.deepcopy(a[int(rng.integers(len(a)))])
        samples.append(sample)
    return samples


# ------------------------------------------------------------------------------ the sweep
@dataclass(frozen=True)
class Sweep:
    """A validated sweep file and its cases.

    Attributes:
        spec: the typed sweep file.
        source: the sweep file (as given), for messages.
        base_dir: folder against which relative paths of the base task are resolved.
        task: the base task as plain data.
        setup_hash: SHA-256 of what every case shares: the base task, ``simulate`` and the
            solver options (part of every case id).
        cases: the cases in expansion order, plain data: ``index``, ``case_id``, ``method``,
            ``parameters`` (key path -> value), ``task`` (the base task with the parameters
            applied), ``base_dir`` and ``simulate``.
        varied: the key paths varied, in file order.
    """

    spec: SweepSpec
    source: str
    base_dir: str
    task: dict
    setup_hash: str
    cases: list[dict] = field(repr=False)
    varied: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.spec.name or Path(self.source).stem


def _parameter_sets(spec: SweepSpec, doc: YamlDocument) -> tuple[list[dict], dict[str, tuple]]:
    """Parameter sets (key path -> value) in expansion order, and where each key path is
    written in the sweep file."""
    where: dict[str, tuple] = {}
    for name in spec.grid:
        where.setdefault(name, ("grid", name))
    for i, entry in enumerate(spec.cases):
        for name in entry:
            where.setdefault(name, ("cases", i, name))
    if spec.random is not None:
        for name in spec.random.parameters:
            where.setdefault(name, ("random", "parameters", name))
    for name, at in where.items():
        try:
            parse_key_path(name)
        except ValueError as exc:
            raise doc.error(at, str(exc)) from None
        if name == "method":
            raise doc.error(
                at,
                "the method is not a task parameter: list the methods under "
                "'methods' (e.g. methods: [analytic, optimal])",
            )
    for name, values in spec.grid.items():
        if not values:
            raise doc.error(("grid", name), "expected at least one value")
    total = math.prod(len(v) for v in spec.grid.values()) * max(1, len(spec.cases))
    total *= (spec.random.samples if spec.random is not None else 1) * len(spec.methods)
    if total > MAX_CASES:  # checked before anything is expanded or drawn
        raise doc.error(
            (), f"the sweep expands to {total} cases, more than the {MAX_CASES} allowed"
        )
    grid_sets = [dict(zip(spec.grid, combo)) for combo in itertools.product(*spec.grid.values())]
    list_sets = [dict(entry) for entry in spec.cases] or [{}]
    random_sets = [{}] if spec.random is None else draw_samples(spec.random, doc, ("random",))
    sets = []
    for g, c, r in itertools.product(grid_sets, list_sets, random_sets):
        clash = (set(g) & set(c)) | (set(g) & set(r)) | (set(c) & set(r))
        if clash:
            name = min(clash)
            raise doc.error(
                where[name],
                f"parameter '{name}' is varied in more than one of grid, "
                "cases and random; vary each parameter in one place",
            )
        sets.append({**g, **c, **r})
    return sets, where


def expand_cases(
    spec: SweepSpec, doc: YamlDocument, task: dict, setup_hash: str, base_dir: str
) -> tuple[list[dict], dict[str, tuple]]:
    """The cases of a sweep (see :class:`Sweep`), in a fixed order: parameter sets in file order
    (grid, then list, then random samples, innermost last), each with every method.

    Raises:
        TaskFileError: a bad key path, a parameter that cannot be put in the task, or two cases
            with the same method and parameters.
    """
    sets, where = _parameter_sets(spec, doc)
    cases, seen = [], {}
    for parameters in sets:
        try:
            case_task = apply_overrides(task, parameters)
        except KeyError as exc:
            name = str(exc.args[0]).split("'")[1]
            raise doc.error(where[name], exc.args[0]) from None
        for method in spec.methods:
            case_id = case_id_from(method, parameters, setup_hash)
            index = len(cases)
            if case_id in seen:
                raise doc.error(
                    (),
                    f"case {index} ({method}, {canonical_json(parameters)}) is the "
                    f"same as case {seen[case_id]}; every case must differ",
                )
            seen[case_id] = index
            cases.append(
                {
                    "index": index,
                    "case_id": case_id,
                    "method": method,
                    "parameters": parameters,
                    "task": case_task,
                    "base_dir": base_dir,
                    "simulate": spec.simulate,
                }
            )
    return cases, where


def sweep_from_document(
    doc: YamlDocument, base_dir: str | Path, solver_options: dict[str, Any] | None = None
) -> Sweep:
    """A :class:`Sweep` from a parsed sweep file.

    The base task and the task of every case are loaded in full (robot, mission, limits: see
    :func:`balance_opt.io.task.task_from_document`), about 10 ms each. Limits no plan can meet and
    missions that cannot be built (an unreachable goal) are not errors of the sweep file: such
    a case fails when it runs, and the sweep goes on.

    Args:
        doc: the sweep file's document.
        base_dir: folder of the sweep file (relative paths start there).
        solver_options: Ipopt options for every case (``--solver-option``); part of the ids.

    Raises:
        TaskFileError: anything wrong in the sweep file or the base task, or a parameter value
            of the wrong type or at an unknown key (located at the parameter in the sweep file).
    """
    if not isinstance(doc.data, dict):
        raise doc.error(
            (), "expected a mapping with the keys of a sweep (task, grid, cases, random)"
        )
    spec = from_data(SweepSpec, doc)
    base_dir = Path(base_dir)
    if isinstance(spec.task, str):
        task_path = (base_dir / spec.task).resolve()
        if not task_path.is_file():
            raise doc.error(("task",), f"no task file {task_path}")
        task_doc, prefix = load_yaml(task_path), ()
    else:
        task_path, prefix = None, ("task",)
        task_doc = YamlDocument(
            doc.data["task"],
            doc.source,
            {k[1:]: v for k, v in doc.lines.items() if k[:1] == ("task",)},
        )
    task_dir = task_path.parent if task_path is not None else base_dir.resolve()
    task = task_doc.data
    task_hash = hashlib.sha256(canonical_json(task).encode()).hexdigest()
    _load_task(task_doc, task_dir, task_hash, prefix)
    solver_options = dict(solver_options or {})
    setup = {"task": task_hash, "simulate": spec.simulate, "solver_options": solver_options}
    setup_hash = hashlib.sha256(canonical_json(setup).encode()).hexdigest()
    cases, where = expand_cases(spec, doc, task, setup_hash, str(task_dir))
    for case in cases:
        case["solver_options"] = solver_options
    _check_case_tasks(cases, doc, task_doc, task_dir, where)
    logger.info("sweep %s: %d case(s)", doc.source, len(cases))
    return Sweep(spec, doc.source, str(task_dir), task, setup_hash, cases, tuple(where))


def _load_task(task_doc: YamlDocument, task_dir: Path, task_hash: str, prefix: tuple):
    """Load the base task; errors in an inline task get the ``task.`` prefix on their key path."""
    from balance_opt.io.task import task_from_document

    try:
        return task_from_document(task_doc, task_dir, task_hash)
    except TaskFileError as exc:
        if not prefix:
            raise
        raise type(exc)(exc.source, exc.line, (*prefix, *exc.path), exc.reason) from None


def _check_case_tasks(
    cases: list[dict],
    doc: YamlDocument,
    task_doc: YamlDocument,
    task_dir: Path,
    where: dict[str, tuple],
) -> None:
    """Load the task of every distinct parameter set; an error is reported at the line of the
    varied parameter in the sweep file. Limits no plan can meet and missions that cannot be
    built are left to fail their case when it runs: in a study they are results, not typos."""
    from balance_opt.io.task import TaskLimitsError, TaskTrajectoryError, task_from_document

    checked = set()
    for case in cases:
        key = canonical_json(case["parameters"])
        if not case["parameters"] or key in checked:
            continue
        checked.add(key)
        try:
            task_from_document(
                YamlDocument(case["task"], task_doc.source, task_doc.lines), task_dir, key
            )
        except (TaskLimitsError, TaskTrajectoryError):
            continue
        except TaskFileError as exc:
            culprit = _varied_prefix(exc.path, case["parameters"])
            if culprit is None:
                raise
            value = canonical_json(case["parameters"][culprit])
            inner = format_path(exc.path)
            inner = "" if inner == culprit else f"{inner}: "
            raise doc.error(
                where[culprit], f"{culprit} = {value} (case {case['index']}): {inner}{exc.reason}"
            ) from None


def _varied_prefix(path: tuple, parameters: dict[str, Any]) -> str | None:
    """The varied parameter whose key path is a prefix of ``path`` (or extends it)."""
    for name in parameters:
        p = parse_key_path(name)
        n = min(len(p), len(path))
        if p[:n] == tuple(path[:n]):
            return name
    return None


def load_sweep(path: str | Path, solver_options: dict[str, Any] | None = None) -> Sweep:
    """Read, validate and expand the sweep file at ``path`` (see :func:`sweep_from_document`)."""
    doc = load_yaml(path)
    return sweep_from_document(doc, Path(path).resolve().parent, solver_options)


def parse_sweep(
    text: str, source: str, base_dir: str | Path, solver_options: dict[str, Any] | None = None
) -> Sweep:
    """A :class:`Sweep` from YAML text (tests, generated sweeps)."""
    return sweep_from_document(parse_yaml(text, source), base_dir, solver_options)


def parameter_columns(parameters: dict[str, Any]) -> dict[str, Any]:
    """Flat table columns of a parameter set: a list becomes one column per item
    (``mission.goal[0]``, ...), a mapping one column per key; scalars stay as they are."""
    out: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, list):
            for i, item in enumerate(value):
                walk(f"{prefix}[{i}]", item)
        elif isinstance(value, dict):
            for key, item in value.items():
                walk(f"{prefix}.{key}", item)
        else:
            out[prefix] = value

    for name, value in parameters.items():
        walk(name, value)
    return out


def is_number(value: Any) -> bool:
    """A real number (not a boolean), finite or not."""
    return (
        isinstance(value, (int, float))
        and not isinstance(value, bool)
        and not (isinstance(value, float) and math.isnan(value))
    )


# ------------------------------------------------------------------------------ running a sweep
#: The case function of task sweeps (see :mod:`balance_opt.sweep.runner`).
TASK_RUNNER = "balance_opt.sweep.runner:run_task_case"
#: Files a sweep writes in its output folder (besides ``cases/``).
MANIFEST = "sweep.json"


@dataclass
class SweepOutcome:
    """What :func:`run_sweep` did: the run (results, ran, skipped), the files written and the
    summary written to ``summary.json``."""

    run: Any
    files: dict[str, Path]
    summary: dict[str, Any]


def prepare_output_dir(out_dir: str | Path, resume: bool, force: bool) -> Path:
    """Check (and create) the output folder of a sweep.

    An existing, non-empty folder is used only with ``resume`` (its finished cases are kept)
    or ``force`` (the results of a previous sweep in it are deleted first).

    Raises:
        InputError: the folder is not empty and neither ``resume`` nor ``force`` is given, or it
            is a file.
    """
    from balance_opt.errors import InputError
    from balance_opt.sweep.engine import CASES_DIR

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output {out_dir} exists and is not a directory")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not resume:
        if not force:
            raise InputError(
                f"output directory {out_dir} exists and is not empty; nothing was run. "
                "Use --resume to finish the sweep in it, --force to start it over, "
                "or choose another --output"
            )
        for old in [
            *(out_dir / CASES_DIR).glob("*.json"),
            *(out_dir / "plots").glob("*.png"),
            out_dir / "results.csv",
            out_dir / "summary.json",
            out_dir / MANIFEST,
        ]:
            old.unlink(missing_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    return out_dir


def run_sweep(
    sweep: Sweep,
    out_dir: str | Path,
    jobs: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    force: bool = False,
    retry_failed: bool = False,
    plots: bool = True,
    runner: str = TASK_RUNNER,
    on_result=None,
    engine=None,
) -> SweepOutcome:
    """Run every case of a sweep and write its results, table, summary and plots.

    Args:
        sweep: the sweep (:func:`load_sweep`).
        out_dir: output folder: ``sweep.json`` (the cases), ``cases/<case_id>.json`` (one per
            case, written as it finishes), ``results.csv``, ``summary.json``, ``plots/*.png``.
        jobs: worker processes (0: in this process); with ``scheduler="local"``, the workers
            of the local Dask cluster.
        scheduler: None (local process pool), ``"local"`` (a Dask cluster on the loopback
            interface, started and stopped here) or a Dask scheduler address.
        resume: keep the finished cases found in ``out_dir`` and run the others.
        force: start over in a non-empty ``out_dir``.
        retry_failed: with ``resume``, run the failed cases again too.
        plots: draw the summary plots.
        runner: ``"module:function"`` of the case function.
        on_result: progress callback, see :func:`balance_opt.sweep.engine.run_cases`.
        engine: an engine object to use instead of the one ``jobs`` and ``scheduler`` describe.

    Returns:
        The outcome; the table and summary are written even when cases failed. If the run is
        interrupted (``KeyboardInterrupt``), the table of the cases finished so far is written
        before the interruption goes on.
    """
    from balance_opt.sweep.engine import make_engine, run_cases, write_json_atomic
    from balance_opt.sweep.report import write_report

    out_dir = prepare_output_dir(out_dir, resume, force)
    manifest = {
        "name": sweep.name,
        "source": sweep.source,
        "setup_hash": sweep.setup_hash,
        "varied": list(sweep.varied),
        "methods": list(sweep.spec.methods),
        "cases": [
            {k: c[k] for k in ("index", "case_id", "method", "parameters")} for c in sweep.cases
        ],
    }
    write_json_atomic(out_dir / MANIFEST, manifest)
    engine = engine if engine is not None else make_engine(jobs, scheduler)
    extra = {"name": sweep.name, "source": sweep.source, "engine": engine.describe()}
    try:
        run = run_cases(
            sweep.cases,
            runner,
            out_dir,
            engine,
            resume=resume,
            retry_failed=retry_failed,
            on_result=on_result,
        )
    except KeyboardInterrupt:
        from balance_opt.sweep.engine import iter_results

        done = list(iter_results(out_dir, [c["case_id"] for c in sweep.cases]))
        write_report(
            out_dir, done, sweep.varied, plots=False, extra_summary={**extra, "interrupted": True}
        )
        logger.warning(
            "interrupted: %d of %d case(s) finished; run again with --resume to go on",
            len(done),
            len(sweep.cases),
        )
        raise
    extra.update(
        workers=run.workers, elapsed_s=run.elapsed_s, ran=len(run.ran), skipped=len(run.skipped)
    )
    files = write_report(out_dir, run.results, sweep.varied, plots=plots, extra_summary=extra)
    summary = json.loads(files["summary"].read_text())
    return SweepOutcome(run, files, summary)


# ------------------------------------------------------------------------------ command line
def add_sweep_parser(subparsers) -> Any:
    """Add the ``sweep`` subcommand to the ``balance-opt`` command line."""
    p = subparsers.add_parser(
        "sweep",
        help="run a study: many tasks from a sweep file, on a process pool or a Dask cluster",
        description="Run every case of a sweep file (a base task and the parameters to vary); "
        "write one result per case as it finishes, the table results.csv, "
        "summary.json and plots. Exit code 0 when every case succeeded, 1 when some "
        "failed (their errors are in the table), 2 for a bad sweep file.",
    )
    p.add_argument("sweep", nargs="?", help="sweep file (YAML)")
    p.add_argument(
        "-o", "--output", metavar="DIR", help="output directory (default: results/<sweep name>)"
    )
    p.add_argument(
        "-j",
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="worker processes (default: the number of CPUs; 0 runs the cases in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on Dask: the address of a scheduler (tcp://host:8786), or 'local' to start "
        "a local cluster of --jobs worker processes on 127.0.0.1",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="finish an interrupted sweep in --output: skip the cases already done",
    )
    p.add_argument(
        "--retry-failed", action="store_true", help="with --resume, run failed cases again"
    )
    p.add_argument(
        "-f",
        "--force",
        action="store_true",
        help="start over in an existing, non-empty output directory",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the summary plots")
    p.add_argument(
        "--solver-option",
        action="append",
        metavar="KEY=VALUE",
        help="Ipopt option for every optimal case (repeatable)",
    )
    p.add_argument(
        "--schema", action="store_true", help="print the JSON Schema of sweep files and exit"
    )
    p.add_argument(
        "--reference",
        action="store_true",
        help="print the sweep-file reference (Markdown) and exit",
    )
    p.add_argument("--runner", default=TASK_RUNNER, help=argparse.SUPPRESS)
    p.set_defaults(run=run_sweep_command)
    return p


def run_sweep_command(args) -> int:
    """``balance-opt sweep``: returns 0 when every case succeeded, 1 when some failed."""
    import os

    from balance_opt.cli import parse_solver_option
    from balance_opt.errors import InputError

    if args.schema:
        print(json.dumps(sweep_json_schema(), indent=2))
        return 0
    if args.reference:
        print(sweep_reference_markdown())
        return 0
    if args.sweep is None:
        raise InputError("sweep: give a sweep file, or --schema")
    solver_options = dict(
        parse_solver_option(s) for s in getattr(args, "solver_option", None) or []
    )
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 0:
        raise InputError(f"--jobs must be >= 0, got {jobs}")
    if args.retry_failed and not args.resume:
        raise InputError("--retry-failed goes with --resume")
    sweep = load_sweep(args.sweep, solver_options)
    out_dir = Path(args.output) if args.output else Path("results") / sweep.name
    if args.scheduler is None:
        jobs = min(jobs, len(sweep.cases)) if jobs else 0

    def progress(record, done, total):
        metrics = record.get("metrics") or {}
        drift = metrics.get(MAX_DRIFT_KEY)
        what = (
            f"max drift {drift:.3g} rad"
            if isinstance(drift, float)
            else (record.get("error") or {}).get("message", "")
        )
        logger.info(
            "[%d/%d] case %d %s %s: %s (%.2f s)",
            done,
            total,
            record["index"],
            record["method"],
            record["status"],
            what[:200],
            record["timing"]["case_s"],
        )

    outcome = run_sweep(
        sweep,
        out_dir,
        jobs=jobs,
        scheduler=args.scheduler,
        resume=args.resume,
        force=args.force,
        retry_failed=args.retry_failed,
        plots=not args.no_plots,
        runner=args.runner,
        on_result=progress,
    )
    run = outcome.run
    logger.info(
        "%d case(s): %d run in %.1f s on %d worker(s), %d skipped (already done), %d failed; "
        "table %s",
        len(run.results),
        len(run.ran),
        run.elapsed_s,
        run.workers,
        len(run.skipped),
        len(run.failed),
        outcome.files["table"],
    )
    return 1 if run.failed else 0


#: Metric shown in the progress lines.
MAX_DRIFT_KEY = "max_drift_rad"


__all__ = [
    "METHODS",
    "Distribution",
    "RandomSamples",
    "Sweep",
    "SweepOutcome",
    "SweepSpec",
    "add_sweep_parser",
    "apply_overrides",
    "canonical_json",
    "case_id_from",
    "draw_samples",
    "expand_cases",
    "load_sweep",
    "parameter_columns",
    "parse_key_path",
    "parse_sweep",
    "prepare_output_dir",
    "run_sweep",
    "run_sweep_command",
    "sweep_from_document",
    "sweep_json_schema",
    "sweep_reference_markdown",
]
