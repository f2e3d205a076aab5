"""A mission's path and its re-timing: the path ``q_M(sigma)``, ``sigma`` in [0, 1], of a given
mission trajectory (for a point-to-point mission the straight joint segment ``q0 + sigma (qf -
q0)``, exactly the path of the quintic profile, which only times it; for every other mission
the given trajectory at ``sigma T0``, through :data:`PATH_SEGMENTS` quintic Hermite pieces:
positions, first and second derivatives of the given trajectory at their ends, C2), the mission
followed along it with another timing ``sigma(t)``, and what the mission joints' limits allow a
straight path's progress (the shortest rest-to-rest duration). The optimal planner plans the
timing (:mod:`balance_opt.optimal.timing`)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import casadi as cs
import numpy as np

from balance_opt.errors import InputError
from balance_opt.motion.trajectories import JointTrajectory, PointToPoint

#: Quintic Hermite pieces of a curved path (a mission that is not point to point).
PATH_SEGMENTS = 40


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
        if self.path.linear:
            _, g1, g2 = PointToPoint([0.0], [1.0], self.path.duration).sample(t * scale)
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
