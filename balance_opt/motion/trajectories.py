"""Joint-space trajectories: ``duration`` [s], ``dof`` and ``sample(t) -> (q, q_dot, q_ddot)``
(each (T, dof)); at rest at the end points outside ``[0, duration]``."""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError, TrajectoryError
from balance_opt.model.summary import vector_text
from balance_opt.motion.result import BalanceResult


class JointTrajectory:
    """Base class: a joint-space trajectory on ``[0, duration]``."""

    duration: float
    dof: int

    def sample(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError

    @property
    def start(self) -> np.ndarray:
        return self.sample(np.array([0.0]))[0][0]

    @property
    def end(self) -> np.ndarray:
        return self.sample(np.array([self.duration]))[0][0]


class PointToPoint(JointTrajectory):
    """Rest-to-rest motion from ``q0`` to ``qf`` with a quintic time law (the paper's PTP):
    ``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5``, zero velocity and acceleration at both ends.

    Args:
        q0, qf: start and goal [rad].
        duration: motion time [s].
    """

    def __init__(self, q0, qf, duration: float):
        self.q0 = np.asarray(q0, dtype=float).ravel()
        self.qf = np.asarray(qf, dtype=float).ravel()
        if self.q0.shape != self.qf.shape:
            raise TrajectoryError(f"start has {self.q0.size} joints but goal has {self.qf.size}")
        self.duration = T = float(duration)
        if not T > 0 or not np.isfinite(T):
            raise TrajectoryError(f"duration must be a positive number of seconds, got {T}")
        self.dof = self.q0.size

    def sample(self, t):
        T = self.duration
        tau = np.clip(np.atleast_1d(np.asarray(t, dtype=float)) / T, 0.0, 1.0)[:, None]
        s = tau**3 * (10 - 15 * tau + 6 * tau**2)
        ds = 30 * tau**2 * (1 - tau) ** 2 / T
        dds = 60 * tau * (1 - tau) * (1 - 2 * tau) / T**2
        dq = self.qf - self.q0
        return self.q0 + s * dq, ds * dq, dds * dq


class ViaPoints(JointTrajectory):
    """A smooth motion through via points (``times`` from 0, ``points`` (K, dof)), at rest at the
    first and last: a quintic B-spline, C4 inside, so accelerations and jerks are continuous."""

    def __init__(self, times: Sequence[float], points):
        self.times = np.asarray(times, dtype=float)
        self.points = np.atleast_2d(np.asarray(points, dtype=float))
        if self.points.shape[0] != self.times.size or self.times.size < 2:
            raise TrajectoryError(
                f"via points need matching times and points, at least 2; got "
                f"{self.times.size} times and {self.points.shape[0]} points"
            )
        if self.times[0] != 0.0 or np.any(np.diff(self.times) <= 0):
            raise TrajectoryError(
                f"via-point times must start at 0 and increase strictly, got {self.times.tolist()}"
            )
        self.duration = float(self.times[-1])
        self.dof = self.points.shape[1]
        zeros = [(1, np.zeros(self.dof)), (2, np.zeros(self.dof))]
        if (
            self.times.size == 2
        ):  # a B-spline of degree 5 needs more points: the quintic PTP is that spline
            self._ptp = PointToPoint(self.points[0], self.points[1], self.duration)
            self._spline = None
        else:
            from scipy.interpolate import make_interp_spline  # a slow import: only when used

            self._spline = make_interp_spline(self.times, self.points, k=5, bc_type=(zeros, zeros))

    def sample(self, t):
        if self._spline is None:
            return self._ptp.sample(t)
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        s = self._spline
        return s(t), s(t, 1), s(t, 2)


# ---------------------------------------------------------------------------------- sampled
class SampledTrajectory(JointTrajectory):
    """A joint trajectory given as samples (T,) and (T, dof): quintic Hermite with positions,
    velocities and accelerations (to replay a plan), cubic Hermite without accelerations, a
    natural cubic spline from positions alone. Times start at 0 and increase strictly.

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
            from scipy.interpolate import CubicSpline  # a slow import: only when used

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


class MissionWindow:
    """A joint motion over ``[t0, t1]`` of a longer one (a motion after a capture, the mission of
    a capture's phase, of a re-plan), its clock starting at 0.

    Attributes:
        dof, duration, start: as a trajectory's.
    """

    def __init__(self, mission, t0: float, t1: float):
        self.mission, self.t0 = mission, float(t0)
        self.duration = float(t1) - float(t0)
        self.dof = mission.dof
        self.start = np.asarray(mission.sample(np.array([self.t0]))[0])[0]

    def sample(self, t):
        return self.mission.sample(np.asarray(t, dtype=float) + self.t0)


class CsvTrajectory(SampledTrajectory):
    """A trajectory read from a CSV file: a ``time`` column, one column per joint by name
    (natural cubic spline); TrajectoryError names the file, and the line or column at fault."""

    def __init__(self, path: str | Path, joint_names: Sequence[str], time_column: str = "time"):
        self.path = Path(path)
        self.joint_names = tuple(joint_names)
        where = str(self.path)
        try:
            with self.path.open(newline="") as fh:
                rows = list(csv.reader(fh))
        except OSError as exc:
            raise TrajectoryError(f"{where}: cannot read trajectory CSV: {exc.strerror}") from None
        rows = [r for r in rows if r and any(c.strip() for c in r)]
        if len(rows) < 3:
            raise TrajectoryError(
                f"{where}: needs a header line and at least 2 samples, found {max(len(rows) - 1, 0)}"
            )
        header = [h.strip() for h in rows[0]]
        missing = [c for c in (time_column, *self.joint_names) if c not in header]
        if missing:
            raise TrajectoryError(
                f"{where}: line 1: missing column(s) {', '.join(missing)}; header has {', '.join(header)}"
            )
        cols = [header.index(c) for c in (time_column, *self.joint_names)]
        data = np.empty((len(rows) - 1, len(cols)))
        for i, row in enumerate(rows[1:]):
            if len(row) != len(header):
                raise TrajectoryError(
                    f"{where}: line {i + 2}: {len(row)} fields, header has {len(header)}"
                )
            for k, c in enumerate(cols):
                try:
                    data[i, k] = float(row[c])
                except ValueError:
                    raise TrajectoryError(
                        f"{where}: line {i + 2}, column '{header[c]}': not a number: {row[c]!r}"
                    ) from None
        if not np.all(np.isfinite(data)):
            raise TrajectoryError(f"{where}: non-finite values")
        t = data[:, 0]
        if t[0] != 0.0:
            raise TrajectoryError(f"{where}: line 2: time must start at 0, got {t[0]}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise TrajectoryError(
                f"{where}: line {bad[0] + 3}: time does not increase ({t[bad[0]]} then {t[bad[0] + 1]})"
            )
        super().__init__(t, data[:, 1:])


TrajectoryLike = JointTrajectory | Callable | tuple


def as_sampler(trajectory: TrajectoryLike, dof: int, what: str) -> tuple[Callable, float | None]:
    """``(sample, duration)`` for a trajectory given as an object with ``sample(t)``, a callable
    ``f(t) -> (q, q_dot, q_ddot)``, a tuple ``(t, q[, q_dot[, q_ddot]])``, or a
    :class:`BalanceResult` (its ``what`` part, interpolated); TrajectoryError for a wrong number
    of joints."""
    if isinstance(trajectory, tuple):
        trajectory = SampledTrajectory(*trajectory)
    elif isinstance(trajectory, BalanceResult):
        trajectory = SampledTrajectory.from_result(trajectory, what)
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


def arm_samples(robot, sample_M: Callable, sample_B: Callable, t) -> list[np.ndarray]:
    """``[q, q_dot, q_ddot]`` (T, n) each: mission and balance samples at times ``t`` stacked
    into the robot's arm vectors."""
    out = [np.empty((t.size, robot.n)) for _ in range(3)]
    for samples, cols in (
        (sample_M(t), robot.mission_indices),
        (sample_B(t), robot.balance_indices),
    ):
        for full, part in zip(out, samples):
            full[:, cols] = part
    return out


# ---------------------------------------------------------------------------------- Cartesian goals
#: Inverse kinematics: distance to the goal position that counts as reached [m].
IK_POSITION_TOLERANCE = 1e-6
#: Inverse kinematics: angle to the goal orientation that counts as reached [rad].
IK_ORIENTATION_TOLERANCE = 1e-6
#: Damping of the Gauss-Newton steps [m or rad]: bounds the steps near singular configurations.
IK_DAMPING = 1e-3
#: Largest joint step of one Gauss-Newton iteration [rad].
IK_MAX_STEP = 0.5
#: Iterations per start, and starts (the arm's start, then seeded random ones within the limits).
IK_MAX_ITERATIONS = 200
IK_STARTS = 12
IK_SEED = 0
#: Range sampled for a joint without finite limits [rad].
IK_UNLIMITED_RANGE = np.pi
#: How far from orthonormal a goal rotation matrix may be.
ROTATION_ATOL = 1e-9


def _goal_rotation(orientation) -> np.ndarray | None:
    """A goal orientation (quaternion (x, y, z, w) or 3 x 3 rotation matrix) as a matrix."""
    if orientation is None:
        return None
    rot = np.asarray(orientation, dtype=float)
    if rot.shape == (3, 3):
        orthonormal = np.allclose(rot.T @ rot, np.eye(3), rtol=0, atol=ROTATION_ATOL)
        if not orthonormal or np.linalg.det(rot) <= 0:
            raise TrajectoryError("Cartesian goal orientation matrix is not a rotation")
        rot = pin.Quaternion(rot).coeffs()  # as a quaternion: one normalisation for both forms
    if rot.size == 4 and np.all(np.isfinite(rot)) and np.linalg.norm(rot) > 0:
        x, y, z, w = rot.ravel() / np.linalg.norm(rot)
        return pin.Quaternion(w, x, y, z).toRotationMatrix()
    raise TrajectoryError(
        "Cartesian goal orientation must be a quaternion (x, y, z, w) or a 3 x 3 rotation "
        f"matrix, got {rot.tolist()}"
    )


def solve_cartesian_goal(robot, q_start, position, orientation=None) -> np.ndarray:
    """The joint goal [rad] that puts the mission end effector on a goal pose in the frame of
    the base at its initial pose, by damped Gauss-Newton within the position limits from the
    arm's start, then from seeded random starts. ``orientation``: a quaternion (x, y, z, w), a
    3 x 3 rotation matrix or ``None``.

    Raises:
        TrajectoryError: bad inputs, or the goal is out of reach; ``distance`` [m] and ``angle``
            [rad] say how far the best configuration found stays from it.
    """
    goal_p = np.asarray(position, dtype=float).ravel()
    if goal_p.size != 3 or not np.all(np.isfinite(goal_p)):
        raise TrajectoryError(
            f"Cartesian goal position must be 3 finite numbers [m], got {goal_p.tolist()}"
        )
    goal_R = _goal_rotation(orientation)
    arm = robot.mission
    q_start = np.asarray(q_start, dtype=float).ravel()
    if q_start.size != arm.dof:
        raise TrajectoryError(
            f"Cartesian goal: the {arm.name} arm has {arm.dof} joints, start has {q_start.size}"
        )
    model = robot.model
    data = model.createData()
    frame = model.getFrameId(arm.ee_frame)
    lim = robot.limits.subset(arm.indices)
    lower = np.where(np.isfinite(lim.lower), lim.lower, -IK_UNLIMITED_RANGE)
    upper = np.where(np.isfinite(lim.upper), lim.upper, IK_UNLIMITED_RANGE)
    cols = 6 + arm.indices  # of robot.arm_columns: mimic followers folded in
    q_full = robot.neutral()

    def error(q):
        q_full[arm.indices] = q
        qp = robot.pin_q(q_full)
        J = pin.computeFrameJacobian(model, data, qp, frame, pin.LOCAL_WORLD_ALIGNED)
        J = robot.arm_columns(J)[:, cols]
        pose = data.oMf[frame]
        e = goal_p - pose.translation
        if goal_R is None:
            return e, J[:3], 0.0
        e_rot = pose.rotation @ pin.log3(pose.rotation.T @ goal_R)  # world-frame rotation error
        return np.r_[e, e_rot], J, float(np.linalg.norm(e_rot))

    def reached(e, angle):
        close = np.linalg.norm(e[:3]) <= IK_POSITION_TOLERANCE
        return close and angle <= IK_ORIENTATION_TOLERANCE

    rng = np.random.default_rng(IK_SEED)
    starts = [np.clip(q_start, lower, upper)]
    starts += [rng.uniform(lower, upper) for _ in range(IK_STARTS - 1)]
    best = (np.inf, np.inf, q_start)
    for q in starts:
        for _ in range(IK_MAX_ITERATIONS):
            e, J, angle = error(q)
            if reached(e, angle):
                return q
            step = J.T @ np.linalg.solve(J @ J.T + IK_DAMPING**2 * np.eye(J.shape[0]), e)
            scale = np.abs(step).max() / IK_MAX_STEP
            q = np.clip(q + (step / scale if scale > 1 else step), lower, upper)
        e, _, angle = error(q)
        if reached(e, angle):
            return q
        if (np.linalg.norm(e[:3]), angle) < best[:2]:
            best = (float(np.linalg.norm(e[:3])), angle, q)
    distance, angle, closest_q = best
    closest = goal_p - error(closest_q)[0][:3]
    start = goal_p - error(q_start)[0][:3]
    what = f"{distance:.6g} m" + ("" if goal_R is None else f" and {angle:.6g} rad")
    err = TrajectoryError(
        f"Cartesian goal {goal_p.tolist()} for end effector "
        f"'{arm.ee_frame}' of the {arm.name} arm is unreachable within the "
        f"joint limits: remaining distance {what}; the closest point reached is "
        f"{vector_text(closest)} m (joints {vector_text(closest_q)}), the end effector starts at "
        f"{vector_text(start)} m"
    )
    err.distance, err.angle, err.closest = distance, angle, closest
    raise err


def cartesian_goal(robot, q_start, position, duration: float, orientation=None) -> PointToPoint:
    """Quintic rest-to-rest motion of the mission arm to a Cartesian goal in ``duration`` [s]."""
    goal = solve_cartesian_goal(robot, q_start, position, orientation)
    return PointToPoint(q_start, goal, duration)
