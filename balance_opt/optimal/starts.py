"""Multi-start of the optimal planner: ``options.starts`` initial guesses, the plan of the
smallest objective kept."""

from __future__ import annotations

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
    ``(message, status)``: the planner's errors do not pickle)."""

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
    the smallest objective; ``info["starts"]`` holds every start's outcome and the spread."""
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
