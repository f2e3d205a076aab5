"""The cases of a sweep: key paths into a task, parameter sets (grid, list, seeded random
samples), their expansion into cases, and the stable id of each case.

A case is plain data (a dict): ``index``, ``case_id``, ``method``, ``parameters`` (key path ->
value), ``task`` (the base task's data with the parameters put in), ``base_dir`` and
``simulate``. The types of the sweep file are here (:class:`SweepSpec`); the file is read by
:mod:`balance_opt.sweep.spec`.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from balance_opt.config.typed_config import setting
from balance_opt.config.yaml_lines import YamlDocument, format_path

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


def canonical_json(data: Any) -> str:
    """JSON with sorted keys and no spaces: equal data, equal text (floats as ``repr``)."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)


def case_id_from(method: str, parameters: dict[str, Any], setup_hash: str) -> str:
    """Stable id of a case: a hash of its method, its parameters and what all cases share (the
    base task, ``simulate``, the solver options: ``setup_hash``)."""
    text = canonical_json({"method": method, "parameters": parameters, "setup": setup_hash})
    return hashlib.sha256(text.encode()).hexdigest()[:CASE_ID_DIGITS]


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


def _checked_draw(dist: Distribution) -> tuple[str, Any, Any]:
    """``(kind, a, b)`` of a distribution, its bounds as arrays.

    Raises:
        ValueError: bounds of mismatched shapes, ``low > high`` or a negative ``std``.
    """
    if dist.uniform is not None:
        low, high = (_as_array(v, f"uniform {k}") for k, v in zip(("low", "high"), dist.uniform))
        if low.shape != high.shape:
            raise ValueError(f"low has shape {low.shape} but high has {high.shape}")
        if np.any(low > high):
            raise ValueError(
                f"low must not exceed high, got low={_plain(low)}, high={_plain(high)}"
            )
        return "uniform", low, high
    if dist.normal is not None:
        mean, std = (_as_array(v, f"normal {k}") for k, v in zip(("mean", "std"), dist.normal))
        if mean.shape != std.shape and std.ndim != 0:
            raise ValueError(f"mean has shape {mean.shape} but std has {std.shape}")
        if np.any(std < 0):
            raise ValueError(f"std must not be negative, got {_plain(std)}")
        return "normal", mean, np.broadcast_to(std, mean.shape)
    if dist.integers is not None:
        low, high = dist.integers
        if low > high:
            raise ValueError(f"low must not exceed high, got [{low}, {high}]")
        return "integers", low, high
    return "choice", list(dist.choice), None


def _draw(rng: np.random.Generator, kind: str, a: Any, b: Any) -> Any:
    """One value of a checked distribution (see :func:`_checked_draw`)."""
    if kind == "uniform":
        return _plain(rng.uniform(a, b))
    if kind == "normal":
        return _plain(rng.normal(a, b))
    if kind == "integers":
        return int(rng.integers(a, b, endpoint=True))
    return copy.deepcopy(a[int(rng.integers(len(a)))])


def draw_samples(random: RandomSamples, doc: YamlDocument, at: tuple) -> list[dict[str, Any]]:
    """The parameter sets of a ``random`` block, drawn with ``numpy.random.default_rng(seed)``
    in a fixed order (sample by sample, parameters in file order): the same file gives the same
    samples on every machine.

    Raises:
        TaskFileError: bounds of mismatched shapes, ``low > high`` or a negative ``std``.
    """
    draws = {}
    for name, dist in random.parameters.items():
        try:
            draws[name] = _checked_draw(dist)
        except ValueError as exc:
            raise doc.error((*at, "parameters", name), str(exc)) from None
    rng = np.random.default_rng(random.seed)
    return [
        {name: _draw(rng, *draw) for name, draw in draws.items()} for _ in range(random.samples)
    ]


def _parameter_places(spec: SweepSpec, doc: YamlDocument) -> dict[str, tuple]:
    """Where each varied key path is written in the sweep file, after checking the key paths
    and the number of cases (before anything is expanded or drawn)."""
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
    if total > MAX_CASES:
        raise doc.error(
            (), f"the sweep expands to {total} cases, more than the {MAX_CASES} allowed"
        )
    return where


def _parameter_sets(spec: SweepSpec, doc: YamlDocument) -> tuple[list[dict], dict[str, tuple]]:
    """Parameter sets (key path -> value) in expansion order, and where each key path is
    written in the sweep file."""
    where = _parameter_places(spec, doc)
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
    """The cases of a sweep (see the module docstring), in a fixed order: parameter sets in file order
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


def varied_prefix(path: tuple, parameters: dict[str, Any]) -> str | None:
    """The varied parameter whose key path is a prefix of ``path`` (or extends it)."""
    for name in parameters:
        p = parse_key_path(name)
        n = min(len(p), len(path))
        if p[:n] == tuple(path[:n]):
            return name
    return None


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
