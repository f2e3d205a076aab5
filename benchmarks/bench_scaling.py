"""How the optimal planner's time grows with the number of intervals N and of joints.

For each task (default: the paper task, 3 + 3 joints, and Baxter, 7 + 7) and each N, in one
process with the kernels already compiled in the cache: the first plan at that N (it builds the
NLP structure of that N) and a second one (the structure reused, as in a sweep), each split as
the planner reports it (build of the final NLP, guess, Ipopt over every solve of the plan,
re-simulation), with Ipopt's iterations (every solve: the peak objective's three stages), the time
per iteration and the process CPU time of the second plan. The per-robot model (symbolic maps
and kernels, once per robot) is timed separately.

    python benchmarks/bench_scaling.py [--tasks examples/capture_task.yaml ...]
                                       [--intervals 50 100 200 400] [--objective integral]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TASKS = (ROOT / "examples" / "capture_task.yaml", ROOT / "examples" / "baxter_floating.yaml")
INTERVALS = (50, 100, 200, 400)


def task_with_intervals(path: Path, intervals: int, objective: str | None = None):
    """The task of ``path`` with ``optimal.intervals`` (and ``optimal.objective``) set."""
    import yaml

    from balance_opt.tasks.task import task_from_dict

    data = yaml.safe_load(path.read_text())
    data.setdefault("optimal", {})["intervals"] = intervals
    if objective:
        data["optimal"]["objective"] = objective
    return task_from_dict(data, path.parent, source=f"{path.name} (N = {intervals})")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=Path, nargs="+", default=list(TASKS))
    parser.add_argument("--intervals", type=int, nargs="+", default=list(INTERVALS))
    parser.add_argument(
        "--objective", choices=("peak", "integral"), help="of every plan (default: the task's)"
    )
    args = parser.parse_args(argv)

    from balance_opt.app.models import ModelCache
    from balance_opt.app.pipeline import plan_optimal

    print(f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} before")
    print(
        "\n| task | joints (mission + balance) | N | NLP build [s] | guess [s] | Ipopt [s] "
        "| iterations | Ipopt per iteration [ms] | re-simulation [s] | plan, structure reused "
        "[s] | its CPU [s] |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for path in args.tasks:
        models = ModelCache()
        start = time.perf_counter()
        first = task_with_intervals(path, args.intervals[0], args.objective)
        models.planner_model(first.robot, first.spec.robot.backend).kernels()
        model_s = time.perf_counter() - start
        joints = f"{first.robot.mission_indices.size} + {first.robot.balance_indices.size}"
        for n in args.intervals:
            task = task_with_intervals(path, n, args.objective)
            built = plan_optimal(task, models=models).info["wall_time_s"]
            w0, c0 = time.perf_counter(), time.process_time()
            again = plan_optimal(task, models=models)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            split, iters = again.info["wall_time_s"], again.info["total_iterations"]
            ipopt = again.info["total_solve_time_s"]  # every Ipopt solve (the peak's stages)
            print(
                f"| {path.stem} | {joints} | {n} | {built['build']:.2f} | {split['guess']:.2f} "
                f"| {ipopt:.2f} | {iters} | {1000 * ipopt / max(iters, 1):.1f} "
                f"| {split['resimulate']:.2f} | {wall:.2f} | {cpu:.2f} |",
                flush=True,
            )
        print(f"| {path.stem}: per-robot model and kernels (from the cache) {model_s:.2f} s |")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
