"""``plan``, ``simulate``, ``compare`` (a task's run and its summary on stdout) and
``paper-figures``."""

from __future__ import annotations

import contextlib
import os
import sys
import time

from balance_opt.commands.common import (
    EXIT_OK,
    EXIT_SOLVER,
    PAPER_FIGURES_FOLDER,
    default_output_folder,
    early_output,
    ipopt_options_of,
    load_task_file,
    log,
    methods_of,
    print_cartesian_goal,
)
from balance_opt.report.output_dir import OutputFolder


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


def run_task_command(args) -> int:
    """``plan``, ``simulate`` and ``compare``."""
    from balance_opt.app.pipeline import run_task

    methods = methods_of(args)
    with early_output(args) as folder:
        task = load_task_file(args.task, args.backend)
        solver_options = ipopt_options_of(args, task)
        folder = folder or OutputFolder(default_output_folder(task.name), args.force)
        if args.command == "compare" and task.spec.mission.timing == "free":
            from balance_opt.app.task_run import GIVEN_TIMING

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
    print_cartesian_goal(task)
    elapsed = time.perf_counter() - started
    print(f"wrote {len(run.files)} files to {folder.target} in {elapsed:.1f} s")
    for name, res in run.results.items():
        m = run.metrics["methods"][name]
        count = violation_count_text(m["limit_violations"], m["limit_violations_by_kind"])
        print(
            f"  {name:<13s} max drift {res.max_drift:.3g} rad, final drift "
            f"{res.final_drift:.3g} rad, {count} limit violations"
        )
        failed = ["FAILED: the solver's last iterate, not a plan"] if name in run.failures else []
        for line in failed + _more_summary(m):
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
    if closed and closed.get("diverged"):
        named = ", ".join(f"model {k} ({v})" for k, v in closed["diverged"].items())
        lines.append(f"closed loop: {len(closed['diverged'])} simulations diverged: {named}")
    if closed and closed["samples"]:
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


def cmd_paper_figures(args) -> int:
    from balance_opt.app.study import paper_figures

    with early_output(args) as folder:
        task = None if args.task is None else load_task_file(args.task, None)
        solver_options = ipopt_options_of(args, task)
        folder = folder or OutputFolder(PAPER_FIGURES_FOLDER, args.force)
        files = paper_figures(
            folder, task=task, solver_options=solver_options, backend=args.backend
        )
    print(f"wrote {len(files)} files to {folder.target}")
    return EXIT_OK
