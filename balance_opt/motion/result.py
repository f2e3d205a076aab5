"""The result of a balance plan, shared by every method so any two compare field by field;
it knows nothing of figures (:func:`balance_opt.report.plots.plot_result` draws one)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from balance_opt.model.limits import JointLimits
from balance_opt.motion.so3 import relative_rotation, rotation_angle, rpy_from_quaternion

if TYPE_CHECKING:
    import pandas

#: Excess below which a limit counts as met [rad, rad/s, rad/s^2]: solver tolerance, not physics.
LIMIT_TOLERANCE = 1e-6
#: Relative excess over an effort limit that still counts as inside (numerical tolerance): the
#: optimal planner's refinement and the reported effort figures share it.
EFFORT_TOLERANCE = 1e-6
#: Relative momentum residual above which a plan's samples do not follow momentum conservation
#: (a motion too fast for its samples, or a law that ran away): its figures are not to be
#: trusted. Sound plans stay below 1e-6 (the finite-difference floor of the check).
UNTRUSTED_RESIDUAL = 1e-3


@dataclass(frozen=True)
class LimitViolation:
    """One stretch of time in which a joint is outside one of its limits.

    Attributes:
        joint: joint name.
        kind: ``"position"``, ``"velocity"`` or ``"acceleration"``.
        t_start: first sample outside the limit [s].
        t_end: last sample outside the limit [s].
        worst_excess: largest distance beyond the limit over the stretch [rad, rad/s, rad/s^2].
        step: for a rate step (:func:`rate_steps`), the jump of the joint rate [rad/s]: an
            instantaneous change, an acceleration no arm performs; ``worst_excess`` is then the
            jump over one sample interval less the limit.
    """

    joint: str
    kind: str
    t_start: float
    t_end: float
    worst_excess: float
    step: float | None = None

    def __str__(self) -> str:
        unit = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2"}[self.kind]
        if self.step is not None:
            return (
                f"{self.joint}: rate step of {self.step:.4g} rad/s at t = {self.t_start:.3f} s, "
                f"an instantaneous change (no finite acceleration; over one sample "
                f"{self.worst_excess:.4g} rad/s^2 beyond the acceleration limit)"
            )
        return (
            f"{self.joint}: {self.kind} limit exceeded by up to {self.worst_excess:.4g} {unit} "
            f"from t = {self.t_start:.3f} s to {self.t_end:.3f} s"
        )


def limit_bounds(limits: JointLimits, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of each joint's limit of ``kind`` (a rate limit is symmetric)."""
    if kind == "position":
        return limits.lower, limits.upper
    value = getattr(limits, kind)
    return -value, value


def find_limit_violations(
    t, names, q, q_dot, q_ddot, limits: JointLimits, tolerance: float = LIMIT_TOLERANCE
) -> list[LimitViolation]:
    """Every stretch of samples (times ``t`` (T,)) where a joint of ``names`` leaves its
    position, velocity or acceleration ``limits`` by more than ``tolerance``; ``q``, ``q_dot``,
    ``q_ddot`` are (T, n)."""
    found = []
    checks = (
        ("position", q, np.maximum(q - limits.upper, limits.lower - q)),
        ("velocity", q_dot, np.abs(q_dot) - limits.velocity),
        ("acceleration", q_ddot, np.abs(q_ddot) - limits.acceleration),
    )
    for kind, values, excess in checks:
        if values is None:
            continue
        for j, name in enumerate(names):
            outside = excess[:, j] > tolerance
            if not outside.any():
                continue
            edges = np.diff(np.r_[0, outside.astype(int), 0])
            for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
                worst = float(excess[start:stop, j].max())
                found.append(LimitViolation(name, kind, float(t[start]), float(t[stop - 1]), worst))
    return found


def rate_steps(
    t: float, dt: float, names, before, after, limits: JointLimits
) -> list[LimitViolation]:
    """The joints of ``names`` whose rate jumps at time ``t`` [s] (from ``before`` to ``after``,
    (n,) [rad/s]) by more than :data:`LIMIT_TOLERANCE` while they have an acceleration limit,
    as acceleration violations: a step is an infinite acceleration; ``worst_excess`` is the
    jump over the sample interval ``dt`` [s] less the limit (what finite differences of the
    samples give), at least 0."""
    jump = np.abs(np.asarray(after, dtype=float) - np.asarray(before, dtype=float))
    found = []
    for j, name in enumerate(names):
        limit = float(limits.acceleration[j])
        if np.isfinite(limit) and jump[j] > LIMIT_TOLERANCE:
            excess = max(float(jump[j]) / dt - limit, 0.0)
            found.append(LimitViolation(name, "acceleration", t, t, excess, float(jump[j])))
    return found


class AttitudeHistory:
    """The base attitude read two ways, for any motion with a ``quaternion`` array (T, 4)."""

    quaternion: np.ndarray

    @property
    def rpy(self) -> np.ndarray:
        """Base roll, pitch, yaw (T, 3) [rad] (``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
        return rpy_from_quaternion(self.quaternion)

    @property
    def angle(self) -> np.ndarray:
        """Base rotation from the initial attitude, ``|log(R_0^T R)|`` (T,) [rad]."""
        return rotation_angle(relative_rotation(self.quaternion[:1], self.quaternion))


#: Columns of :meth:`BalanceResult.columns` after the joints.
ATTITUDE_COLUMNS = tuple(
    "base_" + c for c in ("qx", "qy", "qz", "qw", "roll", "pitch", "yaw", "angle")
)
#: ``BalanceResult.info`` entries left out of ``metrics.json`` and of summaries (kept in the
#: NPZ): large arrays.
BULKY_INFO_KEYS = ("history",)
#: Rows of :meth:`BalanceResult.__repr__` at most (a notebook cell's worth).
REPR_LINES = 12


@dataclass(eq=False)
class BalanceResult(AttitudeHistory):
    """A balance motion and the base attitude it produces, sampled on a time grid.

    Attitude quantities are the base orientation relative to the world (the initial attitude
    is the identity unless the task says otherwise); the base angular velocity is in the base
    frame. Joint arrays are (T, n) with columns in the order of ``mission_joints`` and
    ``balance_joints``.

    Attributes:
        method: what produced it (``"analytic"``, ``"optimal"``, ``"mission-only"``,
            ``"balance-only"``, ``"simulation"``).
        t: sample times [s].
        mission_joints, balance_joints: joint names.
        q_M, q_dot_M, q_ddot_M: mission arm [rad, rad/s, rad/s^2].
        q_B, q_dot_B, q_ddot_B: balance arms [rad, rad/s, rad/s^2].
        quaternion: base attitude (T, 4), (x, y, z, w).
        omega: base angular velocity (T, 3), base frame [rad/s].
        momentum_residual: relative angular momentum residual (T,), ``|L(t) - L0|`` over the
            largest angular momentum the joints carry plus ``|L0|``, recomputed from the
            exported samples alone (:mod:`balance_opt.motion.momentum_check`; a simulation's
            from its state).
        sigma_min: smallest singular value of ``J_wB`` along the path (T,).
        violations: every joint-limit violation of the balance (and mission) joints.
        info: method-specific details (damping used, the integrator's statistics, ...), plain
            data only; an optimal plan's solver details are in ``solver`` (:meth:`details`
            joins both).
        solver: for optimal plans, how the plan was solved and checked: every Ipopt solve, the
            stages, the refinement, the re-simulation's checks, the timings
            (:class:`~balance_opt.optimal.refine.PlanReport`); ``None`` for the other methods.

    Equality (``==``) compares the motion: method, joint names, every array (exactly, NaN equal
    to NaN) and the limit violations, not ``info`` or ``solver``; it never raises. Results are
    mutable, hence unhashable.
    """

    method: str
    t: np.ndarray
    mission_joints: tuple[str, ...]
    balance_joints: tuple[str, ...]
    q_M: np.ndarray
    q_dot_M: np.ndarray
    q_ddot_M: np.ndarray
    q_B: np.ndarray
    q_dot_B: np.ndarray
    q_ddot_B: np.ndarray
    quaternion: np.ndarray
    omega: np.ndarray
    momentum_residual: np.ndarray
    sigma_min: np.ndarray
    violations: list[LimitViolation] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    solver: Any = field(default=None, repr=False)

    @classmethod
    def from_arm_vectors(
        cls,
        robot,
        method: str,
        t,
        q,
        q_dot,
        q_ddot,
        quaternion,
        omega,
        momentum_residual,
        sigma_min,
        info=None,
    ) -> BalanceResult:
        """A result from whole arm-vector arrays (T, n) of ``robot``: split into the mission and
        balance columns, with every limit violation found on the samples."""
        M, B = robot.mission_indices, robot.balance_indices
        return cls(
            method=method,
            t=t,
            mission_joints=robot.mission.joints,
            balance_joints=tuple(j for a in robot.balance_arms for j in a.joints),
            q_M=q[:, M],
            q_dot_M=q_dot[:, M],
            q_ddot_M=q_ddot[:, M],
            q_B=q[:, B],
            q_dot_B=q_dot[:, B],
            q_ddot_B=q_ddot[:, B],
            quaternion=quaternion,
            omega=omega,
            momentum_residual=momentum_residual,
            sigma_min=sigma_min,
            violations=find_limit_violations(t, robot.joint_names, q, q_dot, q_ddot, robot.limits),
            info=dict(info or {}),
        )

    @property
    def max_drift(self) -> float:
        """Largest base rotation from the initial attitude over the motion [rad]."""
        return float(self.angle.max())

    @property
    def final_drift(self) -> float:
        """Base rotation from the initial attitude at the end of the motion [rad]."""
        return float(self.angle[-1])

    def summary(self) -> dict[str, Any]:
        """Scalar figures of merit, plain floats (for tables and ``metrics.json``)."""
        return {
            "method": self.method,
            "duration_s": float(self.t[-1] - self.t[0]),
            "max_drift_rad": self.max_drift,
            "final_drift_rad": self.final_drift,
            "max_base_rate_rad_s": float(np.linalg.norm(self.omega, axis=1).max()),
            "peak_balance_rate_rad_s": float(np.abs(self.q_dot_B).max())
            if self.q_dot_B.size
            else 0.0,
            "max_momentum_residual": float(np.max(self.momentum_residual)),
            "min_sigma_min": float(np.min(self.sigma_min)),
            "limit_violations": len(self.violations),
        }

    def warnings(self) -> list[str]:
        """What makes this plan untrustworthy, in words (empty for a sound plan): a momentum
        residual above :data:`UNTRUSTED_RESIDUAL`."""
        residual = float(np.nanmax(self.momentum_residual)) if self.t.size > 1 else 0.0
        if not residual > UNTRUSTED_RESIDUAL:
            return []
        peak = float(np.abs(self.q_ddot_B).max()) if self.q_ddot_B.size else 0.0
        return [
            f"untrustworthy: relative momentum residual {residual:.3g} > {UNTRUSTED_RESIDUAL:g} "
            f"(the samples do not follow momentum conservation; peak balance joint "
            f"acceleration {peak:.3g} rad/s^2, smallest singular value of J_wB "
            f"{float(np.min(self.sigma_min)):.3g})"
        ]

    # ------------------------------------------------------------------ notebook helpers
    @property
    def status(self) -> str:
        """The solver's status for optimal plans (``solver.status``; a plan joined from two
        phases, the one its ``info`` names), ``"ok"`` for the other methods (which either return
        a motion or raise)."""
        if "status" not in self.info and self.solver is not None:
            return str(self.solver.status)
        return str(self.info.get("status", "ok"))

    def details(self) -> dict[str, Any]:
        """What the written files hold of the method's details (the NPZ's ``info``,
        ``metrics.json``'s ``details``): ``info`` followed, for an optimal plan, by its solver's
        report as plain data (``solver.as_info()``), built on each call; an entry ``info`` has
        itself wins (a plan joined from two phases holds both phases' figures there)."""
        out = dict(self.info)
        if self.solver is not None:
            out.update((k, v) for k, v in self.solver.as_info().items() if k not in out)
        return out

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BalanceResult):
            return NotImplemented
        for f in fields(self):
            if f.name in ("info", "solver"):
                continue
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                a, b = np.asarray(a), np.asarray(b)
                if a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # mutable value type

    def __repr__(self) -> str:
        duration = float(self.t[-1] - self.t[0]) if self.t.size else 0.0
        lines = [
            f"BalanceResult(method={self.method!r}, status={self.status!r})",
            f"  time       {duration:.4g} s, {self.t.size} samples",
            f"  mission    {_joint_list(self.mission_joints)}",
            f"  balance    {_joint_list(self.balance_joints)}",
        ]
        if self.t.size:
            lines.append(
                f"  drift      peak {_angle(self.max_drift)}, final {_angle(self.final_drift)}"
            )
            if self.q_dot_B.size:
                peak_rate = float(np.abs(self.q_dot_B).max())
                lines.append(f"  rates      balance joints up to {peak_rate:.4g} rad/s")
        if self.violations:
            lines.append(
                f"  limits     {len(self.violations)} violation(s), first: {self.violations[0]}"
            )
        else:
            lines.append("  limits     all met")
        lines += [f"  WARNING    {w}" for w in self.warnings()]
        return "\n".join(lines[:REPR_LINES])

    def columns(self) -> tuple[list[str], np.ndarray]:
        """Column names and (T, k) values of the motion's table (its CSV file,
        ``docs/outputs.md``): ``time`` [s], one per arm joint by name (mission joints first), the
        base attitude as a quaternion (``base_qx .. base_qw``), as roll, pitch, yaw and as the
        rotation from the start (``base_angle``)."""
        names = ["time", *self.mission_joints, *self.balance_joints, *ATTITUDE_COLUMNS]
        values = np.column_stack(
            [self.t, self.q_M, self.q_B, self.quaternion, self.rpy, self.angle]
        )
        return names, values

    def to_dataframe(self) -> pandas.DataFrame:
        """The :meth:`columns` as a table indexed by ``time``; the unit of each column is in
        ``df.attrs["units"]``."""
        import pandas as pd

        names, values = self.columns()
        df = pd.DataFrame(values[:, 1:], index=pd.Index(self.t, name="time"), columns=names[1:])
        units = dict.fromkeys(names[1 : -len(ATTITUDE_COLUMNS)], "rad")
        units.update(dict.fromkeys(ATTITUDE_COLUMNS[:4], "1"))
        units.update(dict.fromkeys(ATTITUDE_COLUMNS[4:], "rad"))
        df.attrs["units"] = {"time": "s", **units}
        df.attrs["method"] = self.method
        return df


def _joint_list(names: tuple[str, ...], limit: int = 4) -> str:
    """``"a, b, c (3)"``: the first ``limit`` names and the count."""
    shown = ", ".join(names[:limit]) + (", ..." if len(names) > limit else "")
    return f"{shown} ({len(names)} joints)"


def _angle(value: float) -> str:
    """An angle in radians and degrees."""
    return f"{value:.4g} rad ({np.degrees(value):.3g} deg)"
