"""Free-floating inverse dynamics of a joint motion: the arm-joint torques [N m; N for prismatic
joints] that make the joints follow it while nothing acts on the base.

In the reduced coordinates ``[v_b; q_dot]`` (``v = G [v_b; q_dot]``, ``G`` the robot's
``velocity_map``), ``M_r [a_b; q_ddot] + h_r = [0; tau]``: the base rows fix ``a_b``, the joint
rows give ``tau``, from one RNEA and one CRBA. The base twist follows from momentum conservation,
``M_r,bb v_b + M_r,bj q_dot = h`` (the momentum ``h0`` moved to the base origin, base frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import matrix_from_quaternion


@dataclass(frozen=True)
class InverseDynamics:
    """Torques ``tau`` (T, n) of the ``joints``, base twist and spatial acceleration (T, 6) in
    the base frame [m/s, rad/s; m/s^2, rad/s^2]."""

    joints: tuple[str, ...]
    tau: np.ndarray
    base_twist: np.ndarray
    base_acceleration: np.ndarray


def symmetric(M: np.ndarray) -> np.ndarray:
    """The whole matrices (..., nv, nv) from the upper triangles CRBA fills."""
    upper = np.triu(M)
    return upper + np.swapaxes(np.triu(upper, 1), -1, -2)


def free_floating_torques(
    robot: FloatingRobot, q, q_dot, q_ddot, quaternion=None, h0=None
) -> InverseDynamics:
    """Free-floating inverse dynamics of a motion of every arm joint: ``q``, ``q_dot``,
    ``q_ddot`` (T, n) in arm order; ``quaternion`` (T, 4) matters only for a non-zero ``h0``
    (world frame [N s; N m s], zero by default)."""
    q, q_dot, q_ddot = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, q_dot, q_ddot))
    T = q.shape[0]
    h0 = np.zeros(6) if h0 is None else np.asarray(h0, dtype=float)
    model, data = robot.model, robot.model.createData()
    maps = NumericMaps(robot)  # Pinocchio vectors of the whole motion at once
    qps, vs, accs = maps.configurations(q), maps.velocities(q_dot), maps.velocities(q_ddot)
    M = np.empty((T, model.nv, model.nv))
    com = np.empty((T, 3))
    for k in range(T):  # Pinocchio per sample, the algebra on whole arrays below
        M[k] = pin.crba(model, data, qps[k])
        com[k] = data.Ycrb[1].lever  # CoM in the base frame
    M = robot.arm_columns(np.swapaxes(robot.arm_columns(symmetric(M)), 1, 2))  # G^T M G
    M_bb = M[:, :6, :6]
    # the momentum at the base origin, base axes: M_r,b: [v_b; q_dot] = h
    h = np.zeros((T, 6))
    if np.any(h0):
        R = np.eye(3) if quaternion is None else matrix_from_quaternion(quaternion)
        p = np.broadcast_to(h0[:3] @ R, (T, 3))  # R^T h0 per sample
        L = np.broadcast_to(h0[3:] @ R, (T, 3))
        h = np.concatenate([p, L + np.cross(com, p)], axis=-1)
    twist = np.linalg.solve(M_bb, (h - np.matvec(M[:, :6, 6:], q_dot))[..., None])[..., 0]
    vs[:, :6] = twist
    f = np.empty((T, model.nv))
    for k in range(T):
        f[k] = pin.rnea(model, data, qps[k], vs[k], accs[k])
    f = robot.arm_columns(f)  # G^T f
    acc = -np.linalg.solve(M_bb, f[:, :6, None])[..., 0]
    tau = f[:, 6:] + np.matvec(M[:, 6:, :6], acc)
    return InverseDynamics(tuple(robot.joint_names), tau, twist, acc)


def plan_joint_torques(result: BalanceResult, robot: FloatingRobot, h0=None) -> np.ndarray:
    """Joint torques (T, n) of a plan's joint motion (other arm joints held at neutral), in the
    plan's mission then balance order, for the momentum ``h0`` (world frame; zero by default)."""
    names = (*result.mission_joints, *result.balance_joints)
    columns = [robot.joint_index(j) for j in names]
    T = result.t.size
    q = np.tile(robot.neutral(), (T, 1))
    q_dot, q_ddot = np.zeros((T, robot.n)), np.zeros((T, robot.n))
    q[:, columns] = np.hstack([result.q_M, result.q_B])
    q_dot[:, columns] = np.hstack([result.q_dot_M, result.q_dot_B])
    q_ddot[:, columns] = np.hstack([result.q_ddot_M, result.q_ddot_B])
    return free_floating_torques(robot, q, q_dot, q_ddot, result.quaternion, h0).tau[:, columns]
