"""Quality of the optimal plan on the capture task (issue 11): the peak and final drift
of each objective at 10 s (as shipped) and 20 s (``mission.duration: 20``), against the
reference values of the issue, with their solve times.

Objectives: ``peak`` (the default: rest at both ends) and ``integral`` with the old ends
(``start: still``, ``end: free``: the old default plan). Drifts are those of the re-simulated
plan (numeric Pinocchio). The NLPs are built before the clock starts; "solve" is the wall time
of :meth:`BalanceNLP.solve` (every Ipopt solve, the re-simulations and the refinement), "ipopt"
Ipopt's own time of the last solve.

Run: ``python benchmarks/bench_quality.py [--intervals 100]``.
"""

from __future__ import annotations

import argparse
import time

from balance_opt.app.scenarios import capture_task
from balance_opt.motion.trajectories import PointToPoint
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp

#: Issue 11's reference [rad]: (mission arm alone, old default, best found with limits met).
REFERENCE = {10.0: (0.0929, 0.0306, 0.0207), 20.0: (0.0929, 0.0136, 0.0064)}
OBJECTIVES = {
    "peak": {},
    "integral (old ends)": {"objective": "integral", "start": "still", "end": "free"},
}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", type=int, default=100)
    parser.add_argument("--durations", type=float, nargs="+", default=[10.0, 20.0])
    args = parser.parse_args(argv)
    capture = capture_task()
    model = PlannerModel(capture.robot)
    for extra in OBJECTIVES.values():  # build every structure before timing
        options = PlannerOptions(intervals=args.intervals, **extra)
        nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
        nlp.variant(objective="integral")
    rows = []
    for duration in args.durations:
        m = capture.mission
        mission = PointToPoint(m.q0, m.qf, duration) if duration != m.duration else m
        for name, extra in OBJECTIVES.items():
            options = PlannerOptions(intervals=args.intervals, **extra)
            nlp = build_balance_nlp(model, mission, capture.q_B0, options)
            start = time.perf_counter()
            plan = nlp.solve()
            wall = time.perf_counter() - start
            rows.append((duration, name, plan, wall))
    print(
        "| task | objective | peak [rad] | final [rad] | reference alone / old / best "
        "| solve [s] | ipopt [s] | iterations |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for duration, name, plan, wall in rows:
        ref = " / ".join(f"{v:.4f}" for v in REFERENCE.get(duration, ()))
        info = plan.info
        print(
            f"| {duration:g} s | {name} | {plan.max_drift:.4f} | {plan.final_drift:.5f} | {ref} "
            f"| {wall:.1f} | {info['wall_time_s']['solve']:.1f} | {info['iterations']} |"
        )


if __name__ == "__main__":
    main()
