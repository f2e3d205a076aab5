"""Numeric momentum maps with Pinocchio, for one configuration or a batch: the reference for the
symbolic maps and the fast path of the analytic law, the replays and the simulator.

Computed with the base at the identity pose, so in base-frame axes and independent of the base
pose (``docs/physics.md``, "Momentum maps"); mimic followers are folded into their drivers'
columns (``FloatingRobot.arm_columns``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from balance_opt.model import coupling
from balance_opt.model.coupling import CouplingMeasures, coupling_measures
from balance_opt.model.robot import FloatingRobot


def base_angular_velocity(I_G: np.ndarray, A: np.ndarray, q_dot: np.ndarray, ell=None):
    """Base angular velocity forced by the joints, base frame [rad/s] (Eq. 26):
    ``omega = I_G^{-1} (ell - A q_dot)``, which is ``J_wM q_dot_M + J_wB q_dot_B`` at zero
    momentum. Batched over leading dimensions.

    Args:
        I_G: locked inertia about the CoM, base axes (..., 3, 3) [kg m^2].
        A: angular rows of ``A_G`` for the joints in ``q_dot`` (..., 3, k) [kg m^2].
        q_dot: joint rates (..., k) [rad/s].
        ell: the system's angular momentum about the CoM in base axes, ``R^T L`` (..., 3)
            [N m s]; ``None`` for zero.
    """
    rhs = -np.matvec(A, q_dot)
    if ell is not None:
        rhs = rhs + ell
    return np.linalg.solve(I_G, rhs[..., None])[..., 0]


def angular_jacobian_rate(I_G, dI_G, dA, J_w) -> np.ndarray:
    """``dJ_w/dt = -I_G^{-1} (dA + dI_G J_w)`` (..., 3, n), from ``I_G J_w = -A``."""
    return -np.linalg.solve(I_G, dA + dI_G @ J_w)


class NumericMaps:
    """Momentum maps of a floating robot evaluated with numeric Pinocchio; methods take one
    configuration (n,) or, where they say so, a batch (T, n). One instance per thread (it owns
    a Pinocchio data)."""

    def __init__(self, robot: FloatingRobot):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.mass = robot.total_mass

    # ------------------------------------------------------------------ Pinocchio vectors
    def configurations(self, q, quaternion=None) -> np.ndarray:
        """Pinocchio configurations (..., nq) of arm vectors (..., n): base at the origin with
        attitude ``quaternion`` (..., 4), (x, y, z, w), identity by default."""
        out = self.robot.pin_q(q)
        if quaternion is not None:
            out[..., 3:7] = quaternion
        return out

    def velocities(self, q_dot, omega=None) -> np.ndarray:
        """Pinocchio velocities (..., nv) of arm rates (..., n), the base not translating and
        turning at ``omega`` (..., 3) [rad/s, base frame] (at rest by default)."""
        out = self.robot.pin_v(q_dot)
        if omega is not None:
            out[..., 3:6] = omega
        return out

    # ------------------------------------------------------------------ centroidal maps
    def centroidal(self, q, quaternion=None) -> np.ndarray:
        """Pinocchio's whole ``A_G``, (6, nv) for one configuration or (T, 6, nv) for a batch,
        base attitude ``quaternion`` (identity by default: base-frame axes)."""
        qp = self.configurations(q, quaternion)
        if qp.ndim == 1:
            return pin.computeCentroidalMap(self.model, self.data, qp)
        full = np.empty((qp.shape[0], 6, self.model.nv))  # whole matrices: slicing costs more
        model, data, cmap = self.model, self.data, pin.computeCentroidalMap
        for k in range(qp.shape[0]):
            full[k] = cmap(model, data, qp[k])
        return full

    def angular_blocks(self, Ag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(I_G, A)`` (..., 3, 3) and (..., 3, n), arm order, from Pinocchio ``A_G`` (..., 6, nv):
        the angular momentum about the CoM is ``I_G omega + A q_dot``."""
        rows = self.robot.arm_columns(Ag[..., 3:, :])[..., 3:]
        return rows[..., :3], rows[..., 3:]

    def angular_maps(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(I_G, A)`` at one configuration or a batch, base-frame axes."""
        return self.angular_blocks(self.centroidal(q))

    def angular_map_rates(self, q, q_dot, Ag=None) -> tuple[np.ndarray, np.ndarray]:
        """Time derivatives ``(dI_G, dA)`` along a joint motion, each (T, 3, .) (the base's own
        motion changes none of these base-frame maps).

        Pinocchio's ``dAg`` is exact only in the product ``dAg v``: it leaves out the motion of
        the CoM the rows are taken about. The true matrix derivative of the angular rows is
        ``dAg_ang - [c_dot]_x Ag_lin`` with ``c_dot = Ag_lin v / m`` (tested against finite
        differences); the balance law needs the matrix itself (damping, null space).

        Args:
            q: arm configurations (T, n) [rad].
            q_dot: arm rates (T, n) [rad/s].
            Ag: :meth:`centroidal` at ``q`` if already computed.
        """
        qp = self.configurations(q)
        vp = self.velocities(q_dot)
        T = qp.shape[0]
        d_full = np.empty((T, 6, self.model.nv))
        model, data, cmap_rate = self.model, self.data, pin.computeCentroidalMapTimeVariation
        fill = Ag is None
        Ag = np.empty_like(d_full) if fill else Ag
        for k in range(T):
            d_full[k] = cmap_rate(model, data, qp[k], vp[k])
            if fill:
                Ag[k] = data.Ag
        lin = Ag[:, :3]
        c = np.matvec(lin, vp) / self.mass  # CoM velocity (T, 3)
        cross = np.cross(c[:, :, None], lin, axis=1)  # [c_dot]_x applied to each column
        return self.angular_blocks(np.concatenate([d_full[:, :3], d_full[:, 3:] - cross], axis=1))

    def centroidal_momentum_matrix(self, q, rotation: np.ndarray | None = None) -> np.ndarray:
        """``A_G`` (6 x (6+n), arm order): momentum [linear; angular] about the CoM per
        [base twist in base frame; arm joint rates]. Axes of the base frame, or of the world
        when the base ``rotation`` is given."""
        quaternion = None if rotation is None else pin.Quaternion(rotation).coeffs()
        return self.robot.arm_columns(self.centroidal(q, quaternion))

    # ------------------------------------------------------------------ base motion
    def angular_jacobians(self, q) -> tuple[np.ndarray, np.ndarray]:
        """``(J_wM, J_wB)``: base angular velocity in the base frame per mission and balance
        rates (balance arms stacked), for one configuration or a batch."""
        J = coupling.angular_jacobian(*self.angular_maps(q))
        return J[..., self.robot.mission_indices], J[..., self.robot.balance_indices]

    def base_jacobian(self, q) -> np.ndarray:
        """``J_base`` (6 x n): base twist in the base frame per arm joint rates, zero momentum."""
        return coupling.base_jacobian(self.centroidal_momentum_matrix(q))

    def base_twist(self, q, q_dot, h0_base=None) -> np.ndarray:
        """Base twist [linear; angular] in the base frame forced by the joint rates, for the
        momentum ``h0_base`` ([linear; angular about the CoM], base-frame axes; zero by default)."""
        h0 = np.zeros(6) if h0_base is None else np.asarray(h0_base, dtype=float)
        A = self.centroidal_momentum_matrix(q)
        omega = base_angular_velocity(A[3:, 3:6], A[3:, 6:], q_dot, h0[3:])
        p = h0[:3] - A[:3, 6:] @ q_dot - A[:3, 3:6] @ omega
        return np.r_[np.linalg.solve(A[:3, :3], p), omega]

    def balance_sigma_min(self, I_G, A) -> np.ndarray:
        """Smallest singular value of ``J_wB`` among its first three (...,), from the angular
        maps (:meth:`angular_maps`) of one configuration or a batch."""
        J_wB = coupling.angular_jacobian(I_G, A[..., self.robot.balance_indices])
        return np.linalg.svd(J_wB, compute_uv=False)[..., -1]

    # ------------------------------------------------------------------ end effectors
    def ee_jacobian(self, q, arm: str = "mission") -> np.ndarray:
        """Frame Jacobian of an arm's end effector (6 x (6+n), base columns first), linear
        velocity of its origin and angular velocity in base-frame axes, base at identity."""
        frame = self.model.getFrameId(self.robot.arm(arm).ee_frame)
        pin.computeJointJacobians(self.model, self.data, self.configurations(q))
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, frame, pin.LOCAL_WORLD_ALIGNED)
        return self.robot.arm_columns(J)

    def ee_generalized_jacobian(self, q, arm: str = "mission") -> tuple[np.ndarray, np.ndarray]:
        """``(J_star, M)`` of Eq. 20-22
        (:func:`balance_opt.model.coupling.generalized_jacobian`)."""
        J_star = coupling.generalized_jacobian(self.ee_jacobian(q, arm), self.base_jacobian(q))
        return J_star, J_star[:, self.robot.arm(arm).indices]

    def coupling_factors(self, q, arm: str = "mission") -> tuple[np.ndarray, np.ndarray]:
        """``(M, N)`` of Eq. 22 and 24."""
        _, M = self.ee_generalized_jacobian(q, arm)
        J_base_arm = self.base_jacobian(q)[:, self.robot.arm(arm).indices]
        return M, coupling.coupling_factor(J_base_arm, M)

    def force_map(self, q, F_e, arm: str = "mission") -> np.ndarray:
        """``F_B = N^{-T} F_e`` (Eq. 25), Moore-Penrose inverse where ``N`` is rank deficient."""
        _, M = self.ee_generalized_jacobian(q, arm)
        J_base_arm = self.base_jacobian(q)[:, self.robot.arm(arm).indices]
        return coupling.force_on_base(J_base_arm, M, np.asarray(F_e, dtype=float))

    def coupling_measures(self, q) -> CouplingMeasures:
        """Singular values and condition number of ``J_wB``, norm of ``J_wM`` at ``q``."""
        return coupling_measures(*self.angular_jacobians(q), self.robot.balance_arm_columns)
