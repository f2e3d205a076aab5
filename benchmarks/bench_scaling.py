"""How the optimal planner's time grows with the number of intervals N and of joints.

For each task (default: the capture task, 3 + 3 joints, and Baxter, 7 + 7) and each N, in one
process with the kernels already compiled in the cache: the first plan at that N (it builds the
NLP structure of that N) and a second one (the structure reused, as in a sweep), each split as
the planner reports it (build of the final NLP, guess, Ipopt over every solve of the plan,
re-simulation), with Ipopt's iterations of every stage of the peak objective, the time per
iteration, the process CPU time of the second plan and its ratio to the first N's (target: at
N = 400 at most 5 times N = 100's). The per-robot model (symbolic maps and kernels, once per
robot) is timed separately. The table also replaces the ``scaling`` section of
``docs/performance.md``.

    python benchmarks/bench_scaling.py [TASK ...] [--intervals 100 200 400]
                                       [--objective integral] [--no-doc]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from perf_doc import write_section

ROOT = Path(__file__).resolve().parents[1]
TASKS = (ROOT / "examples" / "capture_task.yaml", ROOT / "examples" / "baxter_floating.yaml")
INTERVALS = (100, 200, 400)


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
    parser.add_argument("tasks", type=Path, nargs="*", default=list(TASKS))
    parser.add_argument("--intervals", type=int, nargs="+", default=list(INTERVALS))
    parser.add_argument(
        "--objective", choices=("peak", "integral"), help="of every plan (default: the task's)"
    )
    parser.add_argument("--no-doc", action="store_true", help="do not write docs/performance.md")
    args = parser.parse_args(argv)

    from balance_opt.app.models import ModelCache
    from balance_opt.app.pipeline import plan_optimal
    from balance_opt.optimal.nlp import point_kernels

    load = os.getloadavg()[0]
    print(f"{os.cpu_count()} CPUs, load average {load:.2f} before")
    lines = [
        "| task | joints | N | NLP build [s] | guess [s] | Ipopt [s] | iterations by stage "
        "| Ipopt per iteration [ms] | re-simulation [s] | plan, structure reused [s] "
        "| its CPU [s] | CPU x first N | max drift [rad] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    print("\n".join(lines), flush=True)
    for path in args.tasks:
        models = ModelCache()
        start = time.perf_counter()
        first = task_with_intervals(path, args.intervals[0], args.objective)
        point_kernels(models.planner_model(first.robot, first.spec.robot.backend))
        model_s = time.perf_counter() - start
        joints = f"{first.robot.mission_indices.size} + {first.robot.balance_indices.size}"
        first_cpu = None
        for n in args.intervals:
            task = task_with_intervals(path, n, args.objective)
            built = plan_optimal(task, models=models).solver.last.wall_time_s
            w0, c0 = time.perf_counter(), time.process_time()
            again = plan_optimal(task, models=models)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            first_cpu = first_cpu or cpu
            split, iters = again.solver.last.wall_time_s, again.solver.iterations
            ipopt = again.solver.solve_s  # every Ipopt solve (the peak's stages)
            stages = again.details().get("stages") or []
            by_stage = " + ".join(f"{s['iterations']}" for s in stages) or str(iters)
            lines.append(
                f"| {path.stem} | {joints} | {n} | {built['build']:.2f} | {split['guess']:.2f} "
                f"| {ipopt:.2f} | {by_stage} | {1000 * ipopt / max(iters, 1):.1f} "
                f"| {split['resimulate']:.2f} | {wall:.2f} | {cpu:.2f} | {cpu / first_cpu:.2f} "
                f"| {again.max_drift:.5f} |"
            )
            print(lines[-1], flush=True)
        lines.append(f"| {path.stem}: per-robot model and kernels from the cache {model_s:.2f} s |")
        print(lines[-1])
    lines += [
        "",
        "Iterations by stage: the peak objective's stages in order "
        "(`PEAK_STAGES` in `balance_opt/optimal/options.py`).",
    ]
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    if not args.no_doc:
        command = " ".join(["python benchmarks/bench_scaling.py", *sys.argv[1:]])
        print(f"wrote {write_section('scaling', command, lines, load)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
