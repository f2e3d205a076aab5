"""The outer loop of the optimal planner: the peak objective's stages, bounds reached through the
peak problem, and limits held on the whole re-simulated motion.

Three strategies around one Ipopt solve (:meth:`~balance_opt.optimal.solve.BalanceNLP.solve_once`):

* **The peak objective** (:func:`plan_peak`) in three stages, each warm started from the
  last: the integral objective's plan, the smooth peak (an L16 norm of the drift, no
  inequality rows), the epigraph. The two inner stages' plans are only warm starts, so they
  are solved more cheaply than the last: on a grid four times coarser (twice with the
  trapezoidal rule, :func:`~balance_opt.optimal.options.inner_intervals`), the smooth peak's
  plan interpolated onto the plan's grid (:func:`~balance_opt.optimal.guess.resampled`), and
  with the joint limits held at the collocation points only (no rows between them). On the
  capture task (N = 100) the coarse grid took the inner stages from 1.6 s to 0.3 s, and the
  epigraph stage started from it took 56 iterations against 58, to the same plan; without
  the rows an Ipopt iteration costs about a quarter less.
* **Bounds that converge** (:func:`solve_with_bounds`). A hard path attitude bound started
  from a guess that drifts three times too far stalls Ipopt. So the peak problem is solved
  first without the bound (its epigraph variable is the bound's elastic relaxation): its peak
  is the smallest the planner finds. A bound below it fails at once, naming that peak; a
  bound above it is met by the peak plan itself (peak objective), or the bounded problem is
  solved warm started from the peak plan, which is feasible (integral objective).
* **Limits on the whole motion** (:func:`refine`). Torques and attitude bounds are rows at the
  collocation points. After each solve every one is checked on the re-simulated motion (torques
  from the free-floating inverse dynamics on the fine grid); where one is broken beyond its
  tolerance (:data:`TORQUE_TOLERANCE`, :data:`ATTITUDE_TOLERANCE`), its bound is tightened
  by the measured ratio (torques: on the broken intervals only) and the problem solved again,
  warm started, up to :data:`MAX_ROUNDS` times.

Several starts are :mod:`balance_opt.optimal.starts`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.optimal import ledger
from balance_opt.optimal.constraints import TorqueLimit
from balance_opt.optimal.options import SUCCESS_STATUSES, inner_intervals
from balance_opt.optimal.problem import PlannerSolverError
from balance_opt.result import BalanceResult

log = logging.getLogger(__name__)

#: Relative excess of a torque over its effort limit, on the re-simulated motion, that is
#: accepted without refining.
TORQUE_TOLERANCE = 2e-3
#: Relative excess of the re-simulated attitude over an attitude bound accepted without refining.
ATTITUDE_TOLERANCE = 1e-3
#: Re-solves of the refinement at most.
MAX_ROUNDS = 6
#: Relative excess of a bound over the smallest peak below which the peak plan is re-solved
#: with the bound (its re-simulated peak may cross it between the points).
BOUND_MARGIN = 1e-3


def stage_changes(options, name: str) -> dict:
    """The option changes that make a problem with ``options`` the inner stage ``name``
    (``"integral"`` or ``"smooth"``) of :func:`plan_peak`: its grid, and for the integral
    stage the integral objective without attitude bounds."""
    changes = {"intervals": inner_intervals(options.intervals, options.transcription)}
    if name == "integral":
        changes.update(objective="integral", path_attitude_bound=None, terminal_attitude_bound=None)
    return changes


def solve_with_bounds(nlp, guess) -> BalanceResult:
    """Solve a problem whose path attitude bound may stall Ipopt (see the module docstring),
    then :func:`refine`. The plan, or the result a failure carries, holds the totals of every
    Ipopt solve behind it (:mod:`balance_opt.optimal.ledger`).

    Raises:
        PlannerSolverError: the bound is below the smallest peak found (its message states
            it), or Ipopt failed.
    """
    with ledger.ledger() as work:
        try:
            result = _solve_with_bounds(nlp, guess)
        except SolverError as exc:
            if exc.result is not None:
                ledger.stamp(exc.result.info, work)
            raise
    ledger.stamp(result.info, work)
    return result


def _solve_with_bounds(nlp, guess) -> BalanceResult:
    bound = nlp.options.path_attitude_bound
    if bound is None:
        first = plan_peak(nlp, guess) if nlp.options.objective == "peak" else nlp.solve_once(guess)
        return refine(nlp, first)
    free = nlp.variant(objective="peak", path_attitude_bound=None, terminal_attitude_bound=None)
    peak_plan = plan_peak(free, guess)
    smallest = peak_plan.max_drift
    peak_plan.info["smallest_peak_rad"] = smallest
    if smallest > bound * (1.0 + ATTITUDE_TOLERANCE):
        t = float(peak_plan.t[int(np.argmax(peak_plan.angle))])
        raise PlannerSolverError(
            f"path_attitude_bound {bound:.6g} rad is below the smallest peak the planner found, "
            f"{smallest:.6g} rad (at t = {t:.3f} s): no plan met it",
            "Bound_Below_Smallest_Peak",
            peak_plan,
            "path attitude bound",
            t,
            smallest - bound,
        )
    same = nlp.options.objective == "peak" and nlp.options.terminal_attitude_bound is None
    if same and smallest <= bound * (1.0 - BOUND_MARGIN):
        # the peak plan of the bounded problem is the free one: the bound is not active
        result = peak_plan
        result.info["refinement"] = {"rounds": 0, "tightened": [], "iterations": 0, "solve_s": 0.0}
        return result
    result = nlp.solve_once(free.solution_of(peak_plan))
    result.info["smallest_peak_rad"] = smallest
    bounded = _report("bounded", nlp, result.info)
    result.info["stages"] = peak_plan.info.get("stages", []) + [bounded]
    return refine(nlp, result)


def plan_peak(nlp, guess) -> BalanceResult:
    """Solve a peak problem in stages, each warm started from the last: the integral
    objective's plan, the smooth peak (the ``smooth`` stage: the drift's L_16 norm, without
    the epigraph's inequality rows, priced like the peak at the start's peak ``c``), then the
    exact epigraph. From the integral plan of the paper task the epigraph alone took 579
    Ipopt iterations; from the smooth peak's plan about 40. The inner stages run on a coarser
    grid (:func:`stage_changes`) and are not re-simulated. Should the epigraph stage fail,
    the smooth peak is solved on the plan's grid from the inner stage's plan and kept (with
    a warning). ``info["stages"]`` reports each stage's status, iterations, intervals and
    drifts."""
    # the first stage: done by a multi-start, or here
    if isinstance(guess, IntegralStart):  # solved outside this plan's ledger
        first = guess
        ledger.record(first.report.get("iterations", 0), first.report.get("solve_s", 0.0))
    else:
        first = integral_stage(nlp, guess)
    stages, guess = [dict(first.report)], first.following
    smooth = nlp.stage("smooth")
    # its reference drift: the start's peak (the smooth term then weighs like the peak's)
    X, _ = smooth.unpack(smooth.initial_guess(guess)).points()
    smooth.peak_reference = max(float(np.linalg.norm(X[:3], axis=0).max()), 1e-4)
    smooth.update_bounds()
    guess = smooth_plan = _stage(smooth, guess, "smooth", stages)
    try:
        result = nlp.solve_once(guess)
    except SolverError as exc:
        if stages[-1]["status"] not in SUCCESS_STATUSES:
            raise
        log.warning("peak stage failed (%s); the smooth peak's plan is kept", exc)
        failed = exc.result.info if exc.result is not None else {}
        stages.append(_report("peak", nlp, failed, status=exc.status))
        result = _smooth_plan(nlp, smooth, smooth_plan)
        stages.append(_report("smooth, re-simulated", nlp, result.info))
    else:
        stages.append(
            _report(
                "peak",
                nlp,
                result.info,
                max_drift_rad=result.max_drift,
                final_drift_rad=result.final_drift,
            )
        )
    result.info["stages"] = stages
    return result


def _report(stage: str, nlp, info: dict, status=None, **more) -> dict:
    """``info["stages"]``'s entry of a stage solved by ``nlp.solve_once`` from the ``info`` of
    its result (a failure's may be empty, its ``status`` given): its grid, status, iterations
    and Ipopt's time."""
    return {
        "stage": stage,
        "intervals": nlp.N,
        "status": str(status) if status is not None else info.get("status", "unknown"),
        "iterations": info.get("iterations", 0),
        "solve_s": info.get("wall_time_s", {}).get("solve", 0.0),
        **more,
    }


def _smooth_plan(nlp, smooth, guess) -> BalanceResult:
    """The smooth peak as the plan of the peak problem ``nlp`` (a failed epigraph stage's
    fallback): solved on ``nlp``'s grid with the rows between the points, priced at the
    reference drift of the inner ``smooth`` stage, from ``guess``. Its ``nlp_solution`` is
    the peak problem's (with ``S``, the plan's own peak), as every later step expects."""
    final = nlp.stage("smooth", final=True)
    final.peak_reference = smooth.peak_reference
    final.update_bounds()
    result = final.solve_once(guess)
    result.info["nlp_solution"] = nlp.initial_guess(final.solution_of(result)).tolist()
    return result


@dataclass
class IntegralStart:
    """The first stage of :func:`plan_peak`, done: its report and the next stage's guess (the
    integral plan, or the original guess when the stage failed)."""

    report: dict
    following: object


def integral_stage(nlp, guess) -> IntegralStart:
    """The first stage of :func:`plan_peak` for the problem ``nlp``: the integral objective's
    plan, without bounds, from ``guess``."""
    if isinstance(guess, np.ndarray):  # a decision vector of this problem
        guess = nlp.unpack(nlp.initial_guess(guess))
    integral = nlp.stage("integral")
    stages = []
    following = _stage(integral, guess, "integral", stages)
    return IntegralStart(stages[0], following)


def _stage(nlp, guess, name: str, stages: list):
    """Solve one inner stage of :func:`plan_peak` from ``guess``; returns the next stage's
    guess: the solution, or ``guess`` itself when the stage failed."""
    sol, report = nlp.solve_stage(guess)
    stages.append({"stage": name, **report})
    if report["status"] in SUCCESS_STATUSES:
        return sol
    log.info("%s stage ended with %s; the next stage starts from its guess", name, report)
    return guess


def refine(nlp, result: BalanceResult) -> BalanceResult:
    """Tighten the torque and attitude bounds the re-simulated motion breaks and solve again,
    warm started, until every one holds (or :data:`MAX_ROUNDS`); see the module docstring.
    ``info["refinement"]`` lists what was tightened in each round."""
    rounds, iterations, seconds, stages = [], 0, 0.0, result.info.get("stages")
    for _ in range(MAX_ROUNDS):
        tightened = _tighten(nlp, result)
        if not tightened:
            break
        rounds.append(tightened)
        log.info("refinement: %s", "; ".join(tightened))
        nlp.update_bounds()
        result = nlp.solve_once(nlp.unpack(np.array(result.info["nlp_solution"])))
        iterations += result.info["iterations"]
        seconds += result.info["wall_time_s"]["solve"]
    else:
        if _tighten(nlp, result, dry=True):
            log.warning("refinement: bounds still broken after %d rounds", MAX_ROUNDS)
    for kind in nlp.structure.kinds:  # a plan some kind rejects is a failure
        kind.accept(nlp, result)
    result.info["refinement"] = {
        "rounds": len(rounds),
        "tightened": rounds,
        "iterations": iterations,
        "solve_s": seconds,
    }
    if stages is not None:
        result.info["stages"] = stages
    return result


def _tighten(nlp, result: BalanceResult, dry: bool = False) -> list[str]:
    """Lower the bounds the re-simulated ``result`` breaks beyond tolerance (unless ``dry``);
    returns what it lowered, in words."""
    out = []
    if nlp.structure.key.torque_limits:
        out += _tighten_torques(nlp, result, dry)
    for kind in nlp.structure.kinds:  # the kinds that tighten their own bounds
        out += kind.tighten(nlp, result, dry)
    for name, bound, value in (
        ("path_bound", nlp.options.path_attitude_bound, result.max_drift),
        ("terminal_bound", nlp.options.terminal_attitude_bound, result.final_drift),
    ):
        if bound is not None and value > bound * (1.0 + ATTITUDE_TOLERANCE):
            current = getattr(nlp, name)
            if not dry:
                setattr(nlp, name, current * bound / value * (1.0 - ATTITUDE_TOLERANCE / 2))
            out.append(f"{name.replace('_', ' ')} {current:.6g} -> {getattr(nlp, name):.6g} rad")
    return out


def _tighten_torques(nlp, result: BalanceResult, dry: bool) -> list[str]:
    """Scale the effort bounds of the points of every interval where a torque exceeds its limit
    by more than :data:`TORQUE_TOLERANCE` by ``limit / peak`` there."""
    effort = nlp.limits.effort
    ratio = np.abs(TorqueLimit.torques(nlp, result)) / effort  # (T, n_B), inf effort -> 0
    if not ratio.size or ratio.max() <= 1.0 + TORQUE_TOLERANCE:
        return []
    N = nlp.N
    interval = np.minimum((result.t / nlp.h).astype(int), N - 1)
    per_interval = np.zeros((N, nlp.model.n_B))
    np.maximum.at(per_interval, interval, ratio)
    broken = per_interval > 1.0 + TORQUE_TOLERANCE / 2
    if not dry:
        scale = np.where(broken, (1.0 - TORQUE_TOLERANCE / 4) / per_interval, 1.0)
        mids = nlp.transcription.has_midpoints
        for k in np.flatnonzero(broken.any(axis=1)):
            columns = [k, k + 1] + ([N + 1 + k] if mids else [])
            for c in columns:
                nlp.torque_factor[:, c] = np.minimum(
                    nlp.torque_factor[:, c], nlp.torque_factor[:, c] * scale[k]
                )
    worst = float(ratio.max() - 1.0)
    return [f"torque bounds on {int(broken.any(axis=1).sum())} intervals (worst +{worst:.2%})"]
