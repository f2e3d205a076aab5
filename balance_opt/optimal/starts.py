"""Multi-start of the optimal planner: ``options.starts`` initial guesses, the plan of the
smallest objective kept.

The guesses are the chosen one, the other named one (``analytic``, ``rest``), then smooth
random motions drawn in this process from ``options.seed`` (so a run is reproducible whatever
runs the starts). The starts are mapped over an executor the caller passes (anything with
``map``, e.g. a :class:`concurrent.futures.ProcessPoolExecutor` or a Dask client's executor),
by default one after the other in this process. A start sent to another process pickles as the
problem's data, not its compiled NLPs: the process builds the problem it solves (the compiled
kernels come from the on-disk cache).

A plan through the peak problem (the peak objective, or a path attitude bound) begins with the
integral objective's plan (:func:`~balance_opt.optimal.refine.plan_peak`), and different
starts often reach the same one: every start runs that first
stage, those whose plans agree (:data:`SAME_PLAN`, :data:`SAME_CONTROL`) are merged, and only
the distinct ones go on through the later stages, the bounds and the refinement.
``info["starts"]`` reports every start (a merged one names the start it joined), the
distinct plans and ``workers`` (1: this process; ``None``: an executor's).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.optimal.guess import random_guess
from balance_opt.optimal.options import GUESSES, PEAK_STAGES
from balance_opt.optimal.refine import IntegralStart, integral_stage, solve_with_bounds

log = logging.getLogger(__name__)

#: Largest difference between two first-stage plans' states (rad, rad/s) under which they are
#: one plan.
SAME_PLAN = 1e-4
#: The same for their controls (rad/s^2, or rad/s^3 with jerk control): Ipopt's tolerance
#: leaves more in them than in the states.
SAME_CONTROL = 1e-3


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


class StartTask:
    """One phase of a start on a problem, a callable of the start's guess: ``"first"`` the
    integral stage (its :class:`~balance_opt.optimal.refine.IntegralStart`), ``"plan"`` the
    whole solve (``(result, None)`` or ``(None, error)``; in another process the error as
    ``(message, status)``: the planner's errors do not pickle).

    Pickled, it is the problem's data (robot, mission, ``q_B0``, options, ``h0``, the stage);
    unpickled, it builds that problem."""

    def __init__(self, nlp, phase: str):
        self.nlp, self.phase, self.remote = nlp, phase, False

    def __getstate__(self) -> dict:
        n, key = self.nlp, self.nlp.structure.key
        stage = None if key.between_points else key.objective
        data = (n.model.robot, n.robot, n.mission, n.q_B0, n.options, n.h0, stage)
        # the problem's own class rebuilds it (pickled by reference: no import of solve here)
        return {"build": type(n).from_data, "data": data, "phase": self.phase}

    def __setstate__(self, state: dict) -> None:
        self.nlp = state["build"](*state["data"])
        self.phase, self.remote = state["phase"], True

    def __call__(self, guess):
        if self.phase == "first":
            return integral_stage(self.nlp, guess)
        try:
            return solve_with_bounds(self.nlp, guess), None
        except SolverError as exc:
            return None, ((str(exc), str(exc.status)) if self.remote else exc)


def same_first_plan(a: IntegralStart, b: IntegralStart) -> bool:
    """Two first stages reached one plan: both solved, states within :data:`SAME_PLAN`,
    controls within :data:`SAME_CONTROL`."""
    if not (a.report.success and b.report.success):
        return False
    x, y = a.following, b.following
    return bool(np.abs(x.X - y.X).max() <= SAME_PLAN and np.abs(x.U - y.U).max() <= SAME_CONTROL)


def multi_start(nlp, guess, executor=None):
    """Solve from ``options.starts`` guesses (see the module docstring) and keep the plan of
    the smallest objective; ``info["starts"]`` holds every start's outcome and the spread.

    Args:
        nlp: the problem (a :class:`~balance_opt.optimal.solve.BalanceNLP`).
        guess: the first start's guess.
        executor: what runs the starts (its ``map``); ``None``: this process, in turn.

    Raises:
        SolverError: every start failed (the first start's error, or its message and status).
    """
    run = map if executor is None else executor.map
    guesses = start_guesses(nlp, guess)
    single = nlp.variant(starts=1)
    starting = [g for _, g in guesses]
    owner = list(range(len(starting)))
    if nlp.options.objective == "peak" or nlp.options.path_attitude_bound is not None:
        # decision vectors as states and controls: the first stage's problem needs no other
        starting = [
            nlp.unpack(nlp.initial_guess(g)) if isinstance(g, np.ndarray) else g for g in starting
        ]
        first = list(run(StartTask(single.at_stage(PEAK_STAGES[0]), "first"), starting))
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
        runs.append({**entry, **_outcome(result)})
        if best is None or result.info["objective"] < best.info["objective"]:
            best = result
    if best is None:
        raise first_error
    done = [r for r in runs if "objective" in r]
    log.info("multi-start: %d starts, %d solved, %d distinct", len(runs), len(done), len(distinct))
    best.info["starts"] = {
        "runs": runs,
        "solved": len(done),
        "distinct": len(distinct),
        "workers": 1 if executor is None else None,  # an executor's own count is its own
        "objective_spread": _spread(done, "objective"),
        "max_drift_spread_rad": _spread(done, "max_drift_rad"),
    }
    return best


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


def _spread(runs: list[dict], key: str) -> float:
    return float(max(r[key] for r in runs) - min(r[key] for r in runs))
