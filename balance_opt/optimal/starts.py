"""Multi-start of the optimal planner: ``options.starts`` initial guesses solved in parallel
processes, the plan of the smallest objective kept.

The guesses are the chosen one, the other named one (``analytic``, ``rest``), then smooth
random motions drawn in this process from ``options.seed`` (so a run is reproducible whatever
the number of workers). With more than one start and more than one CPU the starts run in a
pool of ``spawn`` workers (at most one per CPU): each worker builds its own
:class:`~balance_opt.optimal.model.PlannerModel` from the pickled robot once, loading the
compiled kernel library from the on-disk cache, and keeps it for its next starts. Each start is
the whole single-start solve (:func:`~balance_opt.optimal.refine.solve_with_bounds`: the peak
stages, the bounds, the refinement), untightened. ``info["starts"]`` reports every start.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.optimal.guess import random_guess
from balance_opt.optimal.options import GUESSES

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
        "solve_s": result.info["wall_time_s"]["solve"],
    }


def _solve_here(nlp, guess):
    """One start in this process: ``(result, None)`` or ``(None, error)``."""
    from balance_opt.optimal.refine import solve_with_bounds

    try:
        return solve_with_bounds(nlp.variant(starts=1), guess), None
    except SolverError as exc:
        return None, exc


def _worker_start(model_robot, robot, mission, q_B0, options, guess):
    """One start in a worker process (see the module docstring). Returns ``(result, None)`` or
    ``(None, (message, status))``: the planner's errors do not pickle."""
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.solve import build_balance_nlp

    key = (model_robot.name, tuple(model_robot.joint_names))
    if key not in _WORKER_MODELS:
        _WORKER_MODELS[key] = PlannerModel(model_robot)
    nlp = build_balance_nlp(_WORKER_MODELS[key], mission, q_B0, options, robot)
    result, error = _solve_here(nlp, guess)
    if error is not None:
        return None, (str(error), str(error.status))
    return result, None


def _run_parallel(nlp, guesses, jobs: int) -> list:
    """Every start in a pool of ``jobs`` spawn workers, in the order of ``guesses``."""
    from balance_opt.sweep.workers import new_pool, stop_pool

    options = dataclasses.replace(nlp.options, starts=1)
    pool = new_pool(jobs, "spawn")
    try:
        futures = [
            pool.submit(
                _worker_start, nlp.model.robot, nlp.robot, nlp.mission, nlp.q_B0, options, g
            )
            for _, g in guesses
        ]
        out = [f.result() for f in futures]
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)
    return out


def workers_for(starts: int) -> int:
    """Worker processes for ``starts`` starts: one per CPU, at most one per start (1: in this
    process)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(starts, cpus or 1))


def multi_start(nlp, guess, jobs: int | None = None):
    """Solve from ``options.starts`` guesses (see the module docstring) and keep the plan of
    the smallest objective; ``info["starts"]`` holds every start's outcome and the spread.

    Args:
        nlp: the problem (a :class:`~balance_opt.optimal.solve.BalanceNLP`).
        guess: the first start's guess.
        jobs: worker processes (default :func:`workers_for`; 1 solves in this process).

    Raises:
        SolverError: every start failed (the first start's error, or its message and status).
    """
    guesses = start_guesses(nlp, guess)
    jobs = workers_for(len(guesses)) if jobs is None else max(1, jobs)
    if jobs > 1:
        outcomes = _run_parallel(nlp, guesses, jobs)
    else:
        outcomes = [_solve_here(nlp, g) for _, g in guesses]
    best, first_error, runs = None, None, []
    for (label, _), (result, error) in zip(guesses, outcomes):
        if result is None:
            if first_error is None:
                first_error = (
                    error if isinstance(error, SolverError) else SolverError(error[0], error[1])
                )
            runs.append({"guess": label, "status": str(first_error.status)})
            continue
        runs.append({"guess": label, **_outcome(result)})
        if best is None or result.info["objective"] < best.info["objective"]:
            best = result
    if best is None:
        raise first_error
    solved = [r for r in runs if "objective" in r]
    best.info["starts"] = {
        "runs": runs,
        "solved": len(solved),
        "workers": jobs,
        "objective_spread": float(
            max(r["objective"] for r in solved) - min(r["objective"] for r in solved)
        ),
        "max_drift_spread_rad": float(
            max(r["max_drift_rad"] for r in solved) - min(r["max_drift_rad"] for r in solved)
        ),
    }
    return best
