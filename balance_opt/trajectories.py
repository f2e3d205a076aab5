"""Mission-arm trajectories in joint space, sampled at any times with position, velocity and
acceleration.

Every trajectory has ``duration`` [s], ``dof`` and ``sample(t) -> (q, q_dot, q_ddot)`` for an
array of times ``t`` (T,), each (T, dof). Before ``0`` and after ``duration`` the arm rests at
its end points.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.interpolate import CubicSpline, make_interp_spline

from .errors import TrajectoryError


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


def _check_duration(duration) -> float:
    duration = float(duration)
    if not duration > 0 or not np.isfinite(duration):
        raise TrajectoryError(f"duration must be a positive number of seconds, got {duration}")
    return duration


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
        self.duration = _check_duration(duration)
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
    """A smooth motion through via points, at rest at the first and last.

    The profile is a quintic B-spline through the points with zero velocity and acceleration at
    both ends: C4 inside, so accelerations (Eq. 32) and jerks are continuous.

    Args:
        times: strictly increasing times of the points [s], the first 0.
        points: (K, dof) joint positions [rad], K >= 2.
    """

    def __init__(self, times: Sequence[float], points):
        self.times = np.asarray(times, dtype=float)
        self.points = np.atleast_2d(np.asarray(points, dtype=float))
        if self.points.shape[0] != self.times.size or self.times.size < 2:
            raise TrajectoryError(f"via points need matching times and points, at least 2; got "
                                  f"{self.times.size} times and {self.points.shape[0]} points")
        if self.times[0] != 0.0 or np.any(np.diff(self.times) <= 0):
            raise TrajectoryError(f"via-point times must start at 0 and increase strictly, got {self.times.tolist()}")
        self.duration = float(self.times[-1])
        self.dof = self.points.shape[1]
        zeros = [(1, np.zeros(self.dof)), (2, np.zeros(self.dof))]
        if self.times.size == 2:  # a B-spline of degree 5 needs more points: the quintic PTP is that spline
            self._ptp = PointToPoint(self.points[0], self.points[1], self.duration)
            self._spline = None
        else:
            self._spline = make_interp_spline(self.times, self.points, k=5, bc_type=(zeros, zeros))

    def sample(self, t):
        if self._spline is None:
            return self._ptp.sample(t)
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        s = self._spline
        return s(t), s(t, 1), s(t, 2)


class CsvTrajectory(JointTrajectory):
    """A trajectory read from a CSV file: a ``time`` column, one column per joint by name.

    Samples are interpolated with a cubic spline (C2). Columns for other joints are ignored;
    times must start at 0 and increase strictly.

    Args:
        path: CSV file.
        joint_names: the columns to read, in the arm's joint order.
        time_column: name of the time column.

    Raises:
        TrajectoryError: naming the file, and the line or column at fault.
    """

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
            raise TrajectoryError(f"{where}: needs a header line and at least 2 samples, found {max(len(rows) - 1, 0)}")
        header = [h.strip() for h in rows[0]]
        missing = [c for c in (time_column, *self.joint_names) if c not in header]
        if missing:
            raise TrajectoryError(f"{where}: line 1: missing column(s) {', '.join(missing)}; header has {', '.join(header)}")
        cols = [header.index(c) for c in (time_column, *self.joint_names)]
        data = np.empty((len(rows) - 1, len(cols)))
        for i, row in enumerate(rows[1:]):
            if len(row) != len(header):
                raise TrajectoryError(f"{where}: line {i + 2}: {len(row)} fields, header has {len(header)}")
            for k, c in enumerate(cols):
                try:
                    data[i, k] = float(row[c])
                except ValueError:
                    raise TrajectoryError(f"{where}: line {i + 2}, column '{header[c]}': "
                                          f"not a number: {row[c]!r}") from None
        if not np.all(np.isfinite(data)):
            raise TrajectoryError(f"{where}: non-finite values")
        t = data[:, 0]
        if t[0] != 0.0:
            raise TrajectoryError(f"{where}: line 2: time must start at 0, got {t[0]}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise TrajectoryError(f"{where}: line {bad[0] + 3}: time does not increase ({t[bad[0]]} then {t[bad[0] + 1]})")
        self.duration = float(t[-1])
        self.dof = len(self.joint_names)
        self._spline = CubicSpline(t, data[:, 1:], bc_type="natural")

    def sample(self, t):
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        s = self._spline
        return s(t), s(t, 1), s(t, 2)
