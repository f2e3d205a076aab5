"""Runge-Kutta-Munthe-Kaas integrators of the free-floating dynamics on the manifold of Pinocchio
configurations (``docs/physics.md``, "Attitude"): a step works in the local coordinates ``u``
of ``q = pin.integrate(q_n, u)``, with ``u_dot = dDifference(q_n, q) v``, so plain RK in ``u``
keeps its order. :func:`rk4` (fixed step, the plan sampled at every stage time first) and
:func:`dopri5` (Dormand-Prince 5(4), error control on the tangent increments, landing on every
output time) take ``dyn(q, v, q_des, q_dot_des, q_ddot_des[, tau_des]) -> (a, tau)`` and the plan
as ``plan.sample(t)`` in arm order; ``dyn.check(t, q, v, q_des, v_des)`` stops a diverging
state at every output sample.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError

#: Step-size control of the adaptive integrator: safety factor and bounds of the step ratio.
STEP_SAFETY = 0.9
STEP_GROWTH_MAX = 5.0
STEP_SHRINK_MIN = 0.2
#: Smallest step the adaptive integrator accepts before giving up [s].
MIN_STEP = 1e-10


# Dormand-Prince 5(4): nodes, stage matrix, 5th-order weights (the solution) and 4th-order weights.
_DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
_DP_A = np.array(
    [
        [0, 0, 0, 0, 0, 0, 0],
        [1 / 5, 0, 0, 0, 0, 0, 0],
        [3 / 40, 9 / 40, 0, 0, 0, 0, 0],
        [44 / 45, -56 / 15, 32 / 9, 0, 0, 0, 0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0, 0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0, 0],
        [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0],
    ]
)
_DP_B5 = _DP_A[6]
_DP_B4 = np.array([5179 / 57600, 0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40])
_ARG1 = pin.ArgumentPosition.ARG1


def _stage(dyn, q, du, vs, planned):
    """One stage from ``q``: the configuration ``integrate(q, du)`` moving at ``vs``, its
    acceleration and torque with the plan ``planned`` at the stage's time, and its rate in the
    local coordinates, ``dDifference(q, qs) vs``: ``(qs, a, tau, u)``."""
    qs = pin.integrate(dyn.model, q, du)
    a, tau = dyn(qs, vs, *planned)
    return qs, a, tau, pin.dDifference(dyn.model, q, qs, _ARG1) @ vs


def rk4(dyn, plan, x0, t_end: float, dt: float, stride: int):
    """Fixed-step RKMK4 (see the module docstring). Returns output arrays and step counts."""
    model = dyn.model
    n_steps = max(1, math.ceil(t_end / dt - 1e-9))
    h = t_end / n_steps
    # planned joint state at every stage time: index 2k is t_k, 2k+1 is t_k + h/2
    grid = np.arange(2 * n_steps + 1) * (h / 2)
    P = plan.sample(grid)  # (q, q_dot, q_ddot[, the plan's torques]) per stage time
    out_steps = np.unique(np.r_[np.arange(0, n_steps, stride), n_steps])
    is_out = np.zeros(n_steps + 1, dtype=bool)
    is_out[out_steps] = True
    T = out_steps.size
    Q, V, A, TAU = (np.empty((T, m)) for m in (model.nq, model.nv, model.nv, dyn.idx_v.size))
    q, v = x0
    h2, h6 = h / 2, h / 6
    j = 0
    for k in range(n_steps):
        i = 2 * k
        a1, tau1 = dyn(q, v, *(X[i] for X in P))
        if is_out[k]:
            dyn.check(k * h, q, v, P[0][i], P[1][i])
            Q[j], V[j], A[j], TAU[j] = q, v, a1, tau1
            j += 1
        _, a2, _, u2 = _stage(dyn, q, h2 * v, v + h2 * a1, [X[i + 1] for X in P])
        _, a3, _, u3 = _stage(dyn, q, h2 * u2, v + h2 * a2, [X[i + 1] for X in P])
        _, a4, _, u4 = _stage(dyn, q, h * u3, v + h * a3, [X[i + 2] for X in P])
        q = pin.integrate(model, q, h6 * (v + 2.0 * (u2 + u3) + u4))
        v = v + h6 * (a1 + 2.0 * (a2 + a3) + a4)
    dyn.check(n_steps * h, q, v, P[0][-1], P[1][-1])
    a_end, tau_end = dyn(q, v, *(X[-1] for X in P))
    Q[j], V[j], A[j], TAU[j] = q, v, a_end, tau_end
    stats = {"steps": n_steps, "step_s": h, "rhs_evaluations": 4 * n_steps + 1}
    return out_steps * h, Q, V, A, TAU, stats


def dopri5(dyn, plan, x0, t_end: float, opts, output_dt: float):
    """Adaptive RKMK Dormand-Prince 5(4) with steps that land on the output times."""
    model = dyn.model
    n_out = max(1, math.ceil(t_end / output_dt - 1e-9))
    t_out = np.linspace(0.0, t_end, n_out + 1)
    nv = model.nv
    Q, V, A, TAU = (np.empty((t_out.size, m)) for m in (model.nq, nv, nv, dyn.idx_v.size))

    def planned(t):
        return [x[0] for x in plan.sample(np.array([t]))]

    q, v = x0
    t, h = 0.0, min(opts.dt, opts.max_step)
    a, tau = dyn(q, v, *planned(t))
    Q[0], V[0], A[0], TAU[0] = q, v, a, tau
    KU, KV = np.empty((7, nv)), np.empty((7, nv))
    accepted = rejected = evaluations = 0
    for j in range(1, t_out.size):
        while t < t_out[j]:
            step = min(h, t_out[j] - t)
            last = step >= t_out[j] - t
            KU[0], KV[0] = v, a
            for s in range(1, 7):
                du, vs = step * (_DP_A[s, :s] @ KU[:s]), v + step * (_DP_A[s, :s] @ KV[:s])
                qs, a_s, tau_s, KU[s] = _stage(dyn, q, du, vs, planned(t + _DP_C[s] * step))
                KV[s] = a_s
            evaluations += 6
            # the 7th stage sits at the new state (first same as last)
            dv5 = step * (_DP_B5 @ KV)
            eu, ev = step * ((_DP_B5 - _DP_B4) @ KU), step * ((_DP_B5 - _DP_B4) @ KV)
            v_new = v + dv5
            scale_u = opts.atol + opts.rtol
            scale_v = opts.atol + opts.rtol * np.maximum(np.abs(v), np.abs(v_new))
            err = math.sqrt((np.sum((eu / scale_u) ** 2) + np.sum((ev / scale_v) ** 2)) / (2 * nv))
            if err <= 1.0:
                t = t_out[j] if last else t + step
                # qs is integrate(q, du5): stage 7's nodes are the 5th-order weights
                q, v, a, tau = qs, v_new, a_s, tau_s
                accepted += 1
            else:
                rejected += 1
            factor = STEP_SAFETY * err**-0.2 if err > 0 else STEP_GROWTH_MAX
            h_new = step * min(STEP_GROWTH_MAX, max(STEP_SHRINK_MIN, factor))
            if not last or err > 1.0:  # a step cut short to land on an output time says little
                h = min(h_new, opts.max_step)
            if h < MIN_STEP:
                raise InputError(
                    f"adaptive integration stalled at t = {t:.6g} s (step {h:.3g} s below "
                    f"{MIN_STEP} s); loosen 'rtol'/'atol' or check the gains"
                )
        dyn.check(t, q, v, *planned(t)[:2])
        Q[j], V[j], A[j], TAU[j] = q, v, a, tau
    stats = {"steps": accepted, "rejected_steps": rejected, "rhs_evaluations": evaluations + 1}
    return t_out, Q, V, A, TAU, stats
