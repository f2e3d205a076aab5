"""balance-opt's DOP853 (motion/dop853.py) against SciPy's ``solve_ivp(method="DOP853")``: the
same states at the output times, the same number of right-hand side evaluations, the same
failure where a solution blows up."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from balance_opt.motion import dop853


def pendulum(t, y):
    return np.array([y[1], -9.81 * np.sin(y[0]) - 0.1 * y[1] + 0.3 * np.cos(2 * t)])


def spinning_quaternion(t, y):
    """``q_dot = 1/2 q * (omega, 0)`` with a time-varying rate: the attitude replay's form."""
    wx, wy, wz = 0.3 * np.sin(t), 0.2 * np.cos(3 * t), 0.1
    x, yy, z, w = y
    return 0.5 * np.array(
        [
            w * wx + yy * wz - z * wy,
            w * wy + z * wx - x * wz,
            w * wz + x * wy - yy * wx,
            -(x * wx + yy * wy + z * wz),
        ]
    )


def blows_up(t, y):
    return y**2  # y = 1 / (1 - t): infinite at t = 1


CASES = [
    (pendulum, np.array([1.0, 0.0]), np.linspace(0.0, 10.0, 101), 1e-10, 1e-12, np.inf),
    (pendulum, np.array([2.5, 1.0]), np.linspace(0.0, 3.0, 7), 1e-6, 1e-9, 0.05),
    (
        spinning_quaternion,
        np.array([0.0, 0.0, 0.0, 1.0]),
        np.linspace(0.0, 10.0, 1001),
        1e-10,
        1e-12,
        np.inf,
    ),
    (
        spinning_quaternion,
        np.array([0.1, 0.2, 0.3, 0.9]),
        np.array([0.0, 0.01, 5.0, 5.5]),
        1e-8,
        1e-10,
        np.inf,
    ),
]


@pytest.mark.parametrize(("rhs", "y0", "t", "rtol", "atol", "max_step"), CASES)
def test_same_states_and_evaluations_as_scipy(rhs, y0, t, rtol, atol, max_step):
    ours = dop853.solve(rhs, y0, t, rtol, atol, max_step)
    ref = solve_ivp(
        rhs, (t[0], t[-1]), y0, method="DOP853", t_eval=t, rtol=rtol, atol=atol, max_step=max_step
    )
    assert ours.status == ref.status == 0
    np.testing.assert_array_equal(ours.t, ref.t)
    np.testing.assert_allclose(ours.y, ref.y, rtol=0, atol=1e-14)
    assert ours.nfev == ref.nfev


def test_blow_up_fails_where_scipy_fails():
    t = np.linspace(0.0, 2.0, 21)
    ours = dop853.solve(blows_up, np.array([1.0]), t, 1e-10, 1e-12)
    ref = solve_ivp(blows_up, (0.0, 2.0), [1.0], method="DOP853", t_eval=t, rtol=1e-10, atol=1e-12)
    assert ours.status == ref.status == -1
    assert ours.message == ref.message
    np.testing.assert_array_equal(ours.t, ref.t)  # the output times up to t = 1
    assert ours.t[-1] < 1.1 and ours.t.size < t.size
    np.testing.assert_allclose(ours.y, ref.y, rtol=1e-14)


def test_exact_solution_to_the_tolerance():
    t = np.linspace(0.0, 0.9, 10)
    sol = dop853.solve(blows_up, np.array([1.0]), t, 1e-12, 1e-14)
    np.testing.assert_allclose(sol.y[0], 1.0 / (1.0 - t), rtol=1e-9)
