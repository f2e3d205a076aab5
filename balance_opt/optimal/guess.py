"""Initial guesses of the balance NLP: a sampled balance-arm motion turned into a point of the
NLP."""

from __future__ import annotations

import logging

import numpy as np

from balance_opt.errors import InputError, SolverError
from balance_opt.motion.result import BalanceResult
from balance_opt.optimal.layout import Solution
from balance_opt.optimal.options import GUESSES
from balance_opt.optimal.problem import BalanceProblem
from balance_opt.optimal.timing import guess_timing

log = logging.getLogger(__name__)


def guess_solution(problem: BalanceProblem, guess) -> Solution:
    """The guess named by ``guess``, unclipped."""
    if isinstance(guess, BalanceResult):
        return from_samples(problem, guess.t, guess.q_B, guess.q_dot_B, guess.q_ddot_B)
    if guess not in GUESSES:
        raise InputError(
            f"initial guess must be one of {', '.join(GUESSES)} or a BalanceResult, got {guess!r}"
        )
    if guess == "analytic":
        try:
            return analytic_guess(problem)
        except SolverError as exc:
            log.info("analytic law failed (%s); starting from rest", exc)
    # the balance arm held at q_B0, the attitude it leaves (Phase I's)
    q_B, t = np.tile(problem.q_B0, (2, 1)), np.array([0.0, problem.horizon])
    return from_samples(problem, t, q_B, np.zeros_like(q_B), np.zeros_like(q_B))


def random_guess(problem: BalanceProblem, rng) -> Solution:
    """A smooth random balance motion from rest to rest: ``q_B0`` plus three raised-cosine
    modes per joint with amplitudes drawn up to 0.5 rad (the m-th mode's divided by m),
    clipped to the limits by :func:`from_samples`."""
    T, n_B = problem.horizon, problem.model.n_B
    t = np.linspace(0.0, T, max(4 * problem.N + 1, 201))
    q, qd, qdd = (
        np.tile(problem.q_B0, (t.size, 1)),
        np.zeros((t.size, n_B)),
        np.zeros((t.size, n_B)),
    )
    for m in (1, 2, 3):
        a = rng.uniform(-0.5, 0.5, size=n_B) / m
        w = 2.0 * np.pi * m / T
        q += 0.5 * np.outer(1.0 - np.cos(w * t), a)
        qd += 0.5 * w * np.outer(np.sin(w * t), a)
        qdd += 0.5 * w**2 * np.outer(np.cos(w * t), a)
    return from_samples(problem, t, q, qd, qdd)


def analytic_guess(problem: BalanceProblem) -> Solution:
    """The analytic law's balance motion (Eq. 31, 32), clipped to the limits."""
    from balance_opt.analytic.options import BalanceLawOptions
    from balance_opt.analytic.rollout import rollout
    from balance_opt.motion.options import IntegrationOptions

    t = np.linspace(0.0, problem.horizon, max(4 * problem.N + 1, 201))
    law = BalanceLawOptions(h0=tuple(problem.h0.tolist()))
    # a starting point needs no 1e-10 tolerance: Ipopt ends at the same plan from 1e-6
    loose = IntegrationOptions(rtol=1e-6, atol=1e-9)
    mission = problem.timed_mission
    plan = rollout(problem.robot, mission, problem.q_B0, law, t_eval=t, integration=loose)
    return from_samples(problem, plan.t, plan.q_B, plan.q_dot_B, plan.q_ddot_B)


def from_samples(problem: BalanceProblem, t, q_B, q_dot_B, q_ddot_B) -> Solution:
    """A point of the NLP from sampled balance motion (T, n_B) at times ``t`` (T,):
    interpolated at the points, clipped to the limits, the initial state imposed and the
    attitude integrated along it. With control ``"jerk"`` the jerk is the acceleration's
    finite difference at the nodes (midpoints: the mean of the two nodes')."""
    pts, lim, N = problem.point_times, problem.limits, problem.N
    has_midpoints = problem.transcription.has_midpoints

    def at(values):
        values = np.atleast_2d(values)
        return np.array([np.interp(pts, t, values[:, j]) for j in range(values.shape[1])])

    q = np.clip(at(q_B).T, lim.lower, lim.upper).T
    qd = np.clip(at(q_dot_B).T, -lim.velocity, lim.velocity).T
    qdd = np.clip(at(q_ddot_B).T, -lim.acceleration, lim.acceleration).T
    if problem.control == "jerk":
        states = np.vstack([q, qd, qdd])
        u = np.gradient(qdd[:, : N + 1], problem.h, axis=1)
        u = np.hstack([u, 0.5 * (u[:, :-1] + u[:, 1:])]) if has_midpoints else u
    else:
        states, u = np.vstack([q, qd]), qdd
    Z = np.vstack([np.zeros((3, pts.size)), states])
    sol = Solution(
        Z[:, : N + 1].copy(),
        u[:, : N + 1].copy(),
        Z[:, N + 1 :].copy() if has_midpoints else None,
        u[:, N + 1 :].copy() if has_midpoints else None,
    )
    sol.X[3:, 0] = problem.unpack(problem.lbx).X[3:, 0]
    attitude_along(problem, sol)
    if problem.free_timing:  # the mission at the given timing, stretched to the horizon
        guess_timing(problem, sol)
    return sol


def attitude_along(problem: BalanceProblem, sol: Solution) -> None:
    """Fill the attitude rows of ``sol`` with the transcription's quadrature, from ``phi = 0``,
    of the base rate ``omega_b`` its joint motion forces (the nodes by the Simpson or
    trapezoidal rule, the midpoints by the Hermite interpolation). ``phi_dot = Jr^{-1}(phi)
    omega_b`` is ``omega_b`` up to terms of order ``|phi| |omega_b|``: a guess, not a solution
    of the defects."""
    dyn = problem.model.dynamics_fun(problem.control).map(problem.point_times.size)
    Z, V = sol.points()
    Z = Z.copy()
    Z[:3] = 0.0
    _, omega = dyn(Z, V, problem.mission_samples)
    omega = np.array(omega)
    N, h = problem.N, problem.h
    w0, w1 = omega[:, :N], omega[:, 1 : N + 1]
    if problem.transcription.has_midpoints:
        step = h / 6.0 * (w0 + 4.0 * omega[:, N + 1 :] + w1)
    else:
        step = h / 2.0 * (w0 + w1)
    sol.X[:3] = np.hstack([np.zeros((3, 1)), np.cumsum(step, axis=1)])
    if sol.Xm is not None:
        sol.Xm[:3] = 0.5 * (sol.X[:3, :-1] + sol.X[:3, 1:]) + h / 8.0 * (w0 - w1)


def resampled(sol: Solution, N: int) -> Solution:
    """The point ``sol`` of an NLP on another number of intervals ``N`` over the same horizon
    (the same transcription; ``S`` is dropped): on each of its intervals, its states and its
    controls are interpolated through the interval's points, by the quadratic through the
    nodes and the midpoint (Hermite-Simpson) or linearly (trapezoidal): a guess, whose defects
    Ipopt removes in its first iterations. Points both grids share keep their values exactly."""
    n = sol.X.shape[1] - 1
    # a free timing's progress too (its mission joints follow from it: guess_timing)
    pairs = [("X", "U")] + ([("P", "A")] if sol.P is not None else [])
    names = [a + m for pair in pairs for m in ("", "m") for a in pair]
    if n == N:
        copies = {k: getattr(sol, k) for k in names}
        return Solution(**{k: None if v is None else v.copy() for k, v in copies.items()})
    has_midpoints = sol.Xm is not None
    nodes = np.arange(N + 1) * (n / N)  # the new points in units of sol's intervals
    taus = [nodes, nodes[:-1] + 0.5 * (n / N)] if has_midpoints else [nodes]
    out = {}
    for pair in pairs:
        for a in pair:
            v = [_interpolate(getattr(sol, a), getattr(sol, a + "m"), tau) for tau in taus]
            out[a], out[a + "m"] = v[0], (v[1] if has_midpoints else None)
    return Solution(**out)


def _interpolate(a: np.ndarray, mid: np.ndarray | None, tau: np.ndarray) -> np.ndarray:
    """Rows ``a`` at the nodes (and ``mid`` at the midpoints) of ``n`` unit intervals, at
    ``tau`` in [0, n]: each interval's interpolating polynomial."""
    n = a.shape[1] - 1
    k = np.minimum(tau.astype(int), n - 1)
    s = tau - k
    a0, a1 = a[:, k], a[:, k + 1]
    if mid is None:
        return a0 + s * (a1 - a0)
    # Lagrange basis of the nodes s = 0, 1 and the midpoint s = 1/2
    return (
        a0 * ((1.0 - s) * (1.0 - 2.0 * s))
        + mid[:, k] * (4.0 * s * (1.0 - s))
        + a1 * (s * (2.0 * s - 1.0))
    )
