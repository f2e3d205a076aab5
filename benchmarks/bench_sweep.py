"""Sweep throughput: 100 optimal-planner cases of the paper's capture task (seeded random
capture configurations of the mission arm) run with 1 and with 2 worker processes.

Prints, for each number of workers, the wall time of the whole sweep (worker start-up, symbolic
model and NLP build in each worker, every case, every result file), cases per second, the
speed-up, and the per-case overhead beyond the solve itself:

* ``overhead vs Ipopt``: ``(workers x wall - sum of Ipopt solve times) / sum of Ipopt solve
  times``: everything that is not Ipopt (initial guess, re-simulation, metrics, start-up,
  scheduling, files), per unit of solve;
* ``overhead vs case``: the same against the time each case took inside its worker, i.e. what
  the sweep machinery alone adds (start-up, model build, transfers, files).

Targets: 2 workers at least 1.7 times as fast as 1; overhead at most 10 %.

    python benchmarks/bench_sweep.py [--cases 100] [--intervals 50] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER_TASK = ROOT / "examples" / "paper_capture.yaml"
#: Box of the random capture configurations of the mission arm [rad].
GOAL_LOW, GOAL_HIGH = (0.6, 0.4, -2.0), (1.6, 1.2, -1.0)


def sweep_text(cases: int, intervals: int, seed: int) -> str:
    return (
        f"task: {PAPER_TASK}\nname: bench\nmethods: [optimal]\n"
        f"grid:\n  optimal.intervals: [{intervals}]\n"
        f"random:\n  seed: {seed}\n  samples: {cases}\n  parameters:\n"
        f"    mission.goal: {{uniform: [{list(GOAL_LOW)}, {list(GOAL_HIGH)}]}}\n"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=100)
    parser.add_argument(
        "--intervals", type=int, default=50, help="collocation intervals N of every case"
    )
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--scheduler", default=None, help="'local' for a local Dask cluster instead of the pool"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    from balance_opt.sweep import parse_sweep, run_sweep
    from balance_opt.sweep_report import is_timing_column, results_table

    sweep = parse_sweep(sweep_text(args.cases, args.intervals, args.seed), "bench.yaml", ROOT)
    print(
        f"{len(sweep.cases)} optimal cases of the paper task, N = {args.intervals}, "
        f"engine: {args.scheduler or 'process pool'}, {os.cpu_count()} CPUs, "
        f"load average before: {os.getloadavg()[0]:.2f}"
    )
    rows, tables = [], []
    for workers in args.workers:
        with tempfile.TemporaryDirectory(prefix="bench_sweep_") as out:
            start = time.perf_counter()
            outcome = run_sweep(sweep, out, jobs=workers, scheduler=args.scheduler, plots=False)
            wall = time.perf_counter() - start
        results = outcome.run.results
        ok = [r for r in results if r["status"] == "ok"]
        solve = sum(r["timing"].get("planner_solve_s", 0.0) for r in results)
        case = sum(r["timing"]["case_s"] for r in results)
        iterations = [
            r["metrics"]["solver"]["iterations"] for r in ok if r["metrics"].get("solver")
        ]
        rows.append(
            (
                workers,
                wall,
                len(results) / wall,
                solve,
                case,
                len(ok),
                sum(iterations) / max(1, len(iterations)),
            )
        )
        print(
            f"  {workers} worker(s): {wall:.1f} s, load average after: {os.getloadavg()[0]:.2f}",
            flush=True,
        )
        columns, table = results_table(results)
        keep = [c for c in columns if not is_timing_column(c)]
        tables.append([[row.get(c) for c in keep] for row in table])

    base = rows[0][1]
    print(
        f"\n{'workers':>7} {'wall [s]':>9} {'cases/s':>8} {'speed-up':>8} {'Ipopt [s]':>9} "
        f"{'cases [s]':>9} {'ovh vs Ipopt':>12} {'ovh vs case':>11} {'ok':>4} {'iter/case':>9}"
    )
    for workers, wall, rate, solve, case, n_ok, iters in rows:
        over_solve = (workers * wall - solve) / solve if solve else float("nan")
        over_case = (workers * wall - case) / case
        print(
            f"{workers:>7} {wall:>9.2f} {rate:>8.3f} {base / wall:>8.2f} {solve:>9.2f} {case:>9.2f} "
            f"{100 * over_solve:>11.1f}% {100 * over_case:>10.1f}% {n_ok:>4} {iters:>9.1f}"
        )
    same = all(t == tables[0] for t in tables[1:])
    print(f"\naggregated tables (timing columns aside) identical across worker counts: {same}")
    if len(rows) > 1:
        speedup = base / rows[-1][1]
        print(f"speed-up {rows[-1][0]} vs {rows[0][0]} workers: {speedup:.2f} (target >= 1.7)")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
