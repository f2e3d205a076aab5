"""The constraint kinds of the balance NLP, each one object that owns everything about it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np

from balance_opt.errors import InputError
from balance_opt.motion.result import EFFORT_TOLERANCE, LIMIT_TOLERANCE, BalanceResult, limit_bounds
from balance_opt.motion.so3 import matrix_from_quaternion
from balance_opt.optimal import collision
from balance_opt.optimal.collocation import Transcription, bernstein_value
from balance_opt.optimal.problem import (
    BalanceProblem,
    Block,
    NLPParameters,
    PlannerSolverError,
    Solution,
    StructureKey,
    unit_of,
)
from balance_opt.optimal.timing import MISSION_LEVELS, PATH_STATES, path_levels

#: The balance joints' derivatives, in the order of their Bernstein levels.
DERIVATIVES = ("position", "velocity", "acceleration")
#: Unit of the peak objective's epigraph variable: ``S = peak^2 / PEAK_SCALE^2`` [rad], so that
#: ``S`` is of order 1 on drifts of a few hundredths of a radian.
PEAK_SCALE = 0.01
#: Exponent ``p`` of the smooth peak (the ``smooth`` stage of the peak objective): the drift's
#: weighted L_p norm to the power p, ``sum_k q_k (|phi_k| / c)^p``.
PEAK_POWER = 16
#: Relative excess of the re-simulated drift over an attitude bound within which the bound
#: counts as kept: the refinement tightens above it, a plan still above it fails.
ATTITUDE_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Violation:
    """The worst breach of a constraint by a motion."""

    constraint: str
    time: float
    amount: float
    unit: str

    def __str__(self) -> str:
        return f"{self.constraint} at t = {self.time:.3f} s, by {self.amount:.4g} {self.unit}"


@dataclass(frozen=True)
class SymbolicNLP:
    """What the constraint rows are made of, in the build (CasADi SX)."""

    key: StructureKey
    transcription: Transcription
    joints: tuple[str, ...]
    state_labels: tuple[str, ...]
    variables: Solution
    levels: list[list]
    x_dot: Any
    torque: Any
    parameters: NLPParameters
    clearance: Any = None
    clearance_labels: tuple[str, ...] = ()
    mission_path: Any = None
    mission_joints: tuple[str, ...] = ()


#: Rows a kind adds to ``g``: a block (not yet stacked) and its values, (rows, columns), symbolic.
Rows = tuple[Block, Any]


def block_rows(nlp: SymbolicNLP, name, labels, unit, values, taus=None, per_interval=False):
    """One block of rows ``values`` named ``name``, a row per label, all in ``unit``, at ``taus``
    (default: every collocation point), or on the intervals that start there."""
    taus = nlp.transcription.point_taus(nlp.key.intervals) if taus is None else taus
    return [(Block(name, tuple(labels), (unit,) * len(labels), taus, per_interval), values)]


def _worst(problem, excess, t: np.ndarray, what: str, unit: str) -> Violation | None:
    """The largest entry of ``excess`` (T, n) above :data:`LIMIT_TOLERANCE`, as a violation of
    ``what`` (formatted with the balance joint of its column) at ``t[row]``, or ``None``."""
    excess = np.asarray(excess, dtype=float)
    if excess.size == 0 or not excess.max() > LIMIT_TOLERANCE:
        return None
    row, col = np.unravel_index(int(np.argmax(excess)), excess.shape)
    what = what.format(problem.balance_joints[col])
    return Violation(what, float(t[row]), float(excess[row, col]), unit)


class Constraint:
    """One kind of constraint of the balance NLP. A kind owns its rows of ``g`` (``(block,
    values)`` pairs, the block named for the failure messages) and their bounds (stacked column
    by column), the bounds it puts on the variables (in place), the check of the re-simulated
    motion (its worst violation beyond :data:`LIMIT_TOLERANCE`), the refinement's tightening
    (changes of :class:`~balance_opt.optimal.problem.Bounds` and what they tighten, in words)
    and the refined plan's acceptance (it raises
    :class:`~balance_opt.optimal.problem.PlannerSolverError` if the plan is no plan)."""

    name = "constraint"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        return []

    def row_bounds(self, problem: BalanceProblem, block: Block) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError(f"{self.name} adds no rows")

    def bound_variables(self, problem: BalanceProblem, lower: Solution, upper: Solution) -> None:
        pass

    def check(self, problem: BalanceProblem, result: BalanceResult) -> Violation | None:
        return None

    def tighten(self, problem: BalanceProblem, result: BalanceResult) -> tuple[dict, list[str]]:
        return {}, []

    def accept(self, problem: BalanceProblem, result: BalanceResult) -> None:
        pass


class Collocation(Constraint):
    """The collocation defects: the attitude by the transcription; the balance joints, a chain
    of integrators, exactly (each node, and each midpoint, is the value of the integrated
    control polynomial, so the continuous plan passes through every node; see
    :mod:`balance_opt.optimal.collocation`). They all vanish."""

    name = "collocation"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        tr, N, v = nlp.transcription, nlp.key.intervals, nlp.variables
        h = nlp.parameters.h
        levels = nlp.levels[:-1]  # the joint states' polynomials, not the control's
        joint_ends = cs.vertcat(*(bernstein_value(level, 1.0) for level in levels))
        joint_mids = cs.vertcat(*(bernstein_value(level, 0.5) for level in levels))
        F = nlp.x_dot
        Fn, Fm = F[:, : N + 1], (F[:, N + 1 :] if tr.has_midpoints else None)
        out = []
        for name, defect in tr.defects(v.X, v.Xm, Fn, Fm, h):
            exact = (
                (v.Xm[3:, :] - joint_mids)
                if name == "Hermite midpoint"
                else (v.X[3:, 1:] - joint_ends)
            )
            block = Block(
                f"collocation ({name})",
                nlp.state_labels,
                tuple(unit_of(r) for r in nlp.state_labels),
                np.arange(N, dtype=float),
                per_interval=True,
            )
            out.append((block, cs.vertcat(defect[:3, :], exact)))
        return out

    def row_bounds(self, problem, block):
        return np.zeros(block.size), np.zeros(block.size)


class JointLimit(Constraint):
    """A joint limit of the balance joints (position, velocity or acceleration) on the
    continuous plan: bounds on the nodes' (and midpoints') values and constraint rows on the
    interior Bernstein coefficients of every interval (see the module docstring)."""

    def __init__(
        self, kind: str, transcription: Transcription, control: str, between_points: bool = True
    ):
        self.kind = kind
        self.name = f"{kind} limit"
        self.level = DERIVATIVES.index(kind)
        self.control = control
        # the control is derivative 2 (acceleration) or 3 (jerk), and each integration raises
        # the degree by one; the first and last coefficients are bounded as variables
        control_level = 2 if control == "acceleration" else 3
        degree = transcription.control_degree + control_level - self.level
        self.interior = tuple(range(1, degree)) if between_points else ()

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        if not self.interior:
            return []
        coefficients = [nlp.levels[self.level][i] for i in self.interior]
        return self._coefficient_rows(nlp, f"{self.kind} limit between points", coefficients)

    def _coefficient_rows(self, nlp: SymbolicNLP, name: str, coefficients: list) -> list[Rows]:
        labels = [f"{j} {self.kind} (control point {i})" for i in self.interior for j in nlp.joints]
        intervals = np.arange(nlp.key.intervals, dtype=float)
        values = cs.vertcat(*coefficients)
        return block_rows(nlp, name, labels, unit_of(self.kind), values, intervals, True)

    def row_bounds(self, problem, block):
        lower, upper = limit_bounds(problem.limits, self.kind)
        reps = len(self.interior) * len(block.taus)  # per row, stacked column by column
        return np.tile(lower, reps).astype(float), np.tile(upper, reps).astype(float)

    def bound_variables(self, problem, lower, upper):
        low, high = limit_bounds(problem.limits, self.kind)
        if self.level == 2 and self.control == "acceleration":  # the control itself
            names, rows = ("U", "Um"), slice(None)
        else:
            names, rows = ("X", "Xm"), problem.model.joint_rows(self.control)[self.level]
        for name in names:
            if getattr(lower, name) is not None:
                getattr(lower, name)[rows, :] = low[:, None]
                getattr(upper, name)[rows, :] = high[:, None]

    def check(self, problem, result):
        values = (result.q_B, result.q_dot_B, result.q_ddot_B)[self.level]
        low, high = limit_bounds(problem.limits, self.kind)
        excess = np.maximum(values - high, low - values)
        return _worst(problem, excess, result.t, f"{self.kind} limit of {{}}", unit_of(self.kind))


class JerkLimit(JointLimit):
    """The balance joints' jerk limits [rad/s^3] on the continuous plan: on every interval the
    jerk is a polynomial (the derivative of the acceleration's, or with control ``"jerk"`` the
    control's own) and every one of its Bernstein coefficients is a row. The acceleration must
    then be continuous, so that the torques, and the reaction on the base, have no steps: the
    trapezoidal rule with control ``"acceleration"`` (a constant acceleration per interval) is
    refused."""

    def __init__(self, transcription: Transcription, control: str):
        if control == "acceleration" and transcription.control_degree == 0:
            raise InputError(
                "constraints.jerk_limits: jerk limits need a continuous acceleration; the "
                f"{transcription.name} rule with control 'acceleration' steps it at every node: "
                "use control 'jerk' or transcription 'hermite-simpson'"
            )
        self.kind, self.name, self.control = "jerk", "jerk limit", control
        # a row per Bernstein coefficient of the jerk: the jerk control's own, or those of the
        # acceleration control's derivative, one degree lower
        degree = transcription.control_degree - (1 if control == "acceleration" else 0)
        self.interior = tuple(range(degree + 1))

    def coefficients(self, levels: list, h) -> list:
        """Bernstein coefficients of the jerk on every interval, each (n_B, N), from the balance
        joints' levels (:func:`~balance_opt.optimal.collocation.joint_chain_coefficients`)."""
        if self.control == "jerk":
            return list(levels[3])
        acceleration = levels[2]
        d = len(acceleration) - 1
        return [(d / h) * (acceleration[i + 1] - acceleration[i]) for i in range(d)]

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        coefficients = self.coefficients(nlp.levels, nlp.parameters.h)
        return self._coefficient_rows(nlp, "jerk limit", coefficients)

    def bound_variables(self, problem, lower, upper):
        pass  # its rows bound every coefficient of the jerk, the nodes' values too

    def check(self, problem, result):
        """The jerk of the re-simulated motion by finite differences of its accelerations: the
        mean jerk over each sample interval, never above the largest."""
        jerk = np.diff(result.q_ddot_B, axis=0) / np.diff(result.t)[:, None]
        excess = np.abs(jerk) - problem.limits.jerk
        return _worst(problem, excess, result.t[:-1], "jerk limit of {}", "rad/s^3")


#: Where the re-simulated plan's torque exceeds its effort limit (beyond
#: :data:`~balance_opt.motion.result.EFFORT_TOLERANCE`), the refinement bounds it this much below the
#: limit (relative) on that interval: the torque rows hold at the collocation points only, and a
#: bound at the limit itself leaves the torque between them just over it again (+0.08 % at the
#: samples was reported as a success before).
TORQUE_MARGIN = 1e-3
#: Points per collocation interval, both ends included, at which the refinement and the check
#: evaluate the torques (:meth:`TorqueLimit.torques`): the torque of a plan bent around a body
#: peaks inside an interval, and a coarse grid there misses a peak by more than the tolerance.
TORQUE_POINTS = 65


def rounds_tried(result: BalanceResult) -> str:
    """``"after n refinement rounds"`` of a refined plan (for the message of a failure)."""
    refinement = (getattr(result, "solver", None) and result.solver.refinement) or {}
    n = refinement.get("rounds", 0)
    said = f"after {n} refinement round{'' if n == 1 else 's'}"
    if "failed" in refinement:
        said += f" (the next re-solve failed: {refinement['failed']})"
    return said


class TorqueLimit(Constraint):
    """The balance joints' effort limits [N m] on the torques of the free-floating inverse
    dynamics, at the collocation points (the point kernels compute the torques)."""

    name = "torque limit"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        return block_rows(nlp, self.name, [f"{j} torque" for j in nlp.joints], "N m", nlp.torque)

    def row_bounds(self, problem, block):
        effort = problem.limits.effort[:, None] * problem.bounds.torque_factor
        return -effort.ravel(order="F"), effort.ravel(order="F")

    @staticmethod
    def torques(problem: BalanceProblem, result: BalanceResult) -> tuple[np.ndarray, np.ndarray]:
        """The balance joints' torques of the free-floating inverse dynamics of a plan, on the
        continuous motion (:data:`TORQUE_POINTS` per interval and the result's own samples,
        those the reported effort figures read): ``(t (T,) [s], torques (T, n_B) [N m])``."""
        solution = getattr(getattr(result, "solver", None), "solution", None)
        if solution is None or not hasattr(problem, "trajectory"):
            t, q_B, qd_B, qdd_B = result.t, result.q_B, result.q_dot_B, result.q_ddot_B
            q_M, qd_M, qdd_M = result.q_M, result.q_dot_M, result.q_ddot_M
            quaternion = result.quaternion
        else:
            s = np.linspace(0.0, 1.0, TORQUE_POINTS)
            t = ((np.arange(problem.N)[:, None] + s[None, :]) * problem.h).ravel()
            # each point in the interval it starts (the horizon's end in the last one)
            t = np.union1d(t, np.asarray(result.t, dtype=float))
            t = np.unique(np.minimum(t, problem.N * problem.h * (1.0 - 1e-12)))
            q_B, qd_B, qdd_B = problem.trajectory(solution).sample(t)
            motion = problem.mission_motion(solution)
            q_M, qd_M, qdd_M = motion.sample(np.minimum(t, motion.duration))
            quaternion = np.stack(
                [np.interp(t, result.t, result.quaternion[:, i]) for i in range(4)], axis=1
            )
            quaternion /= np.linalg.norm(quaternion, axis=1, keepdims=True)
        torque = problem.model.torque_fun(True).map(t.size)
        Rt = np.swapaxes(matrix_from_quaternion(quaternion), -1, -2)
        h_b = np.hstack([Rt @ problem.h0[:3], Rt @ problem.h0[3:]])  # R^T h0, base axes
        tau = torque(
            np.hstack([q_M, q_B]).T, np.hstack([qd_M, qd_B]).T, np.hstack([qdd_M, qdd_B]).T, h_b.T
        )
        return t, np.array(tau)[problem.model.n_M :].T

    def tighten(self, problem, result):
        """The effort factors lowered at the points of every interval where a torque exceeds
        its limit (by more than :data:`~balance_opt.motion.result.EFFORT_TOLERANCE`), scaled by
        ``(1 - TORQUE_MARGIN) limit / peak`` there."""
        t, tau = self.torques(problem, result)
        ratio = np.abs(tau) / problem.limits.effort  # (T, n_B), inf effort -> 0
        if not ratio.size or ratio.max() <= 1.0 + EFFORT_TOLERANCE:
            return {}, []
        N = problem.N
        interval = np.minimum((t / problem.h).astype(int), N - 1)
        per_interval = np.zeros((N, problem.model.n_B))
        np.maximum.at(per_interval, interval, ratio)
        broken = per_interval > 1.0 + EFFORT_TOLERANCE
        scale = np.where(broken, (1.0 - TORQUE_MARGIN) / per_interval, 1.0)
        factor = np.array(problem.bounds.torque_factor)
        mids = problem.transcription.has_midpoints
        for k in np.flatnonzero(broken.any(axis=1)):
            for c in [k, k + 1] + ([N + 1 + k] if mids else []):
                factor[:, c] = np.minimum(factor[:, c], factor[:, c] * scale[k])
        worst, n = float(ratio.max() - 1.0), int(broken.any(axis=1).sum())
        return {"torque_factor": factor}, [f"torque bounds on {n} intervals (worst +{worst:.3%})"]

    @classmethod
    def _excess(cls, problem, result) -> tuple[np.ndarray, np.ndarray]:
        t, tau = cls.torques(problem, result)
        effort = problem.limits.effort
        over = np.abs(tau) > effort * (1.0 + EFFORT_TOLERANCE)
        return t, np.where(over, np.abs(tau) - effort, 0.0)

    def check(self, problem, result):
        """The worst torque beyond its limit (by more than
        :data:`~balance_opt.motion.result.EFFORT_TOLERANCE` of it)."""
        t, excess = self._excess(problem, result)
        return _worst(problem, excess, t, "torque limit of {}", "N m")

    def accept(self, problem, result):
        """A plan whose torque still exceeds an effort limit after the refinement fails,
        saying by how much."""
        worst = self.check(problem, result)
        if worst is None:
            return
        joint = worst.constraint.removeprefix("torque limit of ")
        limit = float(problem.limits.effort[problem.balance_joints.index(joint)])
        raise PlannerSolverError(
            f"no plan keeps the effort limits: {joint} exceeds its {limit:g} N m by "
            f"{worst.amount:.4g} N m ({worst.amount / limit:+.3%}) at t = {worst.time:.3f} s, "
            f"{rounds_tried(result)}",
            "Effort_Limit",
            result,
            worst.constraint,
            worst.time,
            worst.amount,
        )


def broken_attitude_bounds(options, result: BalanceResult) -> list[tuple[str, float, float]]:
    """The attitude bounds of ``options`` the re-simulated ``result`` breaks by more than
    :data:`ATTITUDE_TOLERANCE` of them: ``(field, bound, value)``, ``field`` ``"path"`` (the
    peak drift) or ``"terminal"`` (the final drift) [rad]."""
    return [
        (field, bound, value)
        for field, bound, value in (
            ("path", options.path_attitude_bound, result.max_drift),
            ("terminal", options.terminal_attitude_bound, result.final_drift),
        )
        if bound is not None and value > bound * (1.0 + ATTITUDE_TOLERANCE)
    ]


class AttitudeBound(Constraint):
    """A bound on the base's rotation from its initial attitude, ``|log R| <= bound``, as rows
    ``|phi|^2 / bound^2 <= 1``: squared, so that the rows are smooth at ``phi = 0``; scaled,
    so that Ipopt's absolute constraint tolerance is relative to the bound. A plan whose
    re-simulated drift still breaks the bound after the refinement fails (:meth:`accept`)."""

    field = "path"

    def row_bounds(self, problem, block):
        return np.full(block.size, -np.inf), np.ones(block.size)

    def accept(self, problem, result):
        """A plan over the bound (by more than :data:`ATTITUDE_TOLERANCE` of it) after the
        refinement fails, naming the bound, the amount, the time and the rounds tried."""
        for field, bound, value in broken_attitude_bounds(problem.options, result):
            if field != self.field:
                continue
            if field == "path":
                t = float(result.t[int(np.argmax(result.angle))])
                said = f"the base turns {value:.6g} rad at t = {t:.3f} s"
            else:
                t = float(result.t[-1])
                said = f"the base ends {value:.6g} rad from its initial attitude"
            raise PlannerSolverError(
                f"no plan keeps the {field}_attitude_bound: {said}, {value - bound:.4g} rad "
                f"({value / bound - 1.0:+.3%}) over its {bound:.6g} rad, {rounds_tried(result)}",
                "Attitude_Bound",
                result,
                f"{field} attitude bound",
                t,
                value - bound,
            )


class PathAttitudeBound(AttitudeBound):
    """``|log R(t)| <= path_attitude_bound`` at every collocation point (the parameter
    ``path_scale`` holds the bound the refinement may have tightened)."""

    name = "path attitude bound"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        X, _ = nlp.variables.points()
        values = nlp.parameters.path_scale * cs.sum1(X[:3, :] ** 2)
        return block_rows(nlp, self.name, ["attitude |phi|^2 / bound^2"], "(relative)", values)

    def check(self, problem, result):
        if problem.options.path_attitude_bound is None:
            return None
        excess = result.angle - problem.options.path_attitude_bound
        return _worst(problem, excess[:, None], result.t, self.name, "rad")


class PeakEpigraph(PathAttitudeBound):
    """The peak objective's epigraph: ``|phi_k|^2 / PEAK_SCALE^2 <= S`` at every collocation
    point, ``S >= 0``; with a path attitude bound, ``S`` is bounded by it (tightened by the
    refinement: ``problem.bounds.path``), and its check is the bound's."""

    name = "peak epigraph"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        X, _ = nlp.variables.points()
        values = cs.sum1(X[:3, :] ** 2) / PEAK_SCALE**2 - nlp.variables.S
        label = "attitude |phi|^2 / PEAK_SCALE^2 - S"
        return block_rows(nlp, self.name, [label], "(relative)", values)

    def row_bounds(self, problem, block):
        return np.full(block.size, -np.inf), np.zeros(block.size)

    def bound_variables(self, problem, lower, upper):
        # a re-plan's: at least the peak the motion already had
        lower.S[:] = 0.0 if problem.start is None else (problem.start.peak / PEAK_SCALE) ** 2
        bound = problem.bounds.path
        upper.S[:] = np.inf if bound is None else (bound / PEAK_SCALE) ** 2


class TerminalAttitudeBound(AttitudeBound):
    """``|log R_T| <= terminal_attitude_bound`` at the last node."""

    name = "terminal attitude bound"
    field = "terminal"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        N = nlp.key.intervals
        values = nlp.parameters.terminal_scale * cs.sumsqr(nlp.variables.X[:3, N])
        label = "attitude |phi_T|^2 / bound^2"
        return block_rows(nlp, self.name, [label], "(relative)", values, np.array([float(N)]))

    def check(self, problem, result):
        excess = result.final_drift - problem.options.terminal_attitude_bound
        return _worst(problem, [[excess]], result.t[-1:], self.name, "rad")


class InitialState(Constraint):
    """The planner's starting point: the base at its initial attitude (``phi = 0``) and the
    balance arm at rest at ``q_B0``; with ``start: rest`` also its acceleration zero (no torque
    step at ``t = 0``)."""

    name, index, when = "initial state", 0, "initial"

    def targets(self, problem: BalanceProblem) -> list[tuple[str, np.ndarray]]:
        """``(derivative, value)`` of the balance joints at the node."""
        n_levels = len(problem.model.joint_rows(problem.control))
        start = problem.start
        if problem.options.start == "rest" or start is not None:
            n_levels = 3
        if start is not None:  # a re-plan: continuous with the motion it takes over
            if not problem.transcription.has_midpoints and n_levels > len(
                problem.model.joint_rows(problem.control)
            ):
                n_levels = 2  # a constant acceleration per interval: it steps at every node
            values = [problem.q_B0, start.velocity, start.acceleration]
            return list(zip(DERIVATIVES[:n_levels], values))
        zeros = np.zeros_like(problem.q_B0)
        return list(zip(DERIVATIVES[:n_levels], [problem.q_B0, zeros, zeros]))

    def bound_variables(self, problem, lower, upper):
        """Each target fixes a state's rows at the node, or (the acceleration with control
        ``"acceleration"``) the control there; the trapezoidal rule's acceleration is constant
        on an interval, the mean of its two nodes' controls: both are fixed."""
        if self.index == 0:  # the start: the base at its initial attitude too
            start = problem.start
            lower.X[:3, 0] = upper.X[:3, 0] = 0.0 if start is None else start.attitude
        node, rows = problem.N if self.index else 0, problem.model.joint_rows(problem.control)
        for kind, value in self.targets(problem):
            level = DERIVATIVES.index(kind)
            if level < len(rows):
                lower.X[rows[level], node] = upper.X[rows[level], node] = value
            elif problem.transcription.has_midpoints:
                lower.U[:, node] = upper.U[:, node] = value
            else:
                nodes = [node, node + (1 if node == 0 else -1)]
                lower.U[:, nodes] = upper.U[:, nodes] = value[:, None]

    def check(self, problem, result):
        state = dict(zip(DERIVATIVES, (result.q_B, result.q_dot_B, result.q_ddot_B)))
        found = [
            _worst(
                problem,
                np.abs(state[kind][self.index] - value)[None, :],
                result.t[[self.index]],
                f"{self.when} {kind} of {{}}",
                unit_of(kind),
            )
            for kind, value in self.targets(problem)
        ]
        return max((v for v in found if v is not None), key=lambda v: v.amount, default=None)


class EndConditions(InitialState):
    """The options ``end`` (``still``: zero velocity at the last node; ``rest``: zero velocity
    and acceleration; ``rest_at_end`` is ``end: rest``) and ``final_configuration`` (the last
    node's position)."""

    name, index, when = "end conditions", -1, "final"

    def targets(self, problem: BalanceProblem) -> list[tuple[str, np.ndarray]]:
        out = []
        if problem.options.final_configuration is not None:
            out.append(("position", np.asarray(problem.options.final_configuration)))
        n_levels = {"free": 1, "still": 2, "rest": 3}[problem.options.end_condition]
        out += [(kind, np.zeros(problem.model.n_B)) for kind in DERIVATIVES[1:n_levels]]
        return out


class Collision(Constraint):
    """Collision avoidance (:mod:`balance_opt.optimal.collision`, which does the work): at
    every collocation point, one row per body the balance joints move, the soft minimum of
    its fitted shapes' distances to the others, at least ``collision.margin`` (its bounds:
    ``problem.bounds.collision``), and rows of their own for pairs that start close (watched,
    unbounded, where their shapes overlap). The shapes contain the bodies; between the points
    the refinement raises a row's bound where the re-simulated motion comes closer than the
    margin (:meth:`tighten`), and a plan that still penetrates, or comes closer than the
    margin (a pair that starts closer: than its start, less the rows' slack), fails
    (:meth:`accept`)."""

    name = "collision"

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        labels = [f"{label} (soft minimum)" for label in nlp.clearance_labels]
        return block_rows(nlp, "collision clearance", labels, "m", nlp.clearance)

    def row_bounds(self, problem, block):
        return problem.bounds.collision.ravel(order="F"), np.full(block.size, np.inf)

    def check(self, problem, result):
        pairs = collision.short(problem, result)
        if not pairs:
            return None
        closest = pairs[0]
        amount = problem.collision.threshold[closest.index] - closest.distance
        return Violation(f"collision margin of {closest.pair}", closest.time, amount, "m")

    def tighten(self, problem, result):
        return collision.tighten(problem, result)

    def accept(self, problem, result):
        """A plan that still penetrates, or comes closer than the margin, after the
        refinement fails, naming the pair, the depth, the time and the rounds tried."""
        rounds = rounds_tried(result)
        pen = collision.report(problem, result).first_penetration
        if pen is not None:
            raise PlannerSolverError(
                f"no collision-free plan found: {pen.pair} penetrate by {pen.depth:.4g} m at "
                f"t = {pen.time:.3f} s, {rounds}",
                "Collision",
                result,
                f"collision of {pen.pair}",
                pen.time,
                pen.depth,
            )
        pairs = collision.short(problem, result)
        if pairs:
            threshold = problem.collision.threshold
            p = max(pairs, key=lambda p: threshold[p.index] - p.distance)  # the farthest in
            threshold = threshold[p.index]
            raise PlannerSolverError(
                f"no plan keeps the collision margin: {p.pair} come within {p.distance:.4g} m "
                f"at t = {p.time:.3f} s, {threshold - p.distance:.4g} m inside the "
                f"{threshold:.4g} m they must keep, {rounds}",
                "Collision",
                result,
                f"collision margin of {p.pair}",
                p.time,
                threshold - p.distance,
            )


class MissionTiming(Constraint):
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
    def motion(problem: BalanceProblem, result: BalanceResult) -> tuple:
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


def constraint_kinds(key: StructureKey) -> tuple[Constraint, ...]:
    """The constraint kinds of a structure, in the order of their rows in ``g`` and of their
    variable bounds (later kinds override earlier ones: the fixed initial and end values win
    over the limits)."""
    transcription = Transcription(key.transcription)
    kinds: list[Constraint] = [Collocation()]
    kinds += [
        JointLimit(kind, transcription, key.control, key.between_points)
        for kind in DERIVATIVES
        if kind in key.joint_limits
    ]
    if "jerk" in key.joint_limits:
        kinds.append(JerkLimit(transcription, key.control))
    if key.torque_limits:
        kinds.append(TorqueLimit())
    if key.objective == "peak":
        kinds.append(PeakEpigraph())
    if key.path_attitude_bound:
        kinds.append(PathAttitudeBound())
    if key.terminal_attitude_bound:
        kinds.append(TerminalAttitudeBound())
    if key.collision:
        kinds.append(Collision())
    if key.timing:
        kinds.append(MissionTiming(transcription))
    kinds += [InitialState(), EndConditions()]
    return tuple(kinds)
