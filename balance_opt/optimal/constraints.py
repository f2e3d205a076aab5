"""The constraint terms of the balance NLP (:class:`~balance_opt.optimal.terms.Term`): the
collocation, the balance joints' limits and torques, the attitude bounds, the start and the end."""

from __future__ import annotations

import casadi as cs
import numpy as np

from balance_opt.errors import InputError
from balance_opt.motion.result import EFFORT_TOLERANCE, BalanceResult, limit_bounds
from balance_opt.motion.so3 import matrix_from_quaternion
from balance_opt.optimal.collocation import Transcription, bernstein_value
from balance_opt.optimal.layout import Block, unit_of
from balance_opt.optimal.problem import BalanceProblem
from balance_opt.optimal.terms import (
    TORQUE_MARGIN,
    TORQUE_POINTS,
    Output,
    PlannerSolverError,
    Rows,
    Size,
    SymbolicNLP,
    Term,
    block_rows,
    points_per_interval,
    rounds_tried,
    worst,
)

#: The balance joints' derivatives, in the order of their Bernstein levels.
DERIVATIVES = ("position", "velocity", "acceleration")
#: Relative excess of the re-simulated drift over an attitude bound within which the bound
#: counts as kept: the refinement tightens above it, a plan still above it fails.
ATTITUDE_TOLERANCE = 1e-3
#: Jacobian non-zeros per variable and per collocation or joint-limit row of an interval, by
#: transcription (fitted to the built NLPs: :meth:`Collocation.size`).
JACOBIAN_FIT = {"hermite-simpson": (5.46, 3.60), "trapezoidal": (4.94, 2.15)}


class Collocation(Term):
    """The collocation defects: the attitude by the transcription; the balance joints, a chain
    of integrators, exactly (each node, and each midpoint, is the value of the integrated
    control polynomial, so the continuous plan passes through every node; see
    :mod:`balance_opt.optimal.collocation`). They all vanish."""

    name = "collocation"

    def outputs(self, model):
        n_x = model.n_x(self.control)
        return (Output("dynamics", n_x, "", lambda point: point.x_dot, with_dynamics=True),)

    def __init__(self, control: str):
        self.control = control

    def values(self, problem):
        return {"h": problem.h, "mission": problem.mission_samples}

    def size(self, n_B, transcription):
        """The states and controls of the points and their defects; the Jacobian fitted
        (:data:`JACOBIAN_FIT`), the dynamics' Hessian dense in a point's attitude, positions and
        rates."""
        points = points_per_interval(transcription)
        n_x = 3 + (3 if self.control == "jerk" else 2) * n_B
        n_w, rows = points * (n_x + n_B), points * n_x
        a, b = JACOBIAN_FIT[transcription.name]
        k = 3 + 2 * n_B
        return Size(n_w, rows, a * n_w + b * rows + points * k * (k + 1) / 2 + n_w + rows)

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        tr, N, v = nlp.transcription, nlp.key.intervals, nlp.variables
        h = nlp.parameters.h
        levels = nlp.levels[:-1]  # the joint states' polynomials, not the control's
        joint_ends = cs.vertcat(*(bernstein_value(level, 1.0) for level in levels))
        joint_mids = cs.vertcat(*(bernstein_value(level, 0.5) for level in levels))
        F = nlp.outputs["dynamics"]
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


class JointLimit(Term):
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

    def size(self, n_B, transcription):
        """A row per interior coefficient and joint, its Jacobian fitted as a defect's."""
        rows = n_B * len(self.interior)
        return Size(0, rows, (JACOBIAN_FIT[transcription.name][1] + 1) * rows)

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
        return worst(problem, excess, result.t, f"{self.kind} limit of {{}}", unit_of(self.kind))


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

    def size(self, n_B, transcription):
        """A row per coefficient and joint, on the controls of its interval: the acceleration's
        three, or (control jerk) one to three of the jerk's."""
        rows = n_B * len(self.interior)
        if self.control == "jerk":
            per_row = 5 / 3 if transcription.has_midpoints else 2
        else:
            per_row = 3
        return Size(0, rows, (per_row + 1) * rows)

    def check(self, problem, result):
        """The jerk of the re-simulated motion by finite differences of its accelerations: the
        mean jerk over each sample interval, never above the largest."""
        jerk = np.diff(result.q_ddot_B, axis=0) / np.diff(result.t)[:, None]
        excess = np.abs(jerk) - problem.limits.jerk
        return worst(problem, excess, result.t[:-1], "jerk limit of {}", "rad/s^3")


class TorqueLimit(Term):
    """The balance joints' effort limits [N m] on the torques of the free-floating inverse
    dynamics, at the collocation points (the point kernels compute the torques)."""

    name = "torque limit"

    def __init__(self, control: str, momentum: bool):
        self.control, self.momentum = control, momentum

    def outputs(self, model):
        torques = model.balance_torque_fun(self.control, self.momentum)
        return (Output("torque", model.n_B, "_torque", lambda p: torques(p.x, p.u, p.m)),)

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        torque = nlp.outputs["torque"]
        return block_rows(nlp, self.name, [f"{j} torque" for j in nlp.joints], "N m", torque)

    def row_bounds(self, problem, block):
        effort = problem.limits.effort[:, None] * problem.bounds.torque_factor
        return -effort.ravel(order="F"), effort.ravel(order="F")

    def size(self, n_B, transcription):
        """A row per point and joint, on the point's positions, rates and controls; its
        Hessian dense in them."""
        points = points_per_interval(transcription)
        rows = points * n_B
        return Size(0, rows, 3 * n_B * rows + points * n_B**2 + rows)

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
        return worst(problem, excess, t, "torque limit of {}", "N m")

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


class AttitudeBound(Term):
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
    #: Jacobian non-zeros of a row: the point's attitude
    row_nonzeros = 3

    def values(self, problem):
        return {"path_scale": 1.0 / problem.bounds.path**2 if problem.bounds.path else 1.0}

    def size(self, n_B, transcription):
        rows = points_per_interval(transcription)
        return Size(0, rows, (self.row_nonzeros + 1) * rows)

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        X, _ = nlp.variables.points()
        values = nlp.parameters.path_scale * cs.sum1(X[:3, :] ** 2)
        return block_rows(nlp, self.name, ["attitude |phi|^2 / bound^2"], "(relative)", values)

    def check(self, problem, result):
        if problem.options.path_attitude_bound is None:
            return None
        excess = result.angle - problem.options.path_attitude_bound
        return worst(problem, excess[:, None], result.t, self.name, "rad")


class TerminalAttitudeBound(AttitudeBound):
    """``|log R_T| <= terminal_attitude_bound`` at the last node."""

    name = "terminal attitude bound"
    field = "terminal"

    def values(self, problem):
        bound = problem.bounds.terminal
        return {"terminal_scale": 1.0 / bound**2 if bound else 1.0}

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        N = nlp.key.intervals
        values = nlp.parameters.terminal_scale * cs.sumsqr(nlp.variables.X[:3, N])
        label = "attitude |phi_T|^2 / bound^2"
        return block_rows(nlp, self.name, [label], "(relative)", values, np.array([float(N)]))

    def check(self, problem, result):
        excess = result.final_drift - problem.options.terminal_attitude_bound
        return worst(problem, [[excess]], result.t[-1:], self.name, "rad")


class InitialState(Term):
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
            worst(
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
