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

from .robot import FloatingRobot


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


def coupling_measures(J_wM: np.ndarray, J_wB: np.ndarray, arm_columns: dict | None = None) -> CouplingMeasures:
    """Coupling measures from the angular Jacobians (see :class:`CouplingMeasures`)."""
    s = np.linalg.svd(J_wB, compute_uv=False)
    per_arm = {}
    for name, cols in (arm_columns or {}).items():
        s_arm = np.linalg.svd(J_wB[:, cols], compute_uv=False)
        per_arm[name] = (s_arm, _condition(s_arm))
    return CouplingMeasures(s, _condition(s), float(np.linalg.norm(J_wM, 2)), per_arm)


class NumericMaps:
    """Momentum maps of a floating robot evaluated with numeric Pinocchio.

    Args:
        robot: the floating robot; its Pinocchio model and data are used (not thread safe).
    """

    def __init__(self, robot: FloatingRobot):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self._cols = np.r_[0:6, robot.pin_v_indices]
        self._mission = robot.mission_indices
        self._balance = robot.balance_indices

    def centroidal_momentum_matrix(self, q, rotation: np.ndarray | None = None) -> np.ndarray:
        """``A_G`` (6 x (6+n), arm order): momentum [linear; angular] about the CoM per
        [base twist in base frame; arm joint rates]. Axes of the base frame, or of the world
        when the base ``rotation`` is given."""
        base = None if rotation is None else pin.SE3(rotation, np.zeros(3))
        A = pin.computeCentroidalMap(self.model, self.data, self.robot.pin_q(q, base))
        return A[:, self._cols].copy()

    def base_jacobian(self, q) -> np.ndarray:
        """``J_base`` (6 x n): base twist in the base frame per arm joint rates, zero momentum."""
        A = self.centroidal_momentum_matrix(q)
        return -np.linalg.solve(A[:, :6], A[:, 6:])

    def base_twist(self, q, q_dot, h0_base=None) -> np.ndarray:
        """Base twist in the base frame forced by the joint rates, for momentum ``h0_base``
        ([linear; angular about the CoM], base-frame axes; zero by default)."""
        A = self.centroidal_momentum_matrix(q)
        rhs = -A[:, 6:] @ q_dot
        if h0_base is not None:
            rhs = rhs + h0_base
        return np.linalg.solve(A[:, :6], rhs)

    def angular_jacobians(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(J_wM, J_wB)``: base angular velocity in the base frame per mission and balance rates."""
        J = self.base_jacobian(q)[3:]
        return J[:, self._mission], J[:, self._balance]

    def ee_jacobian(self, q, arm: str = "mission") -> np.ndarray:
        """Frame Jacobian of an arm's end effector (6 x (6+n), base columns first), linear
        velocity of its origin and angular velocity in base-frame axes, base at identity."""
        frame = self.model.getFrameId(self.robot.arm(arm).ee_frame)
        qp = self.robot.pin_q(q)
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
