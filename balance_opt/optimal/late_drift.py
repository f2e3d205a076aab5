"""The late drift: the drift priced with a weight that rises over the motion's last seconds
(``PlannerOptions.late_drift``), a term of the closed loop's plans
(``docs/executable-plans.md``, "Seventh round").

Its weight is a function of the time left to the end, not of the time since the plan's start:
a re-plan's tail ends where the first plan does, so the first plan and every re-plan price the
same drift at the same instant the same (one objective: without model error a re-plan keeps the
plan's tail, Bellman)."""

from __future__ import annotations

import casadi as cs
import numpy as np

from balance_opt.optimal.terms import SymbolicNLP, Term


def late_weights(weight: float, window: float, to_go: np.ndarray) -> np.ndarray:
    """The late drift's weight [1/(rad^2 s)] at the times ``to_go`` [s] before the end: 0 until
    ``window`` seconds before it, then rising as the square of the time into the window to
    ``weight`` at the end (its rate starts at zero: no kink in the plan's objective)."""
    rise = np.clip(1.0 - np.asarray(to_go, dtype=float) / window, 0.0, 1.0)
    return weight * rise**2


class LateDrift(Term):
    """``int w(t) |phi|^2 dt`` by the transcription's quadrature, ``w`` :func:`late_weights` of
    the time left (``late_drift = (weight, window)`` of the planner options); the epigraph
    stage's only (the inner stages are warm starts)."""

    name = "late drift"

    def values(self, problem):
        weight, window = problem.options.late_drift
        to_go = problem.N * problem.h - problem.point_times
        quadrature = problem.transcription.quadrature_weights(problem.N)
        return {"late_weights": late_weights(weight, window, to_go) * quadrature}

    def cost(self, nlp: SymbolicNLP):
        X, _ = nlp.variables.points()
        drift = cs.sum1(X[:3, :] ** 2)
        return nlp.parameters.h * cs.mtimes(drift, nlp.parameters.late_weights)
