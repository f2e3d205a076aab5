"""What limits a free mission timing with collision avoidance (issue 37): the capture task at
``mission.timing: free``, planned under several settings, one row each.

For each plan: the peak and final drift of the re-simulated motion; the smallest exact distance
between any checked pair (coal) on a 2 ms grid of the motion (joint positions interpolated
linearly between the re-simulation's samples) and its pair; the binding pairs, those that come
within the margin plus 2 cm, each with its smallest exact distance and, at that instant, the
distance of the planner's fitted shapes (which the planner holds to the margin plus 2 mm; the
capsules contain the links, so the difference is what the shapes cost); Ipopt's iterations
over every solve, the status of the last solve and the wall time (inflated on a loaded
machine; the first plan of a setting also compiles its kernels).

The settings: collision avoidance off (the jerk term off: the issue's independent formulation;
and on); the defaults from either initial guess and with ``optimal.starts: 3`` and 6; a margin
of 1 cm, the least the issue asks, with and without the jerk term (and with 6 starts); a
continuation (homotopy) from the plan without avoidance: the collision rows' bounds raised in
``--steps`` equal steps from that plan's row values (less 5 mm) to the problem's own, each solve warm started from the
last (a failed step hands its last iterate on), then the planner's refinement; and the defaults
with the base's pairs or the balance arm's own pair left out (``optimal.collision.ignore``),
which says which bodies cost how much. Run:
``python benchmarks/bench_timing_collision.py [--only N ...] [--steps 6] [task.yaml]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import casadi as cs
import numpy as np
import pinocchio as pin

from balance_opt.app.models import ModelCache
from balance_opt.app.pipeline import plan
from balance_opt.errors import SolverError
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.geometry.shapes import fit_shapes, shape_distance
from balance_opt.optimal.collision import row_values
from balance_opt.optimal.refine import refine
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.tasks.task import load_task

TASK = Path(__file__).resolve().parent.parent / "examples" / "capture_task.yaml"
BASE_PAIRS = (("base_link", "balance_link2"), ("base_link", "balance_link3"))
ARM_PAIR = (("balance_link1", "balance_link3"),)

#: (label, planner option changes, initial guess, continued from the plan without avoidance
#: with this jerk weight (None: planned as the planner does))
SETTINGS = (
    ("avoidance off, jerk 0", {"collision_avoidance": False, "jerk": 0.0}, "analytic", None),
    ("avoidance off", {"collision_avoidance": False}, "analytic", None),
    ("defaults", {}, "analytic", None),
    ("defaults, rest guess", {}, "rest", None),
    ("defaults, 3 starts", {"starts": 3}, "analytic", None),
    ("defaults, 6 starts", {"starts": 6}, "analytic", None),
    ("margin 0.01", {"collision_margin": 0.01}, "analytic", None),
    ("margin 0.01, jerk 0", {"collision_margin": 0.01, "jerk": 0.0}, "analytic", None),
    ("continued from jerk 0", {}, "analytic", 0.0),
    ("continued from jerk 1", {}, "analytic", 1.0),
    ("margin 0.01, jerk 0, continued", {"collision_margin": 0.01, "jerk": 0.0}, "analytic", 0.0),
    ("base pairs ignored", {"collision_ignore": BASE_PAIRS}, "analytic", None),
    ("arm's own pair ignored", {"collision_ignore": ARM_PAIR}, "analytic", None),
    (
        "margin 0.01, jerk 0, 6 starts",
        {"collision_margin": 0.01, "jerk": 0.0, "starts": 6},
        "analytic",
        None,
    ),
)
#: A row the plan without avoidance breaks starts bounded this far below its value there [m].
SLACK = 5e-3


def variant(task, changes: dict, guess: str):
    """The task at a free timing with the planner's ``changes`` (``jerk``: the weight)."""
    changes = dict(changes)
    planner = task.spec.optimal.planner
    if "jerk" in changes:
        changes["weights"] = dataclasses.replace(planner.weights, jerk=changes.pop("jerk"))
    planner = dataclasses.replace(planner, timing="free", **changes)
    optimal = dataclasses.replace(task.spec.optimal, planner=planner, initial_guess=guess)
    mission = dataclasses.replace(task.spec.mission, timing="free")
    spec = dataclasses.replace(task.spec, optimal=optimal, mission=mission)
    return dataclasses.replace(task, spec=spec)


def distances(geometry: RobotGeometry, t, q, step: float = 2e-3):
    """The grid's times and every checked pair's exact distance on it (n_t, n_pairs)."""
    grid = np.arange(t[0], t[-1] + 0.5 * step, step)
    qg = np.stack([np.interp(grid, t, q[:, j]) for j in range(q.shape[1])], axis=1)
    gm, gd = geometry.geometry_model, geometry.geometry_data
    out = []
    for qk in qg:
        pin.computeDistances(geometry.model, geometry.data, gm, gd, geometry.robot.pin_q(qk))
        out.append([r.min_distance for r in gd.distanceResults])
    return grid, qg, np.array(out)


def fitted_distance(geometry: RobotGeometry, shapes, pair, q) -> float:
    """The distance of the fitted shapes of a pair's objects at the arm configuration ``q``."""
    pin.forwardKinematics(geometry.model, geometry.data, geometry.robot.pin_q(q))
    frames = {j: (cs.DM(M.rotation), cs.DM(M.translation)) for j, M in enumerate(geometry.data.oMi)}
    of = {i: s for s in shapes for i in s.objects}
    return float(shape_distance(of[pair.first], of[pair.second], frames))


def continued(case, jerk: float, steps: int, models: ModelCache):
    """The plan of ``case`` continued from its plan without avoidance (at ``jerk``): the
    collision rows' bounds raised in ``steps`` equal steps from that plan's row values (less
    :data:`SLACK`, where below the bound) to the problem's own, then refined."""
    model = models.planner_model(case.robot, case.spec.robot.backend)
    options = case.planner_options(None)

    def nlp_of(opts):
        return build_balance_nlp(model, case.mission, case.q_B0, opts, case.robot, case.h0)

    weights = dataclasses.replace(options.weights, jerk=jerk)
    free = nlp_of(dataclasses.replace(options, collision_avoidance=False, weights=weights))
    result = free.solve(case.spec.optimal.initial_guess)
    nlp = nlp_of(options)
    target = np.array(nlp.bounds.collision)
    low = np.minimum(target, row_values(nlp, result) - SLACK)
    low[:, 0] = target[:, 0]  # the arm starts at rest where it is
    low = np.where(np.isfinite(target), low, target)  # a watched row stays unbounded
    gap = np.where(np.isfinite(target), target - low, 0.0)
    for k in range(1, steps + 1):
        step = nlp if k == steps else nlp.with_bounds(collision=low + k / steps * gap)
        try:
            result = step.solve_once(result.solver.solution, result.solver)
        except SolverError as exc:  # its last iterate is the next start
            result = exc.result
    return refine(nlp, result)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", nargs="?", default=str(TASK), help="task file (capture task)")
    parser.add_argument("--only", type=int, nargs="*", help="rows to plan (0-based)")
    parser.add_argument("--steps", type=int, default=6, help="steps of the continuation")
    args = parser.parse_args(argv)
    task = load_task(args.task)
    geometry = RobotGeometry(task.robot)
    shapes = fit_shapes(geometry)
    models = ModelCache()
    header = (
        f"{'setting':<30} {'margin':>6} {'jerk':>4} {'starts':>6} {'guess':<8} {'from':>4} "
        f"{'peak rad':>9} {'final rad':>9} {'clear m':>8} {'closest pair':<30} {'iters':>6} "
        f"{'wall s':>7} {'last Ipopt status':<26} binding pairs: exact / fitted m"
    )
    print(header)
    print("-" * len(header))
    for row, (label, changes, guess, jerk) in enumerate(SETTINGS):
        if args.only and row not in args.only:
            continue
        case = variant(task, changes, guess)
        options = case.spec.optimal.planner
        start = time.perf_counter()
        try:
            if jerk is None:
                result, status = plan(case, "optimal", models=models), ""
            else:
                result, status = continued(case, jerk, args.steps, models), ""
        except SolverError as exc:
            result, status = exc.result, f" (failed: {exc.status})"
        wall = time.perf_counter() - start
        lead = (
            f"{label:<30} {options.collision_margin:6.2f} {options.weights.jerk:4.1f} "
            f"{options.starts:6d} {guess:<8} {'-' if jerk is None else f'{jerk:.0f}':>4} "
        )
        if result is None:
            print(f"{lead}{status}", flush=True)
            continue
        q = np.hstack([result.q_M, result.q_B])
        grid, qg, d = distances(geometry, result.t, q)
        k = np.unravel_index(np.argmin(d), d.shape)
        binding = []
        for i, pair in enumerate(geometry.pairs):
            j = int(np.argmin(d[:, i]))
            if d[j, i] < options.collision_margin + 0.02:
                fitted = fitted_distance(geometry, shapes, pair, qg[j])
                binding.append(f"{pair.name} {d[j, i]:.4f} / {fitted:.4f} (t {grid[j]:.2f})")
        iterations = result.solver.iterations if result.solver is not None else 0
        last = result.solver.solves[-1].status if result.solver is not None else "-"
        print(
            f"{lead}{result.max_drift:9.4f} {result.final_drift:9.4f} {d[k]:8.4f} "
            f"{geometry.pairs[k[1]].name:<30} {iterations:6d} {wall:7.0f} {last:<26} "
            f"{'; '.join(binding) or '-'}{status}",
            flush=True,
        )


if __name__ == "__main__":
    main()
