"""An independent check that a sampled motion conserves angular momentum: the figure of merit
``momentum_residual`` of every :class:`~balance_opt.result.BalanceResult`.

It uses only what a result exports (times, joint positions and rates, base attitude) and shares
no code with the base rate the planners compute
(:func:`balance_opt.model.maps.base_angular_velocity`): the base rate is recovered from the
exported attitudes by finite differences (:func:`balance_opt.motion.so3.body_rates_from_samples`),
and the momentum is ``A_G(q, R) v`` from ``pin.computeCentroidalMap`` at the exported attitude,
in world axes. An attitude that does not follow the joints (integrated wrongly, or not at all)
shows up as a residual of order one.

The residual is relative (``docs/physics.md``, "Base motion forced by the joints"): the angular
momentum about the CoM against the initial one, ``|L(t) - L0|``, over the largest angular
momentum the arms carry plus ``|L0|`` (:func:`momentum_scale`). Its floor is the
finite-difference error of the recovered rate.
"""

from __future__ import annotations

import numpy as np

from balance_opt.model.maps import NumericMaps
from balance_opt.motion.so3 import body_rates_from_samples

#: Momentum scale below which the residual is reported in absolute terms [N s, N m s].
MOMENTUM_SCALE_FLOOR = 1e-12


def momentum_residual(maps: NumericMaps, t, q, q_dot, quaternion, angular_momentum=None):
    """Relative angular-momentum residual (T,) of a sampled motion (see the module docstring).

    Args:
        t: sample times (T,) [s].
        q, q_dot: arm positions and rates (T, n) [rad, rad/s].
        quaternion: base attitude (T, 4), (x, y, z, w).
        angular_momentum: the initial angular momentum about the CoM, world axes (3,) [N m s];
            ``None`` for zero.

    Returns:
        ``|L(t) - L0| / scale`` per sample; NaN for a single sample (no rate to recover).
    """
    L0 = np.zeros(3) if angular_momentum is None else np.asarray(angular_momentum, dtype=float)
    q_dot = np.asarray(q_dot, dtype=float)
    omega = body_rates_from_samples(t, quaternion)
    Ag = maps.centroidal(np.asarray(q, dtype=float), np.asarray(quaternion, dtype=float))
    L = np.matvec(Ag[:, 3:], maps.velocities(q_dot, omega))
    return np.linalg.norm(L - L0, axis=1) / momentum_scale(maps, Ag, q_dot, L0)


def momentum_scale(maps: NumericMaps, Ag: np.ndarray, q_dot: np.ndarray, L0: np.ndarray) -> float:
    """``max_t sum_arms |A_arm q_dot_arm| + |L0|`` [N m s]: the largest angular momentum the arms
    carry, each on its own (a balance arm that cancels the mission arm's momentum adds to the
    scale rather than removing from it), plus the initial momentum ``L0`` (3,) [N m s]; ``Ag``
    is Pinocchio's ``A_G`` along the motion (T, 6, nv), ``q_dot`` the arm rates (T, n)."""
    carried = np.zeros(q_dot.shape[0])
    for arm in maps.robot.arms:
        rates = np.zeros_like(q_dot)
        rates[:, arm.indices] = q_dot[:, arm.indices]
        carried += np.linalg.norm(np.matvec(Ag[:, 3:], maps.velocities(rates)), axis=1)
    return max(float(carried.max(initial=0.0)) + float(np.linalg.norm(L0)), MOMENTUM_SCALE_FLOOR)
