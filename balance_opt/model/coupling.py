"""The paper's coupling factors (Eq. 19-25) and the coupling measures of ``J_wB``, NumPy's;
the base Jacobian, which the planner's CasADi expressions share, takes the solver of either.
Columns: the base twist [linear; angular] in the base frame, then the arm joints."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Rows of ``J_wB``: the base's three rotations.
N_ROTATIONS = 3
#: Size of a twist or a wrench.
TWIST = 6


# NumPy's LAPACK ``gesv`` throughout; not SciPy's, whose import would slow every command.
def full_rank_pinv(M):
    """Moore-Penrose inverse of a matrix of full rank (tall: left inverse, wide: right inverse),
    from the normal equations: exact on the rank, without an SVD's cut-off."""
    r, c = M.shape
    if r == c:
        return np.linalg.inv(M)
    if r > c:
        return np.linalg.solve(M.T @ M, M.T)
    return M.T @ np.linalg.solve(M @ M.T, np.eye(r))


def base_jacobian(A_G, solve=np.linalg.solve):
    """``J_base = -A_b^{-1} A_j`` (6 x n, Eq. 19): base twist per joint rates, zero momentum;
    ``solve``: ``casadi.solve`` for an expression."""
    return -solve(A_G[:, :TWIST], A_G[:, TWIST:])


def angular_jacobian(I_G, A):
    """``J_w = -I_G^{-1} A`` (3 x n): base angular velocity per joint rates, zero momentum."""
    return -np.linalg.solve(I_G, A)


def generalized_jacobian(J_ee, J_base):
    """``J_e* = J_e,j + J_e,b J_base`` (6 x n, Eq. 20-21) from an end effector's frame Jacobian
    ``J_ee`` (6 x (6 + n), base columns first)."""
    return J_ee[:, TWIST:] + J_ee[:, :TWIST] @ J_base


def coupling_factor(J_base_arm, M):
    """``N = J_base,arm M^+`` (6 x 6, Eq. 24): maps the end effector's twist back to the base
    twist, exactly on the twists the arm can produce (all of them when ``M`` has rank 6)."""
    return J_base_arm @ full_rank_pinv(M)


def force_on_base(J_base_arm, M, F_e):
    """``F_B = N^{-T} F_e`` (Eq. 25), the Moore-Penrose inverse of ``N^T`` when the arm has fewer
    than 6 joints (``N`` rank deficient).

    There ``N^T = B C^T`` with ``B = (M^+)^T`` and ``C = J_base,arm``, both of full column rank,
    so ``pinv(N^T) = pinv(C^T) pinv(B)``: exact without a numeric SVD.
    """
    if M.shape[1] >= TWIST:
        return np.linalg.solve(coupling_factor(J_base_arm, M).T, F_e)
    B = full_rank_pinv(M).T
    return full_rank_pinv(J_base_arm.T) @ (full_rank_pinv(B) @ F_e)


# ---------------------------------------------------------------------------------- measures
@dataclass(frozen=True)
class CouplingMeasures:
    """How strongly the arms couple to the base attitude at one configuration.

    Attributes:
        balance_singular_values: singular values of ``J_wB``, largest first [rad/s per rad/s].
        balance_condition: condition number of ``J_wB`` (``inf`` when rank deficient).
        mission_norm: spectral norm of ``J_wM``: the largest base rate per unit mission rate.
        per_arm: the same per balance arm: ``{arm: (singular values, condition)}``.
    """

    balance_singular_values: np.ndarray
    balance_condition: float
    mission_norm: float
    per_arm: dict

    @property
    def sigma_min(self) -> float:
        """Smallest singular value of ``J_wB`` among its first three (the ones that control the
        base's three rotations)."""
        return float(
            self.balance_singular_values[min(N_ROTATIONS, len(self.balance_singular_values)) - 1]
        )


def _condition(s: np.ndarray) -> float:
    smallest = s[min(N_ROTATIONS, len(s)) - 1]
    return float(s[0] / smallest) if smallest > 0 else float("inf")


def coupling_measures(
    J_wM: np.ndarray, J_wB: np.ndarray, arm_columns: dict | None = None
) -> CouplingMeasures:
    """Coupling measures from the angular Jacobians (see :class:`CouplingMeasures`)."""
    s = np.linalg.svd(J_wB, compute_uv=False)
    per_arm = {}
    for name, cols in (arm_columns or {}).items():
        s_arm = np.linalg.svd(J_wB[:, cols], compute_uv=False)
        per_arm[name] = (s_arm, _condition(s_arm))
    return CouplingMeasures(s, _condition(s), float(np.linalg.norm(J_wM, 2)), per_arm)
