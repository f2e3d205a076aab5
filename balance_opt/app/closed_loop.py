"""The closed-loop study of a run (``--closed-loop``; ``docs/executable-plans.md``, "Closed
loop"): every plan flown on ``closed_loop.samples`` perturbed true robots in forward dynamics, the
optimal plan re-planned every period from the measured state (:mod:`balance_opt.control.flight`),
the analytic law evaluated at the measured state. The true robots are those of the model-error
study (same perturbation and seed unless the task says otherwise), so open and closed
loop are compared on the same truths.

The Monte Carlo runs on the executor the caller passes (the sweep engine's process pool or Dask:
anything with ``map``), in as many chunks as it has workers: each chunk builds the planner model
and the re-plans' NLPs once and flies its models one after the other.
"""

from __future__ import annotations

import dataclasses
import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.dynamics.options import ClosedLoopOptions
from balance_opt.errors import DivergenceError
from balance_opt.motion.result import find_limit_violations
from balance_opt.motion.robustness import PERCENTILE, perturbed_robot

#: Files of the worst closed-loop run (the largest peak drift over every method's runs).
WORST_CSV, WORST_URDF = "closed_loop_worst.csv", "closed_loop_worst.urdf"


def resolved_options(task) -> ClosedLoopOptions:
    """The task's closed-loop options, the perturbation and seed taken from ``robustness:``
    where unset."""
    cl, rb = task.spec.closed_loop, task.spec.robustness
    return dataclasses.replace(
        cl,
        perturbation=rb.perturbation if cl.perturbation is None else cl.perturbation,
        seed=rb.seed if cl.seed is None else cl.seed,
    )


def true_robots(robot, options: ClosedLoopOptions) -> list:
    """The perturbed true robots, drawn as the model-error study draws them."""
    rng = np.random.default_rng(options.seed)
    return [perturbed_robot(robot, options.perturbation, rng) for _ in range(options.samples)]


@dataclass
class ClosedLoopChunk:
    """Some of the closed-loop runs of one method, callable with the true models' indices
    (picklable: it runs in a sweep worker). ``solution``: the optimal plan's NLP solution
    (``None`` for the analytic law, whose plan ``balance`` is tracked)."""

    method: str
    robot: Any
    mission: Any
    q_B0: np.ndarray
    h0: np.ndarray
    planner: Any
    backend: str
    simulation: Any
    options: ClosedLoopOptions
    solution: Any = None
    balance: Any = None
    geometry: tuple | None = None  # (srdf, ignore) of the clearance check, None: no geometry

    def __call__(self, indices: list[int]) -> list[dict]:
        from balance_opt.control.replan import Replanner, closed_loop_planner, margined
        from balance_opt.optimal.model import PlannerModel
        from balance_opt.optimal.solve import build_balance_nlp

        truths = true_robots(self.robot, self.options)
        geometry = self._geometry()
        replanner, prepare_s, first = None, 0.0, self.solution
        if self.solution is not None:
            model = PlannerModel(self.robot, backend=self.backend)
            # the closed loop plans inside its margin: its first plan too (from the open-loop
            # plan), so that a re-plan's start, the plan in force's, is inside it
            robot = margined(self.robot, *self.options.margins)
            planner = closed_loop_planner(self.planner)  # the final drift priced higher
            nlp = build_balance_nlp(
                model, self.mission, self.q_B0, planner, robot=robot, h0=self.h0
            )
            if robot is not self.robot or planner is not self.planner:
                first = nlp.solve(self.solution).solver.solution
            # a re-plan that has used its period stops there (late): the plan in force stays
            replanner = Replanner(nlp, budget=self.options.period)
        out = []
        for k in indices:
            try:
                out.append(self._fly(k, truths[k], replanner, first, k != indices[0], geometry))
            except DivergenceError as error:  # counted and named, not averaged in
                out.append({"index": k, "diverged": str(error)})
            prepare_s += out[-1].pop("prepare_s", 0.0)
        if out:
            out[0]["prepare_s"] = prepare_s
        return out

    def _fly(self, k: int, truth, replanner, first, prepared: bool, geometry) -> dict:
        """The summary of the flight on the true model ``k``."""
        from balance_opt.control.flight import fly_closed_loop
        from balance_opt.dynamics.simulation import simulate

        prepare_s = 0.0
        if replanner is not None:
            run = fly_closed_loop(
                truth, replanner, first, self.simulation, self.options, prepared=prepared
            )
            sim, prepare_s = run.simulation, run.prepare_s
            replans = {"compute_s": run.compute_s.tolist(), "failed": run.failed, "late": run.late}
        else:  # the law's rates depend on the joints alone: it commands what it planned
            sim = simulate(truth, self.mission, self.balance, self.simulation, model=self.robot)
            replans = {"compute_s": [], "failed": 0, "late": 0}
        return dict(self._summary(k, sim, replans, geometry), prepare_s=prepare_s)

    def _geometry(self):
        if self.geometry is None:
            return None
        from balance_opt.geometry.robot_geometry import RobotGeometry

        srdf, ignore = self.geometry
        return RobotGeometry(self.robot, srdf=srdf, ignore=ignore)

    def _summary(self, k: int, sim, replans: dict, geometry) -> dict:
        from balance_opt.motion.so3 import rotation_angle

        angle = rotation_angle(sim.quaternion)
        robot = self.robot
        violations = find_limit_violations(
            sim.t, robot.joint_names, sim.q, sim.q_dot, sim.q_ddot, robot.limits
        )
        clearance = math.inf
        if geometry is not None:
            from balance_opt.geometry.clearance import clearance as clearance_of

            clearance = float(clearance_of(geometry, sim.t, sim.q).min_distance)
        return {
            "index": k,
            "t": sim.t,
            "angle": angle,
            "max_drift": float(angle.max()),
            "final_drift": float(angle[-1]),
            "min_clearance": clearance,
            "limit_violations": [str(v) for v in violations],
            "motion": (sim.t, sim.q, sim.q_dot, sim.q_ddot, sim.quaternion, sim.omega),
            **replans,
        }


@dataclass
class ClosedLoopStudy:
    """The closed-loop study of a run: per method its runs' summaries (by true model), the 95th
    percentile band of the attitude error over time, and the wall time [s]."""

    options: ClosedLoopOptions
    runs: dict[str, list[dict]]
    wall_time_s: float
    bands: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def flown(self, method: str) -> list[dict]:
        """The runs of ``method`` that flew (not stopped as diverged)."""
        return [r for r in self.runs[method] if "diverged" not in r]

    def metrics(self, method: str) -> dict:
        """``methods.<method>.closed_loop`` of ``metrics.json``: the spreads over the runs that
        flew; ``diverged`` names the true models whose simulation was stopped."""
        runs = self.flown(method)
        diverged = {str(r["index"]): r["diverged"] for r in self.runs[method] if "diverged" in r}
        if not runs:
            return {"samples": 0, "period_s": self.options.period, "diverged": diverged}
        peak = np.array([r["max_drift"] for r in runs])
        final = np.array([r["final_drift"] for r in runs])
        times = np.concatenate([np.asarray(r["compute_s"], dtype=float) for r in runs])

        def spread(values):
            return {
                "median_rad": float(np.median(values)),
                "p95_rad": float(np.percentile(values, PERCENTILE)),
                "largest_rad": float(np.max(values)),
            }

        return {
            "samples": len(runs),
            "period_s": self.options.period,
            "max_drift": spread(peak),
            "final_drift": spread(final),
            "replan_time_s": {
                "median": float(np.median(times)) if times.size else 0.0,
                "p95": float(np.percentile(times, PERCENTILE)) if times.size else 0.0,
                "max": float(times.max()) if times.size else 0.0,
            },
            "replans": int(times.size),
            "failed_replans": int(sum(r["failed"] + r["late"] for r in runs)),
            "min_clearance_m": float(min(r["min_clearance"] for r in runs)),
            "limit_violations": int(sum(len(r["limit_violations"]) for r in runs)),
            "diverged": diverged,
        }

    def worst(self) -> tuple[str, dict]:
        """``(method, run)`` of the largest peak drift of every run."""
        return max(
            ((m, r) for m in self.runs for r in self.flown(m)),
            key=lambda mr: mr[1]["max_drift"],
        )


def closed_loop_study(task, plans: dict, executor=None, geometry=None) -> ClosedLoopStudy:
    """Fly each of ``plans`` (``"optimal"``: re-planned; ``"analytic"``) closed loop on the
    task's true robots; ``executor``: anything with ``map`` (``None``: this process);
    ``geometry``: ``(srdf, ignore)`` of the clearance check, ``None`` for no check."""
    started = time.perf_counter()
    options = resolved_options(task)
    workers = max(1, int(getattr(executor, "workers", 1) or 1))
    chunks = [list(range(i, options.samples, workers)) for i in range(workers)]
    chunks = [c for c in chunks if c]
    runs = {}
    for method, plan in plans.items():
        chunk = ClosedLoopChunk(
            method,
            task.robot,
            task.mission,
            task.q_B0,
            task.h0,
            task.spec.optimal.planner,
            task.spec.robot.backend,
            task.spec.simulation,
            options,
            solution=plan.solver.solution if method == "optimal" else None,
            balance=None if method == "optimal" else plan,
            geometry=geometry,
        )
        run = map if executor is None else executor.map
        found = [r for part in run(chunk, chunks) for r in part]
        runs[method] = sorted(found, key=lambda r: r["index"])
    study = ClosedLoopStudy(options, runs, time.perf_counter() - started)
    for method in runs:
        if flown := study.flown(method):
            angles = np.array([r["angle"] for r in flown])
            study.bands[method] = (flown[0]["t"], np.percentile(angles, PERCENTILE, axis=0))
    return study


def write_worst(study: ClosedLoopStudy, task, output_dir: Path) -> list[Path]:
    """The worst run's motion (``closed_loop_worst.csv``, the columns of every trajectory CSV)
    and its true robot (``closed_loop_worst.urdf``)."""
    from balance_opt.model.maps import NumericMaps
    from balance_opt.motion.result import BalanceResult
    from balance_opt.report.outputs import write_trajectory_csv

    if not any(study.flown(m) for m in study.runs):
        return []
    method, run = study.worst()
    truth = true_robots(task.robot, study.options)[run["index"]]
    t, q, q_dot, q_ddot, quaternion, omega = run["motion"]
    maps = NumericMaps(truth)
    result = BalanceResult.from_arm_vectors(
        truth,
        f"{method} closed loop",
        t,
        q,
        q_dot,
        q_ddot,
        quaternion,
        omega,
        np.zeros(t.size),
        maps.balance_sigma_min(*maps.angular_maps(q)),
        {"true_model": run["index"]},
    )
    csv = write_trajectory_csv(output_dir / WORST_CSV, result)
    urdf = output_dir / WORST_URDF
    urdf.write_text(perturbed_urdf(task.robot, truth), encoding="utf-8")
    return [csv, urdf]


def perturbed_urdf(robot, truth) -> str:
    """``robot``'s URDF (its locked joints written in) with the inertial elements of ``truth``:
    each Pinocchio joint's body on its child link; links fixed to it, whose mass Pinocchio merged
    into it, left massless."""
    import pinocchio as pin

    root = ET.fromstring(robot.locked_urdf)
    links = {link.get("name"): link for link in root.iter("link")}
    child = {j.get("name"): j.find("child").get("link") for j in root.iter("joint")}
    base = next(name for name in links if name not in child.values())
    model = truth.model
    for i in range(1, model.njoints):
        body = base if i == 1 else child.get(model.names[i])
        if body not in links:
            continue
        for f in model.frames:  # links fixed to this joint's body: their mass is in its own
            fixed = f.type == pin.FrameType.BODY and int(f.parentJoint) == i
            if fixed and f.name in links and f.name != body:
                _set_inertial(links[f.name], None)
        _set_inertial(links[body], model.inertias[i])
    return ET.tostring(root, encoding="unicode")


def _set_inertial(link, inertia) -> None:
    for old in link.findall("inertial"):
        link.remove(old)
    if inertia is None:
        return
    inertial = ET.SubElement(link, "inertial")
    c = np.asarray(inertia.lever, dtype=float)
    ET.SubElement(inertial, "origin", xyz=" ".join(f"{v:.17g}" for v in c), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{float(inertia.mass):.17g}")
    I = np.asarray(inertia.inertia, dtype=float)
    entries = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2)}
    entries["izz"] = (2, 2)
    ET.SubElement(inertial, "inertia", **{k: f"{I[ij]:.17g}" for k, ij in entries.items()})
