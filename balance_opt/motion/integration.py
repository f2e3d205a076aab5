"""Integration of an attitude state (a unit quaternion (x, y, z, w) first, then e.g. the balance
joints) on SO(3), and the output grids of rollouts and replays (``docs/physics.md``,
"Attitude"). ``"adaptive"``: SciPy's DOP853 with dense output, stopped after
``max_evaluations``; ``"rk4"``: fixed steps no longer than ``step``, renormalised after each.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from balance_opt import progress
from balance_opt.errors import InputError
from balance_opt.motion.options import IntegrationOptions

#: The scheme behind ``"adaptive"``.
ADAPTIVE_SCHEME = "DOP853"
#: Wall time between two progress lines of a long adaptive integration [s].
PROGRESS_EVERY_S = 2.0
#: Relative slack when splitting an output interval into RK4 steps.
_STEP_SLACK = 1e-9


# ---------------------------------------------------------------------------------- output grids
def output_grid(t_eval, duration: float | None, options: IntegrationOptions) -> np.ndarray:
    """The output times: ``t_eval`` checked, else 0 to ``duration`` [s] in
    ``round(duration / options.output_step)`` equal intervals; InputError when neither."""
    if t_eval is not None:
        t = np.asarray(t_eval, dtype=float).ravel()
        if t.size < 2 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
            raise InputError("output times must be at least 2 finite, strictly increasing values")
        return t
    if duration is None:
        raise InputError(
            "output times are needed: a trajectory given as a plain callable has no duration"
        )
    return np.linspace(0.0, duration, max(1, round(duration / options.output_step)) + 1)


# ---------------------------------------------------------------------------------- integration
def integrate(rhs: Callable, y0: np.ndarray, t: np.ndarray, options: IntegrationOptions):
    """Integrate ``y' = rhs(t, y)`` from ``y0`` over the output times ``t`` (the first the
    initial time). Returns ``(Y, stats, message)``: states with normalised quaternions (fewer
    rows when the integration failed), plain-data statistics, and ``None`` or the failure."""
    run = _adaptive if options.method == "adaptive" else _rk4
    Y, stats, message = run(rhs, y0, t, options)
    Y[:, :4] /= np.linalg.norm(Y[:, :4], axis=1, keepdims=True)
    return Y, stats, message


def _adaptive(rhs: Callable, y0: np.ndarray, t: np.ndarray, options: IntegrationOptions):
    """DOP853 stepped here rather than through ``solve_ivp``, so a law whose rates run away is
    stopped after ``options.max_evaluations``."""
    from scipy.integrate import DOP853  # scipy.integrate takes a while to import: on use

    solver = DOP853(
        rhs,
        t[0],
        np.array(y0, dtype=float),
        t[-1],
        rtol=options.rtol,
        atol=options.atol,
        max_step=options.step or np.inf,
    )
    Y = np.empty((t.size, len(y0)))
    Y[0] = y0
    k, message = 1, None
    shown = time.monotonic()
    while k < t.size:
        step_message = solver.step()
        if solver.status == "failed":
            message = f"{step_message} (at t = {solver.t:.6g} s)"
            break
        if t[k] <= solver.t:
            dense = solver.dense_output()
            while k < t.size and t[k] <= solver.t:
                Y[k] = dense(t[k])
                k += 1
        if k < t.size and solver.nfev >= options.max_evaluations:
            message = (
                f"stopped after {solver.nfev} right-hand side evaluations (max_evaluations) at "
                f"t = {solver.t:.6g} s of {t[-1]:.6g} s, steps down to {solver.step_size:.3g} s"
            )
            break
        if time.monotonic() - shown >= PROGRESS_EVERY_S:
            shown = time.monotonic()
            progress.status(
                f"integrating: t = {solver.t:.4g} of {t[-1]:.4g} s, step {solver.step_size:.3g} s, "
                f"{solver.nfev} right-hand side evaluations (at most {options.max_evaluations})"
            )
    stats = {
        "method": "adaptive",
        "scheme": ADAPTIVE_SCHEME,
        "rtol": options.rtol,
        "atol": options.atol,
        "rhs_evaluations": int(solver.nfev),
    }
    return Y[:k].copy(), stats, message


def rk4_stage_times(t: np.ndarray, options: IntegrationOptions):
    """``(times, n_sub, h)`` of the fixed-step RK4 to output times ``t``: the step starts (S),
    midpoints (S) and the end (1) in one array, ``n_sub`` equal steps per output interval (none
    longer than ``options.step``, else ``output_step``), each step's length (S,)."""
    step = options.step or options.output_step
    n_sub = np.maximum(1, np.ceil(np.diff(t) / step - _STEP_SLACK)).astype(int)
    h = np.repeat(np.diff(t) / n_sub, n_sub)
    first = np.repeat(np.cumsum(n_sub) - n_sub, n_sub)
    starts = np.repeat(t[:-1], n_sub) + (np.arange(h.size) - first) * h
    return np.concatenate([starts, starts + 0.5 * h, t[-1:]]), n_sub, h


def _rk4(rhs: Callable, y0: np.ndarray, t: np.ndarray, options: IntegrationOptions):
    times = rk4_stage_times(t, options)[0]
    return rk4_stages(lambda j, y: rhs(times[j], y), y0, t, options)


def rk4_stages(rate: Callable, y0: np.ndarray, t: np.ndarray, options: IntegrationOptions):
    """Classic RK4 to the output times ``t`` on :func:`rk4_stage_times`' steps, the quaternion
    renormalised after each: ``rate(j, y)`` is ``y'`` at stage time ``j`` (the caller may have
    evaluated what it needs at every stage time at once). Returns ``(Y, stats, message)`` as
    :func:`integrate`."""
    _, n_sub, h = rk4_stage_times(t, options)
    S = h.size
    ends = np.append(np.arange(1, S), 2 * S)  # a step's end is the next step's start
    Y = np.empty((t.size, y0.size))
    Y[0] = y = np.array(y0, dtype=float)
    s, message = 0, None
    for k in range(t.size - 1):
        for _ in range(n_sub[k]):
            hs, mid = h[s], S + s
            k1 = rate(s, y)
            k2 = rate(mid, y + 0.5 * hs * k1)
            k3 = rate(mid, y + 0.5 * hs * k2)
            k4 = rate(ends[s], y + hs * k3)
            y = y + (hs / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
            y[:4] /= np.linalg.norm(y[:4])
            s += 1
        if not np.all(np.isfinite(y)):
            message = f"non-finite state (at t = {t[k + 1]:.6g} s)"
            Y = Y[: k + 1]
            break
        Y[k + 1] = y
    step = options.step or options.output_step
    stats = {"method": "rk4", "step": step, "steps": int(S), "rhs_evaluations": 4 * int(S)}
    return Y, stats, message
