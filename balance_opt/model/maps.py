"""Numeric momentum maps with Pinocchio: the reference for the symbolic maps, and the fast path
the analytic law and the simulator use in their inner loops.

Conventions (``physics-notes.md``): Pinocchio's free-flyer velocity ``v[:6]`` is the base twist
in the base frame; ``pin.computeCentroidalMap`` gives ``A_G`` with world-aligned rows about the
CoM. Computed with the base at the identity pose, ``A_G`` is expressed in the base frame, and
``J_base = -A_b^{-1} A_j`` does not depend on the base pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg.lapack import dgesv

from balance_opt.model.robot import FloatingRobot


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
        return float(self.balance_singular_values[min(2, len(self.balance_singular_values) - 1)])


def _condition(s: np.ndarray) -> float:
    smallest = s[min(2, len(s) - 1)]
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


def _columns(indices: np.ndarray) -> slice | np.ndarray:
    """A slice (a view, no copy) when ``indices`` are consecutive and increasing, else the
    index array itself."""
    indices = np.asarray(indices)
    if indices.size and np.array_equal(indices, np.arange(indices[0], indices[0] + indices.size)):
        return slice(int(indices[0]), int(indices[0]) + indices.size)
    return indices


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^{-1} b`` for a small square ``a``: LAPACK ``dgesv`` called directly, several times
    faster than ``np.linalg.solve`` at these sizes (its per-call overhead dominates)."""
    _, _, x, info = dgesv(a, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular momentum map block (LAPACK dgesv info={info})")
    return x


class NumericMaps:
    """Momentum maps of a floating robot evaluated with numeric Pinocchio.

    Built for inner loops: the Pinocchio configuration is written into a preallocated
    template, index arrays are cached (slices where the columns are consecutive), and small
    systems are solved with LAPACK directly.

    Args:
        robot: the floating robot; a private Pinocchio data is created (one ``NumericMaps``
            per thread).
    """

    def __init__(self, robot: FloatingRobot):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self._cols = np.r_[0:6, robot.pin_v_indices]
        self._cols_view = _columns(self._cols)
        self._mission = robot.mission_indices
        self._balance = robot.balance_indices
        # arm columns of A_G in Pinocchio's order, by arm (for the angular Jacobians)
        joint_cols = robot.pin_v_indices - 6
        self._mission_pin = _columns(joint_cols[self._mission])
        self._balance_pin = _columns(joint_cols[self._balance])
        # configuration template: base at the identity, locked joints in place
        self._q_template = robot.pin_q(robot.neutral())
        ids = [self.model.getJointId(j) for j in robot.joint_names]
        self._fast_q = all(self.model.joints[i].nq == 1 for i in ids)  # no continuous joint
        self._idx_q = np.array([self.model.joints[i].idx_q for i in ids])

    def _pin_q(self, q) -> np.ndarray:
        """Pinocchio configuration of the arm vector ``q``, base at the identity."""
        if not self._fast_q:
            return self.robot.pin_q(q)
        qp = self._q_template.copy()
        qp[self._idx_q] = q
        return qp

    def _A_pin(self, q) -> np.ndarray:
        """``A_G`` with the base at the identity, columns in Pinocchio's order."""
        return pin.computeCentroidalMap(self.model, self.data, self._pin_q(q))

    def centroidal_momentum_matrix(self, q, rotation: np.ndarray | None = None) -> np.ndarray:
        """``A_G`` (6 x (6+n), arm order): momentum [linear; angular] about the CoM per
        [base twist in base frame; arm joint rates]. Axes of the base frame, or of the world
        when the base ``rotation`` is given."""
        if rotation is None:
            A = self._A_pin(q)
        else:
            base = pin.SE3(rotation, np.zeros(3))
            A = pin.computeCentroidalMap(self.model, self.data, self.robot.pin_q(q, base))
        return A[:, self._cols_view] if isinstance(self._cols_view, slice) else A[:, self._cols]

    def base_jacobian(self, q) -> np.ndarray:
        """``J_base`` (6 x n): base twist in the base frame per arm joint rates, zero momentum."""
        A = self.centroidal_momentum_matrix(q)
        J = _solve(A[:, :6], A[:, 6:])
        return np.negative(J, out=J)

    def base_twist(self, q, q_dot, h0_base=None) -> np.ndarray:
        """Base twist in the base frame forced by the joint rates, for momentum ``h0_base``
        ([linear; angular about the CoM], base-frame axes; zero by default)."""
        A = self.centroidal_momentum_matrix(q)
        rhs = -A[:, 6:] @ q_dot
        if h0_base is not None:
            rhs = rhs + h0_base
        return _solve(A[:, :6], rhs)

    def angular_jacobians(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(J_wM, J_wB)``: base angular velocity in the base frame per mission and balance rates.

        Uses the block structure of ``A_b``: base linear velocity adds no angular momentum about
        the CoM (``A_b[3:, :3] = 0``), so ``omega_b = -I_G^{-1} A_j[3:] q_dot`` with the locked
        inertia ``I_G = A_b[3:, 3:]``: a 3 x 3 solve instead of the 6 x 6 one.
        """
        A = self._A_pin(q)
        J = _solve(A[3:, 3:6], A[3:, 6:])
        np.negative(J, out=J)
        return J[:, self._mission_pin], J[:, self._balance_pin]

    def ee_jacobian(self, q, arm: str = "mission") -> np.ndarray:
        """Frame Jacobian of an arm's end effector (6 x (6+n), base columns first), linear
        velocity of its origin and angular velocity in base-frame axes, base at identity."""
        frame = self.model.getFrameId(self.robot.arm(arm).ee_frame)
        qp = self._pin_q(q)
        pin.computeJointJacobians(self.model, self.data, qp)
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, frame, pin.LOCAL_WORLD_ALIGNED)
        return J[:, self._cols]

    def ee_generalized_jacobian(self, q, arm: str = "mission") -> tuple[np.ndarray, np.ndarray]:
        """``(J_star, M)`` of Eq. 20-22: see :meth:`SymbolicMaps.ee_generalized_jacobian_fun`."""
        J = self.ee_jacobian(q, arm)
        J_star = J[:, 6:] + J[:, :6] @ self.base_jacobian(q)
        return J_star, J_star[:, self.robot.arm(arm).indices]

    def coupling_factors(self, q, arm: str = "mission") -> tuple[np.ndarray, np.ndarray]:
        """``(M, N)`` of Eq. 22 and 24."""
        _, M = self.ee_generalized_jacobian(q, arm)
        N = self.base_jacobian(q)[:, self.robot.arm(arm).indices] @ np.linalg.pinv(M)
        return M, N

    def force_map(self, q, F_e, arm: str = "mission") -> np.ndarray:
        """``F_B = N^{-T} F_e`` (Eq. 25), Moore-Penrose inverse where ``N`` is rank deficient."""
        _, N = self.coupling_factors(q, arm)
        return np.linalg.pinv(N.T) @ np.asarray(F_e, dtype=float)

    def coupling_measures(self, q) -> CouplingMeasures:
        return coupling_measures(*self.angular_jacobians(q), self.robot.balance_arm_columns)
