"""The closed loop's re-plans against their period (``docs/executable-plans.md``, "Closed loop"):
the capture task's optimal plan flown on perturbed true robots, re-planned every period from
the measured state, in this process, one model after the other.

Prints, per true model, the peak and final drift open loop (the plan flown unchanged) and closed
loop, the re-plans' Ipopt iterations and compute times; then the compute times of every re-plan
(median, 95th percentile, largest) against the period, and the time to build the re-plans' NLPs
before the motion (not a re-plan: a controller does it before it starts). Every re-plan is
applied whatever its time (``deadline = inf``), so that the drifts are those of a controller
that has the time; the count of re-plans over their period says how many a real one would drop.
The first plan is made before the motion and is not a re-plan.

Also printed: where a re-plan's time goes (Ipopt's calls of the compiled kernels against its
own work, mostly MUMPS's factorisations), the drift the open-loop flights have reached at the
first two re-plans (what the closed loop cannot undo) and the joint-limit violations by joint
and kind. ``--budget`` gives every re-plan Ipopt's ``max_wall_time`` of its period (as
``balance-opt compare`` does) and drops a late one: the motion then depends on the machine.
``--trace`` prints every re-plan: the true drift there, the peak and final drift it plans.

Run: ``python benchmarks/closed_loop.py [TASK] [--models K] [--period S] [--momentum zero|
measured] [--margin F] [--position-margin RAD] [--jerk J] [--floor measured|plan] [--budget]
[--terminal F] [--late W,L|none] [--trace] [--pick K,..] [--end-period S
[--end-window S]]`` (default: ``examples/capture_task.yaml``, 4 models, its ``closed_loop:`` period
and margins; ``--terminal``: the factor on the final drift's price in the closed loop's plans,
``control.replan.TERMINAL_FACTOR`` by default; ``--late``: their late drift's weight and window,
``control.replan.LATE_DRIFT`` by default).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np

from balance_opt.app.closed_loop import resolved_options, true_robots
from balance_opt.app.models import ModelCache
from balance_opt.control.flight import fly_closed_loop, period_starts
from balance_opt.control.replan import (
    LATE_DRIFT,
    TERMINAL_FACTOR,
    Replanner,
    closed_loop_planner,
    margined,
)
from balance_opt.dynamics.simulation import simulate_plan
from balance_opt.motion.result import find_limit_violations
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.tasks.task import load_task

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", nargs="?", default=str(ROOT / "examples" / "capture_task.yaml"))
    parser.add_argument("--models", type=int, default=4, help="true models flown")
    parser.add_argument("--period", type=float, help="control period [s]")
    parser.add_argument("--momentum", choices=("zero", "measured"), default="zero")
    parser.add_argument("--margin", type=float, help="closed-loop limit margin (fraction)")
    parser.add_argument("--position-margin", type=float, help="closed-loop position margin [rad]")
    parser.add_argument("--jerk", type=float, help="closed-loop jerk bound [rad/s^3]")
    parser.add_argument("--floor", choices=("measured", "plan"), default="measured")
    parser.add_argument(
        "--budget", action="store_true", help="stop Ipopt at the period, drop late re-plans"
    )
    parser.add_argument("--trace", action="store_true", help="every re-plan of every model")
    parser.add_argument("--pick", help="fly only these of the models (comma-separated indices)")
    parser.add_argument(
        "--end-period", type=float, help="period over the last seconds [s] (0: the period's)"
    )
    parser.add_argument("--end-window", type=float, help="those last seconds [s]")
    parser.add_argument(
        "--terminal", type=float, default=TERMINAL_FACTOR, help="factor on the final drift's price"
    )
    parser.add_argument(
        "--late",
        help="the late drift's WEIGHT,WINDOW (1/(rad^2 s), s; 'none': not priced)",
    )
    args = parser.parse_args()
    late = LATE_DRIFT if args.late is None else _late(args.late)

    task = load_task(args.task)
    options = resolved_options(task)
    options = dataclasses.replace(
        options,
        samples=args.models,
        period=args.period or options.period,
        momentum=args.momentum,
        peak_floor=args.floor,
        margin=options.margin if args.margin is None else args.margin,
        position_margin=(
            options.position_margin if args.position_margin is None else args.position_margin
        ),
        jerk=options.jerk if args.jerk is None else args.jerk,
        end_period=options.end_period if args.end_period is None else (args.end_period or None),
        end_window=options.end_window if args.end_window is None else args.end_window,
    )
    pick = None if args.pick is None else {int(k) for k in args.pick.split(",")}
    model = ModelCache().planner_model(task.robot, task.spec.robot.backend)
    planner = task.spec.optimal.planner
    started = time.perf_counter()
    nlp = build_balance_nlp(model, task.mission, task.q_B0, planner, robot=task.robot, h0=task.h0)
    plan = nlp.solve(task.spec.optimal.initial_guess)
    print(
        f"{task.name}: first plan (N = {nlp.N}) in {time.perf_counter() - started:.1f} s: "
        f"peak {plan.max_drift:.4g} rad, final {plan.final_drift:.4g} rad"
    )
    # the closed loop plans inside its margin, its first plan too (as balance-opt compare)
    robot = margined(task.robot, *options.margins)
    closed_plan, closed = plan, closed_loop_planner(planner, args.terminal, late)
    if robot is not task.robot or closed is not planner:
        nlp = build_balance_nlp(model, task.mission, task.q_B0, closed, robot=robot, h0=task.h0)
        closed_plan = nlp.solve(plan.solver.solution)
        print(
            f"closed-loop first plan, limits {options.margin:.0%} inside, final drift priced "
            f"{args.terminal:g} times, late drift {late}: peak "
            f"{closed_plan.max_drift:.4g} rad, final {closed_plan.final_drift:.4g} rad"
        )
    replanner = Replanner(nlp, budget=options.period if args.budget else None)
    end = f", every {options.end_period:g} s over the last {options.end_window:g} s"
    print(
        f"period {options.period:g} s{end if options.end_period else ''}, momentum at a "
        f"re-plan: {options.momentum}, peak floor: "
        f"{options.peak_floor}, "
        f"{options.perturbation:.0%} model error, seed {options.seed}"
    )
    header = (
        f"{'model':>5} {'open peak':>10} {'closed peak':>11} {'open final':>10} "
        f"{'closed final':>12} {'failed':>6} {'over':>4} {'limits open/closed':>18}  iterations"
    )
    print(header)
    times, prepare_s, violated = [], None, 0
    peaks, finals, early, kinds, outcomes = [], [], [], Counter(), []
    m = max(1, round(options.period / nlp.h))
    starts = period_starts(nlp.N, nlp.h, options)
    periods = {a: (b - a) * nlp.h for a, b in itertools.pairwise(starts)}  # a re-plan's own
    overs = 0
    first = True
    for k, truth in enumerate(true_robots(task.robot, options)):
        if pick is not None and k not in pick:
            continue
        open_loop = simulate_plan(truth, plan, task.spec.simulation)
        run = fly_closed_loop(
            truth,
            replanner,
            closed_plan,
            task.spec.simulation,
            options,
            prepared=not first,
            deadline=options.period if args.budget else math.inf,
        )
        prepare_s, first = (run.prepare_s if first else prepare_s), False
        times += run.compute_s.tolist()
        outcomes += run.replans
        peaks.append(run.max_drift)
        finals.append(run.final_drift)
        over = sum(r.compute_s > periods[r.node] for r in run.replans)
        overs += over
        found = [violations(task.robot, s) for s in (open_loop, run.simulation)]
        limits = [len(v) for v in found]
        violated += limits[1]
        kinds.update(f"{v.joint} {v.kind}" for v in found[1])
        early.append([_drift_at(open_loop, i * m * nlp.h) for i in (1, 2)])
        # a re-plan stopped by its budget: "+" its iterate applied, "-" late (dropped)
        iterations = " ".join(
            f"{r.iterations}{('+' if r.success else '-') if r.stopped else ''}" for r in run.replans
        )
        if args.trace:
            _trace(run, nlp.h)
        print(
            f"{k:>5} {float(open_loop.angle.max()):>10.4g} {run.max_drift:>11.4g} "
            f"{float(open_loop.angle[-1]):>10.4g} {run.final_drift:>12.4g} {run.failed:>6} "
            f"{over:>4} {limits[0]:>9}/{limits[1]:<8}  {iterations}"
        )
    t = np.array(times)
    print(
        f"closed loop over {args.models} models: peak median {np.median(peaks):.4g}, "
        f"95 % {np.percentile(peaks, 95):.4g} rad; final median {np.median(finals):.4g}, "
        f"95 % {np.percentile(finals, 95):.4g} rad"
    )
    print(
        f"re-plans: {t.size}, compute time median {np.median(t):.3f} s, 95 % "
        f"{np.percentile(t, 95):.3f} s, largest {t.max():.3f} s; {overs} "
        f"over their period; NLPs built before the motion in {prepare_s:.1f} s"
    )
    print(
        f"joint limit violations of the closed-loop runs (true limits): {violated}"
        + "".join(f"; {n} {k}" for k, n in sorted(kinds.items()))
    )
    solve, kernels = sum(r.solve_s for r in outcomes), sum(r.kernels_s for r in outcomes)
    its = np.array([r.iterations for r in outcomes])
    print(
        f"Ipopt: {its.sum()} iterations over the re-plans (median {np.median(its):.0f}, 95 % "
        f"{np.percentile(its, 95):.0f}, largest {its.max()}), {1e3 * solve / max(its.sum(), 1):.1f} ms each; the kernels' "
        f"evaluations {kernels / max(solve, 1e-12):.0%} of Ipopt's time, its own work the rest; "
        f"set-up and plan {t.sum() - solve:.2f} s in all"
    )
    early = np.array(early)
    nominal = [
        _drift_at(simulate_plan(task.robot, plan, task.spec.simulation), i * m * nlp.h)
        for i in (1, 2)
    ]
    for i, label in enumerate(("first", "second")):
        print(
            f"drift at the {label} re-plan ({(i + 1) * m * nlp.h:g} s): nominal plan "
            f"{nominal[i]:.4g} rad; open-loop flights median {np.median(early[:, i]):.4g}, "
            f"95 % {np.percentile(early[:, i], 95):.4g}, largest {early[:, i].max():.4g} rad"
        )


def _trace(run, h: float) -> None:
    """Per re-plan: its time, the true drift measured there, the peak floor it was given, the
    peak and final drift it plans, its Ipopt iterations and its last iterate's violation."""
    sim = run.simulation
    for r in run.replans:
        t = r.node * h
        planned = "-"
        if r.segment is not None:
            drift = np.linalg.norm(r.segment.solution.X[:3], axis=0)
            planned = f"peak {drift.max():.4g} final {drift[-1]:.4g}"
        print(
            f"    t {t:5.2f} s: drift {_drift_at(sim, t):.4g} rad, plans {planned}; "
            f"{r.iterations} its, {r.status}, violation {r.violation:.1e}, {r.compute_s:.3f} s"
        )


def _late(text: str):
    """``--late``: ``WEIGHT,WINDOW`` or ``none``."""
    return None if text == "none" else tuple(float(v) for v in text.split(","))


def violations(robot, sim) -> list:
    """The stretches of a simulated motion outside the robot's (true) joint limits."""
    return find_limit_violations(
        sim.t, robot.joint_names, sim.q, sim.q_dot, sim.q_ddot, robot.limits
    )


def _drift_at(sim, t: float) -> float:
    """A simulation's drift at the time ``t`` [s] (its nearest sample)."""
    return float(sim.angle[int(np.argmin(np.abs(sim.t - t)))])


if __name__ == "__main__":
    main()
