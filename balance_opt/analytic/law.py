"""The paper's analytic balance law (Eq. 26-32; ``docs/physics.md``, "The balance law"):
balance-arm rates and accelerations that cancel the base rotation the mission arm causes.

With ``omega_f = J_wM q_dot_M + omega_h`` the base rate the mission arm (and ``h0``) would force
and ``e_R = log(R_0^T R)`` the optional attitude feedback (gain ``K``), the balance arm is asked
for ``J_wB q_dot_B = b = -omega_f - K e_R`` (Eq. 31), solved by
:mod:`balance_opt.analytic.least_squares`, and for its exact time derivative (Eq. 32).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from balance_opt.analytic.least_squares import (
    VelocityLawSolution,
    acceleration_law,
    velocity_law,
)
from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.errors import InputError
from balance_opt.model.coupling import angular_jacobian
from balance_opt.model.maps import NumericMaps, angular_jacobian_rate, base_angular_velocity
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.so3 import (
    IDENTITY_QUATERNION,
    inverse_right_jacobian,
    matrix_from_quaternion,
    relative_rotation,
    rotvec_from_quaternion,
)

log = logging.getLogger(__name__)


@dataclass
class LawPath:
    """The law at one configuration or, per sample, along a motion: ``q_dot_B`` [rad/s], the
    base rate ``omega`` it leaves [rad/s, base frame], the ``residual`` ``J_wB q_dot_B - b``,
    ``sigma_min`` and ``damping``; along a motion also ``q_ddot_B`` (Eq. 32) and the
    ``condition`` number of ``J_wB`` (``inf`` where singular)."""

    q_dot_B: np.ndarray
    omega: np.ndarray
    residual: np.ndarray
    sigma_min: np.ndarray | float
    damping: np.ndarray | float
    q_ddot_B: np.ndarray | None = None
    condition: np.ndarray | None = None


@dataclass
class _Solved:
    """The velocity level at some samples, with what the acceleration level reuses."""

    sol: VelocityLawSolution
    J_wB: np.ndarray
    q_dot: np.ndarray  # whole arm rates, mission and the law's balance rates
    omega: np.ndarray  # base rate they leave
    omega_free: np.ndarray  # base rate with the balance arm at rest
    ell: np.ndarray  # R^T L
    e_R: np.ndarray  # attitude error


class BalanceLaw:
    """The analytic balance law of a robot, evaluated with numeric Pinocchio.

    Args:
        options: law settings (defaults: :class:`BalanceLawOptions`).
        q_B0: initial balance configuration [rad]; the null-space goal of joints without finite
            limits (default: the neutral configuration).

    Raises:
        InputError: a null-space goal of the wrong size.
    """

    def __init__(self, robot: FloatingRobot, options: BalanceLawOptions | None = None, q_B0=None):
        self.robot = robot
        self.options = options or BalanceLawOptions()
        self.maps = NumericMaps(robot)
        self.mission = robot.mission_indices
        self.balance = robot.balance_indices
        self.goal = self._null_space_goal(q_B0)
        self.reference = IDENTITY_QUATERNION  # R_0 of the feedback: the initial attitude
        self.angular_momentum = self.options.angular_momentum

    def _null_space_goal(self, q_B0) -> np.ndarray:
        if self.options.null_space_goal is not None:
            goal = np.array(self.options.null_space_goal)
            if goal.size != self.balance.size:
                raise InputError(
                    f"balance law option 'null_space_goal' has {goal.size} values, "
                    f"the balance joints are {self.balance.size}"
                )
            return goal
        # mid-range, or the start for a joint without finite limits
        lim = self.robot.limits.subset(self.balance)
        start = self.robot.neutral()[self.balance] if q_B0 is None else q_B0
        finite = np.isfinite(lim.lower) & np.isfinite(lim.upper)
        goal = np.array(start, dtype=float)
        goal[finite] = 0.5 * (lim.lower[finite] + lim.upper[finite])
        return goal

    # ------------------------------------------------------------------ pieces
    def _solve(self, I_G, A, q_dot_M, q_B, quaternion) -> _Solved:
        """Eq. 31 at one sample or a batch."""
        shape = quaternion.shape[:-1] + (3,)
        if self.angular_momentum.any():  # R^T L
            L = np.broadcast_to(self.angular_momentum, shape)
            ell = np.vecmat(L, matrix_from_quaternion(quaternion))
        else:
            ell = np.zeros(shape)
        if self.options.attitude_gain:
            e_R = rotvec_from_quaternion(relative_rotation(self.reference, quaternion))
        else:
            e_R = np.zeros(shape)
        J_wB = angular_jacobian(I_G, A[..., self.balance])
        omega_free = base_angular_velocity(I_G, A[..., self.mission], q_dot_M, ell)
        b = -omega_free - self.options.attitude_gain * e_R
        z = -self.options.null_space_gain * (q_B - self.goal)
        sol = velocity_law(J_wB, b, z, self.options)
        q_dot = np.empty(q_B.shape[:-1] + (self.robot.n,))
        q_dot[..., self.mission] = q_dot_M
        q_dot[..., self.balance] = sol.q_dot_B
        omega = base_angular_velocity(I_G, A, q_dot, ell)
        return _Solved(sol, J_wB, q_dot, omega, omega_free, ell, e_R)

    # ------------------------------------------------------------------ one sample
    def rates(self, q, q_dot_M, quaternion=None) -> LawPath:
        """Balance joint rates at one instant (Eq. 31) for the arm vector ``q`` [rad], the
        mission rates ``q_dot_M`` [rad/s] and the base attitude (x, y, z, w; identity)."""
        q = np.asarray(q, dtype=float)
        quaternion = (
            IDENTITY_QUATERNION if quaternion is None else np.asarray(quaternion, dtype=float)
        )
        I_G, A = self.maps.angular_maps(q)
        s = self._solve(I_G, A, np.asarray(q_dot_M, dtype=float), q[self.balance], quaternion)
        sol = s.sol
        return LawPath(sol.q_dot_B, s.omega, sol.residual, float(sol.sigma_min), float(sol.damping))

    # ------------------------------------------------------------------ along a path
    def along(self, q, q_dot_M, q_ddot_M, quaternion) -> LawPath:
        """The law (Eq. 31 and 32) along sampled arm vectors ``q`` (T, n) [rad], mission rates
        and accelerations (T, n_M) and base attitudes (T, 4)."""
        q = np.asarray(q, dtype=float)
        Ag = self.maps.centroidal(q)
        I_G, A = self.maps.angular_blocks(Ag)
        s = self._solve(I_G, A, q_dot_M, q[:, self.balance], quaternion)
        dI_G, dA = self.maps.angular_map_rates(q, s.q_dot, Ag)
        dJ_wB = angular_jacobian_rate(I_G, dI_G, dA[..., self.balance], s.J_wB)
        # I_G omega_f = R^T L - A_M q_dot_M, differentiated (d/dt R^T L = -omega x R^T L):
        # I_G d(omega_f)/dt = (-omega x R^T L - dI_G omega_f) - [dA_M, A_M] [q_dot_M; q_ddot_M]
        M = self.mission
        momentum_terms = -np.cross(s.omega, s.ell) - np.matvec(dI_G, s.omega_free)
        omega_free_dot = base_angular_velocity(
            I_G,
            np.concatenate([dA[..., M], A[..., M]], axis=-1),
            np.concatenate([q_dot_M, q_ddot_M], axis=-1),
            momentum_terms,
        )
        b_dot = -omega_free_dot
        K = self.options.attitude_gain
        if K:
            b_dot = b_dot - K * np.matvec(inverse_right_jacobian(s.e_R), s.omega)
        z_dot = -self.options.null_space_gain * s.sol.q_dot_B
        q_ddot_B = acceleration_law(s.sol, dJ_wB, b_dot, z_dot)
        sol = s.sol
        return LawPath(
            sol.q_dot_B, s.omega, sol.residual, sol.sigma_min, sol.damping, q_ddot_B, sol.condition
        )
