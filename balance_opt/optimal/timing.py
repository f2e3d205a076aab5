"""Co-planned mission timing (``mission.timing: free``): the given mission defines a path, the
planner chooses how fast it is followed, together with the balance motion.

The path is ``q_M(sigma)``, ``sigma`` in [0, 1] (:class:`~balance_opt.motion.retiming.MissionPath`:
the straight joint segment of a point-to-point mission, else C2 quintic pieces through the
given trajectory). The planner's variables are ``sigma``, ``sigma_dot``
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
breaking one fails (:class:`MissionTiming`).

The path progress reported (the plan's ``solver.timing``) is ``s(t)``: the time at which the given
trajectory passes where the re-timed one is at ``t`` (``s = t`` for the given timing).
"""

from __future__ import annotations

import casadi as cs
import numpy as np

from balance_opt.motion.result import LIMIT_TOLERANCE
from balance_opt.motion.retiming import PATH_SEGMENTS, RetimedMission
from balance_opt.optimal.collocation import (
    CollocatedTrajectory,
    Transcription,
    bernstein_value,
    joint_chain_coefficients,
)
from balance_opt.optimal.terms import (
    TORQUE_MARGIN,
    TORQUE_POINTS,
    PlannerSolverError,
    Term,
    Violation,
    block_rows,
    rounds_tried,
)

#: Samples of the path progress in a plan's ``solver.timing`` (and ``metrics.json``).
PROGRESS_SAMPLES = 201
#: Rows of the path chain's states (``sigma``, ``sigma_dot``) and of the mission data ``M``
#: per mission joint (``q_M``, ``q_dot_M``, ``q_ddot_M``).
PATH_STATES = ("progress", "progress rate")
MISSION_LEVELS = ("position", "velocity", "acceleration")


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
    """A plan's ``solver.timing`` (``metrics.json``'s ``timing``): the duration, the path progress ``s(t)`` (given-time equivalent, at
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


class MissionTiming(Term):
    """A free mission timing's rows and bounds (:mod:`balance_opt.optimal.timing`): the path
    progress ``sigma`` integrated exactly, the mission joints on the path at every point,
    ``sigma`` in [0, 1] and never backwards on the continuous motion, the mission joints within
    their limits (on a straight path between the points too, through ``sigma``'s Bernstein
    coefficients). On a curved path the limits between the points are checked on the
    continuous re-timed motion (:meth:`check`), lowered by the refinement on the intervals that
    break them (:meth:`tighten`, ``problem.bounds.mission_factor``), and a plan still breaking
    one fails (:meth:`accept`)."""

    name = "mission timing"

    def __init__(self, transcription: Transcription):
        self.transcription = transcription
        degree = transcription.control_degree + 2  # sigma's polynomial degree
        # interior Bernstein coefficients of sigma, sigma_dot, sigma_ddot
        self.interior = tuple(tuple(range(1, degree - k)) for k in range(3))

    def rows(self, nlp):
        tr, N, v, h = self.transcription, nlp.key.intervals, nlp.variables, nlp.parameters.h
        levels = path_levels(tr, v, h)
        states = levels[:-1]
        ends = cs.vertcat(*(bernstein_value(level, 1.0) for level in states))
        out = block_rows(
            nlp,
            "mission timing (collocation)",
            PATH_STATES,
            "(path)",
            v.P[:, 1:] - ends,
            np.arange(N, dtype=float),
            True,
        )
        if tr.has_midpoints:
            mids = cs.vertcat(*(bernstein_value(level, 0.5) for level in states))
            out += block_rows(
                nlp,
                "mission timing (midpoint)",
                PATH_STATES,
                "(path)",
                v.Pm - mids,
                np.arange(N, dtype=float),
                True,
            )
        # the mission joints at every point on the path
        path = nlp.mission_path
        P = v.P if v.Pm is None else cs.horzcat(v.P, v.Pm)
        A = v.A if v.Am is None else cs.horzcat(v.A, v.Am)
        M = v.M if v.Mm is None else cs.horzcat(v.M, v.Mm)
        columns = []
        for k in range(P.shape[1]):
            q, d1, d2 = path.symbolic(P[0, k])
            sd, sdd = P[1, k], A[0, k]
            columns.append(cs.vertcat(q, d1 * sd, d2 * sd**2 + d1 * sdd) - M[:, k])
        labels = [f"{j} {kind}" for kind in MISSION_LEVELS for j in nlp.mission_joints]
        out += block_rows(nlp, "mission on its path", labels, "(path)", cs.horzcat(*columns))
        # between the points: sigma in [0, 1], sigma_dot >= 0 (and the limits of a straight path)
        coefficients, labels = [], []
        names = ("progress", "progress rate", "progress acceleration")
        for level, indices, name in zip(levels, self.interior, names):
            for i in indices:
                coefficients.append(level[i])
                labels.append(f"{name} (control point {i})")
        out += block_rows(
            nlp,
            "mission timing between points",
            labels,
            "(path)",
            cs.vertcat(*coefficients),
            np.arange(N, dtype=float),
            True,
        )
        return out

    def _level_bounds(self, problem) -> list[tuple[float, float]]:
        v_max, a_max = problem.path_rate_limits
        return [(0.0, 1.0), (0.0, v_max), (-a_max, a_max)]

    def row_bounds(self, problem, block):
        if block.name != "mission timing between points":
            return np.zeros(block.size), np.zeros(block.size)
        lo, hi = [], []
        for (low, high), indices in zip(self._level_bounds(problem), self.interior):
            lo += [low] * len(indices)
            hi += [high] * len(indices)
        reps = len(block.taus)
        return np.tile(lo, reps).astype(float), np.tile(hi, reps).astype(float)

    def bound_variables(self, problem, lower, upper):
        bounds = self._level_bounds(problem)
        for name in ("P", "Pm"):
            if getattr(lower, name) is not None:
                for r in (0, 1):
                    getattr(lower, name)[r, :], getattr(upper, name)[r, :] = bounds[r]
        for name in ("A", "Am"):
            if getattr(lower, name) is not None:
                getattr(lower, name)[:], getattr(upper, name)[:] = bounds[2]
        lim, N, n = problem.mission_limits, problem.N, problem.model.n_M
        rates = np.r_[lim.velocity, lim.acceleration][:, None] * np.ones(problem.point_times.size)
        if problem.bounds.mission_factor is not None:  # lowered by the refinement
            rates = rates * problem.bounds.mission_factor
        for name, columns in (("M", slice(0, N + 1)), ("Mm", slice(N + 1, None))):
            low, high = getattr(lower, name), getattr(upper, name)
            if low is not None:
                low[:n], high[:n] = lim.lower[:, None], lim.upper[:, None]
                low[n:], high[n:] = -rates[:, columns], rates[:, columns]
        # the ends: sigma 0 and 1, the mission arm at rest (no torque step either)
        lower.P[:, 0] = upper.P[:, 0] = 0.0
        lower.P[0, N] = upper.P[0, N] = 1.0
        lower.P[1, N] = upper.P[1, N] = 0.0
        if problem.transcription.has_midpoints:
            lower.A[:, [0, N]] = upper.A[:, [0, N]] = 0.0
        else:  # the trapezoidal rule's acceleration is constant on an interval
            lower.A[:, [0, 1, N - 1, N]] = upper.A[:, [0, 1, N - 1, N]] = 0.0

    @staticmethod
    def motion(problem, result) -> tuple:
        """The re-timed mission of a plan on the continuous motion (:data:`TORQUE_POINTS` per
        interval and the result's own samples): ``(t (T,) [s], q, q_dot, q_ddot (T, n_M))``;
        without the plan's solution (or a problem that cannot re-time), the result's samples."""
        solution = getattr(getattr(result, "solver", None), "solution", None)
        if solution is None or not hasattr(problem, "mission_motion"):
            return result.t, result.q_M, result.q_dot_M, result.q_ddot_M
        s = np.linspace(0.0, 1.0, TORQUE_POINTS)
        t = ((np.arange(problem.N)[:, None] + s[None, :]) * problem.h).ravel()
        t = np.union1d(t, np.asarray(result.t, dtype=float))
        t = np.unique(np.minimum(t, problem.N * problem.h))
        return (t, *problem.mission_motion(solution).sample(t))

    @classmethod
    def ratios(cls, problem, result) -> tuple[np.ndarray, dict]:
        """The mission joints' excess over their limits on the continuous motion, relative to
        each limit: ``(t, {kind: (T, n_M)})``, ``kind`` ``position`` (beyond the nearer end of
        the range, over the range's width), ``velocity``, ``acceleration`` (over the limit);
        zero within the limits (and for an infinite one)."""
        lim = problem.mission_limits
        t, q, qd, qdd = cls.motion(problem, result)
        with np.errstate(invalid="ignore", divide="ignore"):
            width = np.where(np.isfinite(lim.upper - lim.lower), lim.upper - lim.lower, np.inf)
            beyond = np.maximum(q - lim.upper, lim.lower - q)
            ratios = {
                "position": np.maximum(beyond, 0.0) / width,
                "velocity": np.maximum(np.abs(qd) / lim.velocity - 1.0, 0.0),
                "acceleration": np.maximum(np.abs(qdd) / lim.acceleration - 1.0, 0.0),
            }
        return t, {k: np.nan_to_num(v, nan=0.0, posinf=0.0) for k, v in ratios.items()}

    @staticmethod
    def _limit(problem, kind: str, col: int) -> tuple[float, str]:
        """The limit of ``kind`` of mission joint ``col`` and its unit (of a prismatic joint in
        m, of a revolute one in rad; per s, s^2)."""
        lim, robot = problem.mission_limits, problem.robot
        unit = robot.joint_units[int(robot.mission_indices[col])]
        if kind == "velocity":
            return float(lim.velocity[col]), f"{unit}/s"
        if kind == "acceleration":
            return float(lim.acceleration[col]), f"{unit}/s^2"
        return float(lim.upper[col] - lim.lower[col]), unit

    def check(self, problem, result):
        """The mission joints' worst breach of their position, velocity and acceleration
        limits on the continuous re-timed motion (between the points on a curved path), ranked
        by the breach relative to its limit (a position's to the range's width), reported in
        the joint's unit; breaches below :data:`LIMIT_TOLERANCE` of the limit are none."""
        t, ratios = self.ratios(problem, result)
        worst = None
        for kind, ratio in ratios.items():
            if not ratio.size or ratio.max() <= LIMIT_TOLERANCE:
                continue
            row, col = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
            if worst is None or ratio[row, col] > worst[0]:
                worst = (float(ratio[row, col]), kind, int(row), int(col))
        if worst is None:
            return None
        ratio, kind, row, col = worst
        limit, unit = self._limit(problem, kind, col)
        joint = problem.robot.mission.joints[col]
        return Violation(f"{kind} limit of {joint}", float(t[row]), ratio * limit, unit)

    def tighten(self, problem, result):
        """The mission joints' velocity and acceleration bounds lowered at the points of every
        interval where the continuous motion breaks a limit (by more than
        :data:`LIMIT_TOLERANCE` of it), scaled by ``(1 - TORQUE_MARGIN) / (1 + excess)``
        there. Positions are the path's, whatever the timing: not tightened."""
        t, ratios = self.ratios(problem, result)
        N, n = problem.N, problem.model.n_M
        interval = np.minimum((t / problem.h).astype(int), N - 1)
        per_interval = np.zeros((N, 2 * n))
        np.maximum.at(
            per_interval, interval, np.hstack([ratios["velocity"], ratios["acceleration"]])
        )
        broken = per_interval > LIMIT_TOLERANCE
        if not broken.any():
            return {}, []
        scale = np.where(broken, (1.0 - TORQUE_MARGIN) / (1.0 + per_interval), 1.0)
        before = problem.bounds.mission_factor
        before = np.ones((2 * n, problem.point_times.size)) if before is None else before
        factor = before.copy()
        mids = problem.transcription.has_midpoints
        for k in np.flatnonzero(broken.any(axis=1)):
            # a node two broken intervals share takes the lower of their scales, not both
            for c in [k, k + 1] + ([N + 1 + k] if mids else []):
                factor[:, c] = np.minimum(factor[:, c], before[:, c] * scale[k])
        worst, count = float(per_interval.max()), int(broken.any(axis=1).sum())
        words = f"mission joint bounds on {count} intervals (worst +{worst:.3%})"
        return {"mission_factor": factor}, [words]

    def accept(self, problem, result):
        """A plan whose re-timed mission still breaks a mission joint's limit after the
        refinement fails, naming the joint, the limit, the amount, the time and the rounds."""
        worst = self.check(problem, result)
        if worst is None:
            return
        kind, joint = worst.constraint.split(" limit of ")
        col = problem.robot.mission.joints.index(joint)
        limit, _ = self._limit(problem, kind, col)
        lim = problem.mission_limits
        if kind == "position":
            said = (
                f"{joint} leaves its range [{lim.lower[col]:g}, {lim.upper[col]:g}] "
                f"{worst.unit} by {worst.amount:.4g} {worst.unit} (the path's, whatever its "
                "timing)"
            )
        else:
            said = (
                f"{joint} exceeds its {kind} limit {limit:g} {worst.unit} by {worst.amount:.4g} "
                f"{worst.unit} ({worst.amount / limit:+.3%})"
            )
        raise PlannerSolverError(
            f"no free timing keeps the mission joints' limits: {said} at "
            f"t = {worst.time:.3f} s, {rounds_tried(result)}",
            "Mission_Limit",
            result,
            worst.constraint,
            worst.time,
            worst.amount,
        )
