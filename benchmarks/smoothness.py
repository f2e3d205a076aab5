"""Smoothness of the optimal plan on the capture task (issue 25): what the jerk regulariser and
jerk limits cost the peak drift, and what they buy.

For each setting the optimal plan (peak objective, N = 100) is solved and its re-simulated
motion measured: peak and final drift, acceleration reversals per balance joint (hysteresis of a
tenth of the acceleration limit, :mod:`balance_opt.motion.smoothness`), the largest jerk and the
largest torque rate of the balance joints (free-floating inverse dynamics of the plan), the Ipopt
iterations and the solve time (NLPs built inside the clock the first time a structure is met).

Settings: ``weights.jerk`` 0 (no regulariser: the old default), the default and others given
with ``--jerk-weights``; control ``jerk`` with ``smoothness`` 0.1 and no jerk regulariser (the
other way to smooth, for reference); the default regulariser with a jerk limit on every balance
joint (``--jerk-limits``, rad/s^3).

Run: ``python benchmarks/smoothness.py [--jerk-weights 0 1 10] [--jerk-limits 20 5]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from balance_opt.app.pipeline import run_task
from balance_opt.app.scenarios import CAPTURE_BALANCE_ACCELERATION, capture_task
from balance_opt.dynamics.inverse_dynamics import plan_joint_torques
from balance_opt.model.library import paper_robot
from balance_opt.motion.smoothness import smoothness
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import JERK_DEFAULT, CostWeights, PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.tasks.task import load_task

BALANCE = ("balance_joint1", "balance_joint2", "balance_joint3")
TASK = "examples/capture_task.yaml"


def _robot(jerk: float | None):
    limits = {j: {"acceleration": CAPTURE_BALANCE_ACCELERATION} for j in BALANCE}
    if jerk is not None:
        for j in BALANCE:
            limits[j]["jerk"] = jerk
    return paper_robot(limits=limits)


def _row(label: str, robot, capture, options: PlannerOptions, guess) -> str:
    start = time.perf_counter()
    model = PlannerModel(robot)
    plan = build_balance_nlp(model, capture.mission, capture.q_B0, options, robot).solve(guess)
    elapsed = time.perf_counter() - start
    tau = plan_joint_torques(plan, robot)[:, len(plan.mission_joints) :]
    limits = robot.limits.acceleration[robot.balance_indices]
    s = smoothness(plan.t, plan.q_ddot_B, plan.balance_joints, limits, tau)
    iterations = plan.solver.iterations if plan.solver is not None else "?"
    return (
        f"{label:32s} {plan.max_drift:8.5f} {plan.final_drift:9.6f} "
        f"{'/'.join(str(int(r)) for r in s.reversals):>10s} {s.max_jerk.max():8.1f} "
        f"{s.max_torque_rate.max():9.1f} {iterations!s:>6s} {elapsed:7.1f}"
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jerk-weights", type=float, nargs="*", default=[0.0, JERK_DEFAULT])
    parser.add_argument("--jerk-limits", type=float, nargs="*", default=[20.0])
    parser.add_argument("--control-jerk", action="store_true", help="add the jerk-control row")
    parser.add_argument(
        "--guess",
        choices=("analytic", "compare"),
        default="compare",
        help="start from the analytic law clipped to the limits, or from the analytic plan "
        "as compare does (the same law, rolled out on its own grid)",
    )
    args = parser.parse_args(argv)
    capture = capture_task()
    guess = "analytic"
    if args.guess == "compare":
        guess = run_task(load_task(TASK), methods=["analytic"]).results["analytic"]
    print(
        f"{'setting':32s} {'peak':>8s} {'final':>9s} {'reversals':>10s} {'jerk':>8s} "
        f"{'tau rate':>9s} {'iter':>6s} {'time':>7s}"
    )
    print(f"{'':32s} {'[rad]':>8s} {'[rad]':>9s} {'(b1/b2/b3)':>10s} {'[r/s^3]':>8s} "
          f"{'[N m/s]':>9s} {'':>6s} {'[s]':>7s}")
    robot = _robot(None)
    for w in args.jerk_weights:
        options = PlannerOptions(weights=CostWeights(jerk=w))
        print(_row(f"weights.jerk {w:g}", robot, capture, options, guess), flush=True)
    if args.control_jerk:
        options = PlannerOptions(
            control="jerk", weights=CostWeights(jerk=0.0, smoothness=0.1)
        )
        print(_row("control jerk, smoothness 0.1", robot, capture, options, guess), flush=True)
    for limit in args.jerk_limits:
        print(
            _row(f"default + jerk limit {limit:g}", _robot(limit), capture, PlannerOptions(), guess),
            flush=True,
        )


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    main()
