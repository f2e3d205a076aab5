"""Smooth plans (issue 25): the smoothness figures of merit, the jerk regulariser's exact
integral, and jerk limits held on the whole continuous plan."""

from __future__ import annotations

import numpy as np
import pytest

from balance_opt.errors import InputError
from balance_opt.model.library import paper_robot
from balance_opt.motion.smoothness import count_reversals, smoothness
from balance_opt.optimal.collocation import (
    CollocatedTrajectory,
    Transcription,
    joint_chain_coefficients,
)
from balance_opt.optimal.constraints import JerkLimit
from balance_opt.optimal.objectives import jerk_integral
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp

BALANCE = ("balance_joint1", "balance_joint2", "balance_joint3")
#: Jerk limit of the capture task's plan in the tests [rad/s^3]: its plan without one reaches
#: about 35 rad/s^3.
JERK_LIMIT = 5.0


# ---------------------------------------------------------------------------------- figures
def test_reversals_count_swings_past_the_hysteresis_only():
    t = np.linspace(0.0, 10.0, 2001)
    rng = np.random.default_rng(0)
    wave = 2.0 * np.sin(2 * np.pi * 0.5 * t)  # 5 periods: 10 extrema, each turned back from
    assert count_reversals(wave, 0.2) == 10
    # ripples below the threshold are not counted, a bang-bang switch always is
    ripple = rng.uniform(-0.09, 0.09, t.size)  # peak to peak below the threshold
    assert count_reversals(wave + ripple, 0.2) == 10
    assert count_reversals(ripple, 0.2) == 0
    assert count_reversals(np.sign(np.sin(2 * np.pi * 2.0 * t)), 0.2) == 39  # 40 switches
    # a smooth rest-to-rest move: up, down, back to zero
    assert count_reversals(np.sin(2 * np.pi * t / 10.0), 0.1) == 2


def test_smoothness_of_a_known_motion():
    t = np.linspace(0.0, 2.0, 201)
    a = np.column_stack([3.0 * t, np.where(t < 1.0, 1.0, -1.0)])  # jerk 3; a step of 2 in 0.01 s
    tau = np.column_stack([5.0 * t, np.zeros_like(t)])
    s = smoothness(t, a, ("a", "b"), [np.inf, 1.0], tau)
    np.testing.assert_allclose(s.max_jerk, [3.0, 200.0], rtol=1e-9)
    np.testing.assert_allclose(s.max_torque_rate, [5.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(s.reversal_threshold, [0.6, 0.1])  # 0.1 of 6 and of 1
    np.testing.assert_array_equal(s.reversals, [0, 0])
    d = s.to_dict()
    assert d["b"] == {
        "max_jerk_rad_s3": pytest.approx(200.0),
        "acceleration_reversals": 0,
        "reversal_threshold_rad_s2": pytest.approx(0.1),
        "max_torque_rate_Nm_s": 0.0,
    }
    with pytest.raises(ValueError, match="a name per joint: 201 samples, 2 joints, 1 names"):
        smoothness(t, a, ("a",))


# ---------------------------------------------------------------------------------- regulariser
@pytest.mark.parametrize("name", ["hermite-simpson", "trapezoidal"])
@pytest.mark.parametrize("control", ["acceleration", "jerk"])
def test_jerk_integral_is_exact_on_the_continuous_plan(name, control):
    """The regulariser's closed form against a dense quadrature of the continuous plan's jerk
    (differences of its acceleration); a constant acceleration per interval has only steps,
    counted as step^2 / h (elsewhere the collocation keeps the acceleration continuous)."""
    rng = np.random.default_rng(1)
    tr, N, n, h = Transcription(name), 6, 2, 0.3
    starts = [rng.standard_normal((n, N)) for _ in range(2 if control == "acceleration" else 3)]
    U = rng.standard_normal((n, N + 1))
    Um = rng.standard_normal((n, N)) if tr.has_midpoints else None
    levels = joint_chain_coefficients(tr, starts, U, Um, h)
    closed = jerk_integral(levels[2], h)
    plan = CollocatedTrajectory(h, levels)
    dense = 0.0
    s = np.linspace(0.0, 1.0, 4001)
    for k in range(N):  # per interval, so the steps at the nodes stay out of the quadrature
        a = plan.sample(np.clip((k + s) * h, k * h + 1e-12, (k + 1) * h - 1e-12))[2]
        jerk = np.diff(a, axis=0) / (h * np.diff(s))[:, None]
        dense += float(np.sum(jerk**2) * h * (s[1] - s[0]))
    if len(levels[2]) == 1:  # a constant acceleration per interval: its steps are priced
        dense += float(np.sum(np.diff(levels[2][0], axis=1) ** 2)) / h
    assert closed == pytest.approx(dense, rel=1e-5)


# ---------------------------------------------------------------------------------- limits
def test_jerk_limits_refused_where_the_acceleration_steps():
    with pytest.raises(InputError, match="jerk limits need a continuous acceleration; the "
                       "trapezoidal rule with control 'acceleration'"):
        JerkLimit(Transcription("trapezoidal"), "acceleration")


def test_jerk_limit_from_overrides():
    robot = paper_robot(limits={"balance_joint2": {"jerk": 4.0}})
    assert robot.limits.jerk[robot.joint_index("balance_joint2")] == 4.0
    assert np.isinf(robot.limits.jerk[robot.joint_index("balance_joint1")])
    with pytest.raises(InputError, match="jerk limit must be positive, got -1"):
        paper_robot(limits={"balance_joint2": {"jerk": -1.0}})


@pytest.fixture(scope="module")
def limited():
    """The capture task with a jerk limit on every balance joint, its integral plan at N = 40."""
    from balance_opt.app.scenarios import capture_task
    from balance_opt.optimal.model import PlannerModel

    capture = capture_task()
    limits = {j: {"acceleration": 2.0, "jerk": JERK_LIMIT} for j in BALANCE}
    robot = paper_robot(limits=limits)
    options = PlannerOptions(objective="integral", intervals=40)
    nlp = build_balance_nlp(
        PlannerModel(robot, compile=False), capture.mission, capture.q_B0, options, robot
    )
    return nlp, nlp.solve()


def test_jerk_limits_hold_on_the_whole_continuous_plan(limited):
    nlp, plan = limited
    assert "jerk" in nlp.structure.key.joint_limits
    sol = plan.solver.solution
    levels = joint_chain_coefficients(
        nlp.transcription, [sol.X[3:6, :-1], sol.X[6:9, :-1]], sol.U, sol.Um, nlp.h
    )
    jerk = np.stack(JerkLimit(nlp.transcription, "acceleration").coefficients(levels, nlp.h))
    # every Bernstein coefficient of the jerk inside the limit: the continuous jerk is
    assert np.abs(jerk).max() <= JERK_LIMIT + 1e-6
    # the limit binds (the plan without it reaches ~35 rad/s^3), and the re-simulated motion
    # (its accelerations sampled) keeps it too
    assert np.abs(jerk).max() > 0.99 * JERK_LIMIT
    sampled = np.abs(np.diff(plan.q_ddot_B, axis=0) / np.diff(plan.t)[:, None])
    assert sampled.max() <= JERK_LIMIT + 1e-6
    assert plan.solver.checks.constraint_violations == ()
    # the acceleration, so the torque on the base, is continuous: no step between samples
    # larger than the limit allows
    assert np.abs(np.diff(plan.q_ddot_B, axis=0)).max() <= JERK_LIMIT * np.diff(plan.t).max()
