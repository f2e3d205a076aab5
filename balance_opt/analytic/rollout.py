"""Phase II: the analytic law's balance trajectory along a mission motion, as a
:class:`~balance_opt.motion.result.BalanceResult`: attitude and balance joints integrated together on
SO(3), then the per-sample outputs evaluated in one batched pass (:meth:`BalanceLaw.along`)."""

from __future__ import annotations

import logging

import numpy as np

from balance_opt.analytic.law import BalanceLaw
from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.errors import InputError, SolverError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.integration import integrate, output_grid
from balance_opt.motion.momentum_check import momentum_residual
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import IDENTITY_QUATERNION, quaternion_rate
from balance_opt.motion.trajectories import TrajectoryLike, as_sampler

log = logging.getLogger(__name__)


def rollout(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    q_B0,
    options: BalanceLawOptions | None = None,
    *,
    integration: IntegrationOptions | None = None,
    t_eval=None,
) -> BalanceResult:
    """Phase II: the balance trajectory of the analytic law (Eq. 31, 32) along a mission motion.

    Args:
        mission: the mission arm's motion (see :func:`~balance_opt.motion.trajectories.as_sampler`).
        q_B0: initial balance joint positions [rad].
        options: the law's settings (``h0``, damping, null space, feedback).
        t_eval: output times [s] (default: every ``integration.output_step`` over the mission).

    Raises:
        SolverError: the integration failed (the law blew up); ``result`` holds the motion up to
            the last output time reached.
    """
    integration = integration or IntegrationOptions()
    options = options or BalanceLawOptions()
    M, B = robot.mission_indices, robot.balance_indices
    sample_M, duration = as_sampler(mission, M.size, "mission")
    q_B0 = np.asarray(q_B0, dtype=float).ravel()
    if q_B0.size != B.size:
        raise InputError(
            f"initial balance configuration has {q_B0.size} values, the balance joints are {B.size}"
        )
    law = BalanceLaw(robot, options, q_B0=q_B0)
    t = output_grid(t_eval, duration, integration)
    q_buf = np.empty(robot.n)

    def rhs(ti, y):
        qM, qdM, _ = sample_M(np.array([ti]))
        q_buf[M] = qM[0]
        q_buf[B] = y[4:]
        s = law.rates(q_buf, qdM[0], y[:4] / np.linalg.norm(y[:4]))
        return np.concatenate((quaternion_rate(y[:4], s.omega), s.q_dot_B))

    Y, stats, failure = integrate(rhs, np.r_[IDENTITY_QUATERNION, q_B0], t, integration)
    result = _result(law, sample_M, t[: Y.shape[0]], Y, stats)
    if failure is not None:
        reason = (
            f"; smallest singular value of J_wB down to {float(result.sigma_min.min()):.3g}, "
            f"balance joint rates up to {float(np.abs(result.q_dot_B).max()):.3g} rad/s: "
            "the law's rates run away (raise analytic.damping_threshold or max_damping)"
            if result.t.size > 1
            else ""
        )
        raise SolverError(
            f"analytic balance law rollout failed: {failure}{reason}", "integration_failed", result
        )
    log.debug("rollout: %d samples, %s", result.t.size, stats)
    return result


def _result(law: BalanceLaw, sample_M, t, Y, stats) -> BalanceResult:
    """The law's outputs at the integrated states ``Y`` = [quaternion, q_B] (T, 4 + n_B)."""
    robot = law.robot
    M, B = robot.mission_indices, robot.balance_indices
    qM, qdM, qddM = sample_M(t)
    q = np.empty((t.size, robot.n))
    q[:, M], q[:, B] = qM, Y[:, 4:]
    quat = Y[:, :4]
    path = law.along(q, qdM, qddM, quat)
    q_dot, q_ddot = np.empty_like(q), np.empty_like(q)
    q_dot[:, M], q_dot[:, B] = qdM, path.q_dot_B
    q_ddot[:, M], q_ddot[:, B] = qddM, path.q_ddot_B
    residual = np.linalg.norm(path.residual, axis=1)
    info = {
        "law": law.options.as_dict(),
        "null_space_goal": law.goal.tolist(),
        "damping_max": float(path.damping.max()),
        "damping_active_fraction": float(np.mean(path.damping > 0)),
        "condition_max": float(path.condition.max()),
        "residual_omega_max": float(residual.max()),
        "residual_omega_rms": float(np.sqrt(np.mean(residual**2))),
        "integration": stats,
    }
    return BalanceResult.from_arm_vectors(
        robot,
        "analytic",
        t,
        q,
        q_dot,
        q_ddot,
        quat,
        path.omega,
        momentum_residual(law.maps, t, q, q_dot, quat, law.angular_momentum),
        path.sigma_min,
        info,
    )
