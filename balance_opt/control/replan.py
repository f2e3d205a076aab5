"""Re-planning the balance arm's remaining motion from the middle of a motion
(``docs/executable-plans.md``, "Closed loop").

A re-plan is the tail of the first plan's problem: the same grid from the switch node to the
end (the horizon and the grid shrink together, so that with the predicted state equal to the
plan's own the tail of the plan solves it: Bellman), starting from a
:class:`~balance_opt.optimal.problem.StartState` (the balance arm's positions, rates and
accelerations, the base's attitude, the peak so far), warm started from the plan in force. Each
tail length is its own NLP structure: :meth:`Replanner.prepare` builds them all before the
motion starts, so that a re-plan costs one warm-started Ipopt solve of the epigraph stage (no
inner stages, no refinement, no re-simulation).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.motion.so3 import (
    quaternion_conjugate,
    quaternion_from_rotvec,
    quaternion_multiply,
    rotvec_from_quaternion,
)
from balance_opt.motion.trajectories import MissionWindow
from balance_opt.optimal.collocation import CollocatedTrajectory
from balance_opt.optimal.layout import Solution
from balance_opt.optimal.problem import StartState
from balance_opt.optimal.solve import BalanceNLP

#: Ipopt options of a re-plan over the epigraph stage's: it starts at the plan in force, shifted,
#: which solves it but for the state's difference; a small barrier parameter keeps it near there
#: (1e-4: on the capture task's 20 true robots 12 % fewer iterations than 1e-6, the 95th
#: percentile 46 against 73, the same drifts; 1e-3, 1e-2 and 1e-8 take more).
REPLAN_IPOPT = {"mu_init": 1e-4, "bound_push": 1e-8, "bound_frac": 1e-8}
#: Ipopt's statuses of a solve stopped by its time budget: a late re-plan, not a failed one.
OUT_OF_TIME = ("Maximum_WallTime_Exceeded", "Maximum_CpuTime_Exceeded")
#: Share of a re-plan's time budget given to Ipopt: it looks at the clock after each iteration,
#: so a stopped solve runs on by the iteration it is in (27 ms on a quiet 2-core machine at the
#: longest tails, 70 ms at a load of 6), and setting up the problem and its plan takes a few
#: milliseconds more.
SOLVE_SHARE = 0.85
#: Largest violation of a constraint or bound (in its own unit: rad, m, ...) by the iterate of a
#: re-plan stopped by its time budget that is applied all the same (a real-time iteration): it
#: starts where the arm is (its start is fixed by bounds, which Ipopt's iterates keep) and
#: keeps every limit and clearance row to within a twentieth of the closed loop's position
#: margin (2 mrad), its objective not yet the optimum's. Above it the re-plan is late and the
#: plan in force stays.
STOPPED_VIOLATION = 1e-4
#: Factor on the peak objective's price of the final drift (``weights.peak_terminal``) in the
#: closed loop's plans, the first one and every re-plan (one objective: without model error a
#: re-plan keeps the plan's tail). At the open-loop plan's price a re-plan from a drifted state
#: traded the final drift for the peak (at 0.03 rad of peak a mrad of it was worth six of the
#: final drift): robot 17 of the capture task planned finals of 5-7 mrad from 3.5 s on and ended
#: 8.7 mrad off. 3 on its 20 true robots: the final drift's 95th percentile 0.0032 rad against
#: 0.0044, the peak's unchanged; 10 gave 0.0070 (robot 18 ended 22 mrad off, its re-plans
#: holding the final for a peak that then grew out of the balance arm's reach).
TERMINAL_FACTOR = 3.0
#: The closed loop's plans' late drift, ``(weight [1/(rad^2 s)], window [s])``
#: (:mod:`~balance_opt.optimal.late_drift`; ``None``: none): the plans bring the base back
#: from 1.5-2 s before the end instead of 1-1.5 s, so that the last re-plans have more of the
#: swing's model error left to correct. On the capture task's 20 true robots the final drift's
#: 95th percentile 0.0026 rad against 0.0029, the peak's 0.0383 against 0.0376; a third of the
#: weight gave 0.0054 rad and a limit left, 3 and 10 times the weight a peak 3 % and 11 % higher.
LATE_DRIFT = (1e4, 3.0)


def margined(robot, margin: float, position: float = 0.0, jerk: float | None = None):
    """``robot`` (a :class:`~balance_opt.model.robot.FloatingRobot`) as a controller that tracks
    its plans imperfectly plans with it, so that the tracked motion stays inside the true limits
    (``docs/executable-plans.md``, "Closed loop"): its balance joints' velocity and acceleration
    limits tightened by the fraction ``margin``, their position limits by ``position`` [rad]
    at each end (at most a quarter of the range), and their jerk at most ``jerk`` [rad/s^3]
    (``None``: the robot's). All zero or unset: ``robot`` itself."""
    if margin == 0 and position == 0 and jerk is None:
        return robot
    limits = robot.limits
    balance = robot.balance_indices
    changed = {}
    for key, scale in (("velocity", 1.0 - margin), ("acceleration", 1.0 - margin)):
        changed[key] = getattr(limits, key).copy()
        changed[key][balance] *= scale
    lower, upper = limits.lower.copy(), limits.upper.copy()
    span = upper[balance] - lower[balance]
    # a finite range only; a quarter of it at most, so that a narrow joint keeps a range
    inward = np.where(np.isfinite(span), np.minimum(position, 0.25 * span), 0.0)
    lower[balance] += inward
    upper[balance] -= inward
    changed.update(lower=lower, upper=upper)
    if jerk is not None:
        changed["jerk"] = limits.jerk.copy()
        changed["jerk"][balance] = np.minimum(changed["jerk"][balance], jerk)
    out = copy.copy(robot)
    out.limits = dataclasses.replace(limits, **changed)
    return out


def closed_loop_planner(options, factor: float = TERMINAL_FACTOR, late=LATE_DRIFT):
    """The planner ``options`` of the closed loop's plans: the final drift priced ``factor``
    times (:data:`TERMINAL_FACTOR`), the drift over the last seconds priced by ``late``
    (:data:`LATE_DRIFT`); ``factor`` 1 and ``late`` ``None``: ``options`` themselves."""
    changes = {}
    if factor != 1:
        terminal = options.weights.peak_terminal * factor
        changes["weights"] = dataclasses.replace(options.weights, peak_terminal=terminal)
    if late is not None:
        changes["late_drift"] = tuple(float(v) for v in late)
    return dataclasses.replace(options, **changes) if changes else options


@dataclass(frozen=True)
class Segment:
    """A plan in force: its solution on the nodes ``node`` to ``N`` of the first plan's grid.

    Attributes:
        node: the first plan's node it starts at (its ``t = 0`` is ``node * h``).
        solution: its NLP solution (states, controls, ``S``).
        trajectory: its balance motion, local time.
    """

    node: int
    solution: Solution
    trajectory: CollocatedTrajectory

    def state(self, node: int) -> tuple[np.ndarray, ...]:
        """``(q_B, q_dot_B, q_ddot_B, phi)`` at a node of the first plan's grid: its own node
        values, exactly (the warm start of the re-plan from there has them)."""
        d = node - self.node
        n_B = self.trajectory.dof
        X = self.solution.X
        q, qd = X[3 : 3 + n_B, d], X[3 + n_B : 3 + 2 * n_B, d]
        qdd = X[3 + 2 * n_B :, d] if X.shape[0] > 3 + 2 * n_B else self.solution.U[:, d]
        return q.copy(), qd.copy(), qdd.copy(), X[:3, d].copy()

    def tail(self, node: int, attitude=None) -> Solution:
        """Its solution from a node of the first plan's grid on (a warm start); with
        ``attitude`` (a rotation vector [rad]) its base attitudes turned so that they start
        there: at zero momentum the same joint motion turns the base by the same rotations
        from wherever it starts, so the guess keeps its collocation defects at zero."""
        d = node - self.node
        s = self.solution
        cut = [None if a is None else a[:, d:].copy() for a in (s.X, s.U, s.Xm, s.Um)]
        if attitude is not None:
            start = quaternion_from_rotvec(s.X[:3, d])
            offset = quaternion_multiply(
                quaternion_from_rotvec(np.asarray(attitude, float)), quaternion_conjugate(start)
            )
            for a in (cut[0], cut[2]):
                if a is not None:
                    turned = quaternion_multiply(offset, quaternion_from_rotvec(a[:3].T))
                    a[:3] = rotvec_from_quaternion(turned).T
        return Solution(*cut, S=None)


@dataclass(frozen=True)
class ReplanOutcome:
    """One re-plan: ``segment`` its plan (``None`` when it failed or was stopped infeasible),
    Ipopt's ``status`` and ``iterations``, ``compute_s`` the wall time of the whole re-plan
    [s], ``solve_s`` Ipopt's and ``kernels_s`` that of its calls of the compiled kernels (the
    rest of Ipopt's is its own work, MUMPS's factorisations mostly), ``violation`` the largest
    constraint violation of the iterate of a re-plan stopped by its time budget."""

    node: int
    segment: Segment | None
    status: str
    iterations: int
    compute_s: float
    solve_s: float = 0.0
    kernels_s: float = 0.0
    violation: float = math.nan

    @property
    def success(self) -> bool:
        return self.segment is not None

    @property
    def stopped(self) -> bool:
        """Stopped by its time budget: its iterate applied if feasible, else late."""
        return self.status in OUT_OF_TIME

    @property
    def out_of_time(self) -> bool:
        """Stopped by its time budget with an infeasible iterate: late (the plan in force
        stays), not failed."""
        return self.stopped and self.segment is None


class Replanner:
    """Re-plans of the first plan's problem ``nlp`` (a
    :class:`~balance_opt.optimal.solve.BalanceNLP` with the peak objective or another) from
    nodes of its grid; ``ipopt``: Ipopt options over :data:`REPLAN_IPOPT`; ``budget``: a
    re-plan's time [s] (its control period), ``None`` for none: Ipopt stops at
    :data:`SOLVE_SHARE` of it (``max_wall_time``), its iterate applied if its constraints hold
    to ``stopped_violation`` (:data:`STOPPED_VIOLATION`; ``None``: never), else the plan in
    force stays."""

    def __init__(
        self,
        nlp: BalanceNLP,
        ipopt: dict | None = None,
        budget: float | None = None,
        stopped_violation: float | None = STOPPED_VIOLATION,
    ):
        if nlp.start is not None:
            raise ValueError("the first plan's problem starts at rest")
        self.nlp = nlp
        self.stopped_violation = stopped_violation
        self.ipopt = {**REPLAN_IPOPT, **(ipopt or {})}
        self.budget = budget
        if budget is not None:
            self.ipopt.setdefault("max_wall_time", SOLVE_SHARE * budget)
        # the periods [s] of the re-plans from some nodes when shorter than ``budget``: theirs
        self.periods: dict[int, float] = {}
        # the problems built before the motion, by node: a re-plan keeps their collision rows
        self.prepared: dict[int, BalanceNLP] = {}

    def first(self, plan) -> Segment:
        """The first plan (a :class:`~balance_opt.motion.result.BalanceResult` of ``nlp``, or its NLP
        :class:`~balance_opt.optimal.problem.Solution`) as the plan in force from node 0."""
        solution = plan if isinstance(plan, Solution) else plan.solver.solution
        return Segment(0, solution, self.nlp.trajectory(solution))

    def problem(self, node: int, start: StartState, q_B: np.ndarray, h0=None) -> BalanceNLP:
        """The re-plan's problem from ``node`` (0 < node < N) with the balance joints at ``q_B``
        [rad] and the momentum ``h0`` (``None``: the first plan's)."""
        nlp = self.nlp
        N = nlp.N - node
        if not 0 < N < nlp.N:
            raise ValueError(f"a re-plan starts at a node inside the grid (1 to {nlp.N - 1})")
        t0 = node * nlp.h
        mission = MissionWindow(nlp.mission, t0, max(nlp.mission.duration, t0))
        options = dataclasses.replace(
            nlp.options,
            intervals=N,
            # the window's end minus its start may round above N * h (node 81 of 100 on 10 s)
            horizon=max(N * nlp.h, mission.duration),
            starts=1,
            rest_configuration=tuple(float(v) for v in nlp.q_rest),
            ipopt={**nlp.options.ipopt, **self._ipopt(node)},
        )
        return BalanceNLP(
            nlp.model,
            mission,
            q_B,
            options,
            nlp.robot,
            nlp.h0 if h0 is None else h0,
            start=start,
        )

    def _ipopt(self, node: int) -> dict:
        """The Ipopt options of the re-plan from ``node``: its own period's time budget when
        that is shorter than ``budget``."""
        period = self.periods.get(node, math.inf)
        if self.budget is None or period >= self.budget:
            return self.ipopt
        return {**self.ipopt, "max_wall_time": SOLVE_SHARE * period}

    def prepare(self, first: Segment, nodes, h0=None, periods: dict | None = None) -> float:
        """Build the NLP of every re-plan from ``nodes`` before the motion (each tail length is
        a structure of its own, cached on the planner model), ``periods`` the periods [s] of
        some of them (node -> seconds: their time budget when shorter than ``budget``);
        returns the time it took [s]."""
        started = time.perf_counter()
        self.periods.update(periods or {})
        # a re-plan runs the compiled kernels, not CasADi's virtual machine (its Hessian alone
        # took half a re-plan's time there): a first plan's background compilation is waited
        # for here, before the motion, like the NLPs below
        self.nlp.model.finish_compiling()
        self.nlp.model.upgrade_kernels()
        for node in nodes:
            q, qd, qdd, phi = first.state(node)
            self.prepared[node] = self.problem(node, StartState(qd, qdd, phi), q, h0)
        return time.perf_counter() - started

    def replan(
        self,
        node: int,
        in_force: Segment,
        attitude: np.ndarray,
        peak: float,
        h0=None,
    ) -> ReplanOutcome:
        """The remaining motion from ``node``: the balance arm where the plan in force has it
        there (the command stays continuous), the base at ``attitude`` (a rotation vector
        [rad]), ``peak`` the largest drift so far [rad]; warm started from the plan in force.
        A failed solve gives no segment."""
        started = time.perf_counter()
        q, qd, qdd, _ = in_force.state(node)
        attitude = np.asarray(attitude, float)
        start = StartState(qd, qdd, attitude, peak, self.prepared.get(node))
        try:
            nlp = self.problem(node, start, q, h0)
            report = nlp.solve_stage(in_force.tail(node, attitude))
        except SolverError as exc:
            return ReplanOutcome(node, None, str(exc.status), 0, time.perf_counter() - started)
        segment, violation = None, math.nan
        applied = report.success
        if report.status in OUT_OF_TIME and self.stopped_violation is not None:
            violation = _violation(nlp, report.solution)
            applied = violation <= self.stopped_violation
        if applied:
            segment = Segment(node, report.solution, nlp.trajectory(report.solution))
        kernels_s = sum(seconds for _, seconds in report.evaluations_s)
        compute_s = time.perf_counter() - started
        return ReplanOutcome(
            node,
            segment,
            report.status,
            report.iterations,
            compute_s,
            report.solve_s,
            kernels_s,
            violation,
        )


def _violation(nlp: BalanceNLP, solution: Solution) -> float:
    """The largest violation of ``nlp``'s constraints and bounds by ``solution``, evaluated
    (Ipopt's own ``inf_pr`` of a stopped iterate is not it: 0.013 where this was 0.054)."""
    w = nlp.pack(solution)
    g = np.asarray(nlp.structure.solver.get_function("nlp_g")(w, nlp.parameters)).ravel()
    return nlp.largest_violation(w, g)[2]
