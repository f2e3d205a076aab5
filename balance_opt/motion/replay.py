"""Replays: the base attitude that GIVEN joint motions of both arms produce, from momentum
conservation alone (no balance law), as a :class:`~balance_opt.result.BalanceResult`.

Used to re-simulate a plan on a fine grid, for the paper's phases and figures
(:mod:`balance_opt.analytic.phases`) and by the optimal planner. The base angular velocity is
:func:`balance_opt.model.maps.base_angular_velocity` at every instant (Eq. 26 with the initial
momentum ``h0``), integrated on SO(3) (:mod:`balance_opt.motion.integration`).
"""

from __future__ import annotations

import numpy as np

from balance_opt.errors import InputError, SolverError
from balance_opt.model.maps import NumericMaps, base_angular_velocity
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.integration import initial_quaternion, integrate, output_grid
from balance_opt.motion.momentum_check import momentum_residual
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.so3 import matrix_from_quaternion, quaternion_rate
from balance_opt.motion.trajectories import TrajectoryLike, as_sampler
from balance_opt.result import BalanceResult


def angular_momentum_of(h0) -> np.ndarray:
    """The angular part, world axes (3,) [N m s], of an initial momentum given as 3 angular or 6
    ``[linear; angular]`` values (``None`` for zero).

    Raises:
        InputError: not 3 or 6 finite values.
    """
    if h0 is None:
        return np.zeros(3)
    h0 = np.asarray(h0, dtype=float).ravel()
    if h0.size not in (3, 6) or not np.all(np.isfinite(h0)):
        raise InputError(
            f"initial momentum h0 must be 3 or 6 finite values, got {h0.size}: {h0.tolist()}"
        )
    return h0[-3:].copy()


def replay(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    balance: TrajectoryLike,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
    quaternion0=None,
    method: str = "simulation",
) -> BalanceResult:
    """Integrate the base attitude for GIVEN joint motions of both arms (momentum conservation).

    The base angular velocity is ``omega = I_G^{-1} (R^T L - A q_dot)`` at every instant (Eq. 26
    with the initial momentum ``h0``), integrated on SO(3) to the integrator's tolerance. Use it
    to re-simulate a plan on a fine grid, or to get the paper's Fig. 3 and 5.

    Args:
        robot: the floating robot.
        mission: mission arm motion: a trajectory with ``sample(t)``, a callable of an array of
            times returning ``(q, q_dot, q_ddot)`` each (T, n_M), or a tuple of sample arrays
            ``(t, q, q_dot, q_ddot)`` (quintic Hermite interpolation, see
            :class:`~balance_opt.motion.trajectories.SampledTrajectory`; its ``from_result`` for
            a result).
        balance: balance arms' motion, the same ways, all balance joints stacked (n_B).
        h0: initial momentum, world frame (3 angular or 6 [linear; angular] values), ``None`` for 0.
        integration: integrator settings.
        t_eval: output times [s] (default: every ``integration.output_step`` over the longer
            motion).
        quaternion0: initial base attitude (x, y, z, w), identity by default.
        method: the result's ``method`` label.

    Returns:
        A result whose ``q_dot``/``q_ddot`` are the given motions' and whose ``omega``, attitude,
        ``sigma_min`` and momentum residual come from the replay.

    Raises:
        SolverError: the integration failed; ``result`` holds the part integrated.
    """
    integration = integration or IntegrationOptions()
    M, B = robot.mission_indices, robot.balance_indices
    sample_M, dur_M = as_sampler(mission, M.size, "mission")
    sample_B, dur_B = as_sampler(balance, B.size, "balance")
    durations = [d for d in (dur_M, dur_B) if d is not None]
    t = output_grid(t_eval, max(durations) if durations else None, integration)
    L = angular_momentum_of(h0)
    spinning = bool(L.any())
    maps = NumericMaps(robot)
    q_buf = np.empty(robot.n)
    qd_buf = np.empty(robot.n)

    def rhs(ti, y):
        tt = np.array([ti])
        qM, qdM, _ = sample_M(tt)
        qB, qdB, _ = sample_B(tt)
        q_buf[M], q_buf[B] = qM[0], qB[0]
        qd_buf[M], qd_buf[B] = qdM[0], qdB[0]
        I_G, A = maps.angular_maps(q_buf)
        ell = matrix_from_quaternion(y / np.linalg.norm(y)).T @ L if spinning else None
        return quaternion_rate(y, base_angular_velocity(I_G, A, qd_buf, ell))

    quat, stats, failure = integrate(rhs, initial_quaternion(quaternion0), t, integration)
    t = t[: quat.shape[0]]
    q, q_dot, q_ddot = (np.empty((t.size, robot.n)) for _ in range(3))
    for samples, cols in ((sample_M(t), M), (sample_B(t), B)):
        for full, part in zip((q, q_dot, q_ddot), samples):
            full[:, cols] = part
    info = {
        "integration": stats,
        "h0": None if h0 is None else np.asarray(h0, dtype=float).tolist(),
    }
    result = _result(maps, method, t, q, q_dot, q_ddot, quat, L, info)
    if failure is not None:
        raise SolverError(f"attitude replay failed: {failure}", "integration_failed", result)
    return result


def _result(maps: NumericMaps, method, t, q, q_dot, q_ddot, quat, L, info) -> BalanceResult:
    """The replayed samples, with the base rate, ``sigma_min`` and the momentum check."""
    I_G, A = maps.angular_maps(q)
    ell = np.vecmat(np.broadcast_to(L, (t.size, 3)), matrix_from_quaternion(quat))  # R^T L
    return BalanceResult.from_arm_vectors(
        maps.robot,
        method,
        t,
        q,
        q_dot,
        q_ddot,
        quat,
        base_angular_velocity(I_G, A, q_dot, ell),
        momentum_residual(maps, t, q, q_dot, quat, L),
        maps.balance_sigma_min(I_G, A),
        info,
    )
