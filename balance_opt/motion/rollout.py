"""Attitude rollouts: integrate the base attitude on SO(3), with the balance joints driven by the
analytic law (:func:`rollout`) or given (:func:`replay`), and return a :class:`BalanceResult`.

Attitude representation: a unit quaternion (x, y, z, w) integrated with its kinematics
``q_dot = 1/2 q * (omega, 0)`` (``R_dot = R [omega]_x``, ``omega`` in the base frame). This flow
keeps ``|q| = 1`` exactly, so the adaptive integrator keeps the norm to within its tolerance
and the fixed-step RK4 renormalises after every step; every quaternion handed out (to the law
and in results) is renormalised. No Euler angles are ever integrated.

Integrators (:class:`IntegrationOptions`):

* ``"adaptive"`` (default): scipy's Dormand-Prince 8(5,3) (``DOP853``) with error control on the
  quaternion and the balance joints (``rtol``, ``atol``) and its 7th-order dense output at the
  output times; exact to the integration tolerance.
* ``"rk4"``: classic fixed-step Runge-Kutta 4, each output interval split into steps no longer
  than ``step``.

Per-sample outputs (``omega``, ``sigma_min``, momentum residual, ``q_dot_B``, ``q_ddot_B`` by
Eq. 31 and 32) are evaluated after the integration at the output times, in one batched pass of
numeric Pinocchio (:class:`balance_opt.analytic.law.AngularMomentumMaps`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from balance_opt.analytic.law import AngularMomentumMaps, BalanceLaw, angular_jacobians_from_maps
from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.errors import InputError, SolverError, TrajectoryError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.so3 import IDENTITY_QUATERNION, matrix_from_quaternion
from balance_opt.motion.trajectories import JointTrajectory
from balance_opt.result import BalanceResult

log = logging.getLogger(__name__)

#: The scipy scheme behind ``"adaptive"``.
ADAPTIVE_SCHEME = "DOP853"
#: Relative slack when splitting an output interval into RK4 steps.
_STEP_SLACK = 1e-9


# ---------------------------------------------------------------------------------- trajectories
class SampledTrajectory(JointTrajectory):
    """A joint trajectory given as samples, interpolated piecewise.

    With positions, velocities and accelerations: quintic Hermite interpolation (C2, error
    O(h^6)), the natural choice to replay a plan or a :class:`BalanceResult`; with positions and
    velocities: cubic Hermite (C1); with positions only: a natural cubic spline (C2). Before the
    first and after the last sample the arm rests at its end positions.

    Args:
        t: strictly increasing sample times (T,) [s], the first 0.
        q: positions (T, dof) [rad].
        q_dot: velocities (T, dof) [rad/s], optional.
        q_ddot: accelerations (T, dof) [rad/s^2], optional (needs ``q_dot``).

    Raises:
        TrajectoryError: bad times or shapes.
    """

    def __init__(self, t, q, q_dot=None, q_ddot=None):
        self.t = np.asarray(t, dtype=float).ravel()
        q = np.asarray(q, dtype=float)
        q = q[:, None] if q.ndim == 1 else q
        if self.t.size < 2 or q.shape[0] != self.t.size:
            raise TrajectoryError(
                f"sampled trajectory needs at least 2 samples and one position row per time; "
                f"got {self.t.size} times and {q.shape[0]} rows"
            )
        if self.t[0] != 0.0 or np.any(np.diff(self.t) <= 0):
            raise TrajectoryError("sampled trajectory times must start at 0 and increase strictly")
        if q_ddot is not None and q_dot is None:
            raise TrajectoryError("sampled trajectory: accelerations given without velocities")
        derivs = [q]
        for name, d in (("velocities", q_dot), ("accelerations", q_ddot)):
            if d is None:
                continue
            d = np.asarray(d, dtype=float).reshape(q.shape[0], -1)
            if d.shape != q.shape:
                raise TrajectoryError(
                    f"sampled trajectory: {name} have shape {d.shape}, positions {q.shape}"
                )
            derivs.append(d)
        if not all(np.all(np.isfinite(d)) for d in derivs):
            raise TrajectoryError("sampled trajectory has non-finite values")
        self.duration = float(self.t[-1])
        self.dof = q.shape[1]
        self._h = np.diff(self.t)
        self._spline = None
        if len(derivs) == 1:
            self._spline = CubicSpline(self.t, q, bc_type="natural")
        else:
            self._coeffs = self._hermite_coefficients(derivs)

    def _hermite_coefficients(self, derivs) -> np.ndarray:
        """Per-interval polynomial coefficients in ``s = (t - t_k) / h`` (K, degree + 1, dof)."""
        h = self._h[:, None]
        p0, p1 = derivs[0][:-1], derivs[0][1:]
        v0, v1 = derivs[1][:-1] * h, derivs[1][1:] * h
        if len(derivs) == 2:  # cubic Hermite
            dp = p1 - p0
            return np.stack([p0, v0, 3 * dp - 2 * v0 - v1, -2 * dp + v0 + v1], axis=1)
        a0, a1 = derivs[2][:-1] * h**2, derivs[2][1:] * h**2
        gap = p1 - p0 - v0 - 0.5 * a0
        dv = v1 - v0 - a0
        da = a1 - a0
        return np.stack(
            [
                p0,
                v0,
                0.5 * a0,
                10 * gap - 4 * dv + 0.5 * da,
                -15 * gap + 7 * dv - da,
                6 * gap - 3 * dv + 0.5 * da,
            ],
            axis=1,
        )

    @classmethod
    def from_result(cls, result: BalanceResult, arm: str = "balance") -> SampledTrajectory:
        """The mission (``arm="mission"``) or balance (``"balance"``) motion of a result."""
        if arm not in ("mission", "balance"):
            raise InputError(f"arm must be 'mission' or 'balance', got {arm!r}")
        s = "M" if arm == "mission" else "B"
        t = result.t - result.t[0]
        return cls(
            t,
            getattr(result, f"q_{s}"),
            getattr(result, f"q_dot_{s}"),
            getattr(result, f"q_ddot_{s}"),
        )

    def sample(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        inside = (t >= 0.0) & (t <= self.duration)
        tc = np.clip(t, 0.0, self.duration)
        if self._spline is not None:
            q, q_dot, q_ddot = self._spline(tc), self._spline(tc, 1), self._spline(tc, 2)
        else:
            k = np.clip(np.searchsorted(self.t, tc, side="right") - 1, 0, self._h.size - 1)
            h = self._h[k][:, None]
            s = ((tc - self.t[k]) / self._h[k])[:, None]
            c = self._coeffs[k]  # (T, degree + 1, dof)
            deg = c.shape[1] - 1
            q = c[:, deg]
            q_dot = deg * c[:, deg]
            q_ddot = deg * (deg - 1) * c[:, deg]
            for j in range(deg - 1, -1, -1):  # Horner for the value and both derivatives
                q = q * s + c[:, j]
                if j >= 1:
                    q_dot = q_dot * s + j * c[:, j]
                if j >= 2:
                    q_ddot = q_ddot * s + j * (j - 1) * c[:, j]
            q_dot = q_dot / h
            q_ddot = q_ddot / h**2
        out = ~inside[:, None]
        return q, np.where(out, 0.0, q_dot), np.where(out, 0.0, q_ddot)


TrajectoryLike = JointTrajectory | Callable | tuple


def as_sampler(trajectory: TrajectoryLike, dof: int, what: str) -> tuple[Callable, float | None]:
    """``(sample, duration)`` for a trajectory given as an object with ``sample(t)``, a callable
    ``f(t) -> (q, q_dot, q_ddot)`` of an array of times, or a tuple of sample arrays
    ``(t, q[, q_dot[, q_ddot]])`` (a :class:`SampledTrajectory`).

    Raises:
        TrajectoryError: the trajectory has the wrong number of joints.
    """
    if isinstance(trajectory, tuple):
        trajectory = SampledTrajectory(*trajectory)
    sample = trajectory.sample if hasattr(trajectory, "sample") else trajectory
    if not callable(sample):
        raise TrajectoryError(
            f"{what} trajectory must have sample(t), be callable or be a tuple of arrays; "
            f"got {type(trajectory).__name__}"
        )
    probe = np.asarray(sample(np.array([0.0]))[0])
    if probe.shape[-1] != dof:
        raise TrajectoryError(
            f"{what} trajectory has {probe.shape[-1]} joints, the robot's {what} joints are {dof}"
        )
    duration = getattr(trajectory, "duration", None)
    return sample, (None if duration is None else float(duration))


def output_times(duration: float, step: float) -> np.ndarray:
    """Output grid from 0 to ``duration`` [s] in ``round(duration / step)`` equal intervals."""
    n = max(1, round(duration / step))
    return np.linspace(0.0, duration, n + 1)


def _check_times(t_eval) -> np.ndarray:
    t = np.asarray(t_eval, dtype=float).ravel()
    if t.size < 2 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
        raise InputError("output times must be at least 2 finite, strictly increasing values")
    return t


# ---------------------------------------------------------------------------------- integration
def _quaternion_rate(quat: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``1/2 q * (omega, 0)`` for one quaternion (x, y, z, w) and a body rate [rad/s]."""
    x, y, z, w = quat
    a, b, c = omega
    return 0.5 * np.array(
        [
            w * a + y * c - z * b,
            w * b + z * a - x * c,
            w * c + x * b - y * a,
            -(x * a + y * b + z * c),
        ]
    )


def integrate(rhs: Callable, y0: np.ndarray, t: np.ndarray, options: IntegrationOptions):
    """Integrate ``y' = rhs(t, y)`` whose first 4 entries are a unit quaternion.

    Args:
        rhs: right-hand side ``(t, y) -> y'``.
        y0: initial state, quaternion first.
        t: output times (T,), the first the initial time.
        options: integrator settings.

    Returns:
        ``(Y, stats, message)``: states at the output times with normalised quaternions (T', ny)
        (T' < T when the integration failed), statistics (plain data) and ``None`` on success,
        else the integrator's message.
    """
    if options.method == "adaptive":
        sol = solve_ivp(
            rhs,
            (t[0], t[-1]),
            y0,
            method=ADAPTIVE_SCHEME,
            t_eval=t,
            rtol=options.rtol,
            atol=options.atol,
            max_step=options.step or np.inf,
        )
        Y = sol.y.T.copy()
        stats = {
            "method": "adaptive",
            "scheme": ADAPTIVE_SCHEME,
            "rtol": options.rtol,
            "atol": options.atol,
            "rhs_evaluations": int(sol.nfev),
        }
        message = (
            None
            if sol.status == 0
            else f"{sol.message} (at t = {sol.t[-1] if sol.t.size else t[0]:.6g} s)"
        )
    else:
        step = options.step or options.output_step
        Y = np.empty((t.size, y0.size))
        Y[0] = y = np.array(y0, dtype=float)
        n_steps, message = 0, None
        for k in range(t.size - 1):
            n_sub = max(1, math.ceil((t[k + 1] - t[k]) / step - _STEP_SLACK))
            h = (t[k + 1] - t[k]) / n_sub
            tk = t[k]
            for i in range(n_sub):
                ti = tk + i * h
                k1 = rhs(ti, y)
                k2 = rhs(ti + 0.5 * h, y + 0.5 * h * k1)
                k3 = rhs(ti + 0.5 * h, y + 0.5 * h * k2)
                k4 = rhs(ti + h, y + h * k3)
                y = y + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
                y[:4] /= np.linalg.norm(y[:4])
            n_steps += n_sub
            if not np.all(np.isfinite(y)):
                message = f"non-finite state (at t = {t[k + 1]:.6g} s)"
                Y = Y[: k + 1]
                break
            Y[k + 1] = y
        stats = {"method": "rk4", "step": step, "steps": n_steps, "rhs_evaluations": 4 * n_steps}
    Y[:, :4] /= np.linalg.norm(Y[:, :4], axis=1, keepdims=True)
    return Y, stats, message


# ---------------------------------------------------------------------------------- results
def _result(
    robot, method, t, q, q_dot, q_ddot, quaternion, omega, momentum_residual, sigma_min, info
):
    return BalanceResult.from_arm_vectors(
        robot, method, t, q, q_dot, q_ddot, quaternion, omega, momentum_residual, sigma_min, info
    )


def _initial_quaternion(quaternion0) -> np.ndarray:
    if quaternion0 is None:
        return IDENTITY_QUATERNION.copy()
    q = np.asarray(quaternion0, dtype=float).ravel()
    if q.size != 4 or not np.all(np.isfinite(q)) or np.linalg.norm(q) == 0:
        raise InputError(
            f"initial attitude must be a non-zero quaternion (x, y, z, w), got {q.tolist()}"
        )
    return q / np.linalg.norm(q)


def _grid(t_eval, duration, options: IntegrationOptions) -> np.ndarray:
    if t_eval is not None:
        return _check_times(t_eval)
    if duration is None:
        raise InputError(
            "output times are needed: a trajectory given as a plain callable has no duration"
        )
    return output_times(duration, options.output_step)


def rollout(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    q_B0,
    options: BalanceLawOptions | None = None,
    *,
    integration: IntegrationOptions | None = None,
    t_eval=None,
    quaternion0=None,
) -> BalanceResult:
    """Phase II: the balance trajectory of the analytic law (Eq. 31) along a mission motion.

    Integrates the base attitude and the balance joints together; ``q_dot_B`` at the output
    times is the law at the integrated state and ``q_ddot_B`` is Eq. 32 there (the exact time
    derivative of the law).

    Args:
        robot: the floating robot.
        mission: the mission arm's motion (see :func:`as_sampler`).
        q_B0: initial balance joint positions [rad].
        options: the law's settings (``h0``, damping, null space, feedback).
        integration: integrator settings.
        t_eval: output times [s] (default: every ``integration.output_step`` over the mission).
        quaternion0: initial base attitude (x, y, z, w), also the feedback's ``R_0`` (identity).

    Returns:
        A result with ``method="analytic"``; ``info`` holds the law's options, damping and
        residual statistics and the integrator's.

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
    quat0 = _initial_quaternion(quaternion0)
    law = BalanceLaw(robot, options, q_B0=q_B0, reference=quat0)
    t = _grid(t_eval, duration, integration)
    q_buf = np.empty(robot.n)

    def rhs(ti, y):
        qM, qdM, _ = sample_M(np.array([ti]))
        quat = y[:4] / np.linalg.norm(y[:4])
        q_buf[M] = qM[0]
        q_buf[B] = y[4:]
        q_dot_B, omega = law.attitude_rate(q_buf, qdM[0], quat)
        return np.concatenate((_quaternion_rate(y[:4], omega), q_dot_B))

    Y, stats, failure = integrate(rhs, np.r_[quat0, q_B0], t, integration)
    t = t[: Y.shape[0]]
    qM, qdM, qddM = sample_M(t)
    q = np.empty((t.size, robot.n))
    q[:, M], q[:, B] = qM, Y[:, 4:]
    quat = Y[:, :4]
    path = law.along(q, qdM, qddM, quat)
    q_dot = np.empty_like(q)
    q_ddot = np.empty_like(q)
    q_dot[:, M], q_dot[:, B] = qdM, path.q_dot_B
    q_ddot[:, M], q_ddot[:, B] = qddM, path.q_ddot_B
    residual = np.linalg.norm(path.residual, axis=1)
    info = {
        "law": options.as_dict(),
        "null_space_goal": law.goal.tolist(),
        "damping_max": float(path.damping.max()),
        "damping_active_fraction": float(np.mean(path.damping > 0)),
        "condition_max": float(path.condition.max()),
        "residual_omega_max": float(residual.max()),
        "residual_omega_rms": float(np.sqrt(np.mean(residual**2))),
        "integration": stats,
    }
    result = _result(
        robot,
        "analytic",
        t,
        q,
        q_dot,
        q_ddot,
        quat,
        path.omega,
        path.momentum_residual,
        path.sigma_min,
        info,
    )
    if failure is not None:
        raise SolverError(
            f"analytic balance law rollout failed: {failure}", "integration_failed", result
        )
    log.debug("rollout: %d samples, %s", t.size, stats)
    return result


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
            :class:`SampledTrajectory`; :meth:`SampledTrajectory.from_result` for a result).
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
    t = _grid(t_eval, max(durations) if durations else None, integration)
    L = BalanceLawOptions(h0=h0).angular_momentum
    spinning = bool(L.any())
    quat0 = _initial_quaternion(quaternion0)
    maps = AngularMomentumMaps(robot)
    q_buf = np.empty(robot.n)
    qd_buf = np.empty(robot.n)

    def rhs(ti, y):
        tt = np.array([ti])
        qM, qdM, _ = sample_M(tt)
        qB, qdB, _ = sample_B(tt)
        q_buf[M], q_buf[B] = qM[0], qB[0]
        qd_buf[M], qd_buf[B] = qdM[0], qdB[0]
        I_G, A = maps.at(q_buf)
        h = -A @ qd_buf
        if spinning:
            h = h + matrix_from_quaternion(y[:4] / np.linalg.norm(y[:4])).T @ L
        return _quaternion_rate(y[:4], np.linalg.solve(I_G, h))

    Y, stats, failure = integrate(rhs, quat0, t, integration)
    t = t[: Y.shape[0]]
    quat = Y
    qM, qdM, qddM = sample_M(t)
    qB, qdB, qddB = sample_B(t)
    q = np.empty((t.size, robot.n))
    q_dot, q_ddot = np.empty_like(q), np.empty_like(q)
    q[:, M], q[:, B] = qM, qB
    q_dot[:, M], q_dot[:, B] = qdM, qdB
    q_ddot[:, M], q_ddot[:, B] = qddM, qddB
    omega, momentum_residual, sigma_min = base_rates_along(maps, q, q_dot, quat, L)
    info = {
        "integration": stats,
        "h0": None if h0 is None else np.asarray(h0, dtype=float).tolist(),
    }
    result = _result(
        robot, method, t, q, q_dot, q_ddot, quat, omega, momentum_residual, sigma_min, info
    )
    if failure is not None:
        raise SolverError(f"attitude replay failed: {failure}", "integration_failed", result)
    return result


def base_rates_along(maps: AngularMomentumMaps, q, q_dot, quaternion, L=None):
    """Base angular velocity, momentum residual and ``sigma_min(J_wB)`` along sampled motion.

    Args:
        maps: the robot's maps.
        q, q_dot: (T, n) arm vectors and rates.
        quaternion: (T, 4) base attitude.
        L: initial angular momentum, world frame (3,) [N m s]; ``None`` for 0.

    Returns:
        ``(omega (T, 3) [rad/s], |I_G omega + A q_dot - R^T L| (T,) [N m s], sigma_min (T,))``.
    """
    I_G, A = maps.along(q)
    ell = np.zeros((q.shape[0], 3))
    if L is not None and np.any(L):
        ell = np.einsum("tji,j->ti", matrix_from_quaternion(quaternion), L)
    h = ell - np.einsum("tij,tj->ti", A, q_dot)
    omega = np.linalg.solve(I_G, h[..., None])[..., 0]
    residual = np.linalg.norm(np.einsum("tij,tj->ti", I_G, omega) - h, axis=1)
    J_wB = angular_jacobians_from_maps(I_G, A)[..., maps.robot.balance_indices]
    sigma_min = np.linalg.svd(J_wB, compute_uv=False)[:, -1]
    return omega, residual, sigma_min
