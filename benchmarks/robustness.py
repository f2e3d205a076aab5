"""Drift under model error on the capture task (issue 25): the spread of each method's drift
over K perturbed models, and what the study costs against the ``compare`` run it belongs to.

The run is ``compare``'s computation without files (every method planned, every plan
simulated, in this process); the study replays each plan's joint motion on the same K models
(:mod:`balance_opt.motion.robustness`). "x compare" is the study's wall time over the run's.

Run: ``python benchmarks/robustness.py [--task examples/capture_task.yaml] [--samples 50]
[--perturbations 0.05 0.1 0.2]``.
"""

from __future__ import annotations

import argparse
import time

from balance_opt.app.pipeline import run_task
from balance_opt.tasks.task import load_task
from balance_opt.motion.options import RobustnessOptions
from balance_opt.motion.robustness import drift_under_model_error


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="examples/capture_task.yaml")
    parser.add_argument("--samples", type=int, default=50)
    parser.add_argument("--perturbations", type=float, nargs="*", default=[0.05, 0.1, 0.2])
    args = parser.parse_args(argv)
    task = load_task(args.task)
    start = time.perf_counter()
    run = run_task(task, simulate=True)
    compare = time.perf_counter() - start
    print(f"compare (no files): {compare:.2f} s")
    print(
        f"{'perturbation':>12s} {'method':>13s} {'nominal':>9s} {'median':>9s} {'p95':>9s} "
        f"{'largest':>9s} | {'final':>9s} {'median':>9s} {'p95':>9s} {'largest':>9s} "
        f"{'study':>7s} {'x compare':>9s}"
    )
    for size in args.perturbations:
        options = RobustnessOptions(samples=args.samples, perturbation=size)
        study = drift_under_model_error(task.robot, run.results, options, h0=task.h0)
        for name, spread in study.to_dict()["methods"].items():
            peak, final = spread["max_drift"], spread["final_drift"]
            print(
                f"{size:12.2f} {name:>13s} {spread['nominal_max_drift_rad']:9.5f} "
                f"{peak['median_rad']:9.5f} {peak['p95_rad']:9.5f} {peak['largest_rad']:9.5f} | "
                f"{spread['nominal_final_drift_rad']:9.5f} {final['median_rad']:9.5f} "
                f"{final['p95_rad']:9.5f} {final['largest_rad']:9.5f} "
                f"{study.wall_time_s:7.2f} {study.wall_time_s / compare:9.2f}"
            )


if __name__ == "__main__":
    main()
