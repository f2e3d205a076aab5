"""What a run writes: trajectories (CSV, NPZ), figures of merit (``metrics.json``) and the
versions of the software that computed them.

* ``<method>.csv``: a ``time`` column [s], one column per arm joint by name [rad; m for a
  prismatic joint] (mission joints first, then balance joints), the base attitude as a
  quaternion (``base_qx .. base_qw``) and as roll, pitch, yaw (``base_roll``, ``base_pitch``,
  ``base_yaw``) [rad], and the rotation angle from the start (``base_angle``) [rad]. A mission
  CSV task (``mission: {type: csv}``) reads it back.
* ``<method>.npz``: every array of the :class:`~balance_opt.result.BalanceResult` by its field
  name, the joint names, and ``info`` as JSON text.
* ``metrics.json``: see :func:`method_metrics` and :func:`run_metrics`.
"""

from __future__ import annotations

import csv
import ctypes
import glob
import importlib.metadata
import json
import logging
import math
import os
import platform
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.model.robot import FloatingRobot
from balance_opt.result import BalanceResult

log = logging.getLogger(__name__)

METRICS_FORMAT = 1
QUATERNION_COLUMNS = ("base_qx", "base_qy", "base_qz", "base_qw")
RPY_COLUMNS = ("base_roll", "base_pitch", "base_yaw")


# =========================================================================================== versions
@lru_cache(maxsize=1)
def ipopt_version() -> str:
    """Version of the Ipopt library bundled with CasADi (e.g. ``"3.14.19"``), or ``"unknown"``.

    Read from the library itself through Ipopt's C interface (``GetIpoptVersion``, Ipopt >= 3.14),
    loaded from CasADi's folder: the library CasADi's ``nlpsol("ipopt")`` plugin loads.
    """
    import casadi

    folder = os.path.dirname(casadi.__file__)
    patterns = ("libipopt.so*", "libipopt*.dylib", "libipopt*.dll", "ipopt*.dll")
    candidates = sorted(
        {p for pat in patterns for p in glob.glob(os.path.join(folder, pat))}, key=len
    )
    for path in candidates:
        try:
            lib = ctypes.CDLL(path)
            getter = lib.GetIpoptVersion
        except (OSError, AttributeError):
            continue
        major, minor, release = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        getter(ctypes.byref(major), ctypes.byref(minor), ctypes.byref(release))
        return f"{major.value}.{minor.value}.{release.value}"
    log.debug("no Ipopt library with GetIpoptVersion in %s", folder)
    return "unknown"


def _distribution_version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def software_versions() -> dict[str, str]:
    """Versions of balance-opt and of the libraries that computed the results."""
    import casadi
    import pinocchio

    from balance_opt import __version__

    return {
        "balance-opt": __version__,
        "pinocchio": pinocchio.__version__,
        "casadi": casadi.__version__,
        "ipopt": ipopt_version(),
        "numpy": np.__version__,
        "adam-robotics": _distribution_version("adam-robotics"),
        "python": platform.python_version(),
    }


# =========================================================================================== trajectories
def trajectory_columns(result: BalanceResult) -> tuple[list[str], np.ndarray]:
    """Column names and (T, k) values of the CSV of ``result`` (see the module docstring)."""
    names = [
        "time",
        *result.mission_joints,
        *result.balance_joints,
        *QUATERNION_COLUMNS,
        *RPY_COLUMNS,
        "base_angle",
    ]
    values = np.column_stack(
        [result.t, result.q_M, result.q_B, result.quaternion, result.rpy, result.angle]
    )
    return names, values


def write_trajectory_csv(path: str | Path, result: BalanceResult) -> Path:
    """Write the CSV of ``result`` (full double precision) and return its path."""
    path = Path(path)
    names, values = trajectory_columns(result)
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        writer.writerows([repr(float(x)) for x in row] for row in values)
    return path


def write_trajectory_npz(path: str | Path, result: BalanceResult) -> Path:
    """Write every array of ``result`` to a compressed ``.npz`` and return its path."""
    path = Path(path)
    np.savez_compressed(
        path,
        method=result.method,
        t=result.t,
        mission_joints=np.array(result.mission_joints),
        balance_joints=np.array(result.balance_joints),
        q_M=result.q_M,
        q_dot_M=result.q_dot_M,
        q_ddot_M=result.q_ddot_M,
        q_B=result.q_B,
        q_dot_B=result.q_dot_B,
        q_ddot_B=result.q_ddot_B,
        quaternion=result.quaternion,
        rpy=result.rpy,
        angle=result.angle,
        omega=result.omega,
        momentum_residual=result.momentum_residual,
        sigma_min=result.sigma_min,
        info=json.dumps(to_json(result.info)),
    )
    return path


# =========================================================================================== metrics
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


def limit_margins(result: BalanceResult, robot: FloatingRobot) -> dict[str, dict[str, float]]:
    """Smallest distance to each limit over the motion, per joint: ``{joint: {"position": m,
    "velocity": m, "acceleration": m}}`` [rad, rad/s, rad/s^2; m, m/s, m/s^2 for a prismatic
    joint]; negative where the limit is broken,
    ``inf`` (``null`` in JSON) where there is no limit."""
    names = (*result.mission_joints, *result.balance_joints)
    q = np.hstack([result.q_M, result.q_B])
    qd = np.hstack([result.q_dot_M, result.q_dot_B])
    qdd = np.hstack([result.q_ddot_M, result.q_ddot_B])
    lim = robot.limits
    out = {}
    for k, name in enumerate(names):
        i = robot.joint_index(name)
        out[name] = {
            "position": float(min(np.min(lim.upper[i] - q[:, k]), np.min(q[:, k] - lim.lower[i]))),
            "velocity": float(lim.velocity[i] - np.max(np.abs(qd[:, k]))),
            "acceleration": float(lim.acceleration[i] - np.max(np.abs(qdd[:, k]))),
        }
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


#: ``BalanceResult.info`` entries left out of ``metrics.json`` (kept in the NPZ): large arrays.
BULKY_INFO_KEYS = ("nlp_solution", "history")


def solver_metrics(info: Mapping[str, Any]) -> dict[str, Any]:
    """Status, iterations and wall times of the solver that produced a result, from its
    ``info`` (keys of :meth:`balance_opt.optimal.solve.BalanceNLP.solve`); ``None`` where the method
    has no such figure (the analytic law has no iterations)."""
    wall = info.get("wall_time_s")
    wall = wall if isinstance(wall, Mapping) else {}
    return {
        "status": info.get("status"),
        "success": info.get("success"),
        "iterations": info.get("iterations"),
        "objective": info.get("objective"),
        "max_constraint_violation": info.get("max_constraint_violation"),
        "solve_time_s": wall.get("solve"),
        "build_time_s": wall.get("build"),
        "wall_time_s": wall or None,
    }


def method_metrics(result: BalanceResult, robot: FloatingRobot, simulation=None) -> dict[str, Any]:
    """Figures of merit of one plan, plain JSON data.

    Keys: the result's :meth:`~BalanceResult.summary`; ``limit_margins`` (per joint, see
    :func:`limit_margins`), ``min_limit_margin`` and ``balance_limit_margin`` per kind;
    ``peak_joint_rates_rad_s`` per joint (m/s for a prismatic joint, whatever the key says); ``violations``; ``solver`` (:func:`solver_metrics`);
    ``details`` (the result's ``info`` without its bulky arrays); and, when a
    ``simulation`` of the plan is given, ``simulation`` with the drift it produced, the tracking
    error, the momentum residual and the peak reaction torques on the base [N m].
    """
    margins = limit_margins(result, robot)
    names = (*result.mission_joints, *result.balance_joints)
    rates = np.abs(np.hstack([result.q_dot_M, result.q_dot_B]))
    out = dict(result.summary())
    out["limit_margins"] = margins
    out["min_limit_margin"] = {
        kind: min(m[kind] for m in margins.values())
        for kind in ("position", "velocity", "acceleration")
    }
    out["balance_limit_margin"] = {
        kind: min(margins[j][kind] for j in result.balance_joints)
        for kind in ("position", "velocity", "acceleration")
    }
    out["peak_joint_rates_rad_s"] = {n: float(rates[:, k].max()) for k, n in enumerate(names)}
    out["violations"] = [str(v) for v in result.violations]
    out["solver"] = solver_metrics(result.info)
    out["details"] = {k: v for k, v in result.info.items() if k not in BULKY_INFO_KEYS}
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
    return to_json(out)


def run_metrics(
    task,
    results: Mapping[str, BalanceResult],
    simulations: Mapping[str, Any] | None = None,
    failures: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The content of ``metrics.json``: the task (file, name, SHA-256), the versions, and
    :func:`method_metrics` of each result by method name; ``failures`` lists methods whose solver
    failed (their best iterate is among ``results``)."""
    from balance_opt.io.capture_metrics import capture_metrics

    simulations = simulations or {}
    capture = capture_metrics(task, results, simulations)  # issue 16; None without a capture
    return to_json(
        {
            "format": METRICS_FORMAT,
            "task": {"file": task.source, "name": task.name, "sha256": task.sha256},
            "versions": software_versions(),
            "methods": {
                name: method_metrics(r, task.robot, simulations.get(name))
                for name, r in results.items()
            },
            "failures": dict(failures or {}),
            **({"capture": capture} if capture is not None else {}),
        }
    )


def write_metrics(path: str | Path, metrics: Mapping[str, Any]) -> Path:
    """Write ``metrics`` as indented JSON (strict: no NaN or Infinity) and return the path."""
    path = Path(path)
    path.write_text(json.dumps(to_json(metrics), indent=2, allow_nan=False) + "\n")
    return path


def read_npz_result(path: str | Path) -> BalanceResult:
    """Read back a result written by :func:`write_trajectory_npz` (violations are not kept)."""
    with np.load(path, allow_pickle=False) as z:
        return BalanceResult(
            method=str(z["method"]),
            t=z["t"],
            mission_joints=tuple(str(s) for s in z["mission_joints"]),
            balance_joints=tuple(str(s) for s in z["balance_joints"]),
            q_M=z["q_M"],
            q_dot_M=z["q_dot_M"],
            q_ddot_M=z["q_ddot_M"],
            q_B=z["q_B"],
            q_dot_B=z["q_dot_B"],
            q_ddot_B=z["q_ddot_B"],
            quaternion=z["quaternion"],
            omega=z["omega"],
            momentum_residual=z["momentum_residual"],
            sigma_min=z["sigma_min"],
            info=json.loads(str(z["info"])),
        )
