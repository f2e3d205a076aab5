"""Co-planned mission timing (``mission.timing: free``): the given mission defines a path, the
planner chooses how fast it is followed, together with the balance motion.

The path is ``q_M(sigma)``, ``sigma`` in [0, 1]: for a point-to-point mission the straight
joint segment ``q0 + sigma (qf - q0)`` (exactly the path of the quintic profile, which only
times it), for every other mission the given trajectory at ``sigma T0``, through
:data:`PATH_SEGMENTS` quintic Hermite pieces (positions, first and second derivatives of the
given trajectory at their ends: C2). The planner's variables are ``sigma``, ``sigma_dot``
(states, ``P``/``Pm``) and ``sigma_ddot`` (control, ``A``/``Am``), a chain of integrators on the
collocation grid like the balance joints, and the mission joints' ``[q_M; q_dot_M; q_ddot_M]``
at every point (``M``/``Mm``, inputs of the point kernels), tied to the path by
``q_dot_M = q_M' sigma_dot``, ``q_ddot_M = q_M'' sigma_dot^2 + q_M' sigma_ddot``.

``sigma(0) = 0``, ``sigma(T) = 1``, the mission arm at rest at both ends (``sigma_dot`` and
``sigma_ddot`` zero: no torque step), ``sigma_dot >= 0`` on the continuous motion (the path is
never followed backwards). The mission joints' limits: at every collocation point on ``M``;
on a straight path, where the mission's rates are ``(qf - q0)`` times ``sigma``'s, also on the
continuous motion, through the Bernstein coefficients of ``sigma``'s polynomials (as the balance
limits are held between the points). On a curved path the limits between the points are checked
on the continuous motion, tightened by the refinement where it breaks them, and a plan still
breaking one fails (:class:`~balance_opt.optimal.constraints.MissionTiming`).

The path progress reported (``info["timing"]``) is ``s(t)``: the time at which the given
trajectory passes where the re-timed one is at ``t`` (``s = t`` for the given timing).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import casadi as cs
import numpy as np

from balance_opt.errors import InputError
from balance_opt.motion.trajectories import JointTrajectory, PointToPoint
from balance_opt.optimal.collocation import (
    CollocatedTrajectory,
    Transcription,
    joint_chain_coefficients,
)

#: Quintic Hermite pieces of a curved path (a mission that is not point to point).
PATH_SEGMENTS = 40
#: Samples of the path progress in ``info["timing"]`` (and ``metrics.json``).
PROGRESS_SAMPLES = 201
#: Rows of the path chain's states (``sigma``, ``sigma_dot``) and of the mission data ``M``
#: per mission joint (``q_M``, ``q_dot_M``, ``q_ddot_M``).
PATH_STATES = ("progress", "progress rate")
MISSION_LEVELS = ("position", "velocity", "acceleration")


def _quintic_hermite(y0, d0, a0, y1, d1, a1, L) -> np.ndarray:
    """Monomial coefficients (6, n) in ``u`` in [0, L] of the quintic with value, slope and
    curvature ``y, d, a`` at both ends."""
    A = np.array(
        [
            [L**3, L**4, L**5],
            [3 * L**2, 4 * L**3, 5 * L**4],
            [6 * L, 12 * L**2, 20 * L**3],
        ]
    )
    rhs = np.stack([y1 - y0 - d0 * L - 0.5 * a0 * L**2, d1 - d0 - a0 * L, a1 - a0], axis=0)
    high = np.linalg.solve(A, rhs)
    return np.vstack([y0, d0, 0.5 * a0, high])


class MissionPath:
    """The mission's path ``q_M(sigma)``, ``sigma`` in [0, 1] (see the module docstring).

    Attributes:
        linear: the straight segment of a point-to-point mission.
        duration: the given mission's duration ``T0`` [s].
        knots: the pieces' ends in ``sigma`` (K + 1,).
        coefficients: monomial coefficients (K, 6, n_M) in ``sigma - knots[k]``.
        key: a digest of the path (it is a constant of its NLP).
    """

    def __init__(self, mission: JointTrajectory):
        self.duration = T0 = float(mission.duration)
        self.dof = n = int(mission.dof)
        self.linear = isinstance(mission, PointToPoint)
        if self.linear:
            self.knots = np.array([0.0, 1.0])
            c = np.zeros((1, 6, n))
            c[0, 0], c[0, 1] = mission.q0, mission.qf - mission.q0
            self.coefficients = c
        else:
            self.knots = np.linspace(0.0, 1.0, PATH_SEGMENTS + 1)
            q, qd, qdd = mission.sample(self.knots * T0)
            qd, qdd = qd * T0, qdd * T0**2  # derivatives in sigma
            L = 1.0 / PATH_SEGMENTS
            self.coefficients = np.stack(
                [
                    _quintic_hermite(q[k], qd[k], qdd[k], q[k + 1], qd[k + 1], qdd[k + 1], L)
                    for k in range(PATH_SEGMENTS)
                ]
            )
        digest = hashlib.sha256(self.knots.tobytes() + self.coefficients.tobytes())
        self.key = ("linear:" if self.linear else "hermite:") + digest.hexdigest()[:16]

    @property
    def slope(self) -> np.ndarray:
        """``q_M'`` of a straight path (n_M,)."""
        return self.coefficients[0, 1]

    def evaluate(self, sigma) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``q_M, q_M', q_M''`` at ``sigma`` (T,) (clipped to [0, 1]), each (T, n_M)."""
        sigma = np.clip(np.atleast_1d(np.asarray(sigma, dtype=float)), 0.0, 1.0)
        k = np.clip(np.searchsorted(self.knots, sigma, side="right") - 1, 0, self.knots.size - 2)
        u = (sigma - self.knots[k])[:, None]
        c = self.coefficients[k]  # (T, 6, n)
        powers = [np.ones_like(u)]
        for _ in range(5):
            powers.append(powers[-1] * u)
        q = sum(c[:, i] * powers[i] for i in range(6))
        d1 = sum(i * c[:, i] * powers[i - 1] for i in range(1, 6))
        d2 = sum(i * (i - 1) * c[:, i] * powers[i - 2] for i in range(2, 6))
        return q, d1, d2

    def symbolic(self, sigma) -> tuple:
        """``q_M, q_M', q_M''`` (each (n_M, 1), CasADi) at a symbolic ``sigma``: on a curved
        path, the sum of the pieces, each switched on on its own knot interval."""
        parts = [cs.SX.zeros(self.dof, 1) for _ in range(3)]
        K = self.knots.size - 1
        for k in range(K):
            c = self.coefficients[k]
            u = sigma - self.knots[k]
            q = sum(cs.DM(c[i]) * u**i for i in range(6))
            d1 = sum(i * cs.DM(c[i]) * u ** (i - 1) for i in range(1, 6))
            d2 = sum(i * (i - 1) * cs.DM(c[i]) * u ** (i - 2) for i in range(2, 6))
            if K == 1:
                return q, d1, d2
            lo = -np.inf if k == 0 else self.knots[k]
            hi = np.inf if k == K - 1 else self.knots[k + 1]
            on = cs.logic_and(sigma >= lo, sigma < hi)
            zero = cs.SX.zeros(self.dof, 1)
            parts = [p + cs.if_else(on, v, zero) for p, v in zip(parts, (q, d1, d2))]
        return tuple(parts)

    def joints(self, sigma, sigma_dot, sigma_ddot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The mission joints ``q_M, q_dot_M, q_ddot_M`` (T, n_M) of a timing (each (T,))."""
        q, d1, d2 = self.evaluate(sigma)
        sd = np.atleast_1d(sigma_dot)[:, None]
        return q, d1 * sd, d2 * sd**2 + d1 * np.atleast_1d(sigma_ddot)[:, None]

    def given_progress(self, t) -> np.ndarray:
        """``sigma`` of the given timing at ``t`` [s] (the quintic profile of a point-to-point
        mission, ``t / T0`` otherwise)."""
        tau = np.clip(np.asarray(t, dtype=float) / self.duration, 0.0, 1.0)
        return tau**3 * (10 - 15 * tau + 6 * tau**2) if self.linear else tau

    def given_time(self, sigma) -> np.ndarray:
        """The time [s] at which the given mission passes ``sigma``: the inverse of
        :meth:`given_progress` (monotone), by interpolation on a fine grid."""
        t = np.linspace(0.0, self.duration, 4001)
        return np.interp(np.asarray(sigma, dtype=float), self.given_progress(t), t)


class RetimedMission(JointTrajectory):
    """The mission's path followed with a timing ``sigma(t)``: a piecewise polynomial of the
    path chain (:class:`~balance_opt.optimal.collocation.CollocatedTrajectory`'s levels), or
    ``scale``-times the given timing (``sigma(t) = given(t * scale)``)."""

    def __init__(self, path: MissionPath, progress=None, duration: float | None = None):
        self.path = path
        self.progress = progress  # a CollocatedTrajectory of sigma, or None: the given, scaled
        self.dof = path.dof
        self.duration = float(progress.duration if progress is not None else duration)

    def timing(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``sigma, sigma_dot, sigma_ddot`` at ``t`` (T,)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        if self.progress is not None:
            s, sd, sdd = self.progress.sample(t)
            return s[:, 0], sd[:, 0], sdd[:, 0]
        scale = self.path.duration / self.duration
        _, g1, g2 = PointToPoint([0.0], [1.0], self.path.duration).sample(t * scale)
        if self.path.linear:
            s = self.path.given_progress(t * scale)
            return s, g1[:, 0] * scale, g2[:, 0] * scale**2
        return t / self.duration, np.full(t.size, 1.0 / self.duration), np.zeros(t.size)

    def sample(self, t):
        return self.path.joints(*self.timing(t))


def initial_timing(path: MissionPath, horizon: float) -> RetimedMission:
    """The given timing stretched to ``horizon``: the planner's starting point."""
    return RetimedMission(path, duration=horizon)


@dataclass(frozen=True)
class MissionData:
    """What the problem knows of the mission's limits (mission arm order)."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


def mission_limits(robot) -> MissionData:
    """The mission joints' limits; a free timing needs finite rate and acceleration limits.

    Raises:
        InputError: a mission joint without a velocity or acceleration limit.
    """
    lim = robot.limits.subset(robot.mission_indices)
    names = robot.mission.joints
    for kind in ("velocity", "acceleration"):
        bad = [n for n, v in zip(names, getattr(lim, kind)) if not np.isfinite(v)]
        if bad:
            raise InputError(
                f"mission joint '{bad[0]}' has no {kind} limit: a free mission timing "
                f"(mission.timing: free) needs one (limits.{bad[0]}.{kind})"
            )
    return MissionData(lim.lower, lim.upper, lim.velocity, lim.acceleration)


def path_rate_limits(path: MissionPath, limits: MissionData) -> tuple[float, float]:
    """Largest ``sigma_dot`` and ``|sigma_ddot|`` of a straight path: the mission joints'
    rate and acceleration limits over ``|qf - q0|`` (``inf`` on a curved path, whose limits are
    rows on ``M``)."""
    if not path.linear:
        return np.inf, np.inf
    slope = np.abs(path.slope)
    moving = slope > 0
    if not moving.any():
        return np.inf, np.inf
    return (
        float(np.min(limits.velocity[moving] / slope[moving])),
        float(np.min(limits.acceleration[moving] / slope[moving])),
    )


def shortest_duration(path: MissionPath, rate_limits: tuple[float, float]) -> float:
    """A lower bound of the duration [s] of a rest-to-rest motion along the path: along a
    straight path, the time optimal motion of ``sigma`` with its rate and acceleration limits
    (accelerate, coast, brake); along a curved one, zero."""
    v, a = rate_limits
    if not np.isfinite(v) or not np.isfinite(a):
        return 0.0
    if v * v / a >= 1.0:  # the rate limit is never reached
        return 2.0 * float(np.sqrt(1.0 / a))
    return 1.0 / v + v / a


def path_levels(transcription: Transcription, sol, h) -> list[list]:
    """Bernstein coefficients of ``sigma``, ``sigma_dot``, ``sigma_ddot`` on every interval."""
    starts = [sol.P[0:1, :-1], sol.P[1:2, :-1]]
    return joint_chain_coefficients(transcription, starts, sol.A, sol.Am, h)


def guess_timing(problem, sol) -> None:
    """Fill the timing blocks of ``sol`` (``P``, ``A``, ``M``, their midpoints) with the
    problem's initial timing (the given one stretched to the horizon), unless ``sol`` has a
    timing already (then only ``M`` is made to agree with it)."""
    N = problem.N
    if sol.P is None:
        s, sd, sdd = problem.timed_mission.timing(problem.point_times)
        P, A = np.vstack([s, sd]), sdd[None, :]
        sol.P, sol.A = P[:, : N + 1].copy(), A[:, : N + 1].copy()
        if problem.transcription.has_midpoints:
            sol.Pm, sol.Am = P[:, N + 1 :].copy(), A[:, N + 1 :].copy()
    P = sol.P if sol.Pm is None else np.hstack([sol.P, sol.Pm])
    A = sol.A if sol.Am is None else np.hstack([sol.A, sol.Am])
    M = np.hstack(problem.mission_path.joints(P[0], P[1], A[0])).T
    sol.M = M[:, : N + 1].copy()
    sol.Mm = M[:, N + 1 :].copy() if problem.transcription.has_midpoints else None


def retimed(problem, sol) -> RetimedMission:
    """The re-timed mission of a solution: ``sigma``'s piecewise polynomial."""
    levels = path_levels(problem.transcription, sol, problem.h)
    return RetimedMission(problem.mission_path, CollocatedTrajectory(problem.h, levels))


def timing_info(problem, result, mission: RetimedMission) -> dict:
    """``info["timing"]``: the duration, the path progress ``s(t)`` (given-time equivalent, at
    :data:`PROGRESS_SAMPLES` of the result's samples), the mission's largest joint rates and
    accelerations (rad/s, rad/s^2; m/s, m/s^2 for a prismatic joint)."""
    path = problem.mission_path
    t = result.t[np.unique(np.linspace(0, result.t.size - 1, PROGRESS_SAMPLES).astype(int))]
    sigma = mission.timing(t)[0]
    joints = problem.robot.mission.joints
    return {
        "timing": "free",
        "duration_s": float(mission.duration),
        "given_duration_s": path.duration,
        "path": "straight joint segment" if path.linear else f"{PATH_SEGMENTS} quintic pieces",
        "progress_t": [float(v) for v in t],
        "progress_s": [float(v) for v in path.given_time(sigma)],
        # named for revolute joints, as every joint figure: a prismatic joint's are in m/s, m/s^2
        "mission_peak_rate_rad_s": dict(zip(joints, np.abs(result.q_dot_M).max(axis=0).tolist())),
        "mission_peak_acceleration_rad_s2": dict(
            zip(joints, np.abs(result.q_ddot_M).max(axis=0).tolist())
        ),
    }
