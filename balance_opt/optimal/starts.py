"""Multi-start of the optimal planner: ``options.starts`` initial guesses solved in parallel
processes, the plan of the smallest objective kept.

The guesses are the chosen one, the other named one (``analytic``, ``rest``), then smooth
random motions drawn in this process from ``options.seed`` (so a run is reproducible whatever
the number of workers). With more than one start and more than one CPU the starts run in a
pool of ``spawn`` workers (at most one per CPU): each worker builds its own
:class:`~balance_opt.optimal.model.PlannerModel` from the pickled robot once, loading the
compiled kernel library from the on-disk cache, and keeps it for its next starts.

A plan through the peak problem (the peak objective, or a path attitude bound) begins with the
integral objective's plan (:func:`~balance_opt.optimal.refine.plan_peak`), and different
starts often reach the same one (on the capture task all eight do): the starts run that first
stage, those whose plans agree (:data:`SAME_PLAN`) are merged, and only the distinct ones go on
through the later stages, the bounds and the refinement. ``info["starts"]`` reports every start
(a merged one names the start it joined).
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.optimal.guess import random_guess
from balance_opt.optimal.options import GUESSES, SUCCESS_STATUSES

#: Largest difference between two first-stage plans' decision vectors (rad, rad/s, rad/s^2)
#: under which they are one plan.
SAME_PLAN = 1e-4

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


def _run(nlp, guess, phase: str):
    """One start's ``phase`` in this process: ``"first"`` the integral stage (an
    :class:`~balance_opt.optimal.refine.IntegralStart`), ``"plan"`` the whole solve:
    ``(result, None)`` or ``(None, error)``."""
    from balance_opt.optimal.refine import integral_stage, solve_with_bounds

    nlp = nlp.variant(starts=1)
    if phase == "first":
        return integral_stage(nlp, guess), None
    try:
        return solve_with_bounds(nlp, guess), None
    except SolverError as exc:
        return None, exc


def _worker(build, model_robot, robot, mission, q_B0, options, h0, guess, phase):
    """:func:`_run` in a worker process (see the module docstring) on the problem ``build``
    (:func:`~balance_opt.optimal.solve.build_balance_nlp`, pickled by name) makes; an error
    comes back as ``(message, status)``: the planner's errors do not pickle."""
    from balance_opt.optimal.model import PlannerModel

    key = (model_robot.name, tuple(model_robot.joint_names))
    if key not in _WORKER_MODELS:
        _WORKER_MODELS[key] = PlannerModel(model_robot)
    nlp = build(_WORKER_MODELS[key], mission, q_B0, options, robot, h0=h0)
    result, error = _run(nlp, guess, phase)
    return (result, None) if error is None else (None, (str(error), str(error.status)))


class _Runner:
    """Runs starts in this process or in a pool of worker processes."""

    def __init__(self, nlp, jobs: int):
        self.nlp, self.pool = nlp, None
        if jobs > 1:
            from balance_opt.sweep.workers import new_pool

            self.pool = new_pool(jobs, "spawn")

    def map(self, guesses: list, phase: str) -> list:
        if self.pool is None:
            return [_run(self.nlp, g, phase) for g in guesses]
        nlp = self.nlp
        options = dataclasses.replace(nlp.options, starts=1)
        args = (type(nlp).build, nlp.model.robot, nlp.robot, nlp.mission, nlp.q_B0, options, nlp.h0)
        futures = [self.pool.submit(_worker, *args, g, phase) for g in guesses]
        return [f.result() for f in futures]

    def close(self, failed: bool) -> None:
        if self.pool is None:
            return
        from balance_opt.sweep.workers import stop_pool

        stop_pool(self.pool) if failed else self.pool.shutdown(wait=True)


def workers_for(starts: int) -> int:
    """Worker processes for ``starts`` starts: one per CPU, at most one per start (1: in this
    process)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(starts, cpus or 1))


def _merge(firsts: list) -> list[int]:
    """For each first-stage outcome the index of the first start with the same plan."""
    owner, vectors = [], []
    for i, (first, _) in enumerate(firsts):
        ok = first is not None and first.report["status"] in SUCCESS_STATUSES
        w = np.concatenate([first.following.X.ravel(), first.following.U.ravel()]) if ok else None
        match = next(
            (j for j, v in vectors if w is not None and np.abs(v - w).max() <= SAME_PLAN), i
        )
        if match == i and w is not None:
            vectors.append((i, w))
        owner.append(match)
    return owner


def _solve_all(runner: _Runner, nlp, guesses) -> tuple[list, list]:
    """Every start's ``(result, error)`` and the start each was merged into."""
    through_peak = nlp.options.objective == "peak" or nlp.options.path_attitude_bound is not None
    if not through_peak:
        return runner.map([g for _, g in guesses], "plan"), list(range(len(guesses)))
    firsts = runner.map([g for _, g in guesses], "first")
    owner = _merge(firsts)
    distinct = sorted(set(owner))
    solved = dict(zip(distinct, runner.map([firsts[i][0] for i in distinct], "plan")))
    return [solved[owner[i]] for i in range(len(guesses))], owner


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
    runner, failed = _Runner(nlp, jobs), True
    try:
        outcomes, owner = _solve_all(runner, nlp, guesses)
        failed = False
    finally:
        runner.close(failed)
    best, first_error, runs = None, None, []
    for i, ((label, _), (result, error)) in enumerate(zip(guesses, outcomes)):
        run = {"guess": label} if owner[i] == i else {"guess": label, "same_as": owner[i]}
        if result is None:
            if first_error is None:
                first_error = (
                    error if isinstance(error, SolverError) else SolverError(error[0], error[1])
                )
            runs.append({**run, "status": str(first_error.status)})
            continue
        runs.append({**run, **_outcome(result)})
        if best is None or result.info["objective"] < best.info["objective"]:
            best = result
    if best is None:
        raise first_error
    solved = [r for r in runs if "objective" in r]
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
