"""Multi-start of the optimal planner: ``options.starts`` initial guesses solved in parallel
processes, the plan of the smallest objective kept.

The guesses are the chosen one, the other named one (``analytic``, ``rest``), then smooth
random motions drawn in this process from ``options.seed`` (so a run is reproducible whatever
the number of processes). With more than one start and more than one CPU the starts run in this
process, which has every problem built, and in a pool of ``spawn`` workers, one per other CPU
(:mod:`balance_opt.optimal.start_schedule` says which task runs where and when): each worker
builds its own :class:`~balance_opt.optimal.model.PlannerModel` from the pickled robot once,
loading the compiled kernel library from the on-disk cache, and keeps it for its next starts;
it builds only the problems of the stages it is given.

A plan through the peak problem (the peak objective, or a path attitude bound) begins with the
integral objective's plan (:func:`~balance_opt.optimal.refine.plan_peak`), and different
starts often reach the same one (on the capture task all eight do): the starts run that first
stage, those whose plans agree (:data:`SAME_PLAN`, :data:`SAME_CONTROL`) are merged, and only
the distinct ones go on through the later stages, the bounds and the refinement, each as soon
as it is known to be distinct. ``info["starts"]`` reports every start (a merged one names the
start it joined), the distinct plans and the processes that solved (``workers``, this one
included).
"""

from __future__ import annotations

import dataclasses
import logging
import os

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.optimal.guess import random_guess
from balance_opt.optimal.options import GUESSES, SUCCESS_STATUSES
from balance_opt.optimal.start_schedule import Lanes, Schedule

log = logging.getLogger(__name__)

#: Largest difference between two first-stage plans' states (rad, rad/s) under which they are
#: one plan.
SAME_PLAN = 1e-4
#: The same for their controls (rad/s^2, or rad/s^3 with jerk control). Ipopt's tolerance
#: leaves more in them than in the states: the eight first plans of the capture task agree to
#: 1.2e-5 in the states and 2.7e-4 rad/s^2 in the accelerations (their later stages end in
#: one plan).
SAME_CONTROL = 1e-3

#: Planner models built in a worker process, by robot name and joints (one per robot).
_WORKER_MODELS: dict = {}


def start_guesses(nlp, guess) -> list[tuple[str, object]]:
    """``(label, guess)`` of every start: the named ones, then random decision vectors."""
    rng = np.random.default_rng(nlp.options.seed)
    named = [guess] + [g for g in GUESSES if g != guess]
    out = []
    for g in named[: nlp.options.starts]:
        out.append((g if isinstance(g, str) else type(g).__name__, g))
    first_state = nlp.unpack(nlp.lbx).X[3:, 0]
    while len(out) < nlp.options.starts:
        out.append(("random", nlp.pack(random_guess(nlp, first_state, rng))))
    return out


def _outcome(result) -> dict:
    """What ``info["starts"]`` records of a solved start."""
    return {
        "status": result.info["status"],
        "objective": result.info["objective"],
        "max_drift_rad": result.max_drift,
        "final_drift_rad": result.final_drift,
        "iterations": result.info["total_iterations"],
        "solve_s": result.info["total_solve_time_s"],  # every Ipopt solve of the start
    }


def _run(nlp, guess, phase: str):
    """One start's ``phase`` in this process: ``"first"`` the integral stage (its
    :class:`~balance_opt.optimal.refine.IntegralStart`), ``"plan"`` the whole solve
    (``(result, None)`` or ``(None, error)``)."""
    from balance_opt.optimal.refine import integral_stage, solve_with_bounds

    if phase == "first":  # on its stage's problem, which one start or several share
        return integral_stage(nlp, guess)
    nlp = nlp.variant(starts=1)
    try:
        return solve_with_bounds(nlp, guess), None
    except SolverError as exc:
        return None, exc


def _worker(build, model_robot, robot, mission, q_B0, options, h0, guess, phase):
    """:func:`_run` in a worker process (see the module docstring) on the problem ``build``
    (:func:`~balance_opt.optimal.solve.build_balance_nlp`, pickled by name) makes; an error
    comes back as ``(message, status)``: the planner's errors do not pickle. A first stage
    builds only the integral problem it solves."""
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.refine import stage_changes

    key = (model_robot.name, tuple(model_robot.joint_names))
    if key not in _WORKER_MODELS:
        _WORKER_MODELS[key] = PlannerModel(model_robot)
    if phase == "first":  # the problem BalanceNLP.stage("integral") makes, built alone
        first = dataclasses.replace(options, **stage_changes(options, "integral"))
        nlp = build(_WORKER_MODELS[key], mission, q_B0, first, robot, h0=h0, stage="integral")
        return _run(nlp, guess, phase)
    nlp = build(_WORKER_MODELS[key], mission, q_B0, options, robot, h0=h0)
    result, error = _run(nlp, guess, phase)
    return (result, None) if error is None else (None, (str(error), str(error.status)))


def workers_for(starts: int) -> int:
    """Processes that solve ``starts`` starts, this one included: one per CPU, at most one per
    start (1: this process alone)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(starts, cpus or 1))


def _same_first_plan(a, b) -> bool:
    """Two first stages' outcomes (:class:`~balance_opt.optimal.refine.IntegralStart`) reached
    one plan: both solved, states within :data:`SAME_PLAN`, controls within
    :data:`SAME_CONTROL`."""
    if any(f.report["status"] not in SUCCESS_STATUSES for f in (a, b)):
        return False
    x, y = a.following, b.following
    return bool(np.abs(x.X - y.X).max() <= SAME_PLAN and np.abs(x.U - y.U).max() <= SAME_CONTROL)


def _solve_all(nlp, guesses, jobs: int) -> tuple[list, list]:
    """Every start's ``(result, error)`` and the start each was merged into, solved in this
    process and ``jobs - 1`` workers (:mod:`balance_opt.optimal.start_schedule`)."""
    staged = nlp.options.objective == "peak" or nlp.options.path_attitude_bound is not None
    starting = [g for _, g in guesses]
    if staged:  # decision vectors of this problem as states and controls (clipped to its
        # bounds, as the first stage does): a worker then builds the first stage's problem only
        starting = [
            nlp.unpack(nlp.initial_guess(g)) if isinstance(g, np.ndarray) else g for g in starting
        ]
    schedule = Schedule(starting, staged, _same_first_plan)
    options = dataclasses.replace(nlp.options, starts=1)
    leading = (type(nlp).build, nlp.model.robot, nlp.robot, nlp.mission, nlp.q_B0, options, nlp.h0)
    lanes = Lanes(lambda kind, g: _run(nlp, g, kind), (_worker, leading), jobs - 1)
    lanes.run(schedule)
    return schedule.outcomes(), schedule.owner


def multi_start(nlp, guess, jobs: int | None = None):
    """Solve from ``options.starts`` guesses (see the module docstring) and keep the plan of
    the smallest objective; ``info["starts"]`` holds every start's outcome and the spread.

    Args:
        nlp: the problem (a :class:`~balance_opt.optimal.solve.BalanceNLP`).
        guess: the first start's guess.
        jobs: processes that solve, this one included (default :func:`workers_for`; 1: this
            process alone).

    Raises:
        SolverError: every start failed (the first start's error, or its message and status).
    """
    guesses = start_guesses(nlp, guess)
    jobs = workers_for(len(guesses)) if jobs is None else max(1, jobs)
    outcomes, owner = _solve_all(nlp, guesses, jobs)
    best, first_error, runs = None, None, []
    for i, ((label, _), (result, error)) in enumerate(zip(guesses, outcomes)):
        run = {"guess": label} if owner[i] == i else {"guess": label, "same_as": owner[i]}
        if result is None:
            error = error if isinstance(error, SolverError) else SolverError(error[0], error[1])
            first_error = first_error or error
            runs.append({**run, "status": str(error.status)})
            continue
        runs.append({**run, **_outcome(result)})
        if best is None or result.info["objective"] < best.info["objective"]:
            best = result
    if best is None:
        raise first_error
    solved = [r for r in runs if "objective" in r]
    log.info(
        "multi-start: %d starts, %d solved, %d distinct, in %d processes",
        len(runs),
        len(solved),
        len(set(owner)),
        jobs,
    )
    best.info["starts"] = {
        "runs": runs,
        "solved": len(solved),
        "distinct": len(set(owner)),
        "workers": jobs,
        "objective_spread": float(
            max(r["objective"] for r in solved) - min(r["objective"] for r in solved)
        ),
        "max_drift_spread_rad": float(
            max(r["max_drift_rad"] for r in solved) - min(r["max_drift_rad"] for r in solved)
        ),
    }
    return best
