"""The SO(3) toolbox (numeric and CasADi faces) against Pinocchio's own SO(3) functions and
finite differences, and body rates recovered from sampled attitudes against known motions."""

import casadi as cs
import numpy as np
import pinocchio as pin
import pytest

from balance_opt.motion.so3 import (
    SERIES_ANGLE,
    body_rates_from_samples,
    inverse_right_jacobian,
    matrix_from_quaternion,
    quaternion_from_rotvec,
    quaternion_multiply,
    relative_rotation,
    rotation_angle,
    rotvec_from_quaternion,
    rpy_from_quaternion,
    skew,
)
from balance_opt.motion.so3_casadi import inverse_right_jacobian_sym, skew_sym

#: Two evaluations of the same closed-form expression.
ALGEBRA_ATOL = 1e-13
#: Richardson-extrapolated central differences, step 1e-4: truncation ~1e-14, rounding ~1e-12.
FD_ATOL = 1e-9


def _rotvecs(rng, n, largest=3.0):
    """Rotation vectors with angles spread from 1e-6 to ``largest`` [rad] (both sides of the
    series threshold)."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * np.geomspace(1e-6, largest, n)[:, None]


def test_exp_log_matrix_and_rpy_match_pinocchio():
    rng = np.random.default_rng(1)
    phi = _rotvecs(rng, 40)
    q = quaternion_from_rotvec(phi)
    R = matrix_from_quaternion(q)
    for k in range(phi.shape[0]):
        np.testing.assert_allclose(R[k], pin.exp3(phi[k]), rtol=0, atol=ALGEBRA_ATOL)
        np.testing.assert_allclose(
            rpy_from_quaternion(q[k]), pin.rpy.matrixToRpy(R[k]), rtol=0, atol=1e-12
        )
    np.testing.assert_allclose(rotvec_from_quaternion(q), phi, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rotvec_from_quaternion(-q), phi, rtol=0, atol=1e-12)  # same R
    np.testing.assert_allclose(rotation_angle(q), np.linalg.norm(phi, axis=1), rtol=0, atol=1e-12)
    # relative rotation: R_a^T R_b
    rel = relative_rotation(q[:-1], q[1:])
    np.testing.assert_allclose(
        matrix_from_quaternion(rel),
        np.swapaxes(R[:-1], 1, 2) @ R[1:],
        rtol=0,
        atol=ALGEBRA_ATOL,
    )
    np.testing.assert_allclose(quaternion_multiply(q[:-1], rel), q[1:], rtol=0, atol=ALGEBRA_ATOL)


def test_skew_numeric_and_casadi():
    rng = np.random.default_rng(2)
    v, w = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(np.matvec(skew(v), w), np.cross(v, w), rtol=0, atol=ALGEBRA_ATOL)
    for k in range(5):
        np.testing.assert_allclose(skew(v[k]), pin.skew(v[k]), rtol=0, atol=0)
        np.testing.assert_allclose(
            np.array(cs.evalf(skew_sym(cs.DM(v[k])))), skew(v[k]), rtol=0, atol=0
        )


def test_inverse_right_jacobian_is_the_rate_of_log():
    """``d/dt log(exp(phi) exp(omega t))`` at 0 is ``Jr^{-1}(phi) omega``: finite differences
    with Pinocchio's log3, on both sides of the series threshold; the batched numeric face and
    the CasADi face agree."""
    rng = np.random.default_rng(3)
    phi = _rotvecs(rng, 30)
    omega = rng.normal(size=(30, 3))
    batched = inverse_right_jacobian(phi)
    phi_s = cs.SX.sym("phi", 3)
    symbolic = cs.Function("jr_inv", [phi_s], [inverse_right_jacobian_sym(phi_s)])
    h = 1e-4
    for k in range(phi.shape[0]):
        R = pin.exp3(phi[k])

        def log_after(t, k=k, R=R):
            return pin.log3(R @ pin.exp3(omega[k] * t))

        d1 = (log_after(h) - log_after(-h)) / (2 * h)
        d2 = (log_after(2 * h) - log_after(-2 * h)) / (4 * h)
        np.testing.assert_allclose(batched[k] @ omega[k], (4 * d1 - d2) / 3, rtol=0, atol=FD_ATOL)
        np.testing.assert_allclose(inverse_right_jacobian(phi[k]), batched[k], rtol=0, atol=0)
        np.testing.assert_allclose(
            np.array(symbolic(phi[k])), batched[k], rtol=0, atol=ALGEBRA_ATOL
        )


def test_inverse_right_jacobian_series_meets_the_closed_form():
    """At the threshold the series and the closed form agree to the closed form's rounding."""
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    below = inverse_right_jacobian(axis * SERIES_ANGLE * (1 - 1e-9))
    above = inverse_right_jacobian(axis * SERIES_ANGLE * (1 + 1e-9))
    np.testing.assert_allclose(below, above, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(inverse_right_jacobian(np.zeros(3)), np.eye(3))


# ---------------------------------------------------------------------------------- sampled
def _known_motion(t):
    """``R(t) = exp(phi(t))`` with a smooth ``phi`` and its body rate ``Jr(phi) phi_dot``."""
    phi = np.c_[0.3 * np.sin(0.7 * t), 0.1 * t**2 / 10, -0.2 * np.cos(0.4 * t) + 0.2]
    phi_dot = np.c_[0.21 * np.cos(0.7 * t), 0.02 * t, 0.08 * np.sin(0.4 * t)]
    omega = np.linalg.solve(inverse_right_jacobian(phi), phi_dot[..., None])[..., 0]
    return quaternion_from_rotvec(phi), omega


@pytest.mark.parametrize("grid", ["uniform", "non-uniform"])
def test_body_rates_from_samples_of_a_known_motion(grid):
    t = np.linspace(0.0, 10.0, 1001)
    if grid == "non-uniform":
        t = t + 0.003 * np.sin(3.0 * t)  # still increasing, spacing from 7 to 13 ms
    q, omega = _known_motion(t)
    rates = body_rates_from_samples(t, q)
    # 7-point stencils at 10 ms: O(h^6) ~ 1e-12 for this motion
    np.testing.assert_allclose(rates, omega, rtol=0, atol=1e-10)


def test_body_rates_across_a_corner_are_one_sided():
    """A rotation about a fixed axis whose rate has a corner at a sample (its acceleration jumps
    from 0 to 1 rad/s^2, as at a collocated plan's nodes): the angle is polynomial on each side,
    and every stencil stays on one side, so the rates are exact to rounding; the centred stencil
    across the corner would err by ~1e-4 rad/s."""
    t = np.linspace(0.0, 1.0, 101)
    late = np.maximum(t - 0.5, 0.0)
    angle, rate = 0.2 * t + 0.5 * late**2, 0.2 + late
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    rates = body_rates_from_samples(t, quaternion_from_rotvec(angle[:, None] * axis))
    np.testing.assert_allclose(rates, rate[:, None] * axis, rtol=0, atol=1e-12)


def test_body_rates_of_short_histories():
    q = quaternion_from_rotvec(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.01]]))
    rates = body_rates_from_samples([0.0, 0.5], q)
    np.testing.assert_allclose(rates, [[0.0, 0.0, 0.02]] * 2, rtol=0, atol=1e-15)
    assert np.isnan(body_rates_from_samples([0.0], q[:1])).all()
