"""The CasADi face of :mod:`balance_opt.motion.so3` (same threshold and coefficients) for
symbolic rotation vectors: the optimal planner's attitude kinematics."""

from __future__ import annotations

import casadi as cs

from balance_opt.motion.so3 import SERIES_ANGLE, jr_inverse_closed, jr_inverse_series


def skew_sym(v):
    """``[v]_x`` (3 x 3) of a CasADi 3-vector."""
    return cs.vertcat(
        cs.horzcat(0, -v[2], v[1]), cs.horzcat(v[2], 0, -v[0]), cs.horzcat(-v[1], v[0], 0)
    )


def _angle(phi):
    """``(a2, small, a2_safe, a)``: ``|phi|^2``, whether the series applies, and a safe angle
    where it does, at which the closed forms and their derivatives stay finite."""
    a2 = cs.dot(phi, phi)
    small = a2 < SERIES_ANGLE**2
    a2_safe = cs.if_else(small, 1.0, a2)
    return a2, small, a2_safe, cs.sqrt(a2_safe)


def inverse_right_jacobian_sym(phi):
    """``Jr^{-1}(phi)`` for a CasADi rotation vector (see
    :func:`balance_opt.motion.so3.inverse_right_jacobian`)."""
    a2, small, a2_safe, a = _angle(phi)
    c_closed = jr_inverse_closed(a2_safe, a, cs.cos(a), cs.sin(a))
    c = cs.if_else(small, jr_inverse_series(a2), c_closed)
    K = skew_sym(phi)
    return cs.SX.eye(3) + 0.5 * K + c * (K @ K)


def rotation_matrix_sym(phi):
    """``R = exp([phi]_x)`` (Rodrigues) for a CasADi rotation vector: ``I + s K + c K^2`` with
    ``s = sin(a)/a``, ``c = (1 - cos a)/a^2``, their series below
    :data:`~balance_opt.motion.so3.SERIES_ANGLE`."""
    a2, small, a2_safe, a = _angle(phi)
    s = cs.if_else(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, cs.sin(a) / a)
    c = cs.if_else(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0, (1.0 - cs.cos(a)) / a2_safe)
    K = skew_sym(phi)
    return cs.SX.eye(3) + s * K + c * (K @ K)
