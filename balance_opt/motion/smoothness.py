"""Smoothness figures of merit of a sampled joint motion, per joint: largest jerk (by finite
differences of the accelerations), acceleration reversals counted with hysteresis
(``REVERSAL_FRACTION`` of the acceleration limit, else of the largest ``|q_ddot|``) and largest
torque rate (``docs/executable-plans.md``, "Smoothness figures of merit")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Fraction of a joint's acceleration scale (its limit, else its largest acceleration) by which
#: the acceleration must move back from an extremum to count as a reversal. A tenth ignores the
#: solver's ripples on a plan's acceleration while any swing of a fifth of the limit's range
#: counts.
REVERSAL_FRACTION = 0.1


@dataclass(frozen=True)
class Smoothness:
    """Smoothness figures of merit of a motion, per joint: ``max_jerk`` [rad/s^3],
    ``reversals``, ``max_torque_rate`` [N m/s] (``None`` without torques) and the
    ``reversal_threshold`` used [rad/s^2]."""

    joints: tuple[str, ...]
    max_jerk: np.ndarray
    reversals: np.ndarray
    max_torque_rate: np.ndarray | None
    reversal_threshold: np.ndarray

    def to_dict(self) -> dict:
        """Plain data, per joint name (for ``metrics.json``)."""
        out = {}
        for i, joint in enumerate(self.joints):
            entry = {
                "max_jerk_rad_s3": float(self.max_jerk[i]),
                "acceleration_reversals": int(self.reversals[i]),
                "reversal_threshold_rad_s2": float(self.reversal_threshold[i]),
            }
            if self.max_torque_rate is not None:
                entry["max_torque_rate_Nm_s"] = float(self.max_torque_rate[i])
            out[joint] = entry
        return out


def count_reversals(values: np.ndarray, threshold: float) -> int:
    """Turns of a signal (T,) that move back more than ``threshold`` from the running extremum."""
    values = np.asarray(values, dtype=float)
    if values.size < 2 or not threshold > 0:
        return 0
    count, direction = 0, 0  # +1 rising, -1 falling, 0 until the first swing
    low = high = extremum = values[0]
    for x in values[1:]:
        if direction == 0:
            low, high = min(low, x), max(high, x)
            if x - low > threshold:
                direction, extremum = 1, x
            elif high - x > threshold:
                direction, extremum = -1, x
        elif direction * (x - extremum) > 0:  # further the same way: a new extremum
            extremum = x
        elif direction * (extremum - x) > threshold:  # back past the hysteresis
            count, direction, extremum = count + 1, -direction, x
    return count


def smoothness(t, q_ddot, joints, acceleration_limit=None, tau=None) -> Smoothness:
    """Smoothness figures of merit of a sampled motion: times ``t`` (T,), ``q_ddot`` and
    optional ``tau`` (T, n), ``acceleration_limit`` per joint (``inf`` or ``None``: none).
    ValueError for mismatched shapes or fewer than two samples."""
    t = np.asarray(t, dtype=float).ravel()
    a = np.asarray(q_ddot, dtype=float).reshape(t.size, -1)
    n = a.shape[1]
    if t.size < 2 or len(joints) != n:
        raise ValueError(
            f"smoothness needs at least 2 samples and a name per joint: {t.size} samples, "
            f"{n} joints, {len(joints)} names"
        )
    dt = np.diff(t)[:, None]
    limit = np.full(n, np.inf) if acceleration_limit is None else np.asarray(acceleration_limit)
    scale = np.where(np.isfinite(limit), limit, np.abs(a).max(axis=0))
    threshold = REVERSAL_FRACTION * scale
    rate = None
    if tau is not None:
        tau = np.asarray(tau, dtype=float).reshape(t.size, n)
        rate = np.abs(np.diff(tau, axis=0) / dt).max(axis=0)
    return Smoothness(
        joints=tuple(joints),
        max_jerk=np.abs(np.diff(a, axis=0) / dt).max(axis=0),
        reversals=np.array([count_reversals(a[:, j], threshold[j]) for j in range(n)]),
        max_torque_rate=rate,
        reversal_threshold=threshold,
    )
