"""The options the ``balance-opt`` subcommands share and how they are read."""

from __future__ import annotations

import argparse
import logging
import re
from pathlib import Path

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


#: Ipopt's iteration log, shown (on stdout) with ``--verbose`` as the optimal planner's progress.
VERBOSE_IPOPT = {"print_level": 5}


def command_line_ipopt(args) -> dict:
    """``--solver-option`` values, checked against Ipopt's own option list."""
    from balance_opt.optimal.ipopt_options import check_ipopt_options

    return check_ipopt_options(
        dict(parse_solver_option(s) for s in getattr(args, "solver_option", None) or [])
    )


def ipopt_options_of(args, task=None) -> dict:
    """``--solver-option`` values; with ``--verbose``, Ipopt's iteration log too (unless the
    task or the command line sets ``print_level``)."""
    options = command_line_ipopt(args)
    task_ipopt = task.spec.optimal.planner.ipopt if task is not None else {}
    if args.verbose and "print_level" not in options and "print_level" not in task_ipopt:
        options.update(VERBOSE_IPOPT)
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


def common_options(parser: argparse.ArgumentParser, top: bool) -> None:
    """``-v``/``-q`` on the top parser and on every subcommand (either place works)."""
    default = False if top else argparse.SUPPRESS
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        default=default,
        help="log debug messages, and show Ipopt's iteration log (stdout)",
    )
    parser.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=default,
        help="print only warnings and errors: no progress",
    )


def run_options(
    parser: argparse.ArgumentParser,
    task_required: bool = True,
    default_output: str = f"{DEFAULT_OUTPUT_ROOT}/<task name>",
) -> None:
    """``TASK`` (unless not ``task_required``), ``--output`` (its help naming
    ``default_output``), ``--force`` and ``--solver-option``: the options of the commands that
    compute."""
    if task_required:
        parser.add_argument("task", help="task file (YAML)")
    parser.add_argument(
        "-o", "--output", metavar="DIR", help=f"output directory (default: {default_output})"
    )
    parser.add_argument(
        "-f",
        "--force",
        action="store_true",
        help="replace an existing, non-empty output folder: its old files are all removed, "
        "once the new results are complete",
    )
    parser.add_argument(
        "--solver-option",
        action="append",
        metavar="KEY=VALUE",
        help="Ipopt option for the optimal planner (repeatable); overrides the task's "
        "optimal.ipopt; values are read as int, float or string",
    )


def method_option(
    parser: argparse.ArgumentParser, help: str = "planning method (default: both)"
) -> None:
    """``-m``/``--method``: analytic, optimal or both (the default), or mission-only (the
    reference alone, which every run computes)."""
    parser.add_argument(
        "-m",
        "--method",
        choices=("analytic", "optimal", "both", "mission-only"),
        default="both",
        help=help,
    )
