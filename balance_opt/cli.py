"""Command line: ``balance-opt SUBCOMMAND ...`` (``balance-opt --help``).

Exit codes: 0 success, 2 bad input (the message names the file, line and key), 1 solver failure
(whatever was computed is still written), 130 interrupted (nothing written), 141 the reader of
the output went away (the code of a program ended by SIGPIPE, without a traceback)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import json
import logging
import os
import re
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path

from balance_opt import __version__, progress
from balance_opt.report.output_dir import OutputFolder

EXIT_OK, EXIT_SOLVER, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
#: A closed output pipe: 128 + SIGPIPE, what a shell reports for ``cat`` ended by it.
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE
__all__ = ["build_parser", "main"]

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
    from balance_opt.optimal.ipopt_options import check_ipopt_options

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


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def _cmd_cache(args) -> int:
    from balance_opt import cache

    folder, env, size = cache.default_cache_dir(), cache.CACHE_ENV, cache.format_size
    origin = f"${env}" if os.environ.get(env) else f"default; set ${env}"
    print(f"cache folder: {folder} ({origin})")
    if not folder.is_dir():
        print("empty (the folder does not exist yet)")
        return EXIT_OK
    if args.clear:
        deleted, kept = cache.clear(folder)
        freed = size(sum(e.size for e in deleted))
        print(f"deleted {_count(len(deleted), 'entry', 'entries')} ({freed})")
        for entry in kept:
            print(f"kept {entry.name}: a build under way in another process")
        return EXIT_OK
    found = cache.entries(folder)
    total = sum(e.size for e in found)
    print(f"size: {size(total)} (bound {size(cache.size_limit())}, ${cache.LIMIT_ENV})")
    for kind in cache.KINDS:
        group = [e for e in found if e.kind == kind]
        if not group:
            continue
        print(
            f"{kind}: {_count(len(group), 'entry', 'entries')}, {size(sum(e.size for e in group))}"
        )
        if not args.list:
            continue
        for e in group:
            used = datetime.datetime.fromtimestamp(e.last_used).strftime("%Y-%m-%d %H:%M")
            print(f"  {e.name}  {size(e.size)}  last used {used}")
    if found and not args.list:
        print("--list shows every entry")
    return EXIT_OK


def _print_joint_lines(chains) -> None:
    """Each chain's joints, one line a chain; nothing for a robot without movable joints."""
    for k, chain in enumerate(chains, 1):
        print(f"    chain {k}: {', '.join(map(str, chain))}")


def _cmd_robots(args) -> int:
    from balance_opt.model.library import ALIASES, example_robots, robot_info

    if args.name:
        info = robot_info(args.name)
        print(f"{info.name}: {info.path}")
        if info.error:
            print(f"  does not load: {info.error}")
            return 2
        joints, chains = _count(info.dof, "movable joint", "movable joints"), len(info.chains)
        print(f"  {joints}, {_count(chains, 'chain', 'chains')}, {info.mass:.2f} kg")
        _print_joint_lines(info.chains)
        for warning in info.warnings:
            print(f"  warning: {warning}")
        return EXIT_OK
    aliases = {}
    for alias, name in ALIASES.items():
        aliases.setdefault(name, []).append(alias)
    failed = []
    robots = example_robots()
    for name in robots:
        info = robot_info(name, robots)
        if info.error:
            failed.append(info)
            continue
        also = f" (also: {', '.join(aliases[name])})" if name in aliases else ""
        print(f"{name}{also}: {info.dof} movable joints, {info.mass:.1f} kg")
        _print_joint_lines(info.chains)
    print(f"{len(robots) - len(failed)} of {len(robots)} robots load; use robot: {{example: NAME}}")
    for info in failed:
        print(f"does not load: {info.name}: {info.error}")
    return EXIT_OK


def _load_task(path, backend: str | None):
    """The task of file ``path`` with ``robot.backend`` replaced by ``backend`` (unless None)."""
    from balance_opt.tasks.task import load_task

    task = load_task(path)
    if backend is None:
        return task
    robot = dataclasses.replace(task.spec.robot, backend=backend)
    return dataclasses.replace(task, spec=dataclasses.replace(task.spec, robot=robot))


def _early_output(args) -> OutputFolder | contextlib.nullcontext:
    """The ``--output`` folder, for a ``with`` block around the whole command: opened (checked,
    locked, staging created) before anything else, even before the task is loaded, and
    committed when the block ends (the run's own ``with`` inside it is not the outermost); a
    null context without ``--output``."""
    return OutputFolder(args.output, args.force) if args.output else contextlib.nullcontext()


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


def _reference_asked(args, schema: Callable[[], dict], reference: Callable[[], str]) -> bool:
    """Print a file format's JSON Schema (``--schema``) or Markdown reference (``--reference``)
    if asked; whether it was."""
    if args.schema:
        print(json.dumps(schema(), indent=2))
    elif args.reference:
        print(reference())
    return args.schema or args.reference


def _cmd_validate(args) -> int:
    """Check every task file given, each error printed with its file; exit 2 if any failed."""
    from balance_opt.errors import InputError
    from balance_opt.tasks.task import check_methods, load_task
    from balance_opt.tasks.task_spec import task_json_schema, task_reference_markdown

    if _reference_asked(args, task_json_schema, task_reference_markdown):
        return EXIT_OK
    if not args.tasks:
        raise InputError("validate: give one or more task files, or --schema")
    failed = 0
    for path in args.tasks:
        try:
            task = load_task(path)
            check_methods(task, _methods(args))
        except InputError as exc:
            failed += 1
            message = str(exc)
            if not message.startswith(str(path)):
                message = f"{path}: {message}"
            print(f"balance-opt: error: {message}", file=sys.stderr)
            continue
        robot = task.robot
        arms = "; ".join(f"{a.name} {a.dof} joints" for a in robot.arms)
        print(
            f"{path}: ok (robot {robot.name}, {arms}; mission {task.spec.mission.type}, "
            f"{task.duration:.3g} s)"
        )
    if failed and len(args.tasks) > 1:
        print(f"{failed} of {len(args.tasks)} task files failed")
    return EXIT_INPUT if failed else EXIT_OK


def _cmd_inspect(args) -> int:
    from balance_opt.errors import InputError
    from balance_opt.model.summary import robot_summary
    from balance_opt.model.symbolic import backend_description  # builds the bridge if used

    srdf = None if args.write_srdf is None else Path(args.write_srdf)
    if srdf is not None and args.task is None:
        raise InputError("inspect --write-srdf: give a task file (its robot, locks and ignores)")
    if srdf is not None and srdf.exists() and not args.force:  # before the work, not after
        raise InputError(f"{srdf} exists; use --force to replace it, or choose another file")
    if args.task is None:
        from balance_opt.model.library import paper_robot

        print(robot_summary(paper_robot()))
        print(f"symbolic backend: {backend_description(args.backend or 'auto')}")
        return EXIT_OK
    task = _load_task(args.task, args.backend)
    print(f"task {task.name} ({task.source}, sha256 {task.sha256[:12]})")
    print(robot_summary(task.robot, task.q0))
    _print_cartesian_goal(task)
    geometry = _print_geometry(task)
    print(f"symbolic backend: {backend_description(task.spec.robot.backend)}")
    if srdf is not None:
        _write_srdf(task, geometry, srdf)
    return EXIT_OK


def _write_srdf(task, geometry, path: Path) -> None:
    """The SRDF of the pairs the robot leaves out (not the task's), for the user to review."""
    from balance_opt.errors import InputError
    from balance_opt.geometry.self_collision import srdf_text
    from balance_opt.report.output_dir import replaced_atomically

    if geometry is None:
        raise InputError(f"--write-srdf {path}: the robot's geometry is not loaded")
    text = srdf_text(task.robot.name, geometry.disabled)
    with replaced_atomically(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    print(f"wrote {path}: {len(geometry.disabled)} disabled link pairs")


def _print_geometry(task):
    """What the clearance check and the planner's collision avoidance hold apart (the task's
    ignored pairs and SRDF applied, or the computed pairs) and the pairs already close at the
    initial configuration; the geometry, or None when it does not load."""
    from balance_opt.errors import InputError
    from balance_opt.geometry.robot_geometry import NoGeometryError, RobotGeometry
    from balance_opt.geometry.self_collision import NEAR

    planner = task.spec.optimal.planner
    try:
        geometry = RobotGeometry(
            task.robot, srdf=planner.collision_srdf, ignore=planner.collision_ignore
        )
    except NoGeometryError as exc:
        print(f"geometry: none ({exc}): no clearance check, no collision avoidance")
        return None
    except InputError as exc:
        print(f"geometry: not loaded ({exc})")
        return None
    s = geometry.summary(task.q0, planner.collision_margin)
    left_out = s["link_pairs_ignored"]
    print(
        f"geometry from the URDF's <{s['source']}> elements: {s['pairs_checked']} pairs checked; "
        f"link pairs left out: {left_out['same body']} same body, {left_out['adjacent']} "
        f"adjacent, {left_out['srdf']} by the SRDF, "
        f"{left_out['default'] + left_out['always'] + left_out['near']} computed, "
        f"{left_out['ignored']} ignored by the task"
    )
    if s["srdf"] is not None:
        print(f"  pairs left out by the SRDF {s['srdf']}")
    else:
        print(
            f"  pairs left out computed (no SRDF): {left_out['adjacent']} adjacent, "
            f"{left_out['default']} in the reference pose, {left_out['always']} in nearly "
            f"every sampled configuration, {left_out['near']} one body apart and never more "
            f"than {NEAR:g} m apart ({s['samples']} samples)"
        )
        reasons = ("default", "reference pose"), ("always", "nearly always"), ("near", "near")
        for reason, what in reasons:
            pairs = [f"{a} / {b}" for (a, b), r in sorted(geometry.ignored.items()) if r == reason]
            if pairs:
                print(f"    {what}: {', '.join(pairs)}")
    close = s["initial_contacts"] + s["initial_within_margin"]
    if not close:
        print(f"  at the initial configuration every pair is at least {s['margin_m']:g} m apart")
    for kind, items in (
        ("in contact", s["initial_contacts"]),
        (f"within the margin {s['margin_m']:g} m", s["initial_within_margin"]),
    ):
        if items:
            pairs = ", ".join(f"{c['pair']} ({c['distance_m']:.4f} m)" for c in items)
            print(f"  {kind} at the initial configuration: {pairs}")
    if s["initial_contacts"]:
        print(
            "  (the task starts in collision: the optimal planner refuses it; move the initial "
            "configuration, or leave the pairs out with robot.srdf or optimal.collision.ignore)"
        )
    return geometry


def _print_cartesian_goal(task) -> None:
    goal = task.cartesian_goal
    if goal:
        values = ", ".join(f"{name} {v:.6g}" for name, v in goal.items())
        print(f"mission goal found by inverse kinematics: {values} [rad or m]")


@contextlib.contextmanager
def _starts_executor(task, methods: tuple[str, ...], args=None):
    """The sweep engine's process pool for the optimal planner's starts (``optimal.starts >
    1``: one worker per start, at most one per CPU) and the closed loop's models
    (``--closed-loop``: one per CPU, or Dask with ``--scheduler``), for this command only;
    ``None`` when there is nothing to run beside this process."""
    if getattr(args, "closed_loop", False):
        from balance_opt.sweep.engine import make_engine

        with make_engine(os.cpu_count() or 1, args.scheduler) as engine:
            log.info("closed loop: %s", engine.describe())
            yield engine
        return
    starts = task.spec.optimal.planner.starts
    jobs = min(starts, os.cpu_count() or 1)
    if "optimal" not in methods or starts < 2 or jobs < 2:
        yield None
        return
    from balance_opt.sweep.engine import LocalPoolEngine

    with LocalPoolEngine(jobs) as engine:
        log.info("optimal planner: %d starts on %d worker processes", starts, jobs)
        yield engine


def _run_task_command(args) -> int:
    """``plan``, ``simulate`` and ``compare``."""
    from balance_opt.app.pipeline import run_task

    methods = _methods(args)
    with _early_output(args) as folder:
        task = _load_task(args.task, args.backend)
        solver_options = ipopt_options_of(args, task)
        folder = folder or OutputFolder(default_output_folder(task.name), args.force)
        if args.command == "compare" and task.spec.mission.timing == "free":
            from balance_opt.app.pipeline import GIVEN_TIMING

            methods += (GIVEN_TIMING,) if "optimal" in methods else ()
        started = time.perf_counter()
        with _starts_executor(task, methods, args) as executor:
            run = run_task(
                task,
                methods=methods,
                simulate=args.simulate,
                output_dir=folder,
                solver_options=solver_options,
                executor=executor,
                robustness=task.spec.robustness.runs_in(
                    "compare" if args.command == "compare" else "plan"
                ),
                closed_loop=getattr(args, "closed_loop", False),
            )
    from balance_opt.report.report import violation_count_text

    # the results on stdout (``compare ... > log`` keeps them), the progress on stderr
    _print_cartesian_goal(task)
    elapsed = time.perf_counter() - started
    print(f"wrote {len(run.files)} files to {folder.target} in {elapsed:.1f} s")
    for name, res in run.results.items():
        m = run.metrics["methods"][name]
        count = violation_count_text(m["limit_violations"], m["limit_violations_by_kind"])
        print(
            f"  {name:<13s} max drift {res.max_drift:.3g} rad, final drift "
            f"{res.final_drift:.3g} rad, {count} limit violations"
        )
        for line in _more_summary(m):
            print(f"  {'':<13s} {line}")
        for warning in m["warnings"]:
            print(f"  {'':<13s} WARNING: {warning}")
    if run.report is not None:
        print(f"report: {run.report}")
    if run.failures:
        for method, message in run.failures.items():
            print(f"balance-opt: solver failure ({method}): {message}", file=sys.stderr)
        return EXIT_SOLVER
    return EXIT_OK


def _methods(args) -> tuple[str, ...]:
    return ("analytic", "optimal") if args.method == "both" else (args.method,)


def _more_summary(metrics: dict) -> list[str]:
    """The clearance, smoothness and model-error lines of one method's summary, from its
    metrics."""
    lines = []
    c = metrics.get("clearance")
    if c and c.get("closest_pair") is not None:
        pen = c.get("first_penetration")
        if pen:
            lines.append(
                f"COLLISION: {pen['pair']} from t = {pen['time_s']:.3f} s, "
                f"{pen['depth_m']:.3g} m deep"
            )
        else:
            lines.append(
                f"smallest distance between bodies {c['min_distance_m']:.3g} m "
                f"({c['closest_pair']}, t = {c['closest_time_s']:.2f} s)"
            )
    smooth = metrics.get("smoothness") or {}
    if smooth and any(v["acceleration_reversals"] for v in smooth.values()):
        reversals = "/".join(str(v["acceleration_reversals"]) for v in smooth.values())
        jerk = max(v["max_jerk_rad_s3"] for v in smooth.values())
        lines.append(f"acceleration reversals {reversals}, largest jerk {jerk:.3g} rad/s^3")
    closed = metrics.get("closed_loop")
    if closed:
        peak, final, times = closed["max_drift"], closed["final_drift"], closed["replan_time_s"]
        lines.append(
            f"closed loop ({closed['samples']} models, period {closed['period_s']:g} s): max "
            f"drift {peak['median_rad']:.3g} (median) / {peak['p95_rad']:.3g} (95 %) rad, final "
            f"{final['p95_rad']:.3g} (95 %) rad; re-plans {times['median']:.3g} s median, "
            f"{times['max']:.3g} s max, {closed['failed_replans']} of {closed['replans']} failed "
            f"or late"
        )
    spread = metrics.get("robustness")
    if spread:
        peak, final = spread["max_drift"], spread["final_drift"]
        lines.append(
            f"under model error: max drift {peak['median_rad']:.3g} (median) / "
            f"{peak['p95_rad']:.3g} (95 %) rad, final {final['p95_rad']:.3g} (95 %) rad"
        )
    return lines


def _cmd_paper_figures(args) -> int:
    from balance_opt.app.study import paper_figures

    with _early_output(args) as folder:
        task = None if args.task is None else _load_task(args.task, None)
        solver_options = ipopt_options_of(args, task)
        folder = folder or OutputFolder(PAPER_FIGURES_FOLDER, args.force)
        files = paper_figures(
            folder, task=task, solver_options=solver_options, backend=args.backend
        )
    print(f"wrote {len(files)} files to {folder.target}")
    return EXIT_OK


def _sweep_progress(record: dict, done: int, total: int) -> None:
    """One log line per finished case of a sweep."""
    metrics = record.get("metrics") or {}
    drift = metrics.get("max_drift_rad")
    what = (
        f"max drift {drift:.3g} rad"
        if isinstance(drift, float)
        else (record.get("error") or {}).get("message", "")
    )
    log.info(
        "[%d/%d] case %d %s %s: %s (%.2f s)",
        done,
        total,
        record["index"],
        record["method"],
        record["status"],
        what[:200],
        record["timing"]["case_s"],
    )


def _cmd_sweep(args) -> int:
    """``balance-opt sweep``: 0 when every case succeeded, 1 when some failed."""
    from balance_opt.errors import InputError
    from balance_opt.sweep.spec import load_sweep, sweep_json_schema, sweep_reference_markdown

    if _reference_asked(args, sweep_json_schema, sweep_reference_markdown):
        return EXIT_OK
    if args.sweep is None:
        raise InputError("sweep: give a sweep file, or --schema")
    progress.configure(False)  # one log line per case, no Ipopt line (workers are silent)
    solver_options = ipopt_options_of(args)
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 0:
        raise InputError(f"--jobs must be >= 0, got {jobs}")
    if args.retry_failed and not args.resume:
        raise InputError("--retry-failed goes with --resume")
    sweep = load_sweep(args.sweep, solver_options)
    if args.backend is not None:  # the same maps either way: the case ids do not change
        for case in sweep.cases:
            case["task"].setdefault("robot", {})["backend"] = args.backend
    out_dir = Path(args.output) if args.output else default_output_folder(sweep.name)
    if args.scheduler is None:
        jobs = min(jobs, len(sweep.cases)) if jobs else 0
    from balance_opt.sweep.run import TASK_RUNNER, run_sweep

    outcome = run_sweep(
        sweep,
        out_dir,
        jobs=jobs,
        scheduler=args.scheduler,
        resume=args.resume,
        force=args.force,
        retry_failed=args.retry_failed,
        plots=not args.no_plots,
        runner=args.runner or TASK_RUNNER,
        on_result=_sweep_progress,
    )
    run = outcome.run
    print(
        f"{len(run.results)} case(s): {len(run.ran)} run in {run.elapsed_s:.1f} s on "
        f"{run.workers} worker(s), {len(run.skipped)} skipped (already done), "
        f"{len(run.failed)} failed; table {outcome.files['table']}"
    )
    return EXIT_SOLVER if run.failed else EXIT_OK


def _scene_page(source: Path, backend: str | None, folder: Path) -> Path:
    """The scene page of a result folder (its ``scene.html``, or one built into ``folder`` from
    its NPZ files and task file) or of a task file (planned here, both methods)."""
    from balance_opt.app import pipeline
    from balance_opt.errors import InputError

    scene, metrics = pipeline.SCENE_FILE, source / pipeline.METRICS_FILE
    if not source.is_dir():
        run = pipeline.run_task(_load_task(source, backend), methods=pipeline.METHODS)
        return pipeline.write_run_scene(run, folder / scene)
    if (source / scene).is_file():
        return source / scene
    from balance_opt.report.outputs import read_npz_result

    if not metrics.is_file():
        raise InputError(f"{source}: no {scene} and no {metrics.name}: not a result folder")
    content = json.loads(metrics.read_text())
    task_file = content.get("task", {}).get("file", "")
    if not Path(task_file).is_file():
        raise InputError(
            f"{metrics}: task file '{task_file}' not found (the scene needs its robot)"
        )
    names = (pipeline.REFERENCE, *pipeline.METHODS)
    results = {n: read_npz_result(f) for n in names if (f := source / f"{n}.npz").is_file()}
    if not results:
        raise InputError(f"{source}: no NPZ trajectories (outputs.npz was off?)")
    failures = content.get("failures") or {}
    run = pipeline.TaskRun(_load_task(task_file, backend), results=results, failures=failures)
    return pipeline.write_run_scene(run, folder / scene)


def _cmd_view(args) -> int:
    import tempfile
    import webbrowser

    # a scene built here (of a task, or of an older result folder, which stays as it was) is
    # kept for the browser to read after the command ends
    folder = Path(tempfile.mkdtemp(prefix="balance-opt-view-"))
    try:
        page = _scene_page(Path(args.source), args.backend, folder).resolve()
    finally:
        if not any(folder.iterdir()):  # the result folder's own page, or an error
            folder.rmdir()
    print(page, flush=True)
    if args.no_browser:
        return EXIT_OK
    if webbrowser.open(page.as_uri(), new=2):
        log.info("opened %s in a browser", page.as_uri())
    else:
        log.warning("no browser found: open %s in one (the file is self-contained)", page)
    return EXIT_OK


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
    def command(name: str, run, help: str, **kwargs) -> argparse.ArgumentParser:
        parser = sub.add_parser(name, help=help, **kwargs)
        parser.set_defaults(run=run)
        return parser

    p = command("validate", _cmd_validate, "check task files (everything short of planning)")
    p.add_argument("tasks", nargs="*", metavar="TASK", help="task files (YAML)")
    _reference_options(p, "task")
    _method_option(
        p,
        "check what these methods need (default: both; analytic leaves out the optimal "
        "planner's checks)",
    )
    command("schema", _cmd_validate, "print the JSON Schema of task files").set_defaults(
        schema=True
    )
    p = command("inspect", _cmd_inspect, "print a robot summary and its coupling measures")
    p.add_argument("task", nargs="?", help="task file (default: the paper's Table 1 robot)")
    _backend_option(p)
    p.add_argument(
        "--write-srdf",
        metavar="FILE",
        help="write the link pairs the robot leaves out of the collision checks (computed, or "
        "its SRDF's) as an SRDF, to review, edit and give as robot.srdf",
    )
    _flag(p, "-f", "--force", help="replace the --write-srdf FILE if it exists")

    for name, help in (
        ("plan", "plan the balance motion, write trajectories, metrics, figures, report"),
        ("simulate", "plan, then check each plan in a forward-dynamics simulation"),
        ("compare", "analytic and optimal plans, simulated, and the comparison report"),
    ):
        p = command(name, _run_task_command, help)
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
        "paper-figures", _cmd_paper_figures, "the paper's study: Figs 2-5 on the Table 1 robot"
    )
    _compute_options(p, str(PAPER_FIGURES_FOLDER))
    p.add_argument(
        "--task",
        help="study this task instead (its robot, mission, balance start and options; both "
        "methods); default: the paper's law on examples/paper_fig5.yaml's scenario and the "
        "law against the optimal plan on examples/capture_task.yaml's",
    )

    p = command(
        "sweep",
        _cmd_sweep,
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

    p = command(
        "view",
        _cmd_view,
        "open the 3D scene of a run's plans in a browser (a self-contained file)",
        description="Open the 3D scene of a result folder (its scene.html, or one built from "
        "its NPZ files into a temporary folder) or of a task file (planned first, both methods) "
        "in a browser; prints the page's path.",
    )
    p.add_argument("source", metavar="RESULT_DIR|TASK", help="result folder or task file")
    _flag(p, "--no-browser", help="print the page's path, open no browser")
    _backend_option(p)

    p = command(
        "cache", _cmd_cache, "show the cache of compiled kernels and the bridge, or clear it"
    )
    _flag(p, "--clear", help="delete every cached entry")
    _flag(p, "--list", help="list every entry (default: a summary)")

    p = command("robots", _cmd_robots, "robots usable as robot.example, with their joints by chain")
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
