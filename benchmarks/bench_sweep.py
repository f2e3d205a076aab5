"""Sweep throughput: seeded random optimal-planner cases of a task (the capture task's: random
capture configurations of the mission arm; another task's: random mission durations within
20 % of its own) run with 1 and with 2 worker processes of the local process pool.

Prints, for each number of workers, the wall time of the whole sweep (worker start-up, symbolic
model and NLP build in each worker, every case, every result file), cases per second, the wall
time as a fraction of one worker's (target: <= 0.6 with 2 workers), and the per-case overhead
beyond the solve, ``(workers x wall - sum of S) / sum of S``, for three meanings of the solve S,
each measured in the workers:

* ``plan``: the planner call of each case (building the NLP from the cached structure, the
  analytic initial guess, Ipopt, the re-simulation of the plan): what ``balance-opt plan`` does
  for the case. Its overhead is what the sweep adds (process start-up, imports, the symbolic
  model, task loading, metrics, transfers, result files, scheduling);
* ``Ipopt``: every Ipopt solve of the case (the peak objective's stages, refinement
  re-solves); its overhead adds the planner's own initial guess and re-simulation;
* ``case``: the whole case in its worker; its overhead is the engine alone.

``CPU/case`` is the CPU time of the workers over the wall time of their cases: below 100 % the
workers waited for a CPU (other processes on the machine, or more workers than cores).
``cases/CPU s`` is the number of cases over the workers' CPU time in their cases: the throughput
of one worker on an idle core (target: >= 1.5 with the default objective at N = 50), which a
loaded machine changes less than the wall time. The table also replaces the ``sweeps``
section of ``docs/performance.md``.

    python benchmarks/bench_sweep.py [TASK] [--cases 64] [--intervals 50] [--workers 1 2]
        [--objective peak|integral] [--scheduler local] [--no-doc]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

from perf_doc import write_section

ROOT = Path(__file__).resolve().parents[1]
PAPER_TASK = (ROOT / "examples" / "capture_task.yaml").resolve()
#: Box of the random capture configurations of the mission arm [rad].
GOAL_LOW, GOAL_HIGH = (0.6, 0.4, -2.0), (1.6, 1.2, -1.0)


def sweep_text(
    task: Path, cases: int, intervals: int, seed: int, objective: str | None = None
) -> str:
    grid = f"grid:\n  optimal.intervals: [{intervals}]\n"
    if objective:
        grid += f"  optimal.objective: [{objective}]\n"
    if task.resolve() == PAPER_TASK:
        varied = f"mission.goal: {{uniform: [{list(GOAL_LOW)}, {list(GOAL_HIGH)}]}}"
    else:
        import yaml

        duration = float(yaml.safe_load(task.read_text())["mission"]["duration"])
        varied = f"mission.duration: {{uniform: [{0.8 * duration:g}, {1.2 * duration:g}]}}"
    return (
        f"task: {task.resolve()}\nname: bench\nmethods: [optimal]\n{grid}"
        f"random:\n  seed: {seed}\n  samples: {cases}\n  parameters:\n    {varied}\n"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", nargs="?", type=Path, default=PAPER_TASK)
    parser.add_argument("--cases", type=int, default=64)
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
    parser.add_argument("--no-doc", action="store_true", help="do not write docs/performance.md")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    from balance_opt.sweep.report import is_timing_column, results_table
    from balance_opt.sweep.run import run_sweep
    from balance_opt.sweep.spec import parse_sweep

    text = sweep_text(args.task, args.cases, args.intervals, args.seed, args.objective)
    sweep = parse_sweep(text, "bench.yaml", ROOT)
    load = os.getloadavg()[0]
    print(
        f"{len(sweep.cases)} optimal cases of {args.task.name}, N = {args.intervals}, "
        f"objective: {args.objective or 'the task default'}, "
        f"engine: {args.scheduler or 'process pool'}, {os.cpu_count()} CPUs, "
        f"load average before: {load:.2f}"
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
    lines = [
        f"{len(sweep.cases)} optimal cases of {args.task.name}, N = {args.intervals}, objective "
        f"{args.objective or 'the task default'}, {args.scheduler or 'process pool'}:",
        "",
        "| workers | wall [s] | cases/s | wall / 1 worker's | plan [s] | Ipopt [s] | case [s] "
        "| overhead / plan | CPU/case | cases/CPU s | ok | iterations |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for workers, wall, n, sums, ok, iters in rows:
        over = 100 * (workers * wall - sums["plan_s"]) / sums["plan_s"] if sums["plan_s"] else 0
        cpu_share = 100 * sums["cpu_s"] / sums["case_s"]
        lines.append(
            f"| {workers} | {wall:.1f} | {n / wall:.2f} | {wall / base:.2f} | {sums['plan_s']:.1f} "
            f"| {sums['planner_ipopt_s']:.1f} | {sums['case_s']:.1f} | {over:.0f} % "
            f"| {cpu_share:.0f} % | {n / sums['cpu_s']:.2f} | {ok} | {iters:.1f} |"
        )
    same = all(t == tables[0] for t in tables[1:])
    lines += ["", f"Aggregated tables (timing columns aside) alike for every worker count: {same}."]
    if len(rows) > 1:
        lines.append(
            f"Wall time of {rows[-1][0]} workers / {rows[0][0]}: {rows[-1][1] / base:.2f} "
            "(target <= 0.6 with 2 workers)."
        )
    print("\n".join(lines))
    if not args.no_doc:
        command = " ".join(["python benchmarks/bench_sweep.py", *sys.argv[1:]])
        print(f"wrote {write_section('sweeps', command, lines, load)}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
