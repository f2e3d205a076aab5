"""What a run writes: trajectories (CSV, NPZ), figures of merit (``metrics.json``) and the
versions of the software that computed them (formats: ``docs/outputs.md``)."""

from __future__ import annotations

import csv
import importlib.metadata
import json
import math
import platform
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.dynamics.inverse_dynamics import plan_joint_torques
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BULKY_INFO_KEYS, EFFORT_TOLERANCE, BalanceResult, limit_bounds
from balance_opt.motion.so3 import relative_rotation, rotation_angle
from balance_opt.solvers.ipopt_options import ipopt_version

#: The arrays of a :class:`~balance_opt.motion.result.BalanceResult` sampled on its time grid.
SAMPLED_ARRAYS = tuple(f.name for f in fields(BalanceResult) if f.type == "np.ndarray")
#: Version of the metrics.json layout; 2: ``effort`` margins added, and ``violations`` /
#: ``limit_violations`` count effort limits too; 3: ``solver.iterations`` and
#: ``solver.solve_time_s`` count every Ipopt solve behind the plan (were the last solve's).
METRICS_FORMAT = 3


def _distribution_version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def software_versions() -> dict[str, str]:
    import casadi
    import pinocchio

    return {
        "balance-opt": _distribution_version("balance-opt"),
        "pinocchio": pinocchio.__version__,
        "casadi": casadi.__version__,
        "ipopt": ipopt_version(),
        "numpy": np.__version__,
        "adam-robotics": _distribution_version("adam-robotics"),
        "python": platform.python_version(),
    }


def write_trajectory_csv(path: str | Path, result: BalanceResult) -> Path:
    """Write the CSV of ``result`` in full double precision."""
    path = Path(path)
    names, values = result.columns()
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        writer.writerows([repr(float(x)) for x in row] for row in values)
    return path


def write_trajectory_npz(
    path: str | Path, result: BalanceResult, joint_torque: np.ndarray | None = None
) -> Path:
    """Write every array of ``result`` to a compressed ``.npz``, with the plan's
    ``joint_torque`` (:func:`~balance_opt.dynamics.inverse_dynamics.plan_joint_torques`) when
    given."""
    path = Path(path)
    extra = {} if joint_torque is None else {"joint_torque": joint_torque}
    np.savez_compressed(
        path,
        **extra,
        method=result.method,
        mission_joints=np.array(result.mission_joints),
        balance_joints=np.array(result.balance_joints),
        **{name: getattr(result, name) for name in (*SAMPLED_ARRAYS, "rpy", "angle")},
        info=json.dumps(to_json(result.details())),
    )
    return path


def to_json(value: Any) -> Any:
    """Plain JSON data from numbers, arrays, tuples and dicts; non-finite floats become None."""
    if isinstance(value, Mapping):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_json(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


#: The kinds of joint limits, in the order of ``metrics.json``.
LIMIT_KINDS = ("position", "velocity", "acceleration")


def limit_margins(result: BalanceResult, robot: FloatingRobot) -> dict[str, dict[str, float]]:
    """Smallest distance to each limit over the motion, per joint: ``{joint: {"position": m,
    "velocity": m, "acceleration": m}}`` [rad, rad/s, rad/s^2; m, m/s, m/s^2 for a prismatic
    joint]; negative where the limit is broken, ``inf`` (``null`` in JSON) where there is no
    limit; a rate step (:func:`~balance_opt.motion.result.rate_steps`) counts as its acceleration
    over one sample."""
    series = {
        "position": np.hstack([result.q_M, result.q_B]),
        "velocity": np.hstack([result.q_dot_M, result.q_dot_B]),
        "acceleration": np.hstack([result.q_ddot_M, result.q_ddot_B]),
    }
    out = {}
    for k, name in enumerate((*result.mission_joints, *result.balance_joints)):
        out[name] = {}
        for kind, x in series.items():
            lo, hi = (b[robot.joint_index(name)] for b in limit_bounds(robot.limits, kind))
            out[name][kind] = float(min(np.min(hi - x[:, k]), np.min(x[:, k] - lo)))
    for v in result.violations:  # a rate step's acceleration is not in the samples
        if v.step is not None:
            out[v.joint][v.kind] = min(out[v.joint][v.kind], -v.worst_excess)
    return out


def _effort_violations(t, names, tau, limits) -> list[str]:
    """Stretches of samples where ``|tau|`` exceeds an effort limit by more than
    :data:`EFFORT_TOLERANCE` of it, worded as :class:`~balance_opt.motion.result.LimitViolation`."""
    found = []
    for j, name in enumerate(names):
        limit = limits[j]
        if not _has_limit(limit):
            continue
        excess = np.abs(tau[:, j]) - limit
        outside = excess > EFFORT_TOLERANCE * limit
        edges = np.diff(np.r_[0, outside.astype(int), 0])
        for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            found.append(
                f"{name}: effort limit exceeded by up to {excess[start:stop].max():.4g} N m "
                f"({excess[start:stop].max() / limit:.3%} of {limit:g} N m) "
                f"from t = {t[start]:.3f} s to {t[stop - 1]:.3f} s"
            )
    return found


def _has_limit(limit: float) -> bool:
    """An effort limit that limits: finite and positive (a URDF without one gives inf)."""
    return bool(np.isfinite(limit) and limit > 0)


def effort_metrics(
    result: BalanceResult, robot: FloatingRobot, h0=None, torques: np.ndarray | None = None
) -> dict[str, Any]:
    """The ``effort`` block of ``docs/outputs.md`` [N m; N for a prismatic joint] from the
    plan's joint ``torques``, else from its free-floating inverse dynamics for the momentum
    ``h0``."""
    names = (*result.mission_joints, *result.balance_joints)
    tau = plan_joint_torques(result, robot, h0) if torques is None else torques
    limits = np.array([robot.limits.effort[robot.joint_index(j)] for j in names])
    joints = {}
    for k, name in enumerate(names):
        i = int(np.argmax(np.abs(tau[:, k])))
        peak, limit = float(abs(tau[i, k])), float(limits[k])
        entry = {"peak_Nm": peak, "peak_time_s": float(result.t[i])}
        if _has_limit(limit):
            margin = limit - peak
            status = "broken" if margin < -EFFORT_TOLERANCE * limit else "inside"
            entry |= {"limit_Nm": limit, "margin_Nm": margin, "relative_margin": margin / limit}
        else:
            status = "no limit"
            entry |= {"limit_Nm": None, "margin_Nm": None, "relative_margin": None}
        joints[name] = {**entry, "status": status}

    def smallest(subset):
        values = [joints[j]["relative_margin"] for j in subset]
        return min((v for v in values if v is not None), default=None)

    return {
        "joints": joints,
        "min_relative_margin": smallest(names),
        "balance_min_relative_margin": smallest(result.balance_joints),
        "violations": _effort_violations(result.t, names, tau, limits),
    }


def relative_limit_margins(
    margins: Mapping[str, Mapping[str, float]], robot: FloatingRobot, joints
) -> dict[str, float]:
    """The smallest margin of :func:`limit_margins` over ``joints``, per kind, relative to the
    size of its limit (the position range, the rate limit): 0 on the limit, 1 at rest for a
    rate; ``inf`` where none of them has that limit."""
    out = {}
    for kind in LIMIT_KINDS:
        values = []
        for j in joints:
            lo, hi = (b[robot.joint_index(j)] for b in limit_bounds(robot.limits, kind))
            if math.isfinite(margins[j][kind]):
                values.append(margins[j][kind] / (hi - lo if kind == "position" else hi))
        out[kind] = min(values, default=math.inf)
    return out


def peak_reaction_torques(simulation) -> dict[str, float]:
    """Largest norm of the torque each arm exerts on the base, and of their sum [N m], from a
    :class:`~balance_opt.dynamics.simulation.SimulationResult` (paper Fig. 4)."""
    out = {
        arm: float(np.linalg.norm(w[:, 3:], axis=1).max())
        for arm, w in simulation.arm_wrenches.items()
    }
    out["total"] = float(np.linalg.norm(simulation.total_wrench[:, 3:], axis=1).max())
    return out


def solver_metrics(info: Mapping[str, Any]) -> dict[str, Any]:
    """The ``solver`` block of ``docs/outputs.md`` from a result's details
    (:meth:`~balance_opt.motion.result.BalanceResult.details`); ``None`` where the
    method has no such figure (the analytic law has no iterations)."""
    wall = info.get("wall_time_s")
    wall = wall if isinstance(wall, Mapping) else {}
    return {
        "status": info.get("status"),
        "success": info.get("success"),
        "iterations": info.get("total_iterations", info.get("iterations")),
        "objective": info.get("objective"),
        "max_constraint_violation": info.get("max_constraint_violation"),
        "solve_time_s": info.get("total_solve_time_s", wall.get("solve")),
        "build_time_s": wall.get("build"),
        "wall_time_s": wall or None,
    }


def _smoothness_metrics(result: BalanceResult, robot: FloatingRobot, torques) -> dict:
    from balance_opt.motion.smoothness import smoothness

    cols = [robot.joint_names.index(j) for j in result.balance_joints]
    tau = None
    if torques is not None:  # columns: mission joints, then balance joints
        tau = np.asarray(torques)[:, len(result.mission_joints) :]
    figures = smoothness(
        result.t, result.q_ddot_B, result.balance_joints, robot.limits.acceleration[cols], tau
    )
    return figures.to_dict()


def method_metrics(
    result: BalanceResult,
    robot: FloatingRobot,
    simulation=None,
    h0=None,
    torques: np.ndarray | None = None,
    clearance=None,
    simulated_clearance=None,
) -> dict[str, Any]:
    """Figures of merit of one plan, plain JSON data (keys: ``docs/outputs.md``); ``h0`` is the
    system's momentum (world frame, zero by default) for the effort figures, unless the plan's
    ``torques`` are given."""
    margins = limit_margins(result, robot)
    names = (*result.mission_joints, *result.balance_joints)
    rates = np.abs(np.hstack([result.q_dot_M, result.q_dot_B]))
    out = dict(result.summary())
    out["limit_margins"] = margins
    out["min_limit_margin"] = {k: min(m[k] for m in margins.values()) for k in LIMIT_KINDS}
    out["balance_limit_margin"] = {
        k: min(margins[j][k] for j in result.balance_joints) for k in LIMIT_KINDS
    }
    out["balance_relative_limit_margin"] = relative_limit_margins(
        margins, robot, result.balance_joints
    )
    out["peak_joint_rates_rad_s"] = {n: float(rates[:, k].max()) for k, n in enumerate(names)}
    out["effort"] = effort_metrics(result, robot, h0, torques)
    out["violations"] = [str(v) for v in result.violations] + out["effort"]["violations"]
    collisions = []
    if clearance is not None:
        out["clearance"] = clearance.to_dict()
        collisions = _collision_violations(clearance)
        out["violations"] += collisions
    out["limit_violations"] = len(out["violations"])
    out["smoothness"] = _smoothness_metrics(result, robot, torques)
    kinds = [v.kind for v in result.violations]
    out["limit_violations_by_kind"] = {
        **{kind: kinds.count(kind) for kind in LIMIT_KINDS},
        "effort": len(out["effort"]["violations"]),
        "collision": len(collisions),
    }
    out["warnings"] = result.warnings()
    details = result.details()
    out["solver"] = solver_metrics(details)
    # the mission's timing: given, or free (the duration, the path progress, the mission's rates)
    out["timing"] = details.get("timing", {"timing": "given"})
    out["details"] = {k: v for k, v in details.items() if k not in BULKY_INFO_KEYS}
    if simulation is not None:
        sim = simulation.as_balance_result("simulation")
        out["simulation"] = {
            "max_drift_rad": sim.max_drift,
            "final_drift_rad": sim.final_drift,
            "max_tracking_error_rad": simulation.max_tracking_error,
            "max_relative_momentum_residual": float(simulation.momentum_residual.max()),
            "peak_reaction_torque_Nm": peak_reaction_torques(simulation),
            "peak_joint_torque_Nm": {
                n: float(np.abs(simulation.tau[:, k]).max())
                for k, n in enumerate(simulation.joint_names)
            },
            "wall_time_s": simulation.info.get("wall_time_s"),
        }
        if simulated_clearance is not None:
            out["simulation"]["clearance"] = simulated_clearance.to_dict()
    return to_json(out)


def _collision_violations(clearance) -> list[str]:
    """The first penetration (or touch) of a motion as a violation."""
    pen = clearance.first_penetration
    if pen is None and clearance.collision_free:
        return []
    if pen is None:  # touching, not penetrating
        closest = clearance.closest
        return [f"{closest.pair}: collision (touching) at t = {closest.time:.3f} s"]
    return [f"{pen.pair}: collision from t = {pen.time:.3f} s, {pen.depth:.4g} m deep"]


def capture_drifts(motion, t_c: float) -> tuple[int, np.ndarray]:
    """The index ``k`` of the last sample of ``motion`` at or before the capture time ``t_c``
    and the drift [rad] from the attitude at the capture at samples ``k`` on."""
    k = int(np.flatnonzero(np.asarray(motion.t) <= t_c + 1e-12)[-1])
    quaternion = np.asarray(motion.quaternion)
    return k, rotation_angle(relative_rotation(quaternion[k : k + 1], quaternion[k:]))


def _capture_block(info: Mapping[str, Any], motion, t_c: float) -> dict[str, Any]:
    """Attitude drift before the capture (from the start) and after it (from the attitude at
    the capture) [rad], and the capture's jumps and impulses."""
    (k, after), from_start = capture_drifts(motion, t_c), motion.angle
    jump = info["omega_jump"]
    vectors = (
        "ee_impulse",
        "base_impulse_coupling",
        "base_momentum_jump",
        "momentum_before",
        "momentum_after",
    )
    return {
        "drift_at_capture_rad": float(from_start[k]),
        "max_drift_before_rad": float(from_start[: k + 1].max()),
        "max_drift_after_rad": float(after.max()),
        "final_drift_since_capture_rad": float(after[-1]),
        "max_drift_rad": float(from_start.max()),
        "omega_jump_rad_s": list(jump),
        "omega_jump_norm_rad_s": float(np.linalg.norm(jump)),
        **{key: list(info[key]) for key in vectors},
    }


def capture_metrics(task, results: Mapping[str, Any], simulations=None) -> dict[str, Any] | None:
    """The ``capture`` block of ``metrics.json``; ``None`` for a task without a capture."""
    target = getattr(task, "target", None)
    if target is None:
        return None
    t_c = float(target.time)
    out: dict[str, Any] = {
        "time_s": t_c,
        "target": {
            "mass_kg": float(target.mass),
            "inertia_kg_m2": np.asarray(target.inertia).tolist(),
            "com_m": np.asarray(target.com).tolist(),
            "linear_velocity_m_s": np.asarray(target.linear_velocity).tolist(),
            "angular_velocity_rad_s": np.asarray(target.angular_velocity).tolist(),
        },
        "methods": {},
        "simulated": {},
    }
    for block, motions in (("methods", results), ("simulated", simulations or {})):
        for name, r in motions.items():
            info = r.info.get("capture")
            if info is not None:
                out[block][name] = _capture_block(info, r, t_c)
    return out


def run_metrics(
    task,
    results: Mapping[str, BalanceResult],
    simulations: Mapping[str, Any] | None = None,
    failures: Mapping[str, str] | None = None,
    torques: Mapping[str, np.ndarray] | None = None,
    robustness=None,
    clearances: Mapping[str, Any] | None = None,
    simulated_clearances: Mapping[str, Any] | None = None,
    geometry: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The content of ``metrics.json`` (``docs/outputs.md``): the task, the versions and
    :func:`method_metrics` of each result, with what the caller has of each method (simulation,
    joint torques, clearance reports), by method name. ``failures``: methods whose solver
    failed (their best iterate is among ``results``); ``robustness``: the plans' drift under
    model error; ``geometry``: what the clearance check holds apart
    (:meth:`~balance_opt.geometry.robot_geometry.RobotGeometry.summary`)."""
    simulations, torques = simulations or {}, torques or {}
    capture = capture_metrics(task, results, simulations)  # None without a capture
    methods = {
        name: method_metrics(
            r,
            task.robot,
            simulations.get(name),
            task.h0,
            torques.get(name),
            (clearances or {}).get(name),
            (simulated_clearances or {}).get(name),
        )
        for name, r in results.items()
    }
    study = None
    if robustness is not None:
        study = robustness.to_dict()
        for name, spread in study.pop("methods").items():
            methods[name]["robustness"] = spread
    return to_json(
        {
            "format": METRICS_FORMAT,
            "task": {
                "file": task.source,
                "name": task.name,
                "sha256": task.sha256,
                **({"cartesian_goal_rad": goal} if (goal := task.cartesian_goal) else {}),
            },
            "versions": software_versions(),
            "methods": methods,
            "failures": dict(failures or {}),
            **({"capture": capture} if capture is not None else {}),
            **({"robustness": study} if study is not None else {}),
            **({"geometry": dict(geometry)} if geometry is not None else {}),
        }
    )


def write_metrics(path: str | Path, metrics: Mapping[str, Any]) -> Path:
    """Write ``metrics`` as strict JSON (no NaN or Infinity)."""
    path = Path(path)
    path.write_text(json.dumps(to_json(metrics), indent=2, allow_nan=False) + "\n")
    return path


def read_npz_result(path: str | Path) -> BalanceResult:
    """A result written by :func:`write_trajectory_npz` (violations are not kept)."""
    with np.load(path, allow_pickle=False) as z:
        return BalanceResult(
            method=str(z["method"]),
            mission_joints=tuple(str(s) for s in z["mission_joints"]),
            balance_joints=tuple(str(s) for s in z["balance_joints"]),
            **{name: z[name] for name in SAMPLED_ARRAYS},
            info=json.loads(str(z["info"])),
        )
