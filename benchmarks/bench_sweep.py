"""Sweep throughput: 100 optimal-planner cases of the capture task (seeded random
capture configurations of the mission arm) run with 1 and with 2 worker processes.

Prints, for each number of workers, the wall time of the whole sweep (worker start-up, symbolic
model and NLP build in each worker, every case, every result file), cases per second, the
speed-up, and the per-case overhead beyond the solve, ``(workers x wall - sum of S) / sum of S``
for three meanings of the solve S, each measured in the workers:

* ``plan``: the planner call of each case (building the NLP from the cached structure, the
  analytic initial guess, Ipopt, the re-simulation of the plan): what ``balance-opt plan`` does
  for the case. Its overhead is what the sweep adds (process start-up, imports, the symbolic
  model, task loading, metrics, transfers, result files, scheduling): the target, <= 10 %;
* ``Ipopt``: every Ipopt solve of the case (the peak objective's three stages, refinement
  re-solves); its overhead adds the planner's own initial guess and re-simulation;
* ``case``: the whole case in its worker; its overhead is the engine alone.

``CPU/case`` is the CPU time of the worker over the wall time of its cases: below 100 % the
workers waited for a CPU (other processes on the machine, or more workers than cores).
``cases/CPU s`` is the number of cases over the CPU time of the workers in their cases: the
throughput per worker on an idle core, which a loaded machine does not change as much.

Target: 2 workers at least 1.7 times as fast as 1. On a shared machine the load average
(printed) and ``CPU/case`` say how much of the cores the benchmark had.

    python benchmarks/bench_sweep.py [--cases 100] [--intervals 50] [--workers 1 2]
        [--objective peak|integral]
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
PAPER_TASK = ROOT / "examples" / "capture_task.yaml"
#: Box of the random capture configurations of the mission arm [rad].
GOAL_LOW, GOAL_HIGH = (0.6, 0.4, -2.0), (1.6, 1.2, -1.0)


def sweep_text(cases: int, intervals: int, seed: int, objective: str | None = None) -> str:
    grid = f"grid:\n  optimal.intervals: [{intervals}]\n"
    if objective:
        grid += f"  optimal.objective: [{objective}]\n"
    return (
        f"task: {PAPER_TASK}\nname: bench\nmethods: [optimal]\n{grid}"
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
        "--objective", choices=("peak", "integral"), help="of every case (default: the task's)"
    )
    parser.add_argument(
        "--scheduler", default=None, help="'local' for a local Dask cluster instead of the pool"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    from balance_opt.sweep.report import is_timing_column, results_table
    from balance_opt.sweep.run import run_sweep
    from balance_opt.sweep.spec import parse_sweep

    text = sweep_text(args.cases, args.intervals, args.seed, args.objective)
    sweep = parse_sweep(text, "bench.yaml", ROOT)
    print(
        f"{len(sweep.cases)} optimal cases of the capture task, N = {args.intervals}, "
        f"objective: {args.objective or 'the task default'}, "
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
        sums = {
            key: sum(r["timing"].get(key, 0.0) for r in results)
            for key in ("plan_s", "planner_ipopt_s", "case_s", "cpu_s")
        }
        iterations = [r["metrics"]["solver"]["iterations"] for r in results if r["status"] == "ok"]
        ok = sum(r["status"] == "ok" for r in results)
        rows.append((workers, wall, len(results), sums, ok, sum(iterations) / max(1, ok)))
        print(f"  {workers} worker(s): {wall:.1f} s, load average after: {os.getloadavg()[0]:.2f}")
        columns, table = results_table(results)
        keep = [c for c in columns if not is_timing_column(c)]
        tables.append([[row.get(c) for c in keep] for row in table])

    base = rows[0][1]
    print(
        f"\n{'workers':>7} {'wall [s]':>8} {'cases/s':>7} {'speed-up':>8} {'plan [s]':>8} "
        f"{'Ipopt [s]':>9} {'case [s]':>8} {'ovh/plan':>8} {'ovh/Ipopt':>9} {'ovh/case':>8} "
        f"{'CPU/case':>8} {'cases/CPU s':>11} {'ok':>4} {'iter':>5}"
    )
    for workers, wall, n, sums, ok, iters in rows:
        over = {k: 100 * (workers * wall - v) / v if v else float("nan") for k, v in sums.items()}
        cpu_share = 100 * sums["cpu_s"] / sums["case_s"]
        print(
            f"{workers:>7} {wall:>8.2f} {n / wall:>7.3f} {base / wall:>8.2f} "
            f"{sums['plan_s']:>8.2f} "
            f"{sums['planner_ipopt_s']:>9.2f} {sums['case_s']:>8.2f} {over['plan_s']:>7.1f}% "
            f"{over['planner_ipopt_s']:>8.1f}% {over['case_s']:>7.1f}% {cpu_share:>7.1f}% "
            f"{n / sums['cpu_s']:>11.3f} "
            f"{ok:>4} {iters:>5.1f}"
        )
    same = all(t == tables[0] for t in tables[1:])
    print(f"\naggregated tables (timing columns aside) identical across worker counts: {same}")
    if len(rows) > 1:
        speedup = base / rows[-1][1]
        print(f"speed-up {rows[-1][0]} vs {rows[0][0]} workers: {speedup:.2f} (target >= 1.7)")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
