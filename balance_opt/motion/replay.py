"""Replays: the base attitude that GIVEN joint motions of both arms produce, from momentum
conservation alone (Eq. 26 with the initial momentum, integrated on SO(3)), as a
:class:`~balance_opt.motion.result.BalanceResult`; with the balance arm held, the paper's Phase I."""

from __future__ import annotations

import numpy as np

from balance_opt.errors import InputError, SolverError
from balance_opt.model.maps import NumericMaps, base_angular_velocity
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.integration import integrate, output_grid, rk4_stage_times, rk4_stages
from balance_opt.motion.momentum_check import momentum_residual
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import IDENTITY_QUATERNION, matrix_from_quaternion, quaternion_rate
from balance_opt.motion.trajectories import PointToPoint, TrajectoryLike, arm_samples, as_sampler


def replay(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    balance: TrajectoryLike,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
    method: str = "simulation",
    attitude0=None,
) -> BalanceResult:
    """Integrate the base attitude for GIVEN joint motions of both arms (Eq. 26 with the initial
    momentum ``h0``, world frame, 3 or 6 values).

    ``mission`` and ``balance`` (all balance joints stacked) take any form
    :func:`~balance_opt.motion.trajectories.as_sampler` takes; ``t_eval`` defaults to every
    ``integration.output_step`` over the longer motion. ``attitude0``: the base's attitude
    at the first output time, a quaternion (x, y, z, w), the identity by default (the drift is
    measured from it: a replay from the middle of a motion gives the attitude it started from).

    Raises:
        SolverError: the integration failed; ``result`` holds the part integrated.
    """
    integration = integration or IntegrationOptions()
    M, B = robot.mission_indices, robot.balance_indices
    sample_M, dur_M = as_sampler(mission, M.size, "mission")
    sample_B, dur_B = as_sampler(balance, B.size, "balance")
    durations = [d for d in (dur_M, dur_B) if d is not None]
    t = output_grid(t_eval, max(durations) if durations else None, integration)
    L = np.zeros(3) if h0 is None else np.asarray(h0, dtype=float).ravel()
    if L.size not in (3, 6) or not np.all(np.isfinite(L)):
        raise InputError(
            f"initial momentum h0 must be 3 or 6 finite values, got {L.size}: {L.tolist()}"
        )
    L = L[-3:].copy()  # the angular part, world axes [N m s]
    maps = NumericMaps(robot)
    # the drift is measured from the initial attitude
    q0 = IDENTITY_QUATERNION.copy() if attitude0 is None else np.array(attitude0, dtype=float)
    if integration.method == "rk4":  # fixed steps: every joint sample known before integrating
        quat, stats, failure = _rk4_given_joints(maps, sample_M, sample_B, L, q0, t, integration)
    else:
        quat, stats, failure = integrate(
            _adaptive_rhs(maps, sample_M, sample_B, L), q0, t, integration
        )
    t = t[: quat.shape[0]]
    q, q_dot, q_ddot = arm_samples(robot, sample_M, sample_B, t)
    info = {
        "integration": stats,
        "h0": None if h0 is None else np.asarray(h0, dtype=float).tolist(),
    }
    result = _result(maps, method, t, q, q_dot, q_ddot, quat, L, info)
    if failure is not None:
        raise SolverError(f"attitude replay failed: {failure}", "integration_failed", result)
    return result


def _adaptive_rhs(maps: NumericMaps, sample_M, sample_B, L: np.ndarray):
    """``y -> y_dot`` at any time, for the adaptive integrator (one configuration per call)."""
    M, B = maps.robot.mission_indices, maps.robot.balance_indices
    spinning = bool(L.any())
    q_buf = np.empty(maps.robot.n)
    qd_buf = np.empty(maps.robot.n)

    def rhs(ti, y):
        tt = np.array([ti])
        qM, qdM, _ = sample_M(tt)
        qB, qdB, _ = sample_B(tt)
        q_buf[M], q_buf[B] = qM[0], qB[0]
        qd_buf[M], qd_buf[B] = qdM[0], qdB[0]
        I_G, A = maps.angular_maps(q_buf)
        ell = matrix_from_quaternion(y / np.linalg.norm(y)).T @ L if spinning else None
        return quaternion_rate(y, base_angular_velocity(I_G, A, qd_buf, ell))

    return rhs


def phase_one(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    q_B0,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
) -> BalanceResult:
    """Phase I (Fig. 2): base attitude with the mission arm moving and the balance arm held at
    ``q_B0`` [rad]. ``method="mission-only"``. Other arguments as in :func:`replay`."""
    if t_eval is not None:
        duration = float(np.max(t_eval))
    else:
        duration = as_sampler(mission, robot.mission.dof, "mission")[1]
        if duration is None:
            raise InputError(
                "output times are needed: the mission motion is a plain callable with no duration"
            )
    q_B0 = np.asarray(q_B0, dtype=float).ravel()
    return replay(
        robot,
        mission,
        PointToPoint(q_B0, q_B0, duration),
        h0=h0,
        integration=integration,
        t_eval=t_eval,
        method="mission-only",
    )


def _to_body(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R^T v`` for the unit quaternion ``q`` (x, y, z, w): ``v - 2 w (u x v) + 2 u x (u x v)``
    with ``u = (x, y, z)``, written out (the inner loop of a spinning replay)."""
    x, y, z, w = q
    a, b, c = v
    cx, cy, cz = y * c - z * b, z * a - x * c, x * b - y * a  # u x v
    return np.array(
        [
            a - 2 * w * cx + 2 * (y * cz - z * cy),
            b - 2 * w * cy + 2 * (z * cx - x * cz),
            c - 2 * w * cz + 2 * (x * cy - y * cx),
        ]
    )


def _rk4_given_joints(maps: NumericMaps, sample_M, sample_B, L, y0, t, options):
    """Classic RK4 on the unit quaternion with the steps of
    :func:`~balance_opt.motion.integration.integrate`, the base rate at every stage time
    evaluated in one batch first (one Pinocchio pass per stage time); with momentum ``L``, its
    attitude-dependent part ``I_G^{-1} R^T L`` is added stage by stage. Returns
    ``(Y, stats, message)``."""
    times, n_sub, h = rk4_stage_times(t, options)
    q, q_dot, _ = arm_samples(maps.robot, sample_M, sample_B, times)
    I_G, A = maps.angular_maps(q)
    omega = base_angular_velocity(I_G, A, q_dot)  # at zero momentum
    if L.any():
        inverse = np.linalg.inv(I_G)

        def rate(j: int, y: np.ndarray) -> np.ndarray:
            """``y'`` at stage time ``j`` for the (unnormalised) quaternion ``y``."""
            return quaternion_rate(y, omega[j] + inverse[j] @ _to_body(y / np.linalg.norm(y), L))

        return rk4_stages(rate, y0, t, options)
    Y, message = _step_matrices(omega, y0, t, n_sub, h)
    step, S = options.step or options.output_step, h.size
    stats = {"method": "rk4", "step": step, "steps": int(S), "rhs_evaluations": 4 * int(S)}
    return Y, stats, message


def attitude_from_rates(omega: np.ndarray, t: np.ndarray, options: IntegrationOptions):
    """The base attitude (..., T, 4) at ``t`` from base rates that do not depend on it (zero
    momentum) given at :func:`~balance_opt.motion.integration.rk4_stage_times` [rad/s, base
    frame], one history or a batch: :func:`replay`'s RK4 steps. SolverError for non-finite
    rates."""
    _, n_sub, h = rk4_stage_times(t, options)
    Y, message = _step_matrices(omega, IDENTITY_QUATERNION, t, n_sub, h)
    if message is not None:
        raise SolverError(f"attitude replay failed: {message}", "integration_failed", None)
    return Y


def _rate_matrices(omega: np.ndarray) -> np.ndarray:
    """``0.5 Omega(omega)`` (..., 4, 4) with ``quaternion_rate(q, omega) = 0.5 Omega q``."""
    a, b, c = np.moveaxis(omega, -1, 0)
    z = np.zeros_like(a)
    rows = [[z, c, -b, a], [-c, z, a, b], [b, -a, z, c], [-a, -b, -c, z]]
    return 0.5 * np.stack([np.stack(r, -1) for r in rows], -2)


def _step_matrices(omega: np.ndarray, y0, t, n_sub, h):
    """RK4 when the rate does not depend on the attitude: each step is one 4 x 4 matrix, all
    built in one batch, then chained. ``omega`` holds the rates at the step starts (S), midpoints
    (S) and the end (1). Returns ``(Y, message)``."""
    S = h.size
    M = _rate_matrices(omega)
    ends = np.append(np.arange(1, S), 2 * S)  # a step's end is the next step's start
    M1, M2, M3 = M[..., :S, :, :], M[..., S : 2 * S, :, :], M[..., ends, :, :]
    eye = np.eye(4)
    hh = h[:, None, None]
    A1 = eye + 0.5 * hh * M1
    A2 = eye + 0.5 * hh * (M2 @ A1)
    A3 = eye + hh * (M2 @ A2)
    P = eye + (hh / 6.0) * (M1 + 2.0 * (M2 @ A1) + 2.0 * (M2 @ A2) + M3 @ A3)
    if omega.ndim > 2:  # a batch of rate histories (..., 2 S + 1, 3): the steps chained at once
        return _chain_batch(P, y0, t, n_sub)
    Y = np.empty((t.size, y0.size))
    Y[0] = y = np.array(y0, dtype=float)
    last = np.cumsum(n_sub) - 1  # the step that ends each output interval
    k = 0
    for s in range(S):
        y = P[s] @ y
        y /= np.sqrt(y @ y)
        if s == last[k]:
            if not np.all(np.isfinite(y)):
                return Y[: k + 1], f"non-finite state (at t = {t[k + 1]:.6g} s)"
            k += 1
            Y[k] = y
    return Y, None


def _chain_batch(P: np.ndarray, y0, t, n_sub):
    """:func:`_step_matrices`' chain for a batch (..., S, 4, 4): ``(Y (..., T, 4), message)``."""
    last = np.cumsum(n_sub) - 1
    Y = np.empty(P.shape[:-3] + (t.size, 4))
    y = np.broadcast_to(np.asarray(y0, dtype=float), P.shape[:-3] + (4,)).copy()
    Y[..., 0, :] = y
    k = 0
    for s in range(P.shape[-3]):
        y = np.einsum("...ab,...b->...a", P[..., s, :, :], y)
        y /= np.linalg.norm(y, axis=-1, keepdims=True)
        if s == last[k]:
            k += 1
            Y[..., k, :] = y
    if not np.all(np.isfinite(Y)):
        return Y, "non-finite state"
    return Y, None


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
