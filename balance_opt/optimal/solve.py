"""Building one balance problem's NLP, solving it with Ipopt and re-simulating the plan."""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import time
from types import SimpleNamespace

import numpy as np

from balance_opt import progress
from balance_opt.errors import InputError, SolverError
from balance_opt.interrupts import raise_if_interrupted
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.retiming import shortest_duration
from balance_opt.motion.so3 import (
    quaternion_conjugate,
    quaternion_from_rotvec,
    quaternion_multiply,
    rotation_angle,
)
from balance_opt.optimal import timing
from balance_opt.optimal.collision import guess_through
from balance_opt.optimal.collocation import CollocatedTrajectory, joint_chain_coefficients
from balance_opt.optimal.constraints import broken_attitude_bounds
from balance_opt.optimal.guess import guess_solution, resampled
from balance_opt.optimal.layout import Solution
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.nlp import build_structure
from balance_opt.optimal.objectives import PEAK_SCALE
from balance_opt.optimal.options import SMOOTH_PLAN, SUCCESS_STATUSES, PlannerOptions, Stage
from balance_opt.optimal.problem import BalanceProblem, StructureKey
from balance_opt.optimal.refine import (
    NLP_FUNCTIONS,
    Checks,
    LastSolve,
    PlanReport,
    SolveReport,
    multi_start,
    solve_with_bounds,
)
from balance_opt.optimal.terms import PlannerSolverError

log = logging.getLogger(__name__)

#: What a variable block's entries are named by in a failure message (else ``"node"``).
POINT_NAMES = {"S": "peak", "Xm": "midpoint", "Um": "midpoint"}


class BalanceNLP(BalanceProblem):
    """One balance planning problem with its compiled NLP (``structure``) and numeric inputs
    (``lbx``/``ubx``, ``lbg``/``ubg``, ``parameters``), built by :func:`build_balance_nlp`;
    ``build_time`` is 0 when the structure was cached. ``stage``: an inner stage of the peak
    objective (``"smooth"`` or ``"integral"``), without the joint-limit rows between the points
    unless ``between``."""

    def __init__(
        self,
        model,
        mission,
        q_B0,
        options,
        robot=None,
        h0=None,
        stage=None,
        between=False,
        *,
        start=None,
    ):
        started = time.perf_counter()
        super().__init__(model, mission, q_B0, options, robot, h0, start)
        momentum = bool(np.any(self.h0 != 0.0))
        collision, exact = "", ""
        if self.collision is not None:
            collision, exact = self.collision.rows.key, self.collision.exact_key
        path = self.mission_path if self.free_timing else None
        timed = path.key if path else ""
        key = StructureKey.of(self.limits, options, momentum, collision, timed, exact)
        if stage is not None:  # an inner stage of the peak objective (balance_opt.optimal.refine)
            key = dataclasses.replace(
                key, objective=stage, path_attitude_bound=False, between_points=between
            )
        built_now = key not in model.nlp_cache
        if built_now:
            model.nlp_cache[key] = build_structure(model, key, self, path)
        self.structure = model.nlp_cache[key]
        self.build_time = self.structure.build_time if built_now else 0.0
        self._set_bounds()
        self.setup_time = time.perf_counter() - started - self.build_time

    def with_bounds(self, **changes) -> BalanceNLP:
        """The same problem with other :class:`~balance_opt.optimal.problem.Bounds`; this one
        is unchanged."""
        new = copy.copy(self)
        new.bounds = dataclasses.replace(self.bounds, **changes)
        new._set_bounds()
        return new

    def _set_bounds(self) -> None:
        values = {}
        for term in self.structure.terms:
            values.update(term.values(self))
        self.parameters = self.structure.parameters.pack(SimpleNamespace(**values))
        # the variables free, narrowed by every term in turn; each block of rows by its term
        n_w, n_g = self.structure.variables.size, self.structure.rows.size
        lower, upper = self.unpack(np.full(n_w, -np.inf)), self.unpack(np.full(n_w, np.inf))
        for term in self.structure.terms:
            term.bound_variables(self, lower, upper)
        self.lbx, self.ubx = self.pack(lower), self.pack(upper)
        self.lbg, self.ubg = np.empty(n_g), np.empty(n_g)
        for block, term in zip(self.structure.rows.blocks, self.structure.row_terms):
            self.lbg[block.slice], self.ubg[block.slice] = term.row_bounds(self, block)

    def variant(self, stage: str | None = None, between: bool = False, **changes) -> BalanceNLP:
        """The same problem with other options (its bounds untightened)."""
        options = dataclasses.replace(self.options, **changes)
        return BalanceNLP(
            self.model,
            self.mission,
            self.q_B0,
            options,
            self.robot,
            self.h0,
            stage,
            between,
            start=self.start,
        )

    def stage(self, stage: Stage | str, final: bool = False) -> BalanceNLP:
        """The same problem as a :class:`~balance_opt.optimal.options.Stage` of the peak
        objective, or the one of the options' ``stages`` of that name (with ``final``,
        :data:`~balance_opt.optimal.options.SMOOTH_PLAN`): its objective, grid and rows; the
        integral stage without attitude bounds. Itself when it is that stage."""
        if isinstance(stage, str):
            stages = self.options.stages
            stage = SMOOTH_PLAN if final else next(s for s in stages if s.name == stage)
        key = self.structure.key
        if key.objective == stage.name and key.between_points == stage.between_points:
            return self
        changes = {"intervals": stage.intervals(self.N, self.transcription.name)}
        if stage.name == "integral":
            changes.update(
                objective="integral", path_attitude_bound=None, terminal_attitude_bound=None
            )
        return self.variant(stage.name, stage.between_points, **changes)

    def unpack(self, w) -> Solution:
        return self.structure.variables.unpack(w)

    def pack(self, sol: Solution) -> np.ndarray:
        return self.structure.variables.pack(sol)

    def initial_guess(self, guess="analytic") -> np.ndarray:
        """The decision vector to start from: ``"analytic"`` (the analytic law, else rest),
        ``"rest"``, a :class:`BalanceResult` (its balance motion, clipped), a :class:`Solution`
        (with or without ``S``, on any grid) or a decision vector."""
        if isinstance(guess, (str, BalanceResult, Solution)):
            if isinstance(guess, Solution):  # of this grid or another (an inner stage's)
                sol = resampled(guess, self.N)
            else:
                sol = guess_solution(self, guess)
            if self.free_timing:
                timing.guess_timing(self, sol)
            if "S" in self.structure.variables.by_name:  # the guess's own peak
                X, _ = sol.points()
                sol.S = np.array([[np.max(np.sum(X[:3] ** 2, axis=0)) / PEAK_SCALE**2]])
            return np.clip(self.pack(sol), self.lbx, self.ubx)
        w, n_w = np.asarray(guess, dtype=float).ravel(), self.structure.variables.size
        if w.size != n_w:
            raise InputError(f"initial guess vector has {w.size} entries, the NLP has {n_w}")
        return w

    def solve(self, initial_guess="analytic", executor=None) -> BalanceResult:
        """The plan (:mod:`balance_opt.optimal.refine`), from ``options.starts`` guesses, their
        starts run by ``executor`` (anything with ``map``; ``None``: this process).

        Raises:
            PlannerSolverError: Ipopt stopped without a solution, or the path attitude bound is
                below the smallest peak found.
        """
        try:
            if self.options.objective == "time":
                result = fastest(self, initial_guess, executor)
            elif self.options.starts > 1:
                result = multi_start(self, initial_guess, executor)
            else:
                result = self._solve_clear_of_bodies(initial_guess)
        except KeyboardInterrupt:  # stopped: the compilations this plan started stop now too
            self.model.stop_compiling()
            raise
        finally:  # a compilation of the kernels this plan started ends with it
            self.model.finish_compiling()
        return result

    def _solve_clear_of_bodies(self, initial_guess) -> BalanceResult:
        """:func:`solve_with_bounds`; should Ipopt fail from the analytic law's guess where that
        guess goes through a body (:func:`~balance_opt.optimal.collision.guess_through`), it
        is solved again from rest, where the arm keeps every row. A plan found and then
        judged in collision after the refinement's rounds is not: the rounds start from the
        plan, not the guess (Baxter's user robot failed the same way from rest)."""
        try:
            return solve_with_bounds(self, initial_guess)
        except PlannerSolverError as exc:
            analytic = isinstance(initial_guess, str) and initial_guess == "analytic"
            if self.collision is None or not analytic or exc.status == "Collision":
                raise
            through = guess_through(self, self.unpack(self.initial_guess(initial_guess)))
            if through is None:
                raise
            log.warning(
                "the plan from the analytic law's guess failed (%s), a guess that goes through "
                "a body (%s): planning again from rest",
                exc,
                through,
            )
        return solve_with_bounds(self, "rest")

    def solve_once(
        self, initial_guess="analytic", before: PlanReport | None = None
    ) -> BalanceResult:
        """Solve with Ipopt once from ``initial_guess`` (see :meth:`initial_guess`) and
        re-simulate the plan, its ``solver`` the report ``before`` followed by this solve.

        Raises:
            PlannerSolverError: Ipopt stopped without a solution; its message names the status
                and the most violated constraint, its ``result`` is the last iterate.
        """
        t0 = time.perf_counter()
        w0 = self.initial_guess(initial_guess)
        t1 = time.perf_counter()
        out, report = self._ipopt(w0)
        t2 = t1 + report.solve_s
        w = np.array(out["x"]).ravel()
        worst = self.largest_violation(w, np.array(out["g"]).ravel())
        result, checks, timing_figures = resimulate(
            self, report.solution, self.trajectory(report.solution)
        )
        t3 = time.perf_counter()
        result.solver = dataclasses.replace(
            (PlanReport(()) if before is None else before).then(report),
            last=self._last_solve(worst, (t0, t1, t2, t3)),
            checks=checks,
            timing=timing_figures,
        )
        if not report.success:
            name, t, amount, unit, where = worst
            raise PlannerSolverError(
                f"Ipopt stopped with status '{report.status}' after {report.iterations} "
                f"iterations; largest constraint violation: {where}, by {amount:.3g} {unit}",
                report.status,
                result,
                name,
                t,
                amount,
            )
        if report.status != SUCCESS_STATUSES[0]:
            log.warning("Ipopt: %s", report.status)
        return result

    def _ipopt(self, w0: np.ndarray) -> tuple[dict, SolveReport]:
        """One Ipopt solve from ``w0``: its raw output and its report."""
        key = self.structure.key
        staged = key.objective != "integral" or not key.between_points  # a stage of the peak
        label = f"Ipopt (N = {self.N}{f', {key.objective} stage' if staged else ''})"
        t0 = time.perf_counter()
        with progress.solving(self.lbg, self.ubg, label):
            out = self.structure.solver(
                x0=w0, p=self.parameters, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg
            )
        raise_if_interrupted()  # Ctrl-C inside Ipopt ends its solve as a "failure": go on
        wall = time.perf_counter() - t0
        stats = self.structure.solver.stats()
        report = SolveReport(
            stage=key.objective,
            intervals=self.N,
            status=str(stats.get("return_status", "unknown")),
            iterations=int(stats.get("iter_count", 0)),
            solve_s=wall,
            objective=float(out["f"]),
            solution=self.unpack(np.array(out["x"]).ravel()),
            evaluations_s=tuple(
                (name, float(stats.get(f"t_wall_nlp_{name}", 0.0))) for name in NLP_FUNCTIONS
            ),
        )
        return out, report

    def solve_stage(self, initial_guess) -> SolveReport:
        """Solve with Ipopt once, not re-simulated, a failure not raised (an inner stage)."""
        return self._ipopt(self.initial_guess(initial_guess))[1]

    def _last_solve(self, worst, times) -> LastSolve:
        t0, t1, t2, t3 = times
        iters = self.structure.solver.stats().get("iterations", {})
        kernels = self.structure.kernels
        return LastSolve(
            violation=worst,
            wall_time_s={
                "build": self.build_time,
                "setup": self.setup_time,
                "guess": t1 - t0,
                "solve": t2 - t1,
                "resimulate": t3 - t2,
            },
            kernels={
                "compiled": kernels.compiled,
                "compile_time_s": kernels.compile_time,
                "library": kernels.library,
            },
            history={k: [float(v) for v in iters.get(k, [])] for k in ("obj", "inf_pr", "inf_du")},
            problem={
                "intervals": self.N,
                "transcription": self.transcription.name,
                "control": self.control,
                "horizon_s": self.horizon,
                "options": self.options.as_dict(),
            },
        )

    def largest_violation(self, w, g) -> tuple[str, float, float, str, str]:
        """``(name, time [s], amount, unit, description)`` of the worst constraint or bound (of
        an interval's constraint, the interval's start)."""
        viol_g = np.maximum(np.maximum(self.lbg - g, g - self.ubg), 0.0)
        viol_x = np.maximum(np.maximum(self.lbx - w, w - self.ubx), 0.0)
        row_worst = viol_g.size and viol_g.max() >= (viol_x.max() if viol_x.size else 0.0)
        viol, layout = (viol_g, "rows") if row_worst else (viol_x, "variables")
        i = int(np.argmax(viol))
        block = getattr(self.structure, layout).block_at(i)
        row, unit, tau = block.locate(i)
        t = tau * self.h
        if row_worst:
            name = f"{block.name}: {row}"
        else:
            name = f"bound on {POINT_NAMES.get(block.name, 'node')} {row}"
        if block.per_interval:
            return (
                name,
                t,
                float(viol[i]),
                unit,
                f"{name} on the interval {t:.3f}-{t + self.h:.3f} s",
            )
        return name, t, float(viol[i]), unit, f"{name} at t = {t:.3f} s"

    def mission_motion(self, sol: Solution):
        """The mission arm's motion of a solution: the given mission, or with a free timing
        its path re-timed (:func:`~balance_opt.optimal.timing.retimed`)."""
        return timing.retimed(self, sol) if self.free_timing else self.mission

    def trajectory(self, sol: Solution) -> CollocatedTrajectory:
        starts = [sol.X[r, :-1] for r in self.model.joint_rows(self.control)]
        levels = joint_chain_coefficients(self.transcription, starts, sol.U, sol.Um, self.h)
        return CollocatedTrajectory(self.h, levels)


#: Width of the bracket [s] at which the search for the shortest duration stops.
TIME_RESOLUTION = 0.1


def fastest(nlp: BalanceNLP, guess, executor=None) -> BalanceResult:
    """``objective: time``: the shortest horizon whose peak plan keeps the path attitude bound
    (and the terminal one), by bisection between the shortest motion the mission joints' limits
    allow (:func:`~balance_opt.motion.retiming.shortest_duration`) and the given duration
    (doubled until feasible, twice at most). A bisection, not the horizon as a variable: with
    rest at the end and no momentum, a plan of a duration is one of every longer duration (both
    arms then wait at rest, and so does the base), so feasibility is monotone in the duration,
    and every probe is an ordinary peak plan, re-simulated and refined. A probe is feasible
    only if its re-simulated plan keeps the bounds (within
    :data:`~balance_opt.optimal.constraints.ATTITUDE_TOLERANCE`). Its report's
    ``minimum_time`` lists the probes.

    Raises:
        InputError: the timing is not free, there is no path attitude bound, or the initial
            momentum is not zero (the base drifts while the arms wait: not monotone).
        PlannerSolverError: not even the longest duration tried keeps the bound.
    """
    bound = nlp.options.path_attitude_bound
    if not nlp.free_timing or bound is None:
        raise InputError(
            "objective time needs a free mission timing (mission.timing: free) and a "
            "path_attitude_bound"
        )
    if np.any(np.asarray(nlp.h0) != 0.0):
        raise InputError(
            "objective time needs a zero initial momentum (initial.momentum): with momentum "
            "the base drifts while the arms wait, and a longer mission is not always stiller"
        )
    probes: list[dict] = []

    def probe(T: float):
        return _probe(nlp, T, guess, executor, probes)

    lo = shortest_duration(nlp.mission_path, nlp.path_rate_limits)
    hi, best = nlp.mission.duration, None
    for longer in (1.0, 2.0, 2.0):
        lo, hi = (hi, hi * longer) if longer > 1.0 else (lo, hi)
        best = probe(hi)
        if best is not None:
            break
    if best is None:
        last = probes[-1]
        raise PlannerSolverError(
            f"objective time: no duration up to {hi:.3g} s keeps the path attitude bound "
            f"{bound:.4g} rad ({last['reason']})",
            "Bound_Not_Kept",
            None,
            "path attitude bound",
            hi,
            0.0,
        )
    while hi - lo > TIME_RESOLUTION:
        T = 0.5 * (lo + hi)
        found = probe(T)
        if found is None:
            lo = T
        else:
            hi, best = T, found
    minimum_time = {
        "duration_s": hi,
        "bracket_s": [lo, hi],
        "resolution_s": TIME_RESOLUTION,
        "probes": probes,
    }
    best.solver = dataclasses.replace(best.solver, minimum_time=minimum_time)
    return best


def _probe(nlp: BalanceNLP, T: float, guess, executor, probes: list) -> BalanceResult | None:
    """One probe of :func:`fastest`: the peak plan of horizon ``T`` if it keeps the attitude
    bounds re-simulated, else ``None``; its outcome appended to ``probes``."""
    variant = nlp.variant(objective="peak", horizon=T)
    try:
        result = variant.solve(guess, executor)
        broken = broken_attitude_bounds(nlp.options, result)
        if broken:  # the refinement's rounds did not bring it within the bound
            field, limit, value = broken[0]
            raise PlannerSolverError(
                f"the re-simulated plan breaks the {field}_attitude_bound {limit:.6g} rad "
                f"by {value - limit:.4g} rad",
                "Attitude_Bound",
                result,
                f"{field} attitude bound",
                T,
                value - limit,
            )
    except SolverError as exc:
        probes.append({"duration_s": T, "feasible": False, "reason": str(exc)})
        log.info("objective time: %.3f s does not keep the bound (%s)", T, exc)
        return None
    drifts = {"max_drift_rad": result.max_drift, "final_drift_rad": result.final_drift}
    probes.append({"duration_s": T, "feasible": True, **drifts})
    log.info("objective time: %.3f s keeps the bound (peak %.4g rad)", T, result.max_drift)
    return result


def build_balance_nlp(
    planner_model: PlannerModel | FloatingRobot,
    mission_trajectory,
    q_B0,
    options: PlannerOptions | None = None,
    robot: FloatingRobot | None = None,
    h0=None,
) -> BalanceNLP:
    """Build the balance NLP of a mission (the arguments:
    :class:`~balance_opt.optimal.problem.BalanceProblem`). The compiled structure is taken from
    ``planner_model.nlp_cache`` when one of the same
    :class:`~balance_opt.optimal.problem.StructureKey` was built; the rest is numeric input.

    Raises:
        InputError: sizes or options that do not fit the robot.
        InfeasibleLimitsError: ``q_B0`` or the final configuration outside the position limits.
    """
    model = (
        planner_model if isinstance(planner_model, PlannerModel) else PlannerModel(planner_model)
    )
    options = options or PlannerOptions()
    return BalanceNLP(model, mission_trajectory, q_B0, options, robot, h0)


def resimulate(
    nlp: BalanceNLP, sol: Solution, trajectory: CollocatedTrajectory
) -> tuple[BalanceResult, Checks, dict | None]:
    """Re-simulate a plan on a fine grid: every interval split into ``sub`` equal steps no
    longer than ``options.resample_step``, so that no RK4 step straddles a node, where the joint
    motion's higher derivatives jump: the motion, its :class:`~balance_opt.optimal.refine.Checks`
    and a free mission timing's figures (``None`` for the given timing)."""
    # imported here: a multi-start's worker that only solves first stages never needs it
    from balance_opt.motion.replay import replay

    sub = max(1, math.ceil(nlp.h / nlp.options.resample_step - 1e-9))
    t = np.arange(nlp.N * sub + 1) * (nlp.h / sub)
    mission = nlp.mission_motion(sol)
    result = replay(
        nlp.robot,
        mission,
        trajectory,
        t_eval=t,
        method="optimal",
        h0=nlp.h0,
        integration=IntegrationOptions(method="rk4", step=float(t[1] - t[0])),
        attitude0=None if nlp.start is None else quaternion_from_rotvec(nlp.start.attitude),
    )
    q_nlp = quaternion_from_rotvec(sol.X[:3].T)
    attitude_defect = rotation_angle(
        quaternion_multiply(quaternion_conjugate(q_nlp), result.quaternion[::sub])
    )
    rows = nlp.model.joint_rows(nlp.control)
    ends = trajectory.interval_ends()
    joint_defect = max(float(np.abs(ends[k] - sol.X[rows[k], 1:].T).max()) for k in (0, 1))
    broken = (term.check(nlp, result) for term in nlp.structure.terms)
    checks = Checks(
        samples=int(t.size),
        step_s=float(t[1] - t[0]),
        attitude_defect_max_rad=float(attitude_defect.max()),
        attitude_defect_final_rad=float(attitude_defect[-1]),
        joint_defect_max=joint_defect,
        max_momentum_residual=float(result.momentum_residual.max()),
        max_drift_rad=result.max_drift,
        final_drift_rad=result.final_drift,
        nlp_final_drift_rad=float(np.linalg.norm(sol.X[:3, -1])),
        limit_violations=tuple(str(v) for v in result.violations),
        constraint_violations=tuple(str(v) for v in broken if v is not None),
        # every checked pair: held by a row, or why not
        collision_pairs=None if nlp.collision is None else nlp.collision.account(),
    )
    figures = timing.timing_info(nlp, result, mission) if nlp.free_timing else None
    return result, checks, figures
