"""Sweep files (``docs/sweeps.md``): a base task and the parameters to vary, expanded into cases
(plain dicts). A case id hashes its method, its parameters and the shared setup, so it is the
same in every run (``--resume`` relies on it)."""

from __future__ import annotations

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

from balance_opt.config.schema import json_schema, reference_markdown
from balance_opt.config.typed_config import from_data, setting
from balance_opt.config.yaml_lines import (
    TaskFileError,
    YamlDocument,
    format_path,
    load_yaml,
    parse_yaml,
)

logger = logging.getLogger(__name__)

#: Hex digits of a case id (48 bits: a collision among a million cases has odds ~2e-3).
CASE_ID_DIGITS = 12
#: Largest number of cases a sweep file may expand to (a typo in a grid should not start a
#: year of computation).
MAX_CASES = 1_000_000
_NAME = r"[^.\[\]\s]+"
_KEY_PATH = re.compile(rf"{_NAME}(?:\.{_NAME}|\[\d+\])*")
_SEGMENT = re.compile(rf"({_NAME})|\[(\d+)\]")


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
    """A sweep: a base task, the methods, and the parameters to vary."""

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


def parse_key_path(text: str) -> tuple[Any, ...]:
    """``"mission.goal[2]"`` -> ``("mission", "goal", 2)`` (the inverse of ``format_path``)."""
    if not isinstance(text, str) or not _KEY_PATH.fullmatch(text):
        raise ValueError(
            f"'{text}' is not a key path (expected names joined by '.', and [i] for "
            "list items, like mission.goal[2])"
        )
    return tuple(name if name else int(index) for name, index in _SEGMENT.findall(text))


def apply_overrides(task: dict, parameters: dict[str, Any]) -> dict:
    """A copy of the task data with each parameter's value put at its key path (missing
    mappings created; a list item must exist)."""
    out = copy.deepcopy(task)
    for text, value in parameters.items():
        path = parse_key_path(text)
        node = out
        for depth, part in enumerate(path):
            where = format_path(path[:depth]) or "the task"
            if isinstance(part, int):
                if not isinstance(node, list) or part >= len(node):
                    raise KeyError(f"parameter '{text}': {where} has no item [{part}]")
            elif not isinstance(node, dict):
                raise KeyError(f"parameter '{text}': {where} is not a mapping")
            elif part not in node and depth < len(path) - 1:
                node[part] = {}
            if depth == len(path) - 1:
                node[part] = copy.deepcopy(value)
            node = node[part]
    return out


def canonical_json(data: Any) -> str:
    """JSON with sorted keys and no spaces: equal data, equal text (floats as ``repr``)."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)


def _sha256(data: Any) -> str:
    return hashlib.sha256(canonical_json(data).encode()).hexdigest()


def case_id_from(method: str, parameters: dict[str, Any], setup_hash: str) -> str:
    """Stable id of a case: a hash of its method, its parameters and ``setup_hash``."""
    key = {"method": method, "parameters": parameters, "setup": setup_hash}
    return _sha256(key)[:CASE_ID_DIGITS]


def _as_array(value: Any, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number or a list of numbers, got {value!r}") from None
    if arr.ndim > 1:
        raise ValueError(f"{what} must be a number or a list of numbers, got {value!r}")
    return arr


def _sampler(dist: Distribution):
    """The function ``rng -> value`` of a distribution, its bounds checked first."""
    if dist.uniform is not None:
        low, high = (_as_array(v, f"uniform {k}") for k, v in zip(("low", "high"), dist.uniform))
        if low.shape != high.shape:
            raise ValueError(f"low has shape {low.shape} but high has {high.shape}")
        if np.any(low > high):
            raise ValueError(
                f"low must not exceed high, got low={low.tolist()}, high={high.tolist()}"
            )
        return lambda rng: np.asarray(rng.uniform(low, high)).tolist()
    if dist.normal is not None:
        mean, std = (_as_array(v, f"normal {k}") for k, v in zip(("mean", "std"), dist.normal))
        if mean.shape != std.shape and std.ndim != 0:
            raise ValueError(f"mean has shape {mean.shape} but std has {std.shape}")
        if np.any(std < 0):
            raise ValueError(f"std must not be negative, got {std.tolist()}")
        std = np.broadcast_to(std, mean.shape)
        return lambda rng: np.asarray(rng.normal(mean, std)).tolist()
    if dist.integers is not None:
        low, high = dist.integers
        if low > high:
            raise ValueError(f"low must not exceed high, got [{low}, {high}]")
        return lambda rng: int(rng.integers(low, high, endpoint=True))
    choices = list(dist.choice)
    return lambda rng: copy.deepcopy(choices[int(rng.integers(len(choices)))])


def draw_samples(random: RandomSamples, doc: YamlDocument) -> list[dict[str, Any]]:
    """The parameter sets of a ``random`` block, drawn in a fixed order (sample by sample,
    parameters in file order) from ``default_rng(seed)``."""
    samplers = {}
    for name, dist in random.parameters.items():
        try:
            samplers[name] = _sampler(dist)
        except ValueError as exc:
            raise doc.error(("random", "parameters", name), str(exc)) from None
    rng = np.random.default_rng(random.seed)
    return [{name: draw(rng) for name, draw in samplers.items()} for _ in range(random.samples)]


def _parameter_places(spec: SweepSpec, doc: YamlDocument) -> dict[str, tuple]:
    """Where each varied key path is written in the sweep file, after checking the key paths
    and the number of cases (before anything is expanded or drawn)."""
    places = [("grid", name) for name in spec.grid]
    places += [("cases", i, name) for i, entry in enumerate(spec.cases) for name in entry]
    random = spec.random.parameters if spec.random else {}
    places += [("random", "parameters", name) for name in random]
    where: dict[str, tuple] = {}
    for at in places:
        where.setdefault(at[-1], at)
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
    if total > MAX_CASES:
        raise doc.error(
            (), f"the sweep expands to {total} cases, more than the {MAX_CASES} allowed"
        )
    return where


def expand_cases(
    spec: SweepSpec, doc: YamlDocument, task: dict, setup_hash: str, base_dir: str, solver_options
) -> tuple[list[dict], dict[str, tuple]]:
    """The cases of a sweep in a fixed order (grid, then list, then random samples, innermost
    last, each with every method) and where each varied key path is in the sweep file.

    Raises:
        TaskFileError: a bad key path, a parameter varied in two places or that cannot be put in
            the task, or two cases with the same method and parameters.
    """
    where = _parameter_places(spec, doc)
    grid_sets = [dict(zip(spec.grid, combo)) for combo in itertools.product(*spec.grid.values())]
    list_sets = [dict(entry) for entry in spec.cases] or [{}]
    random_sets = [{}] if spec.random is None else draw_samples(spec.random, doc)
    cases, seen = [], {}
    for g, c, r in itertools.product(grid_sets, list_sets, random_sets):
        clash = (set(g) & set(c)) | (set(g) & set(r)) | (set(c) & set(r))
        if clash:
            name = min(clash)
            raise doc.error(
                where[name],
                f"parameter '{name}' is varied in more than one of grid, "
                "cases and random; vary each parameter in one place",
            )
        parameters = {**g, **c, **r}
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
                    "solver_options": solver_options,
                }
            )
    return cases, where


def parameter_columns(data: dict[str, Any], lists: bool = True) -> dict[str, Any]:
    """Flat table columns of a parameter set (or of nested ``data``): a mapping becomes one column
    per key (``a.b``), with ``lists`` a list one column per item (``mission.goal[0]``, ...)."""
    out: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if lists and isinstance(value, list):
            for i, item in enumerate(value):
                walk(f"{prefix}[{i}]", item)
        elif isinstance(value, dict):
            for key, item in value.items():
                walk(f"{prefix}.{key}", item)
        else:
            out[prefix] = value

    for name, value in data.items():
        walk(str(name), value)
    return out


def is_number(value: Any) -> bool:
    """A real number (not a boolean, not NaN), finite or not."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value == value


SWEEP_SCHEMA_ID = "https://balance-opt.invalid/sweep.schema.json"


def sweep_json_schema() -> dict:
    """JSON Schema (draft 2020-12) of sweep files (``balance-opt sweep --schema``)."""
    return json_schema(SweepSpec, "balance-opt sweep file", SWEEP_SCHEMA_ID)


def sweep_reference_markdown() -> str:
    """Reference table of every sweep-file key (type, default, meaning)."""
    return reference_markdown(SweepSpec)


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file: its typed ``spec``, ``name`` (the file's stem when it has none),
    ``source``, the ``setup_hash`` every case id includes, the ``cases`` in expansion order and
    the ``varied`` key paths."""

    spec: SweepSpec
    name: str
    source: str
    setup_hash: str
    cases: list[dict] = field(repr=False)
    varied: tuple[str, ...] = ()


def sweep_from_document(
    doc: YamlDocument, base_dir: str | Path, solver_options: dict[str, Any] | None = None
) -> Sweep:
    """A :class:`Sweep` from a parsed sweep file in folder ``base_dir``; ``solver_options``
    (``--solver-option``) apply to every case and enter the ids.

    Raises:
        TaskFileError: anything wrong in the sweep file or the base task, or a parameter value
            of the wrong type or at an unknown key (located at the parameter in the sweep file).
    """
    from balance_opt.tasks.task import task_from_document

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
        task_doc, task_dir, prefix = load_yaml(task_path), task_path.parent, ()
    else:
        lines = {k[1:]: v for k, v in doc.lines.items() if k[:1] == ("task",)}
        task_doc = YamlDocument(doc.data["task"], doc.source, lines)
        task_dir, prefix = base_dir.resolve(), ("task",)
    task = task_doc.data
    task_hash = _sha256(task)
    try:
        task_from_document(task_doc, task_dir, task_hash)
    except TaskFileError as exc:
        if not prefix:
            raise
        raise type(exc)(exc.source, exc.line, (*prefix, *exc.path), exc.reason) from None
    solver_options = dict(solver_options or {})
    setup_hash = _sha256(
        {"task": task_hash, "simulate": spec.simulate, "solver_options": solver_options}
    )
    cases, where = expand_cases(spec, doc, task, setup_hash, str(task_dir), solver_options)
    _check_case_tasks(cases, doc, task_doc, task_dir, where)
    logger.info("sweep %s: %d case(s)", doc.source, len(cases))
    name = spec.name or Path(doc.source).stem
    return Sweep(spec, name, doc.source, setup_hash, cases, tuple(where))


def _check_case_tasks(
    cases: list[dict],
    doc: YamlDocument,
    task_doc: YamlDocument,
    task_dir: Path,
    where: dict[str, tuple],
) -> None:
    """Load the task of every distinct parameter set, errors located at the varied parameter;
    limits no plan can meet and unbuildable missions fail their case when it runs instead. The
    URDF's warnings are not shown again: the load of the base task showed them."""
    from balance_opt.model.robot import urdf_warnings_shown
    from balance_opt.tasks.checks import TaskLimitsError, TaskTrajectoryError
    from balance_opt.tasks.task import task_from_document

    checked = set()
    with urdf_warnings_shown():
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
                # the varied parameter whose key path is a prefix of the culprit's (or extends it)
                paths = {name: parse_key_path(name)[: len(exc.path)] for name in case["parameters"]}
                culprit = next((n for n, p in paths.items() if p == exc.path[: len(p)]), None)
                if culprit is None:
                    raise
                value = canonical_json(case["parameters"][culprit])
                inner = format_path(exc.path)
                inner = "" if inner == culprit else f"{inner}: "
                raise doc.error(
                    where[culprit],
                    f"{culprit} = {value} (case {case['index']}): {inner}{exc.reason}",
                ) from None


def load_sweep(path: str | Path, solver_options: dict[str, Any] | None = None) -> Sweep:
    """Read, validate and expand the sweep file at ``path`` (see :func:`sweep_from_document`)."""
    doc = load_yaml(path)
    return sweep_from_document(doc, Path(path).resolve().parent, solver_options)


def parse_sweep(
    text: str, source: str, base_dir: str | Path, solver_options: dict[str, Any] | None = None
) -> Sweep:
    """A :class:`Sweep` from YAML text (tests, generated sweeps)."""
    return sweep_from_document(parse_yaml(text, source), base_dir, solver_options)
