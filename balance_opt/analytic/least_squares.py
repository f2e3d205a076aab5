"""``J x = b`` for the balance rates (Eq. 31) by exact, damped or minimum-norm least squares
with a null-space term ``(I - V V^T) z``, and the exact time derivative of that solution
(Eq. 32); batched. Damped (``x = V S / (S^2 + lambda^2) U^T b``) where ``sigma_min`` is below
the threshold (``docs/physics.md``, "The balance law")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.model.coupling import N_ROTATIONS


def _safe_divide(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a / b`` with 0 where ``b == 0`` (the pseudo-inverse convention)."""
    return np.divide(a, b, out=np.zeros(np.broadcast(a, b).shape), where=b != 0)


def damping(sigma_min, threshold: float, max_damping: float) -> tuple[np.ndarray, np.ndarray]:
    """Variable damping and its derivative ``(lambda^2, d(lambda^2)/d(sigma_min))``:
    ``lambda_max^2 (1 - (sigma_min / epsilon)^2)^2`` below ``epsilon`` (``threshold``; 0 for
    none), else 0; zero slope at ``epsilon`` keeps ``q_ddot_B`` continuous."""
    sigma_min = np.asarray(sigma_min, dtype=float)
    if threshold <= 0:
        zero = np.zeros_like(sigma_min)
        return zero, zero
    gap = np.clip(1.0 - (sigma_min / threshold) ** 2, 0.0, None)
    return max_damping**2 * gap**2, -4.0 * max_damping**2 * gap * sigma_min / threshold**2


@dataclass
class VelocityLawSolution:
    """One solve of ``J_wB q_dot_B = b`` (Eq. 31), batched: ``q_dot_B``, ``b`` [rad/s], the
    ``residual`` damping leaves, ``sigma_min`` and ``damping``; the SVD and the rest are reused by
    :func:`acceleration_law`."""

    q_dot_B: np.ndarray
    b: np.ndarray
    residual: np.ndarray
    sigma_min: np.ndarray
    damping: np.ndarray
    J_wB: np.ndarray
    U: np.ndarray
    S: np.ndarray
    Vt: np.ndarray
    z: np.ndarray
    damping2_rate: np.ndarray

    @property
    def condition(self) -> np.ndarray:
        """Condition number of ``J_wB`` (``inf`` where singular)."""
        condition = _safe_divide(self.S[..., 0], self.sigma_min)
        condition[self.sigma_min == 0] = np.inf
        return condition


def velocity_law(
    J_wB: np.ndarray, b: np.ndarray, z: np.ndarray, options: BalanceLawOptions
) -> VelocityLawSolution:
    """Solve ``J_wB`` (..., 3, n_B) ``q_dot_B = b`` (Eq. 31), ``z`` (..., n_B) projected on the
    null space of ``J_wB``."""
    U, S, Vt = np.linalg.svd(J_wB, full_matrices=False)
    sigma_min = S[..., -1]
    lam2, dlam2 = damping(sigma_min, options.damping_threshold, options.max_damping)
    gain = _safe_divide(S, S**2 + lam2[..., None])
    q_dot_B = np.vecmat(gain * np.vecmat(b, U), Vt)
    if J_wB.shape[-1] > S.shape[-1]:  # redundant: exact null-space projection (I - V V^T) z
        q_dot_B = q_dot_B + z - np.vecmat(np.matvec(Vt, z), Vt)
    residual = np.matvec(J_wB, q_dot_B) - b
    return VelocityLawSolution(
        q_dot_B, b, residual, sigma_min, np.sqrt(lam2), J_wB, U, S, Vt, z, dlam2
    )


def acceleration_law(
    sol: VelocityLawSolution, dJ_wB: np.ndarray, b_dot: np.ndarray, z_dot: np.ndarray
) -> np.ndarray:
    """Balance joint accelerations (Eq. 32), the exact time derivative of :func:`velocity_law`
    (damping and null-space projector included), from ``dJ_wB``, ``b_dot`` and ``z_dot``."""
    J, U, S, Vt = sol.J_wB, sol.U, sol.S, sol.Vt
    lam2 = sol.damping**2
    denom = S**2 + lam2[..., None]
    # d(sigma_min)/dt = u^T dJ v, for the smallest singular triplet
    sigma_dot = np.einsum("...i,...ij,...j->...", U[..., :, -1], dJ_wB, Vt[..., -1, :])
    lam2_dot = sol.damping2_rate * sigma_dot

    def dls(v):  # J^# v, the (damped) inverse
        return np.vecmat(_safe_divide(S, denom) * np.vecmat(v, U), Vt)

    b = sol.b
    if J.shape[-1] >= N_ROTATIONS:  # x = J^T y, y = (J J^T + lambda^2 I)^{-1} b
        x = np.vecmat(_safe_divide(S, denom) * np.vecmat(b, U), Vt)
        y = np.matvec(U, _safe_divide(np.vecmat(b, U), denom))
        c = (
            b_dot
            - np.matvec(dJ_wB, x)
            - np.matvec(J, np.vecmat(y, dJ_wB))
            - lam2_dot[..., None] * y
        )
        x_dot = np.vecmat(y, dJ_wB) + dls(c)
    else:  # tall: x = (J^T J + lambda^2 I)^{-1} J^T b
        x = dls(b)
        c = np.vecmat(b - np.matvec(J, x), dJ_wB) - lam2_dot[..., None] * x
        x_dot = np.vecmat(_safe_divide(np.matvec(Vt, c), denom), Vt) + dls(
            b_dot - np.matvec(dJ_wB, x)
        )
    if J.shape[-1] > S.shape[-1]:
        x_dot = x_dot + _null_space_rate(sol, dJ_wB, z_dot)
    return x_dot


def _null_space_rate(sol: VelocityLawSolution, dJ_wB, z_dot) -> np.ndarray:
    """Time derivative of the null-space term ``w = P z``, ``P = I - J^+ J``:
    ``dw = -P dJ^T (J J^T)^{-1} J z - J^+ dJ P z + P dz``."""
    U, S, Vt, z = sol.U, sol.S, sol.Vt, sol.z
    Pz = z - np.vecmat(np.matvec(Vt, z), Vt)
    JJinvJz = np.matvec(U, _safe_divide(np.matvec(Vt, z), S))  # (J J^T)^{-1} J z = U S^{-1} V^T z
    v = -np.vecmat(JJinvJz, dJ_wB) + z_dot
    Pv = v - np.vecmat(np.matvec(Vt, v), Vt)
    pinv_term = np.vecmat(_safe_divide(np.vecmat(np.matvec(dJ_wB, Pz), U), S), Vt)
    return Pv - pinv_term
