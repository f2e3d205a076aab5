"""The paper's analytic balance law (Eq. 26-32): balance-arm rates and accelerations that cancel
the base rotation the mission arm causes.

Derived from angular momentum conservation about the system's CoM (``physics-notes.md``). In
base-frame axes, with ``I_G`` the locked inertia about the CoM and ``A_M``, ``A_B`` the angular
rows of the centroidal momentum matrix for the mission and balance joints,

    I_G omega + A_M q_dot_M + A_B q_dot_B = R^T L,                          (Eq. 26, with h0)

so the base angular velocity (base frame) is ``omega = J_wM q_dot_M + J_wB q_dot_B + omega_h``
with ``J_w = -I_G^{-1} A`` and ``omega_h = I_G^{-1} R^T L`` (``L``: initial angular momentum
about the CoM, constant in the world frame; the linear momentum does not enter ``omega``).
Translating the base changes no angular momentum about the CoM, so the angular rows of the
base's linear columns are zero and only ``I_G`` (3 x 3) is solved.

The law asks the balance arm for

    J_wB q_dot_B = b,   b = -J_wM q_dot_M - omega_h - K e_R,                (Eq. 31)

where ``e_R = log(R_0^T R)`` is the optional attitude feedback (gain ``K`` [1/s]), and its time
derivative (Eq. 32, the paper's version mixes indices)

    J_wB q_ddot_B = b_dot - dJ_wB q_dot_B,
    b_dot = -(dJ_wM q_dot_M + J_wM q_ddot_M) - d/dt(omega_h) - K Jr^{-1}(e_R) omega.

How ``J_wB q_dot_B = b`` is solved, with the SVD ``J_wB = U S V^T``:

* square and well conditioned (``sigma_min >= damping_threshold``): the exact solve;
* near a singular configuration (``sigma_min < damping_threshold``): damped least squares
  ``q_dot_B = V S / (S^2 + lambda^2) U^T b`` with Nakamura-Hanafusa variable damping
  ``lambda^2 = max_damping^2 (1 - sigma_min / damping_threshold)^2``, which is continuous and
  has a continuous derivative in ``sigma_min`` (so ``q_ddot_B`` stays continuous). The base
  angular velocity it leaves is reported;
* more joints than 3 (a redundant arm, or several balance arms stacked): the same minimum-norm
  (damped) inverse plus a null-space term ``(I - V V^T) z``, ``z = -k (q_B - q_goal)``, the
  projector onto the exact null space of ``J_wB``, so that the null-space motion never rotates
  the base. The default goal is the middle of the joint range (the initial position for a joint
  without finite limits).

``q_ddot_B`` is the exact time derivative of this velocity law (damping and null-space terms
included), wherever ``J_wB`` has full rank.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.errors import InputError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.so3 import (
    IDENTITY_QUATERNION,
    inverse_right_jacobian,
    matrix_from_quaternion,
    quaternion_conjugate,
    quaternion_multiply,
    rotvec_from_quaternion,
)

log = logging.getLogger(__name__)

#: Rows of ``J_wB``: the base's three rotations.
N_ROTATIONS = 3


# ---------------------------------------------------------------------------------- small helpers
def _mv(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product ``M x`` over leading dimensions."""
    return (M @ x[..., None])[..., 0]


def _mtv(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Batched ``M^T x``."""
    return (np.swapaxes(M, -1, -2) @ x[..., None])[..., 0]


def _safe_divide(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a / b`` with 0 where ``b == 0`` (the pseudo-inverse convention)."""
    return np.divide(a, b, out=np.zeros(np.broadcast(a, b).shape), where=b != 0)


def damping(sigma_min, threshold: float, max_damping: float) -> tuple[np.ndarray, np.ndarray]:
    """Variable damping (Nakamura-Hanafusa style) and its derivative.

    ``lambda^2 = lambda_max^2 (1 - (sigma_min / epsilon)^2)^2`` below ``epsilon``, else 0. A
    function of ``sigma_min^2`` (an eigenvalue of ``J J^T``, smooth where ``sigma_min(t)`` touches
    zero and bounces back) with zero slope at ``epsilon``: the damped rates are C1 in time, so
    ``q_ddot_B`` (Eq. 32) stays continuous through both events.

    Args:
        sigma_min: smallest singular value of ``J_wB`` (...).
        threshold: ``epsilon``; 0 for none.
        max_damping: ``lambda_max``.

    Returns:
        ``(lambda^2, d(lambda^2)/d(sigma_min))``, each (...).
    """
    sigma_min = np.asarray(sigma_min, dtype=float)
    if threshold <= 0:
        zero = np.zeros_like(sigma_min)
        return zero, zero
    gap = np.clip(1.0 - (sigma_min / threshold) ** 2, 0.0, None)
    return max_damping**2 * gap**2, -4.0 * max_damping**2 * gap * sigma_min / threshold**2


# ---------------------------------------------------------------------------------- Pinocchio maps
class AngularMomentumMaps:
    """Angular rows of the centroidal momentum map with numeric Pinocchio, fast and batched.

    With the base at the identity pose (base-frame axes, which these maps do not depend on),
    returns ``I_G`` (3 x 3, locked inertia about the CoM) and ``A`` (3 x n, arm order), so that
    the angular momentum about the CoM is ``I_G omega + A q_dot``; along a motion, also their
    time derivatives. Same maps as :class:`balance_opt.model.maps.NumericMaps`, without its
    per-call conversions, for the integrator's inner loop.

    Args:
        robot: the floating robot (its model; a private Pinocchio data is created).
    """

    def __init__(self, robot: FloatingRobot):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        ids = [self.model.getJointId(j) for j in robot.joint_names]
        idx_q = np.array([self.model.joints[i].idx_q for i in ids])
        nq = np.array([self.model.joints[i].nq for i in ids])
        self._one = np.flatnonzero(nq == 1)
        self._two = np.flatnonzero(nq == 2)  # continuous joints stored as (cos, sin)
        self._idx_q_one = idx_q[self._one]
        self._idx_q_two = idx_q[self._two]
        self._q_ref = robot.pin_q(robot.neutral())  # base at identity, locked joints in place
        self._idx_v = robot.pin_v_indices
        self._angular_cols = np.r_[3:6, self._idx_v]
        self.mass = robot.total_mass

    def pin_configurations(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio configurations (..., nq) of arm vectors (..., n), base at the identity."""
        q = np.asarray(q, dtype=float)
        out = self._q_ref.copy() if q.ndim == 1 else np.tile(self._q_ref, q.shape[:-1] + (1,))
        out[..., self._idx_q_one] = q[..., self._one]
        if self._two.size:
            out[..., self._idx_q_two] = np.cos(q[..., self._two])
            out[..., self._idx_q_two + 1] = np.sin(q[..., self._two])
        return out

    def pin_velocities(self, q_dot: np.ndarray) -> np.ndarray:
        """Pinocchio velocities (..., nv) of arm rates (..., n), the base at rest."""
        q_dot = np.asarray(q_dot, dtype=float)
        out = np.zeros(q_dot.shape[:-1] + (self.model.nv,))
        out[..., self._idx_v] = q_dot
        return out

    def at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(I_G, A)`` at one arm configuration ``q`` (n,)."""
        Ag = pin.computeCentroidalMap(self.model, self.data, self.pin_configurations(q))
        rows = Ag[3:, self._angular_cols]
        return rows[:, :3], rows[:, 3:]

    def centroidal_along(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio's whole ``A_G`` (T, 6, nv) at every sample of a motion, base at identity.

        Args:
            q: arm configurations (T, n) [rad].
        """
        qp = self.pin_configurations(q)
        full = np.empty(
            (qp.shape[0], 6, self.model.nv)
        )  # whole matrices: slicing in the loop costs more
        model, data, cmap = self.model, self.data, pin.computeCentroidalMap
        for k in range(qp.shape[0]):
            full[k] = cmap(model, data, qp[k])
        return full

    def angular_blocks(self, Ag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(I_G, A)`` (..., 3, .) from Pinocchio ``A_G`` matrices (..., 6, nv)."""
        rows = Ag[..., 3:, self._angular_cols]
        return rows[..., :3], rows[..., 3:]

    def along(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(I_G, A)`` at every sample of a motion, each (T, 3, .).

        Args:
            q: arm configurations (T, n) [rad].
        """
        return self.angular_blocks(self.centroidal_along(q))

    def rates_along(self, q: np.ndarray, q_dot: np.ndarray, Ag: np.ndarray | None = None):
        """Time derivatives ``(dI_G, dA)`` along a joint motion, each (T, 3, .) (the base's own
        motion changes none of these base-frame maps).

        Pinocchio's ``dAg`` is exact only in the product ``dAg v``: it leaves out the motion of
        the CoM the rows are taken about. The true matrix derivative of the angular rows is
        ``dAg_ang - [c_dot]_x Ag_lin`` with ``c_dot = Ag_lin v / m`` (tested against finite
        differences); the balance law needs the matrix itself (damping, null space).

        Args:
            q: arm configurations (T, n) [rad].
            q_dot: arm rates (T, n) [rad/s].
            Ag: :meth:`centroidal_along` at ``q`` if already computed.
        """
        qp = self.pin_configurations(q)
        vp = self.pin_velocities(q_dot)
        T = qp.shape[0]
        d_full = np.empty((T, 6, self.model.nv))
        model, data, cmap_rate = self.model, self.data, pin.computeCentroidalMapTimeVariation
        if Ag is None:
            Ag = np.empty_like(d_full)
            for k in range(T):
                d_full[k] = cmap_rate(model, data, qp[k], vp[k])
                Ag[k] = data.Ag
        else:
            for k in range(T):
                d_full[k] = cmap_rate(model, data, qp[k], vp[k])
        lin = Ag[:, :3]
        c = _mv(lin, vp) / self.mass  # CoM velocity (T, 3)
        c0, c1, c2 = (c[:, i, None] for i in range(3))
        l0, l1, l2 = lin[:, 0], lin[:, 1], lin[:, 2]
        cross = np.stack([c1 * l2 - c2 * l1, c2 * l0 - c0 * l2, c0 * l1 - c1 * l0], axis=1)
        return self.angular_blocks(np.concatenate([d_full[:, :3], d_full[:, 3:] - cross], axis=1))


def angular_jacobians_from_maps(I_G: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``J_w = -I_G^{-1} A`` (..., 3, n): base angular velocity per arm rates, zero momentum."""
    return -np.linalg.solve(I_G, A)


def angular_jacobian_rates_from_maps(I_G, dI_G, dA, J_w) -> np.ndarray:
    """``dJ_w/dt = -I_G^{-1} (dA + dI_G J_w)``, from ``I_G J_w = -A``."""
    return -np.linalg.solve(I_G, dA + dI_G @ J_w)


# ---------------------------------------------------------------------------------- the law
@dataclass
class VelocityLawSolution:
    """One solve of Eq. 31 (batched over leading dimensions).

    Attributes:
        q_dot_B: balance joint rates [rad/s].
        b: the base angular velocity the balance arm is asked for, ``J_wB q_dot_B = b`` [rad/s].
        residual: ``J_wB q_dot_B - b`` [rad/s], what the damped inverse leaves undone (zero for
            the exact solve).
        sigma_min: smallest singular value of ``J_wB`` (among its first 3).
        damping: ``lambda`` used (0 when exact).
    """

    q_dot_B: np.ndarray
    b: np.ndarray
    residual: np.ndarray
    sigma_min: np.ndarray
    damping: np.ndarray
    # internals reused by the acceleration level
    J_wB: np.ndarray
    U: np.ndarray
    S: np.ndarray
    Vt: np.ndarray
    z: np.ndarray
    damping2_rate: np.ndarray  # d(lambda^2)/d(sigma_min)


def velocity_law(
    J_wB: np.ndarray, b: np.ndarray, z: np.ndarray, options: BalanceLawOptions
) -> VelocityLawSolution:
    """Solve ``J_wB q_dot_B = b`` (Eq. 31) the way ``options`` says (module docstring).

    Args:
        J_wB: (..., 3, n_B).
        b: requested base angular velocity (..., 3) [rad/s], ``-J_wM q_dot_M - omega_h - K e_R``.
        z: null-space velocity (..., n_B) [rad/s]; projected on the null space of ``J_wB``.
        options: law settings.
    """
    U, S, Vt = np.linalg.svd(J_wB, full_matrices=False)
    sigma_min = S[..., -1]
    lam2, dlam2 = damping(sigma_min, options.damping_threshold, options.max_damping)
    gain = _safe_divide(S, S**2 + lam2[..., None])
    q_dot_B = _mtv(Vt, gain * _mtv(U, b))
    n_B = J_wB.shape[-1]
    if n_B > S.shape[-1]:  # redundant: exact null-space projection (I - V V^T) z
        q_dot_B = q_dot_B + z - _mtv(Vt, _mv(Vt, z))
    residual = _mv(J_wB, q_dot_B) - b
    return VelocityLawSolution(
        q_dot_B, b, residual, sigma_min, np.sqrt(lam2), J_wB, U, S, Vt, z, dlam2
    )


def acceleration_law(
    sol: VelocityLawSolution, dJ_wB: np.ndarray, b_dot: np.ndarray, z_dot: np.ndarray
) -> np.ndarray:
    """Balance joint accelerations (Eq. 32): the exact time derivative of :func:`velocity_law`.

    For a square, undamped ``J_wB`` this is ``J_wB q_ddot_B = b_dot - dJ_wB q_dot_B``; the
    damping (through ``d sigma_min / dt = u^T dJ_wB v``) and the null-space projector add their
    own derivative terms.

    Args:
        sol: the velocity-level solution at the same samples.
        dJ_wB: time derivative of ``J_wB`` (..., 3, n_B).
        b_dot: time derivative of ``b`` (..., 3) [rad/s^2].
        z_dot: time derivative of the null-space velocity (..., n_B) [rad/s^2].

    Returns:
        ``q_ddot_B`` (..., n_B) [rad/s^2].
    """
    J, U, S, Vt = sol.J_wB, sol.U, sol.S, sol.Vt
    n_B = J.shape[-1]
    lam2 = sol.damping**2
    denom = S**2 + lam2[..., None]
    # d(sigma_min)/dt = u^T dJ v, for the smallest singular triplet
    sigma_dot = np.einsum("...i,...ij,...j->...", U[..., :, -1], dJ_wB, Vt[..., -1, :])
    lam2_dot = sol.damping2_rate * sigma_dot

    def dls(v):  # J^# v, the (damped) inverse
        return _mtv(Vt, _safe_divide(S, denom) * _mtv(U, v))

    b = sol.b
    if n_B >= N_ROTATIONS:  # x = J^T y, y = (J J^T + lambda^2 I)^{-1} b
        x = _mtv(Vt, _safe_divide(S, denom) * _mtv(U, b))
        y = _mv(U, _safe_divide(_mtv(U, b), denom))
        c = b_dot - _mv(dJ_wB, x) - _mv(J, _mtv(dJ_wB, y)) - lam2_dot[..., None] * y
        x_dot = _mtv(dJ_wB, y) + dls(c)
    else:  # tall: x = (J^T J + lambda^2 I)^{-1} J^T b
        x = dls(b)
        c = _mtv(dJ_wB, b - _mv(J, x)) - lam2_dot[..., None] * x
        x_dot = _mtv(Vt, _safe_divide(_mv(Vt, c), denom)) + dls(b_dot - _mv(dJ_wB, x))
    if n_B > S.shape[-1]:
        # w = P z, P = I - J^+ J: dw = -P dJ^T (J J^T)^{-1} J z - J^+ dJ P z + P dz
        z = sol.z
        Pz = z - _mtv(Vt, _mv(Vt, z))
        JJinvJz = _mv(U, _safe_divide(_mv(Vt, z), S))  # (J J^T)^{-1} J z = U S^{-1} V^T z
        v = -_mtv(dJ_wB, JJinvJz) + z_dot
        Pv = v - _mtv(Vt, _mv(Vt, v))
        pinv_term = _mtv(Vt, _safe_divide(_mtv(U, _mv(dJ_wB, Pz)), S))
        x_dot = x_dot + Pv - pinv_term
    return x_dot


@dataclass
class LawSample:
    """The law at one configuration (see :meth:`BalanceLaw.rates`).

    Attributes:
        q_dot_B: balance joint rates [rad/s] (Eq. 31).
        omega: base angular velocity these rates leave, base frame [rad/s] (zero for the exact
            open-loop law; ``-K e_R`` with feedback).
        residual: ``J_wB q_dot_B - b`` [rad/s], what damping leaves undone.
        sigma_min: smallest singular value of ``J_wB``.
        damping: ``lambda`` used.
    """

    q_dot_B: np.ndarray
    omega: np.ndarray
    residual: np.ndarray
    sigma_min: float
    damping: float


@dataclass
class LawPath:
    """The law evaluated along a sampled motion (batched :class:`BalanceLaw` output).

    Attributes:
        q_dot_B, q_ddot_B: (T, n_B) [rad/s, rad/s^2] (Eq. 31, 32).
        omega: (T, 3) base angular velocity, base frame [rad/s].
        residual: (T, 3) [rad/s] ``J_wB q_dot_B - b``.
        sigma_min, damping: (T,).
        condition: (T,) condition number of ``J_wB`` (``inf`` where singular).
        momentum_residual: (T,) ``|I_G omega + A q_dot - R^T L|`` [N m s].
    """

    q_dot_B: np.ndarray
    q_ddot_B: np.ndarray
    omega: np.ndarray
    residual: np.ndarray
    sigma_min: np.ndarray
    damping: np.ndarray
    condition: np.ndarray
    momentum_residual: np.ndarray


class BalanceLaw:
    """The analytic balance law of a robot, evaluated with numeric Pinocchio.

    Args:
        robot: the floating robot.
        options: law settings (defaults: :class:`BalanceLawOptions`).
        q_B0: initial balance configuration [rad]; the null-space goal of joints without finite
            limits (default: the neutral configuration).
        reference: ``R_0`` of the attitude feedback, a quaternion (x, y, z, w) (default identity).

    Raises:
        InputError: a null-space goal of the wrong size.
    """

    def __init__(
        self,
        robot: FloatingRobot,
        options: BalanceLawOptions | None = None,
        q_B0=None,
        reference=None,
    ):
        self.robot = robot
        self.options = options or BalanceLawOptions()
        self.maps = AngularMomentumMaps(robot)
        self.mission = robot.mission_indices
        self.balance = robot.balance_indices
        lim = robot.limits.subset(self.balance)
        start = robot.neutral()[self.balance] if q_B0 is None else np.asarray(q_B0, dtype=float)
        if self.options.null_space_goal is not None:
            goal = np.array(self.options.null_space_goal)
            if goal.size != self.balance.size:
                raise InputError(
                    f"balance law option 'null_space_goal' has {goal.size} values, "
                    f"the balance joints are {self.balance.size}"
                )
        else:  # mid-range, or the start for a joint without finite limits
            finite = np.isfinite(lim.lower) & np.isfinite(lim.upper)
            goal = np.array(start, dtype=float)
            goal[finite] = 0.5 * (lim.lower[finite] + lim.upper[finite])
        self.goal = goal
        self.reference = (
            IDENTITY_QUATERNION.copy() if reference is None else np.asarray(reference, dtype=float)
        )
        self.angular_momentum = self.options.angular_momentum

    # ------------------------------------------------------------------ pieces
    def _drift(self, I_G, quaternion):
        """``(omega_h, e_R, l)``: base rate due to h0, the attitude error, ``R^T L`` (batched;
        zeros where h0 or the feedback gain is zero)."""
        shape = quaternion.shape[:-1] + (3,)
        if self.angular_momentum.any():
            ell = _mtv(
                matrix_from_quaternion(quaternion), np.broadcast_to(self.angular_momentum, shape)
            )
            omega_h = np.linalg.solve(I_G, ell[..., None])[..., 0]
        else:
            ell = omega_h = np.zeros(shape)
        if self.options.attitude_gain:
            e_R = rotvec_from_quaternion(
                quaternion_multiply(quaternion_conjugate(self.reference), quaternion)
            )
        else:
            e_R = np.zeros(shape)
        return omega_h, e_R, ell

    def _null_velocity(self, q_B):
        return -self.options.null_space_gain * (q_B - self.goal)

    def _solve(self, I_G, A, q_dot_M, q_B, quaternion):
        J = angular_jacobians_from_maps(I_G, A)
        J_wM, J_wB = J[..., self.mission], J[..., self.balance]
        omega_h, e_R, ell = self._drift(I_G, quaternion)
        b = -_mv(J_wM, q_dot_M) - omega_h - self.options.attitude_gain * e_R
        sol = velocity_law(J_wB, b, self._null_velocity(q_B), self.options)
        omega = _mv(J_wM, q_dot_M) + _mv(J_wB, sol.q_dot_B) + omega_h
        return J, sol, omega, omega_h, e_R, ell

    # ------------------------------------------------------------------ one sample
    def rates(self, q, q_dot_M, quaternion=None) -> LawSample:
        """Balance joint rates at one instant (Eq. 31).

        Args:
            q: arm vector (mission and balance joints) [rad].
            q_dot_M: mission joint rates [rad/s].
            quaternion: base attitude (x, y, z, w), for ``h0`` and the feedback (default identity).
        """
        q = np.asarray(q, dtype=float)
        quaternion = (
            IDENTITY_QUATERNION if quaternion is None else np.asarray(quaternion, dtype=float)
        )
        I_G, A = self.maps.at(q)
        _, sol, omega, *_ = self._solve(
            I_G, A, np.asarray(q_dot_M, dtype=float), q[self.balance], quaternion
        )
        return LawSample(sol.q_dot_B, omega, sol.residual, float(sol.sigma_min), float(sol.damping))

    def attitude_rate(self, q, q_dot_M, quaternion) -> tuple[np.ndarray, np.ndarray]:
        """``(q_dot_B, omega)`` at one instant: the integrator's right-hand side."""
        I_G, A = self.maps.at(q)
        _, sol, omega, *_ = self._solve(I_G, A, q_dot_M, q[self.balance], quaternion)
        return sol.q_dot_B, omega

    def accelerations(self, q, q_dot_M, q_ddot_M, quaternion=None) -> np.ndarray:
        """Balance joint accelerations at one instant (Eq. 32), along the law's own rates.

        Args:
            q: arm vector [rad].
            q_dot_M: mission joint rates [rad/s] (the balance rates are the law's, :meth:`rates`).
            q_ddot_M: mission joint accelerations [rad/s^2].
            quaternion: base attitude (default identity).
        """
        quaternion = (
            IDENTITY_QUATERNION if quaternion is None else np.asarray(quaternion, dtype=float)
        )
        path = self.along(
            np.atleast_2d(q),
            np.atleast_2d(q_dot_M),
            np.atleast_2d(q_ddot_M),
            np.atleast_2d(quaternion),
        )
        return path.q_ddot_B[0]

    # ------------------------------------------------------------------ along a path
    def along(self, q, q_dot_M, q_ddot_M, quaternion) -> LawPath:
        """The law along sampled states, batched (Eq. 31 and 32).

        Args:
            q: (T, n) arm vectors; the balance columns are the state the law acts from [rad].
            q_dot_M, q_ddot_M: (T, n_M) mission rates and accelerations.
            quaternion: (T, 4) base attitude.
        """
        q = np.asarray(q, dtype=float)
        q_B = q[:, self.balance]
        Ag = self.maps.centroidal_along(q)
        I_G, A = self.maps.angular_blocks(Ag)
        J, sol, omega, omega_h, e_R, ell = self._solve(I_G, A, q_dot_M, q_B, quaternion)
        q_dot = np.empty_like(q)
        q_dot[:, self.mission] = q_dot_M
        q_dot[:, self.balance] = sol.q_dot_B
        dI_G, dA = self.maps.rates_along(q, q_dot, Ag)
        dJ = angular_jacobian_rates_from_maps(I_G, dI_G, dA, J)
        J_wM, dJ_wM = J[..., self.mission], dJ[..., self.mission]
        # d(omega_h)/dt = I_G^{-1} (d(R^T L)/dt - dI_G omega_h), d(R^T L)/dt = -omega x R^T L
        ell_dot = -np.cross(omega, ell)
        omega_h_dot = np.linalg.solve(I_G, (ell_dot - _mv(dI_G, omega_h))[..., None])[..., 0]
        b_dot = -(_mv(dJ_wM, q_dot_M) + _mv(J_wM, q_ddot_M)) - omega_h_dot
        K = self.options.attitude_gain
        if K:
            Jr_inv = np.array([inverse_right_jacobian(e) for e in e_R.reshape(-1, 3)])
            Jr_inv = Jr_inv.reshape((*e_R.shape, 3))
            b_dot = b_dot - K * _mv(Jr_inv, omega)
        z_dot = -self.options.null_space_gain * sol.q_dot_B
        q_ddot_B = acceleration_law(sol, dJ[..., self.balance], b_dot, z_dot)
        h_res = _mv(I_G, omega) + _mv(A, q_dot) - ell
        condition = _safe_divide(sol.S[..., 0], sol.sigma_min)
        condition[sol.sigma_min == 0] = np.inf
        return LawPath(
            sol.q_dot_B,
            q_ddot_B,
            omega,
            sol.residual,
            sol.sigma_min,
            sol.damping,
            condition,
            np.linalg.norm(h_res, axis=-1),
        )


def analytic_plan(
    robot: FloatingRobot,
    mission,
    q_B0,
    options: BalanceLawOptions | None = None,
    *,
    t=None,
    integration=None,
):
    """The analytic law's balance plan (Phase II) sampled at the times ``t`` [s]: a shortcut to
    :func:`balance_opt.motion.rollout.rollout` (``t_eval=t``), e.g. for an optimiser's initial guess.

    Raises:
        SolverError: the law could not be integrated (an exact law through a singular ``J_wB``).
    """
    from balance_opt.motion.rollout import rollout  # rollout builds on this module

    return rollout(robot, mission, q_B0, options, integration=integration, t_eval=t)
