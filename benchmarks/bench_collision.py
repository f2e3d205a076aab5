"""Collision avoidance in the optimal planner (issue 24): every example task that plans, with
``optimal.collision.avoid`` on and off, side by side.

For each plan: the peak and final drift of the re-simulated motion, the smallest exact distance
between the robot's checked bodies (coal, every pair the robot's geometry checks:
docs/collision.md, "Which pairs are checked") on a 1 ms grid of the motion (joint positions
interpolated linearly between the re-simulation's samples) and the pair that comes closest, the certified lower bound
of :func:`~balance_opt.geometry.clearance.clearance` on the continuous motion, Ipopt's
iterations and time (every solve behind the plan) per iteration, split into the calls of the
cost and its gradient, of the constraints and their derivatives (``g``, Jacobian, Hessian of the
Lagrangian), and Ipopt's own work (its linear algebra mostly), and the wall time of planning (building the
NLP included: each setting has its own structure), the fastest of ``--repeat`` plans (default
2: the first of each setting also builds the planner model and may run its kernels on CasADi's
VM while they compile), with its ratio to the fastest plan without avoidance. Run:
``python benchmarks/bench_collision.py [--repeat 2] [examples/capture_task.yaml ...]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from balance_opt.app.models import ModelCache
from balance_opt.app.pipeline import plan
from balance_opt.errors import SolverError
from balance_opt.geometry.clearance import clearance
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.tasks.task import load_task

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def with_avoidance(task, avoid: bool):
    planner = dataclasses.replace(task.spec.optimal.planner, collision_avoidance=avoid)
    optimal = dataclasses.replace(task.spec.optimal, planner=planner)
    return dataclasses.replace(task, spec=dataclasses.replace(task.spec, optimal=optimal))


def grid_clearance(geometry: RobotGeometry, t, q, step: float = 1e-3):
    """The smallest exact distance on a grid of ``step`` [s], and its pair."""
    grid = np.arange(t[0], t[-1] + 0.5 * step, step)
    qg = np.stack([np.interp(grid, t, q[:, j]) for j in range(q.shape[1])], axis=1)
    best, pair = np.inf, None
    gm, gd = geometry.geometry_model, geometry.geometry_data
    names = [p.name for p in geometry.pairs]
    for qk in qg:
        pin.computeDistances(geometry.model, geometry.data, gm, gd, geometry.robot.pin_q(qk))
        d = [r.min_distance for r in gd.distanceResults]
        k = int(np.argmin(d))
        if d[k] < best:
            best, pair = d[k], names[k]
    return best, pair


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", help="task files (default: every example that plans)")
    parser.add_argument(
        "--repeat", type=int, default=2, help="plans per setting; the fastest time is printed"
    )
    args = parser.parse_args(argv)
    paths = args.tasks or sorted(
        p for p in EXAMPLES.glob("*.yaml") if not p.name.startswith("sweep")
    )
    header = (
        f"{'task':<26} {'avoid':<5} {'status':<24} {'peak rad':>9} {'final rad':>10} "
        f"{'clear 1ms m':>11} {'bound m':>8} {'closest pair':<34} {'iters':>6} {'ipopt s':>8} "
        f"{'ms/it: cost':>11} {'rows':>5} {'own':>5} {'plan s':>7} {'ratio':>6}"
    )
    print(header)
    print("-" * len(header))
    for path in paths:
        task = load_task(path)
        geometry = RobotGeometry(task.robot)
        models = ModelCache()
        runs: dict[bool, list] = {False: [], True: []}
        for _ in range(args.repeat):  # alternating, so that both see the same machine
            for avoid in (False, True):
                start = time.perf_counter()
                try:
                    result = plan(with_avoidance(task, avoid), "optimal", models=models)
                    status = "ok"
                except SolverError as exc:
                    result, status = exc.result, f"failed: {exc.status}"
                runs[avoid].append((time.perf_counter() - start, result, status))
        base = min(r[0] for r in runs[False])
        for avoid in (False, True):
            wall, result, status = min(runs[avoid], key=lambda r: r[0])
            if result is None:
                print(f"{task.name:<26} {str(avoid):<5} {status}")
                continue
            q = np.hstack([result.q_M, result.q_B])
            best, pair = grid_clearance(geometry, result.t, q)
            bound = clearance(geometry, result.t, q).closest.lower_bound
            report = result.solver
            iters = report.iterations if report is not None else 0
            ipopt_s = report.solve_s if report is not None else float("nan")
            calls = report.evaluations_s if report is not None else {}
            cost = calls.get("f", 0.0) + calls.get("grad_f", 0.0)
            rows = sum(calls.get(k, 0.0) for k in ("g", "jac_g", "hess_l"))
            per = 1e3 / max(iters, 1)
            print(
                f"{task.name:<26} {str(avoid):<5} {status[:24]:<24} {result.max_drift:9.4f} "
                f"{result.final_drift:10.2e} {best:11.4f} {bound:8.4f} {pair:<34} {iters:6d} "
                f"{ipopt_s:8.2f} {cost * per:11.2f} {rows * per:5.2f} "
                f"{(ipopt_s - cost - rows) * per:5.2f} {wall:7.2f} {wall / base:6.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
