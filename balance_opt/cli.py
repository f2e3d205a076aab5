"""Command line: ``balance-opt SUBCOMMAND ...`` (``balance-opt --help``).

Exit codes: 0 success, 2 bad input (the message names the file, line and key), 1 solver failure
(whatever was computed is still written), 130 interrupted (nothing written), 141 the reader of
the output went away (the code of a program ended by SIGPIPE, without a traceback)."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys

from balance_opt import __version__, progress
from balance_opt.commands.cache import cmd_cache
from balance_opt.commands.common import (
    DEFAULT_OUTPUT_ROOT,
    EXIT_BROKEN_PIPE,
    EXIT_INPUT,
    EXIT_INTERRUPTED,
    EXIT_SOLVER,
    PAPER_FIGURES_FOLDER,
)
from balance_opt.commands.inspect import cmd_inspect, cmd_robots, cmd_validate
from balance_opt.commands.sweep import cmd_sweep
from balance_opt.commands.task_run import cmd_paper_figures, run_task_command
from balance_opt.commands.view import cmd_view

__all__ = ["build_parser", "main"]


@contextlib.contextmanager
def _logging_to_stderr(verbose: bool, quiet: bool):
    """Log balance-opt's messages to the current stderr (progress at INFO), and show the live
    progress line there unless ``quiet``, for the block only (:func:`main` called from Python
    must not leave a handler on a stream that may be closed later)."""
    logger = logging.getLogger("balance_opt")
    level = logger.level
    progress.configure(not quiet, sys.stderr)
    handler = progress.LogHandler(sys.stderr)
    handler.setFormatter(
        logging.Formatter("%(asctime)s %(levelname)s %(message)s", "%H:%M:%S")
        if verbose
        else logging.Formatter("%(message)s")
    )
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO)
    try:
        yield
    finally:  # the live line ends before the error message main prints
        progress.configure(False)
        logger.removeHandler(handler)
        logger.setLevel(level)


#: The help of the options the commands that compute share.
_OUTPUT_HELP = "output directory (default: {})"
_FORCE_HELP = (
    "replace an existing, non-empty output folder: its old files are all removed, once the new "
    "results are complete"
)
_SOLVER_OPTION_HELP = (
    "Ipopt option for the optimal planner (repeatable); overrides the task's optimal.ipopt; "
    "values are read as int, float or string"
)


def _flag(parser: argparse.ArgumentParser, *names: str, help: str, **kwargs) -> None:
    parser.add_argument(*names, action="store_true", help=help, **kwargs)


def _compute_options(
    parser, output: str, force: str = _FORCE_HELP, solver_option: str = _SOLVER_OPTION_HELP
) -> None:
    """``--output``, ``--force``, ``--solver-option`` and ``--backend``, with a command's help."""
    parser.add_argument("-o", "--output", metavar="DIR", help=_OUTPUT_HELP.format(output))
    _flag(parser, "-f", "--force", help=force)
    parser.add_argument("--solver-option", action="append", metavar="KEY=VALUE", help=solver_option)
    _backend_option(parser)


def _backend_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--backend",
        choices=("auto", "pinocchio", "adam"),
        help="symbolic backend of the optimal planner (default: the task's robot.backend, auto)",
    )


def _method_option(parser, help: str = "planning method (default: both)") -> None:
    """``-m``/``--method``: analytic, optimal or both (the default), or mission-only (the
    reference alone, which every run computes)."""
    methods = ("analytic", "optimal", "both", "mission-only")
    parser.add_argument("-m", "--method", choices=methods, default="both", help=help)


def _reference_options(parser, what: str) -> None:
    _flag(parser, "--schema", help=f"print the JSON Schema of {what} files and exit")
    _flag(parser, "--reference", help=f"print the {what}-file reference (Markdown) and exit")


def _add_commands(sub) -> None:
    """Every subcommand, in the order ``--help`` lists them."""

    def command(name: str, run, help: str, **kwargs) -> argparse.ArgumentParser:
        parser = sub.add_parser(name, help=help, **kwargs)
        parser.set_defaults(run=run)
        return parser

    _add_input_commands(command)
    _add_run_commands(command)
    _add_sweep_command(command)
    _add_view_and_cache_commands(command)


def _add_input_commands(command) -> None:
    """``validate``, ``schema`` and ``inspect``: the input read, nothing planned."""
    p = command("validate", cmd_validate, "check task files (everything short of planning)")
    p.add_argument("tasks", nargs="*", metavar="TASK", help="task files (YAML)")
    _reference_options(p, "task")
    _method_option(
        p,
        "check what these methods need (default: both; analytic leaves out the optimal "
        "planner's checks)",
    )
    command("schema", cmd_validate, "print the JSON Schema of task files").set_defaults(schema=True)
    p = command("inspect", cmd_inspect, "print a robot summary and its coupling measures")
    p.add_argument("task", nargs="?", help="task file (default: the paper's Table 1 robot)")
    _backend_option(p)
    p.add_argument(
        "--write-srdf",
        metavar="FILE",
        help="write the link pairs the robot leaves out of the collision checks (computed, or "
        "its SRDF's) as an SRDF, to review, edit and give as robot.srdf",
    )
    _flag(p, "-f", "--force", help="replace the --write-srdf FILE if it exists")


def _add_run_commands(command) -> None:
    """``plan``, ``simulate``, ``compare`` and ``paper-figures``."""
    for name, help in (
        ("plan", "plan the balance motion, write trajectories, metrics, figures, report"),
        ("simulate", "plan, then check each plan in a forward-dynamics simulation"),
        ("compare", "analytic and optimal plans, simulated, and the comparison report"),
    ):
        p = command(name, run_task_command, help)
        p.add_argument("task", help="task file (YAML)")
        _compute_options(p, f"{DEFAULT_OUTPUT_ROOT}/<task name>")
        if name != "plan":
            _flag(
                p,
                "--closed-loop",
                help="also fly each plan closed loop on perturbed robots, the optimal plan "
                "re-planned every closed_loop.period from the measured state",
            )
            p.add_argument(
                "--scheduler",
                metavar="ADDRESS",
                help="with --closed-loop, run its models on Dask: a scheduler's address, or "
                "'local' (default: a local process pool, one worker per CPU)",
            )
        if name == "compare":
            no_simulate = "skip the forward-dynamics simulation"
            p.add_argument("--no-simulate", dest="simulate", action="store_false", help=no_simulate)
            p.set_defaults(method="both")
            continue
        _method_option(p)
        if name == "plan":
            _flag(p, "--simulate", help="also simulate each plan (as the simulate command)")
        else:
            p.set_defaults(simulate=True)
    p = command(
        "paper-figures", cmd_paper_figures, "the paper's study: Figs 2-5 on the Table 1 robot"
    )
    _compute_options(p, str(PAPER_FIGURES_FOLDER))
    p.add_argument(
        "--task",
        help="study this task instead (its robot, mission, balance start and options; both "
        "methods); default: the paper's law on examples/paper_fig5.yaml's scenario and the "
        "law against the optimal plan on examples/capture_task.yaml's",
    )


def _add_sweep_command(command) -> None:
    p = command(
        "sweep",
        cmd_sweep,
        "run a study: many tasks from a sweep file, on a process pool or a Dask cluster",
        description="Run every case of a sweep file (a base task and the parameters to vary); "
        "write one result per case as it finishes, the table results.csv, "
        "summary.json and plots. Exit code 0 when every case succeeded, 1 when some "
        "failed (their errors are in the table), 2 for a bad sweep file or an output folder "
        "that cannot be used (another sweep writing to it, for one), 130 when interrupted "
        "(--resume goes on).",
    )
    p.add_argument("sweep", nargs="?", help="sweep file (YAML)")
    _compute_options(
        p,
        "results/<sweep name>",
        "start over in an existing, non-empty output directory",
        "Ipopt option for every optimal case (repeatable)",
    )
    p.add_argument(
        "-j",
        "--jobs",
        type=int,
        metavar="N",
        help="worker processes (default: the number of CPUs; 0 runs the cases in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on Dask: the address of a scheduler (tcp://host:8786), or 'local' to start "
        "a local cluster of --jobs worker processes on 127.0.0.1",
    )
    _flag(
        p, "--resume", help="finish an interrupted sweep in --output: skip the cases already done"
    )
    _flag(p, "--retry-failed", help="with --resume, run failed cases again")
    _flag(p, "--no-plots", help="skip the summary plots")
    _reference_options(p, "sweep")
    # "module:function" of another case function (tests); default: the task runner
    p.add_argument("--runner", help=argparse.SUPPRESS)


def _add_view_and_cache_commands(command) -> None:
    """``view``, ``cache`` and ``robots``."""
    p = command(
        "view",
        cmd_view,
        "open the 3D scene of a run's plans in a browser (a self-contained file)",
        description="Open the 3D scene of a result folder (its scene.html, or one built from "
        "its NPZ files into a temporary folder) or of a task file (planned first, both methods) "
        "in a browser; prints the page's path.",
    )
    p.add_argument("source", metavar="RESULT_DIR|TASK", help="result folder or task file")
    _flag(p, "--no-browser", help="print the page's path, open no browser")
    _backend_option(p)

    p = command(
        "cache", cmd_cache, "show the cache of compiled kernels and the bridge, or clear it"
    )
    _flag(p, "--clear", help="delete every cached entry")
    _flag(p, "--list", help="list every entry (default: a summary)")

    p = command("robots", cmd_robots, "robots usable as robot.example, with their joints by chain")
    p.add_argument("name", nargs="?", help="one robot in detail")


def build_parser() -> argparse.ArgumentParser:
    """The ``balance-opt`` parser: every subcommand, ``-v``/``-q`` on each (either place
    works)."""
    parser = argparse.ArgumentParser(
        prog="balance-opt",
        description="Balance-arm motion planning for free-floating multi-arm space robots: the "
        "paper's analytic law and an optimal planner, compared.",
        epilog="exit codes: 0 success, 2 bad input, 1 solver failure, 130 interrupted, "
        "141 output pipe closed",
    )
    _verbosity(parser, False)
    parser.add_argument("--version", action="version", version=f"balance-opt {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_commands(sub)
    for p in sub.choices.values():
        _verbosity(p, argparse.SUPPRESS)
    return parser


def _verbosity(parser: argparse.ArgumentParser, default) -> None:
    help = "log debug messages, and show Ipopt's iteration log (stdout)"
    _flag(parser, "-v", "--verbose", default=default, help=help)
    _flag(
        parser, "-q", "--quiet", default=default, help="print only warnings and errors: no progress"
    )


def _detach_stdout() -> None:
    """Point stdout at ``/dev/null`` after its reader went away, so that nothing more (the
    interpreter's last flush included) fails on it."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 success, 1 solver failure, 2 bad input,
    130 interrupted by Ctrl-C, SIGTERM or SIGHUP, 141 output pipe closed)."""
    from balance_opt.errors import BalanceOptError, InputError, SolverError
    from balance_opt.interrupts import handling_signals

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    try:
        with _logging_to_stderr(args.verbose, args.quiet), handling_signals():
            code = args.run(args)
            sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
            return code
    except BrokenPipeError:
        _detach_stdout()
        return EXIT_BROKEN_PIPE
    except InputError as exc:
        return _fail(f"error: {exc}", EXIT_INPUT)
    except SolverError as exc:
        return _fail(f"solver failure: {exc}", EXIT_SOLVER)
    except BalanceOptError as exc:
        return _fail(f"failure: {exc}", EXIT_SOLVER)
    except KeyboardInterrupt:
        return _fail("interrupted", EXIT_INTERRUPTED)


def _fail(message: str, code: int) -> int:
    """Print ``balance-opt: message`` on stderr (on a line of its own) and return ``code``."""
    print(f"balance-opt: {message}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
