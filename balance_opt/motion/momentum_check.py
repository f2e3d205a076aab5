"""An independent check that a sampled motion conserves angular momentum: ``momentum_residual``
of every :class:`~balance_opt.motion.result.BalanceResult`.

It shares no code with the planners' base rate: the rate is recovered from the exported
attitudes by finite differences, and the momentum is ``A_G(q, R) v`` in world axes, so an
attitude that does not follow the joints shows as a residual of order one. The residual is
``|L(t) - L0|`` over :func:`momentum_scale` (``docs/physics.md``).
"""

from __future__ import annotations

import numpy as np

from balance_opt.model.maps import NumericMaps
from balance_opt.motion.so3 import body_rates_from_samples

#: Momentum scale below which the residual is reported in absolute terms [N s, N m s].
MOMENTUM_SCALE_FLOOR = 1e-12


def momentum_residual(maps: NumericMaps, t, q, q_dot, quaternion, angular_momentum=None):
    """Relative angular-momentum residual (T,) of a sampled motion (NaN for a single sample);
    ``angular_momentum``: the initial one about the CoM, world axes [N m s], ``None`` for zero."""
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
