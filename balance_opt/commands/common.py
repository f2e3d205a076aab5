"""What the commands share: exit codes, ``--solver-option`` values, the default output folder,
a task loaded with ``--backend``, the ``--output`` folder opened first."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import re
import signal
from collections.abc import Callable
from pathlib import Path

from balance_opt.report.output_dir import OutputFolder

EXIT_OK, EXIT_SOLVER, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
#: A closed output pipe: 128 + SIGPIPE, what a shell reports for ``cat`` ended by it.
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE

log = logging.getLogger("balance_opt.cli")

DEFAULT_OUTPUT_ROOT = Path("results")
PAPER_FIGURES_FOLDER = DEFAULT_OUTPUT_ROOT / "paper_figures"


def parse_solver_option(text: str) -> tuple[str, int | float | str]:
    """``"max_iter=100"`` -> ``("max_iter", 100)``: the value as an int, else a float, else a string.

    Raises:
        InputError: no ``=`` or an empty key.
    """
    from balance_opt.errors import InputError

    key, sep, value = text.partition("=")
    key, value = key.strip(), value.strip()
    if not sep or not key:
        raise InputError(f"--solver-option {text!r}: expected KEY=VALUE, e.g. max_iter=200")
    for convert in (int, float):
        try:
            return key, convert(value)
        except ValueError:
            pass
    return key, value


def ipopt_options_of(args, task=None) -> dict:
    """``--solver-option`` values, checked against Ipopt's own option list; with ``--verbose``,
    Ipopt's iteration log (on stdout, as the optimal planner's progress) too, unless the task or
    the command line sets ``print_level`` (not in a sweep: its workers are silent)."""
    from balance_opt.solvers.ipopt_options import check_ipopt_options

    options = check_ipopt_options(dict(parse_solver_option(s) for s in args.solver_option or []))
    task_ipopt = task.spec.optimal.planner.ipopt if task is not None else {}
    if args.verbose and args.command != "sweep" and "print_level" not in {**task_ipopt, **options}:
        options["print_level"] = 5
    return options


#: Characters a default output folder name keeps; any run of others becomes one ``_``.
_UNSAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


def default_output_folder(name: str) -> Path:
    """``results/<name>``, the default output folder of a task or sweep ``name``, with the name
    made a plain folder name: only letters, digits, ``.``, ``_`` and ``-`` (others become
    ``_``), no leading dot. So a name such as ``../../x`` stays inside ``results/``."""
    safe = _UNSAFE_NAME.sub("_", name).lstrip(".") or "unnamed"
    if safe != name:
        log.warning("name %r is not a plain folder name; the output folder is %s", name, safe)
    return DEFAULT_OUTPUT_ROOT / safe


def count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def load_task_file(path, backend: str | None):
    """The task of file ``path`` with ``robot.backend`` replaced by ``backend`` (unless None)."""
    from balance_opt.tasks.task import load_task

    task = load_task(path)
    if backend is None:
        return task
    robot = dataclasses.replace(task.spec.robot, backend=backend)
    return dataclasses.replace(task, spec=dataclasses.replace(task.spec, robot=robot))


def early_output(args) -> OutputFolder | contextlib.nullcontext:
    """The ``--output`` folder, for a ``with`` block around the whole command: opened (checked,
    locked, staging created) before anything else, even before the task is loaded, and
    committed when the block ends (the run's own ``with`` inside it is not the outermost); a
    null context without ``--output``."""
    return OutputFolder(args.output, args.force) if args.output else contextlib.nullcontext()


def reference_asked(args, schema: Callable[[], dict], reference: Callable[[], str]) -> bool:
    """Print a file format's JSON Schema (``--schema``) or Markdown reference (``--reference``)
    if asked; whether it was."""
    if args.schema:
        print(json.dumps(schema(), indent=2))
    elif args.reference:
        print(reference())
    return args.schema or args.reference


def print_cartesian_goal(task) -> None:
    goal = task.cartesian_goal
    if goal:
        values = ", ".join(f"{name} {v:.6g}" for name, v in goal.items())
        print(f"mission goal found by inverse kinematics: {values} [rad or m]")


def methods_of(args) -> tuple[str, ...]:
    return ("analytic", "optimal") if args.method == "both" else (args.method,)
