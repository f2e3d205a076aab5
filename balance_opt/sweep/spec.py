"""Sweep files: a base task and the parameters to vary (format: ``docs/sweeps.md``).

Each case id hashes its method, its parameters and the base task, so the same case has the same
id in every run whatever the order or the number of workers (``--resume`` relies on it)."""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from balance_opt.config.typed_config import from_data
from balance_opt.config.typed_reference import json_schema, reference_markdown
from balance_opt.config.yaml_lines import (
    TaskFileError,
    YamlDocument,
    format_path,
    load_yaml,
    parse_yaml,
)
from balance_opt.sweep.cases import SweepSpec, canonical_json, expand_cases, varied_prefix

logger = logging.getLogger(__name__)

SWEEP_SCHEMA_ID = "https://balance-opt.invalid/sweep.schema.json"


def sweep_json_schema() -> dict:
    """JSON Schema (draft 2020-12) of sweep files, for editors (``balance-opt sweep --schema``);
    the inline ``task`` and the parameter values are those of task files."""
    return json_schema(SweepSpec, "balance-opt sweep file", SWEEP_SCHEMA_ID)


def sweep_reference_markdown() -> str:
    """Reference table of every sweep-file key (type, default, meaning)."""
    return reference_markdown(SweepSpec)


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


def sweep_from_document(
    doc: YamlDocument, base_dir: str | Path, solver_options: dict[str, Any] | None = None
) -> Sweep:
    """A :class:`Sweep` from a parsed sweep file.

    The base task and the task of every case are loaded in full. Limits no plan can meet and
    missions that cannot be built are not errors of the sweep file: in a study they are results,
    so such a case fails when it runs and the sweep goes on.

    Args:
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
    from balance_opt.tasks.task import task_from_document

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
    from balance_opt.tasks.task import TaskLimitsError, TaskTrajectoryError, task_from_document

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
            culprit = varied_prefix(exc.path, case["parameters"])
            if culprit is None:
                raise
            value = canonical_json(case["parameters"][culprit])
            inner = format_path(exc.path)
            inner = "" if inner == culprit else f"{inner}: "
            raise doc.error(
                where[culprit], f"{culprit} = {value} (case {case['index']}): {inner}{exc.reason}"
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


__all__ = [
    "Sweep",
    "SweepSpec",
    "load_sweep",
    "parse_sweep",
    "sweep_from_document",
    "sweep_json_schema",
    "sweep_reference_markdown",
]
