"""The outer loop of the optimal planner: the peak objective's stages, bounds reached through the
peak problem, limits held on the whole re-simulated motion, and the multi-start
(``options.starts`` initial guesses, the plan of the smallest objective kept)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields, replace

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.motion.result import BalanceResult
from balance_opt.optimal.constraints import ATTITUDE_TOLERANCE, broken_attitude_bounds
from balance_opt.optimal.guess import random_guess
from balance_opt.optimal.layout import Solution
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.objectives import objective_of
from balance_opt.optimal.options import GUESSES, SMOOTH_PLAN, SUCCESS_STATUSES
from balance_opt.optimal.terms import PlannerSolverError

log = logging.getLogger(__name__)

#: Re-solves of the refinement at most.
MAX_ROUNDS = 6
#: Relative excess of a bound over the smallest peak below which the peak plan is re-solved
#: with the bound (its re-simulated peak may cross it between the points).
BOUND_MARGIN = 1e-3
#: The NLP's functions Ipopt calls (CasADi's ``nlp_*`` functions of an ``nlpsol``).
NLP_FUNCTIONS = ("f", "grad_f", "g", "jac_g", "hess_l")
#: Largest difference between two first-stage plans' states (rad, rad/s) under which they are
#: one plan.
SAME_PLAN = 1e-4
#: The same for their controls (rad/s^2, or rad/s^3 with jerk control): Ipopt's tolerance
#: leaves more in them than in the states.
SAME_CONTROL = 1e-3


@dataclass(frozen=True)
class SolveReport:
    """One Ipopt solve, or one stage of a plan (an entry of :attr:`PlanReport.stages`).

    Attributes:
        stage: the objective of the structure solved (``"integral"``, ``"smooth"``, ``"peak"``)
            or the stage's name in the plan (``"bounded"``, ``"smooth, re-simulated"``).
        intervals: its grid's ``N``.
        status, iterations: Ipopt's return status and iterations.
        solve_s: Ipopt's wall time [s].
        objective: the objective's value at the solution.
        solution: the solution (the warm start of what follows it).
        drifts: figures of the stage's plan [rad], by name: ``nlp_max_drift_rad`` and
            ``nlp_final_drift_rad`` at the collocation points (inner stages),
            ``max_drift_rad`` and ``final_drift_rad`` re-simulated (the peak stage).
        evaluations_s: the wall time [s] of Ipopt's calls of each of :data:`NLP_FUNCTIONS`;
            the rest of ``solve_s`` is Ipopt's own work, its linear algebra mostly.
    """

    stage: str
    intervals: int
    status: str
    iterations: int
    solve_s: float
    objective: float
    solution: Solution = field(repr=False)  # arrays: a repr a notebook can read
    drifts: tuple[tuple[str, float], ...] = ()
    evaluations_s: tuple[tuple[str, float], ...] = ()

    @property
    def success(self) -> bool:
        return self.status in SUCCESS_STATUSES

    def as_stage(self, stage: str | None = None, **drifts: float) -> SolveReport:
        return replace(self, stage=stage or self.stage, drifts=tuple(drifts.items()))

    def as_inner_stage(self) -> SolveReport:
        X, _ = self.solution.points()
        return self.as_stage(
            nlp_max_drift_rad=float(np.linalg.norm(X[:3], axis=0).max()),
            nlp_final_drift_rad=float(np.linalg.norm(self.solution.X[:3, -1])),
        )

    def entry(self) -> dict:
        """Its entry of ``info["stages"]`` (``metrics.json``'s ``details.stages``)."""
        fields = ("stage", "intervals", "status", "iterations", "solve_s")
        return {**{k: getattr(self, k) for k in fields}, **dict(self.drifts)}


@dataclass(frozen=True)
class Checks:
    """The re-simulated plan checked (:func:`~balance_opt.optimal.solve.resimulate`;
    ``metrics.json``'s ``details.resimulation``): its samples, the collocation defects, the
    momentum residual, the drift, every limit violation and every term's violation on the
    continuous motion (between the collocation points torques and the path attitude bound are
    not enforced), and what the planner does with each checked pair of bodies."""

    samples: int
    step_s: float
    attitude_defect_max_rad: float
    attitude_defect_final_rad: float
    joint_defect_max: float
    max_momentum_residual: float
    max_drift_rad: float
    final_drift_rad: float
    nlp_final_drift_rad: float
    limit_violations: tuple[str, ...]
    constraint_violations: tuple[str, ...]
    collision_pairs: dict | None = None

    def as_dict(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        for key in ("limit_violations", "constraint_violations"):
            out[key] = list(out[key])
        if self.collision_pairs is None:
            del out["collision_pairs"]
        return out


@dataclass(frozen=True)
class LastSolve:
    """The plan's last Ipopt solve, on the problem it solved (the rest of
    :meth:`PlanReport.as_info`).

    Attributes:
        violation: its worst constraint or bound, ``(name, time [s], amount, unit,
            description)`` (:meth:`~balance_opt.optimal.solve.BalanceNLP.largest_violation`).
        wall_time_s: its wall times [s] by part (``build``, ``setup``, ``guess``, ``solve``,
            ``resimulate``).
        kernels: whether its kernels ran compiled, their compile time [s] and library.
        history: Ipopt's objective and infeasibilities per iteration.
        problem: its grid, transcription, control, horizon and options, as plain data.
    """

    violation: tuple[str, float, float, str, str]
    wall_time_s: dict[str, float]
    kernels: dict
    history: dict[str, list[float]] = field(repr=False)
    problem: dict = field(repr=False)


@dataclass(frozen=True)
class PlanReport:
    """How an optimal plan was solved and checked (``BalanceResult.solver``): the typed record
    the written files' ``info`` is built from (:meth:`as_info`).

    Attributes:
        solves: every Ipopt solve behind the plan, in order (the stages, the bounded problem,
            the refinement's rounds), failed ones included.
        solution: the plan's NLP solution.
        stages: the peak objective's stages, when it was solved in stages (``None`` else).
        refinement: what the refinement (:func:`refine`) did (``details.refinement``): its
            rounds, what it tightened in each, in words, and the Ipopt work of its re-solves
            (``None`` before it ran).
        smallest_peak: with a path attitude bound, the smallest peak found [rad].
        last: the last solve's details (``None`` before a solve was re-simulated).
        checks: the re-simulated plan checked.
        timing: a free mission timing's figures
            (:func:`~balance_opt.optimal.timing.timing_info`; ``None``: the given timing).
        starts: a multi-start's every start (:func:`multi_start`).
        minimum_time: ``objective: time``'s probes (:func:`~balance_opt.optimal.solve.fastest`).
    """

    solves: tuple[SolveReport, ...]
    solution: Solution | None = field(default=None, repr=False)
    stages: tuple[SolveReport, ...] | None = None
    refinement: dict | None = None
    smallest_peak: float | None = None
    last: LastSolve | None = None
    checks: Checks | None = None
    timing: dict | None = None
    starts: dict | None = None
    minimum_time: dict | None = None

    @property
    def status(self) -> str:
        """The last solve's Ipopt status."""
        return self.solves[-1].status

    @property
    def success(self) -> bool:
        return self.solves[-1].success

    @property
    def iterations(self) -> int:
        return sum(s.iterations for s in self.solves)

    @property
    def solve_s(self) -> float:
        return sum(s.solve_s for s in self.solves)

    @property
    def evaluations_s(self) -> dict[str, float]:
        """The wall time [s] of Ipopt's calls of each NLP function, all solves."""
        out = dict.fromkeys(NLP_FUNCTIONS, 0.0)
        for solve in self.solves:
            for name, seconds in solve.evaluations_s:
                out[name] += seconds
        return out

    def then(self, solve: SolveReport) -> PlanReport:
        return replace(self, solves=self.solves + (solve,), solution=solve.solution)

    def as_info(self) -> dict:
        """The report as the plain data of the written files (``metrics.json``'s ``details``,
        the NPZ's ``info``: docs/outputs.md), in their order."""
        out = {}
        if self.checks is not None:
            out["resimulation"] = self.checks.as_dict()
        if self.timing is not None:
            out["timing"] = self.timing
        if self.last is not None:
            out.update(self._last_solve())
        if self.starts is not None:
            out["starts"] = self.starts
        if self.smallest_peak is not None:
            out["smallest_peak_rad"] = self.smallest_peak
        if self.stages is not None:
            out["stages"] = [s.entry() for s in self.stages]
        if self.refinement is not None:
            out["refinement"] = self.refinement
        out["total_iterations"] = self.iterations
        out["total_solve_time_s"] = self.solve_s
        if self.minimum_time is not None:
            out["minimum_time"] = self.minimum_time
        return out

    def _last_solve(self) -> dict:
        solve, last = self.solves[-1], self.last
        name, t, amount, unit, where = last.violation
        return {
            "status": solve.status,
            "success": solve.success,
            "iterations": solve.iterations,
            "objective": solve.objective,
            "max_constraint_violation": amount,
            "max_violation_at": {
                "constraint": name,
                "time_s": t,
                "unit": unit,
                "description": where,
            },
            "wall_time_s": last.wall_time_s,
            "kernels": last.kernels,
            "history": last.history,
            **last.problem,
        }


def _refinement(rounds: list, solves) -> dict:
    return {
        "rounds": len(rounds),
        "tightened": [list(r) for r in rounds],
        "iterations": sum(s.iterations for s in solves),
        "solve_s": sum(s.solve_s for s in solves),
    }


def solve_with_bounds(nlp, guess) -> BalanceResult:
    """Solve (with a path attitude bound through the free peak problem first), then
    :func:`refine`."""
    bound = nlp.options.path_attitude_bound
    if bound is None:
        if objective_of(nlp.options).staged:
            return refine(nlp, plan_peak(nlp, guess))
        return refine(nlp, nlp.solve_once(guess))
    free = nlp.variant(objective="peak", path_attitude_bound=None, terminal_attitude_bound=None)
    peak_plan = plan_peak(free, guess)
    priced = peak_plan.max_drift <= bound * (1.0 + ATTITUDE_TOLERANCE)
    if not priced:
        peak_plan = _lowest_peak(free, peak_plan)
    smallest = peak_plan.max_drift
    peak_plan.solver = replace(peak_plan.solver, smallest_peak=smallest)
    if smallest > bound * (1.0 + ATTITUDE_TOLERANCE):
        t = float(peak_plan.t[int(np.argmax(peak_plan.angle))])
        raise PlannerSolverError(
            f"path_attitude_bound {bound:.6g} rad is below the smallest peak the planner found, "
            f"{smallest:.6g} rad (at t = {t:.3f} s, the final drift left free): no plan met it",
            "Bound_Below_Smallest_Peak",
            peak_plan,
            "path attitude bound",
            t,
            smallest - bound,
        )
    same = objective_of(nlp.options).staged and nlp.options.terminal_attitude_bound is None
    same = same and priced  # else peak_plan leaves the final drift unpriced: not this problem's
    if same and smallest <= bound * (1.0 - BOUND_MARGIN):
        # the peak plan of the bounded problem is the free one: the bound is not active
        peak_plan.solver = replace(peak_plan.solver, refinement=_refinement([], ()))
        return peak_plan
    result = nlp.solve_once(peak_plan.solver.solution, peak_plan.solver)
    bounded = result.solver.solves[-1].as_stage("bounded")
    result.solver = replace(result.solver, stages=result.solver.stages + (bounded,))
    return refine(nlp, result)


def _lowest_peak(free, peak_plan: BalanceResult) -> BalanceResult:
    """The smallest peak of the problem ``free``: its peak problem with the final drift
    unpriced, from its ``peak_plan`` (which prices it, ``weights.peak_terminal``, and so peaks
    higher than it must); ``peak_plan`` itself should that solve fail."""
    loose = free.variant(weights=replace(free.options.weights, peak_terminal=0.0))
    try:
        result = loose.solve_once(peak_plan.solver.solution, peak_plan.solver)
    except SolverError as exc:
        log.warning("peak without the final drift's price failed (%s); its peak stands", exc)
        return peak_plan
    lowest = result.solver.solves[-1].as_stage(
        "peak, final drift free", max_drift_rad=result.max_drift, final_drift_rad=result.final_drift
    )
    result.solver = replace(result.solver, stages=peak_plan.solver.stages + (lowest,))
    return result


def coarsest_problem(nlp):
    """The peak problem ``nlp`` on the coarsest of its epigraph stage's grids
    (:meth:`~balance_opt.optimal.options.Stage.grids`), whose inner stages start its plan:
    ``nlp`` itself up to the stage's ``fine_above``."""
    grids = nlp.options.stages[-1].grids(nlp.N, nlp.transcription.name)
    return nlp if len(grids) == 1 else nlp.variant(intervals=grids[0])


@dataclass(frozen=True)
class IntegralStart:
    """An inner stage of :func:`plan_peak`, done: its report and the next stage's guess (its
    plan, or its own guess when it failed)."""

    report: SolveReport
    following: object


def inner_stage(nlp, stage, guess):
    """The inner ``stage`` of the peak problem ``nlp`` solved: its :class:`IntegralStart` and
    its problem. The smooth stage's reference drift ``c`` is the peak of its start (the smooth
    term then weighs like the peak's)."""
    if isinstance(guess, np.ndarray):  # a decision vector of this problem
        guess = nlp.unpack(nlp.initial_guess(guess))
    stage_nlp = nlp.stage(stage)
    if stage.name == "smooth":
        X, _ = stage_nlp.unpack(stage_nlp.initial_guess(guess)).points()
        reference = max(float(np.linalg.norm(X[:3], axis=0).max()), 1e-4)
        stage_nlp = stage_nlp.with_bounds(peak_reference=reference)
    report = stage_nlp.solve_stage(guess)
    return IntegralStart(report, report.solution if report.success else guess), stage_nlp


def plan_peak(nlp, guess) -> BalanceResult:
    """Solve a peak problem in the stages of its options (by default
    :data:`~balance_opt.optimal.options.PEAK_STAGES`),
    each warm started from the last: the integral objective's plan, the smooth peak (the
    drift's L_16 norm, without the epigraph's rows), then the exact epigraph, which converges
    fast from near its plan. The inner stages are not re-simulated; a failed one hands its
    guess on. On a grid finer than the epigraph stage's ``fine_above``, the inner stages and the
    epigraph first solve the problem on the coarser grids of its
    :meth:`~balance_opt.optimal.options.Stage.grids`. Should the epigraph stage fail, the smooth
    peak is solved on the plan's grid and kept (:data:`~balance_opt.optimal.options.SMOOTH_PLAN`,
    with a warning)."""
    *inner, last = nlp.options.stages
    coarsest = coarsest_problem(nlp)
    if coarsest is not nlp and isinstance(guess, np.ndarray):  # a decision vector of nlp
        guess = nlp.unpack(nlp.initial_guess(guess))
    done, stage_nlp = [], None
    for stage in inner:
        if stage.name == "integral" and isinstance(guess, IntegralStart):  # by a multi-start
            start = guess
        else:
            start, stage_nlp = inner_stage(coarsest, stage, guess)
        if not start.report.success:
            log.info(
                "%s stage: %s; the next starts from its guess", stage.name, start.report.status
            )
        done.append(start.report)
        guess = start.following
    for n in last.grids(nlp.N, nlp.transcription.name)[:-1]:  # the epigraph, coarse to fine
        report = nlp.variant(intervals=n).stage(last).solve_stage(guess)
        if not report.success:  # as an inner stage's failure
            log.info("peak stage (N = %d): %s; the next starts from its guess", n, report.status)
        guess = report.solution if report.success else guess
        done.append(report)
    before = PlanReport(tuple(done))
    stages = tuple(r.as_inner_stage() for r in done)
    try:
        result = nlp.stage(last).solve_once(guess, before)
    except SolverError as exc:
        if not done[len(inner) - 1].success:  # the smooth stage, which the fallback needs
            raise
        log.warning("peak stage failed (%s); the smooth peak's plan is kept", exc)
        before = getattr(exc.result, "solver", None) or before
        stages += before.solves[len(done) :]  # the failed peak stage
        # on the plan's grid, priced at the inner smooth stage's reference drift
        final = nlp.stage(SMOOTH_PLAN).with_bounds(peak_reference=stage_nlp.bounds.peak_reference)
        result = final.solve_once(guess, before)
        w = nlp.initial_guess(result.solver.solution)  # with S: the peak problem's solution
        result.solver = replace(result.solver, solution=nlp.unpack(w))
        stages += (result.solver.solves[-1].as_stage("smooth, re-simulated"),)
    else:
        drifts = {"max_drift_rad": result.max_drift, "final_drift_rad": result.final_drift}
        stages += (result.solver.solves[-1].as_stage(**drifts),)
    result.solver = replace(result.solver, stages=stages)
    return result


def refine(nlp, result: BalanceResult) -> BalanceResult:
    """Tighten the bounds the re-simulated motion breaks and solve again, warm started, until
    every one holds (or :data:`MAX_ROUNDS`); each round solves a new problem."""
    rounds, before, failed = [], len(result.solver.solves), None
    for _ in range(MAX_ROUNDS):
        changes, tightened = _tighten(nlp, result)
        if not tightened:
            break
        log.info("refinement: %s", "; ".join(tightened))
        tighter = nlp.with_bounds(**changes)
        try:
            again = tighter.solve_once(result.solver.solution, result.solver)
        except SolverError as exc:  # the last plan stands, to be judged by what it breaks
            failed = exc
            log.warning("refinement: the re-solve failed: %s", exc)
            break
        rounds.append(tuple(tightened))
        nlp, result = tighter, again
    else:
        if _tighten(nlp, result)[1]:
            log.warning("refinement: bounds still broken after %d rounds", MAX_ROUNDS)
    refinement = _refinement(rounds, result.solver.solves[before:])
    if failed is not None:
        refinement["failed"] = str(failed.status)
    result.solver = replace(result.solver, refinement=refinement)
    for term in nlp.structure.terms:  # a plan some term rejects is a failure (its rounds said)
        term.accept(nlp, result)
    if failed is not None:
        raise failed
    return result


def _tighten(nlp, result: BalanceResult) -> tuple[dict, list[str]]:
    """The bounds the re-simulated ``result`` breaks, tightened (changes of
    :class:`~balance_opt.optimal.problem.Bounds`), and what they lower, in words."""
    changes, out = {}, []
    for term in nlp.structure.terms:
        more, words = term.tighten(nlp, result)
        changes.update(more)
        out += words
    for field, bound, value in broken_attitude_bounds(nlp.options, result):
        current = getattr(nlp.bounds, field)
        changes[field] = current * bound / value * (1.0 - ATTITUDE_TOLERANCE / 2)
        out.append(f"{field} bound {current:.6g} -> {changes[field]:.6g} rad")
    return changes, out


class StartTask:
    """One phase of a start on a problem, a callable of the start's guess: ``"first"`` the
    integral stage (its :class:`IntegralStart`), ``"plan"`` the whole solve (``(result, None)``
    or ``(None, error)``; in another process the error as ``(message, status)``: the planner's
    errors do not pickle)."""

    def __init__(self, nlp, phase: str):
        self.nlp, self.phase, self.remote = nlp, phase, False

    def __getstate__(self) -> dict:
        n, key = self.nlp, self.nlp.structure.key
        stage = None if key.between_points else key.objective
        data = (n.model.robot, n.mission, n.q_B0, n.options, n.robot, n.h0, stage)
        # the problem's own class rebuilds it (pickled by reference: no import of solve here)
        return {"build": type(n), "data": data, "phase": self.phase}

    def __setstate__(self, state: dict) -> None:
        robot, *data = state["data"]
        self.nlp = state["build"](PlannerModel(robot), *data)
        self.phase, self.remote = state["phase"], True

    def __call__(self, guess):
        if self.phase == "first":
            return inner_stage(self.nlp, self.nlp.options.stages[0], guess)[0]
        try:
            return solve_with_bounds(self.nlp, guess), None
        except SolverError as exc:
            return None, ((str(exc), str(exc.status)) if self.remote else exc)


def same_first_plan(a: IntegralStart, b: IntegralStart) -> bool:
    """Two first stages solved and reached one plan."""
    if not (a.report.success and b.report.success):
        return False
    x, y = a.following, b.following
    return bool(np.abs(x.X - y.X).max() <= SAME_PLAN and np.abs(x.U - y.U).max() <= SAME_CONTROL)


def multi_start(nlp, guess, executor=None):
    """Solve from ``options.starts`` guesses (the named ones, then random decision vectors) and
    keep the plan of the smallest objective; its report's ``starts`` holds every start's outcome and
    the spread. Starts whose first stages reach one plan are solved once."""
    run = map if executor is None else executor.map
    rng = np.random.default_rng(nlp.options.seed)
    named = ([guess] + [g for g in GUESSES if g != guess])[: nlp.options.starts]
    guesses = [(g if isinstance(g, str) else type(g).__name__, g) for g in named]
    while len(guesses) < nlp.options.starts:
        guesses.append(("random", nlp.pack(random_guess(nlp, rng))))
    single = nlp.variant(starts=1)
    starting = [g for _, g in guesses]
    owner = list(range(len(starting)))
    if objective_of(nlp.options).staged or nlp.options.path_attitude_bound is not None:
        # decision vectors as states and controls: the first stage's problem needs no other
        starting = [
            nlp.unpack(nlp.initial_guess(g)) if isinstance(g, np.ndarray) else g for g in starting
        ]
        first_stage = coarsest_problem(single).stage(single.options.stages[0])
        first = list(run(StartTask(first_stage, "first"), starting))
        for i in range(len(first)):
            same = (j for j in range(i) if owner[j] == j and same_first_plan(first[j], first[i]))
            owner[i] = next(same, i)
        starting = first
    distinct = sorted(set(owner))
    solved = dict(zip(distinct, run(StartTask(single, "plan"), [starting[i] for i in distinct])))
    best, first_error, runs = None, None, []
    for i, (label, _) in enumerate(guesses):
        result, error = solved[owner[i]]
        entry = {"guess": label} if owner[i] == i else {"guess": label, "same_as": owner[i]}
        if result is None:
            error = error if isinstance(error, SolverError) else SolverError(error[0], error[1])
            first_error = first_error or error
            runs.append({**entry, "status": str(error.status)})
            continue
        last = result.solver.solves[-1]
        runs.append(
            {
                **entry,
                "status": last.status,
                "objective": last.objective,
                "max_drift_rad": result.max_drift,
                "final_drift_rad": result.final_drift,
                "iterations": result.solver.iterations,
                "solve_s": result.solver.solve_s,  # every Ipopt solve of the start
            }
        )
        if best is None or last.objective < best.solver.solves[-1].objective:
            best = result
    if best is None:
        raise first_error
    done = [r for r in runs if "objective" in r]
    log.info("multi-start: %d starts, %d solved, %d distinct", len(runs), len(done), len(distinct))

    def spread(key: str) -> float:
        return float(max(r[key] for r in done) - min(r[key] for r in done))

    starts = {
        "runs": runs,
        "solved": len(done),
        "distinct": len(distinct),
        "workers": 1 if executor is None else None,  # an executor's own count is its own
        "objective_spread": spread("objective"),
        "max_drift_spread_rad": spread("max_drift_rad"),
    }
    best.solver = replace(best.solver, starts=starts)
    return best
