"""A readable summary of a floating robot: arms, joints, limits, mimic and locked joints, and
the coupling measures at a configuration."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot

#: Units of a joint's position, speed, acceleration and effort by its position unit.
_UNITS = {"rad": "[rad, rad/s, rad/s^2, N m]", "m": "[m, m/s, m/s^2, N]"}


def _fmt_limit(x: float) -> str:
    return "inf" if np.isinf(x) else f"{x:.4g}"


def end_effector_poses(robot: FloatingRobot, q) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each arm's end-effector position [m] and roll, pitch, yaw [rad] at the arm vector ``q``,
    the base at its initial pose (the frame a Cartesian goal is given in), by arm name."""
    model = robot.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, robot.pin_q(np.asarray(q, dtype=float)))
    out = {}
    for arm in robot.arms:
        pose = data.oMf[model.getFrameId(arm.ee_frame)]
        out[arm.name] = (pose.translation.copy(), pin.rpy.matrixToRpy(pose.rotation))
    return out


def vector_text(v) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


def robot_summary(robot: FloatingRobot, q=None) -> str:
    """Text summary of ``robot`` with coupling measures at ``q`` (default: ``robot.neutral()``)."""
    q = robot.neutral() if q is None else np.asarray(q, dtype=float)
    lim = robot.limits
    lines = [
        f"robot {robot.name}  ({robot.source})",
        f"  total mass {robot.total_mass:.4g} kg, {robot.n} arm joints, {len(robot.locked)} locked joints",
    ]
    poses = end_effector_poses(robot, q)
    for arm in robot.arms:
        lines.append(f"  {arm.name} arm: {arm.dof} joints, end effector '{arm.ee_frame}'")
        position, rpy = poses[arm.name]
        lines.append(
            f"    end effector at {vector_text(position)} m, roll-pitch-yaw {vector_text(rpy)} rad "
            "(initial base frame)"
        )
        lines.append(
            f"    {'joint':<22} {'lower':>9} {'upper':>9} {'vel':>8} {'acc':>8} {'effort':>8}  units"
        )
        for i in arm.indices:
            lines.append(
                f"    {robot.joint_names[i]:<22} {_fmt_limit(lim.lower[i]):>9} {_fmt_limit(lim.upper[i]):>9} "
                f"{_fmt_limit(lim.velocity[i]):>8} {_fmt_limit(lim.acceleration[i]):>8} {_fmt_limit(lim.effort[i]):>8}"
                f"  {_UNITS[robot.joint_units[i]]}"
            )
    if robot.followers:
        follows = ", ".join(
            f"{j} = {m.multiplier:.4g} {m.driver} + {m.offset:.4g}"
            for j, m in robot.followers.items()
        )
        lines.append(f"  mimic joints moving with their driver: {follows}")
    if robot.locked:
        locked = ", ".join(
            f"{j}={v:.4g}" + (f" (mimics {robot.mimics[j].driver})" if j in robot.mimics else "")
            for j, v in robot.locked.items()
        )
        lines.append(f"  locked: {locked}")
    m = NumericMaps(robot).coupling_measures(q)
    lines.append(f"  coupling at q = [{', '.join(f'{v:.3g}' for v in q)}]:")
    lines.append(f"    |J_wM| = {m.mission_norm:.4g} (base rad/s per mission rad/s)")
    lines.append(
        f"    J_wB singular values = [{', '.join(f'{s:.4g}' for s in m.balance_singular_values)}], "
        f"condition number = {m.balance_condition:.4g}"
    )
    if len(m.per_arm) > 1:
        for name, (s, cond) in m.per_arm.items():
            lines.append(
                f"    {name}: singular values [{', '.join(f'{v:.4g}' for v in s)}], condition {cond:.4g}"
            )
    return "\n".join(lines)
