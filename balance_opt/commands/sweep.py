"""``sweep``: a sweep file's cases run, one log line a finished case."""

from __future__ import annotations

import os
from pathlib import Path

from balance_opt import progress
from balance_opt.commands.common import (
    EXIT_OK,
    EXIT_SOLVER,
    default_output_folder,
    ipopt_options_of,
    log,
    reference_asked,
)


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


def cmd_sweep(args) -> int:
    """``balance-opt sweep``: 0 when every case succeeded, 1 when some failed."""
    from balance_opt.errors import InputError
    from balance_opt.sweep.spec import load_sweep, sweep_json_schema, sweep_reference_markdown

    if reference_asked(args, sweep_json_schema, sweep_reference_markdown):
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
