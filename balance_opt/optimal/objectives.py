"""The objective's terms of the balance NLP (:class:`~balance_opt.optimal.terms.Term`), summed
in the order of the structure's terms: the running cost, the final attitude, the peak (its
epigraph, or the smooth peak of its inner stage) and the jerk price.

The ``integral`` objective is the running cost and the final attitude; the ``peak`` objective
adds the epigraph's ``peak * s^2`` and the jerk price and scales the running cost down by
``regularisation`` (:class:`~balance_opt.optimal.options.CostWeights`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from math import comb

import casadi as cs
import numpy as np

from balance_opt.optimal.constraints import PathAttitudeBound
from balance_opt.optimal.layout import Block
from balance_opt.optimal.terms import (
    Output,
    Rows,
    Size,
    SymbolicNLP,
    Term,
    block_rows,
    points_per_interval,
)

#: Unit of the peak objective's epigraph variable: ``S = peak^2 / PEAK_SCALE^2`` [rad], so that
#: ``S`` is of order 1 on drifts of a few hundredths of a radian.
PEAK_SCALE = 0.01
#: Exponent ``p`` of the smooth peak (the ``smooth`` stage of the peak objective): the drift's
#: weighted L_p norm to the power p, ``sum_k q_k (|phi_k| / c)^p``.
PEAK_POWER = 16


class RunningCost(Term):
    """``int L dt`` by the transcription's quadrature, ``L = omega |omega_b|^2 + attitude
    |phi|^2 + smoothness |u|^2 + rest |q_B - q_rest|^2`` computed by the point kernels (its
    weights and ``q_rest`` are their inputs); scaled by ``regularisation`` in the peak
    objective's structures (``regularised``)."""

    name = "running cost"
    #: the weights of ``L``'s parts (:class:`~balance_opt.optimal.options.CostWeights`), in
    #: the order of the kernels' input ``running_weights``
    weights = ("omega", "attitude", "smoothness", "rest")

    def __init__(self, regularised: bool):
        self.regularised = regularised

    def outputs(self, model):
        def running(p):
            w, dq = p.inputs["running_weights"], p.x[3 : 3 + model.n_B] - p.inputs["q_rest"]
            phi = p.x[:3]
            return (
                w[0] * cs.dot(p.omega, p.omega)
                + w[1] * cs.dot(phi, phi)
                + w[2] * cs.dot(p.u, p.u)
                + w[3] * cs.dot(dq, dq)
            )

        inputs = (("running_weights", len(self.weights)), ("q_rest", model.n_B))
        return (Output(self.name, 1, "", running, inputs=inputs, with_dynamics=True),)

    def values(self, problem):
        weights = problem.options.weights
        factor = weights.regularisation if self.regularised else 1.0
        values = factor * np.array([getattr(weights, name) for name in self.weights])
        return {"running_weights": values, "q_rest": problem.q_rest}

    def cost(self, nlp: SymbolicNLP):
        quadrature = cs.DM(nlp.transcription.quadrature_weights(nlp.key.intervals))
        return nlp.parameters.h * cs.mtimes(nlp.outputs[self.name], quadrature)

    def size(self, n_B, transcription):
        """The controls' squares: a Hessian entry per point and control."""
        return Size(0, 0, points_per_interval(transcription) * n_B)


class TerminalCost(Term):
    """``terminal |log R_T|^2`` (``peak_terminal`` in the peak objective's structures)."""

    name = "terminal cost"

    def __init__(self, weight: str):
        self.weight = weight

    def values(self, problem):
        return {"terminal_weight": getattr(problem.options.weights, self.weight)}

    def cost(self, nlp: SymbolicNLP):
        N = nlp.key.intervals
        return nlp.parameters.terminal_weight * cs.sumsqr(nlp.variables.X[:3, N])


class PeakEpigraph(PathAttitudeBound):
    """The peak objective's epigraph: ``peak * s^2`` priced through the variable ``S`` with
    ``|phi_k|^2 / PEAK_SCALE^2 <= S`` at every collocation point, ``S >= 0``; with a path
    attitude bound, ``S`` is bounded by it (tightened by the refinement:
    ``problem.bounds.path``), and its check is the bound's."""

    name = "peak epigraph"
    row_nonzeros = 4  # the point's attitude and S

    def values(self, problem):
        return {"peak_weight": problem.options.weights.peak}

    def variables(self):
        label = ("attitude peak^2 / PEAK_SCALE^2",)
        return (Block("S", label, ("(relative)",), np.array([0.0])),)

    def cost(self, nlp: SymbolicNLP):
        return nlp.parameters.peak_weight * PEAK_SCALE**2 * nlp.variables.S

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        X, _ = nlp.variables.points()
        values = cs.sum1(X[:3, :] ** 2) / PEAK_SCALE**2 - nlp.variables.S
        label = "attitude |phi|^2 / PEAK_SCALE^2 - S"
        return block_rows(nlp, self.name, [label], "(relative)", values)

    def row_bounds(self, problem, block):
        return np.full(block.size, -np.inf), np.zeros(block.size)

    def bound_variables(self, problem, lower, upper):
        # a re-plan's: at least the peak the motion already had
        lower.S[:] = 0.0 if problem.start is None else (problem.start.peak / PEAK_SCALE) ** 2
        bound = problem.bounds.path
        upper.S[:] = np.inf if bound is None else (bound / PEAK_SCALE) ** 2


class SmoothPeak(Term):
    """The peak objective's ``smooth`` stage: ``sum_k q_k (|phi_k| / c)^PEAK_POWER`` over the
    collocation points, ``q_k`` the quadrature weights scaled to sum to 1: the drift's L_p norm
    to the power p, which prices the peak and, unlike the epigraph, has no inequality rows
    (Ipopt solves it like the integral objective); separable over the points. Weighted to cost
    what ``peak * s^2`` does at ``|phi| = c`` (``problem.bounds.peak_reference``, see
    :func:`~balance_opt.optimal.refine.plan_peak`)."""

    name = "smooth peak"

    def values(self, problem):
        c = problem.bounds.peak_reference
        weight = 2.0 * problem.options.weights.peak * c**2 / PEAK_POWER
        return {"smooth_weight": weight, "smooth_scale": 1.0 / c**2}

    def cost(self, nlp: SymbolicNLP):
        par, weights = nlp.parameters, nlp.transcription.quadrature_weights(nlp.key.intervals)
        X, _ = nlp.variables.points()
        ratio = cs.sum1(X[:3, :] ** 2) * par.smooth_scale
        q = cs.DM(weights / weights.sum())
        return par.smooth_weight * cs.mtimes(ratio ** (PEAK_POWER // 2), q)


class JerkPrice(Term):
    """``regularisation * jerk * int |q_dddot_B|^2 dt`` over the continuous plan (the peak
    objective's: its plans are bang-bang with singular arcs, and without a price on the
    changes of the accelerations the solver stops on a chattering one). Only the peak
    objective's own plan prices it: its inner stages are warm starts, with no price to bend
    them."""

    name = "jerk price"

    def __init__(self, control: str):
        self.control = control

    def values(self, problem):
        weights = problem.options.weights
        priced = problem.options.objective == "peak"
        return {"jerk_weight": weights.regularisation * weights.jerk if priced else 0.0}

    def cost(self, nlp: SymbolicNLP):
        return nlp.parameters.jerk_weight * jerk_integral(nlp.levels[2], nlp.parameters.h)

    def size(self, n_B, transcription):
        """It couples an interval's controls (a Hessian entry per joint and pair of them)."""
        if transcription.has_midpoints:
            return Size(0, 0, 3 * n_B)
        return Size(0, 0, (1 if self.control == "jerk" else 2) * n_B)


@dataclass(frozen=True)
class Objective:
    """An objective of a structure (``StructureKey.objective``): the terms it adds to every
    structure's (after the limits and torques, before the bounds: their rows' order), whether
    it prices the running cost scaled by ``regularisation`` and the final attitude by
    ``peak_terminal`` (``regularised``), and whether a plan of it is solved through the
    options' stages (``staged``: :func:`~balance_opt.optimal.refine.plan_peak`)."""

    terms: Callable[[str], tuple[Term, ...]]  # of the control
    regularised: bool = False
    staged: bool = False


#: The objectives by name: a new one is an entry (and its terms); ``"smooth"`` is the peak
#: objective's inner stage. ``objective: time`` searches the horizon with peak plans
#: (:func:`~balance_opt.optimal.solve.fastest`).
OBJECTIVES = {
    "integral": Objective(lambda control: ()),
    "smooth": Objective(lambda control: (SmoothPeak(),), regularised=True),
    "peak": Objective(
        lambda control: (PeakEpigraph(), JerkPrice(control)), regularised=True, staged=True
    ),
}


def objective_of(options) -> Objective:
    """The objective a plan of the planner ``options`` solves (``time``: peak plans)."""
    return OBJECTIVES["peak" if options.objective == "time" else options.objective]


def jerk_integral(acceleration: list, h):
    """``int |q_dddot|^2 dt`` of a piecewise polynomial acceleration, summed over its joints."""
    d = len(acceleration) - 1
    if d == 0:  # a constant per interval: the steps are all there is
        jumps = acceleration[0][:, :-1] - acceleration[0][:, 1:]
        return _sum_all(jumps * jumps) / h
    m, total = d - 1, 0
    b = [(d / h) * (acceleration[i + 1] - acceleration[i]) for i in range(d)]
    for i in range(m + 1):
        for j in range(m + 1):
            gram = comb(m, i) * comb(m, j) / ((2 * m + 1) * comb(2 * m, i + j))
            total = total + h * gram * _sum_all(b[i] * b[j])
    return total


def _sum_all(x):
    return cs.sum1(cs.sum2(x)) if isinstance(x, (cs.SX, cs.MX, cs.DM)) else np.sum(x)
