"""The optimal balance planner (issue 4): its model against numeric Pinocchio, its assembled
derivatives against CasADi's own AD, its plans re-simulated, its failures.

Every plan here is judged by its re-simulation (numeric Pinocchio, ``rollout.replay``), never by
the NLP's own numbers. The kernels run on CasADi's virtual machine (``compile=False``): the same
functions as the compiled ones, without a C compiler's first-time cost in the test run.

Tasks:

* *in-plane*: the mission arm's pitch joints only (yaw held at 0), so the base turns about one
  axis the balance arm controls well: the analytic law stays far inside the limits;
* *capture*: the capture task (``scenarios.capture_task``), where the analytic law
  breaks the limits (its balance joint 3 runs 8 rad past its limit) and the J_wB of the balance
  arm is singular at its start (rank 2: its yaw is 0, so it cannot roll the base). With the
  URDF's 1 rad/s joint rate limits, the best plan in 10 s keeps the largest drift about 3 times
  below Phase I's (a hard path bound of a fifth of Phase I's is locally infeasible: Ipopt
  says so). The same move in 20 s (same path, so the same Phase I drift: the attitude change of
  a zero-momentum motion depends on the path only) leaves the balance arm the speed to do
  5 times better: that is the 5x test.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from math import comb
from types import SimpleNamespace

import casadi as cs
import numpy as np
import pinocchio as pin
import pytest

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.analytic.rollout import rollout
from balance_opt.app.scenarios import CAPTURE_MISSION_GOAL, CAPTURE_MISSION_START
from balance_opt.errors import InfeasibleLimitsError, InputError
from balance_opt.model.library import paper_robot
from balance_opt.model.maps import NumericMaps
from balance_opt.motion.replay import phase_one
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import (
    SERIES_ANGLE,
    inverse_right_jacobian,
    matrix_from_quaternion,
    quaternion_from_rotvec,
)
from balance_opt.motion.so3_casadi import inverse_right_jacobian_sym
from balance_opt.motion.trajectories import PointToPoint
from balance_opt.optimal.collocation import (
    CollocatedTrajectory,
    Transcription,
    bernstein_value,
    joint_chain_coefficients,
)
from balance_opt.optimal.constraints import TorqueLimit
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.nlp import point_kernels
from balance_opt.optimal.options import CostWeights, PlannerOptions
from balance_opt.optimal.problem import BalanceProblem, StructureKey
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.optimal.terms import PlannerSolverError
from balance_opt.solvers import codegen
from balance_opt.solvers.codegen import compile_functions

#: Model against numeric Pinocchio [rad/s], and exact algebra [rad/s].
MODEL_TOLERANCE = 1e-9
ALGEBRA_TOLERANCE = 1e-12
#: Assembled gradient/Jacobian/Hessian against CasADi's AD of the same NLP (relative to the
#: largest entry).
DERIVATIVE_TOLERANCE = 1e-9
#: The optimal plan may be worse than an analytic law that stays inside the limits by at most
#: this much re-simulated drift [rad] (the analytic law's own is ~7e-6 rad on the in-plane task,
#: Phase I's 3e-2 rad).
DRIFT_TOLERANCE = 1e-6
#: A hard terminal-attitude bound is met by the re-simulated plan within this [rad]: the
#: collocation error of Hermite-Simpson at N = 100 on the capture task (~1e-7 rad).
TERMINAL_TOLERANCE = 1e-6
#: Joint values of the continuous plan at the nodes vs the NLP's [rad, rad/s].
NODE_TOLERANCE = 1e-9
#: NLP attitude at the nodes against the re-simulated one, relative to the drift (Hermite-Simpson,
#: N = 50, velocity limits active: ~5e-4).
COLLOCATION_RELATIVE_ERROR = 1e-3
#: The analytic law the plans are compared with.
NEAR_EXACT_LAW = BalanceLawOptions(damping_threshold=1e-4, max_damping=1e-3)
#: The objective and end conditions these tests were written for (the peak objective and the
#: rest ends are tested in test_quality.py).
INTEGRAL = {
    "objective": "integral",
    "start": "still",
    "end": "free",
    # the plans these tests measure predate collision avoidance (tests/test_collision.py)
    "collision_avoidance": False,
}
#: Drift reduction against Phase I required on the capture move.
DRIFT_REDUCTION_20S = 5.0
DRIFT_REDUCTION_10S = 2.5


def bernstein_basis(degree: int, s: np.ndarray) -> np.ndarray:
    """The Bernstein basis polynomials of ``degree`` at ``s`` in [0, 1]: (len(s), degree + 1)."""
    s = np.asarray(s, dtype=float)[:, None]
    i = np.arange(degree + 1)[None, :]
    binomials = np.array([comb(degree, k) for k in range(degree + 1)], dtype=float)[None, :]
    return binomials * s**i * (1.0 - s) ** (degree - i)


# ---------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def in_plane(capture):
    """The mission arm's pitch joints only, 10 s."""
    return PointToPoint(CAPTURE_MISSION_START, (0.0, 0.9, -1.6), 10.0)


@pytest.fixture(scope="module")
def capture_plan(model, capture):
    """The capture task in 10 s, default options at N = 50."""
    return build_balance_nlp(
        model, capture.mission, capture.q_B0, PlannerOptions(**INTEGRAL, intervals=50)
    ).solve()


@pytest.fixture(scope="module")
def capture_law(capture):
    """The near-exact analytic law on the capture task, 1001 samples."""
    t = np.linspace(0.0, capture.mission.duration, 1001)
    return _near_exact_law(capture.robot, capture.mission, capture.q_B0, t)


def _near_exact_law(robot, mission, q_B0, t):
    """The analytic law with its damping 10 times weaker than the default: close to the exact
    Eq. 31 wherever J_wB is not singular."""
    return rollout(robot, mission, q_B0, NEAR_EXACT_LAW, t_eval=t)


def _random_points(rng, model, control, n):
    lim = model.robot.limits
    q = rng.uniform(
        np.maximum(lim.lower, -2.5), np.minimum(lim.upper, 2.5), size=(n, model.robot.n)
    )
    q_dot = rng.uniform(-1.0, 1.0, size=(n, model.robot.n))
    phi = rng.normal(size=(n, 3)) * rng.uniform(0.0, 1.0, size=(n, 1))
    extra = rng.normal(size=(n, model.n_B)) if control == "jerk" else np.empty((n, 0))
    return q, q_dot, phi, extra


# ---------------------------------------------------------------------------------- the model
@pytest.mark.parametrize("control", ["acceleration", "jerk"])
def test_dynamics_match_numeric_pinocchio(model, control):
    rng = np.random.default_rng(4)
    numeric = NumericMaps(model.robot)
    M, B = model.robot.mission_indices, model.robot.balance_indices
    dyn = model.dynamics_fun(control)
    for q, q_dot, phi, extra in zip(*_random_points(rng, model, control, 20)):
        u = rng.normal(size=model.n_B)
        x = np.r_[phi, q[B], q_dot[B], extra]
        m = np.r_[q[M], q_dot[M], rng.normal(size=M.size), np.zeros(6)]  # h0 = 0
        x_dot, omega = (np.array(v).ravel() for v in dyn(x, u, m))
        J_wM, J_wB = numeric.angular_jacobians(q)
        omega_ref = J_wM @ q_dot[M] + J_wB @ q_dot[B]
        np.testing.assert_allclose(omega, omega_ref, rtol=0, atol=MODEL_TOLERANCE)
        np.testing.assert_allclose(
            x_dot[:3], inverse_right_jacobian(phi) @ omega_ref, rtol=0, atol=MODEL_TOLERANCE
        )
        np.testing.assert_allclose(
            x_dot[3:],
            np.r_[q_dot[B], extra, u] if control == "jerk" else np.r_[q_dot[B], u],
            rtol=0,
            atol=ALGEBRA_TOLERANCE,
        )


def test_attitude_kinematics_on_so3():
    """``phi_dot = Jr^{-1}(phi) omega`` is the body rate ``omega`` of ``R = exp(phi)``: a step
    along ``phi_dot`` equals ``R exp(omega dt)`` to second order, on both branches of the
    series switch, and the expression and its Hessian are finite at ``phi = 0``."""
    rng = np.random.default_rng(7)
    phi_s = cs.SX.sym("phi", 3)
    fun = cs.Function("jr", [phi_s], [inverse_right_jacobian_sym(phi_s)])
    hess = cs.Function(
        "h",
        [phi_s],
        [cs.hessian(cs.sum1(inverse_right_jacobian_sym(phi_s) @ cs.DM([1, 2, 3])), phi_s)[0]],
    )
    assert np.all(np.isfinite(np.array(hess(np.zeros(3)))))
    np.testing.assert_array_equal(np.array(fun(np.zeros(3))), np.eye(3))
    dt = 1e-6
    for scale in (0.5 * SERIES_ANGLE, 2.0 * SERIES_ANGLE, 0.3, 2.0):
        phi = rng.normal(size=3)
        phi *= scale / np.linalg.norm(phi)
        omega = rng.normal(size=3)
        Jr_inv = np.array(fun(phi))
        np.testing.assert_allclose(
            Jr_inv, inverse_right_jacobian(phi), rtol=0, atol=ALGEBRA_TOLERANCE
        )
        R_next = matrix_from_quaternion(quaternion_from_rotvec(phi + dt * Jr_inv @ omega))
        R_ref = matrix_from_quaternion(quaternion_from_rotvec(phi)) @ pin.exp3(omega * dt)
        np.testing.assert_allclose(R_next, R_ref, rtol=0, atol=1e-11)


def test_torques_reproduce_the_accelerations_in_forward_dynamics(model):
    """Joint torques of the free-floating inverse dynamics, applied with no wrench on the base,
    give back the joint accelerations in Pinocchio's ABA (an independent algorithm)."""
    rng = np.random.default_rng(11)
    robot = model.robot
    numeric = NumericMaps(robot)
    tau_fun = model.torque_fun()
    data = robot.model.createData()
    for q, q_dot, _, _ in zip(*_random_points(rng, model, "acceleration", 10)):
        q_ddot = rng.normal(size=robot.n)
        tau = np.array(tau_fun(q, q_dot, q_ddot)).ravel()
        v = robot.pin_v(q_dot, numeric.base_twist(q, q_dot))
        tau_full = np.zeros(robot.model.nv)
        tau_full[robot.pin_v_indices] = tau
        a = pin.aba(robot.model, data, robot.pin_q(q), v, tau_full)
        np.testing.assert_allclose(a[robot.pin_v_indices], q_ddot, rtol=0, atol=MODEL_TOLERANCE)


@pytest.mark.parametrize(
    "transcription, control, extra",
    [
        (
            "hermite-simpson",
            "acceleration",
            {"path_attitude_bound": 0.2, "terminal_attitude_bound": 0.1},
        ),
        ("trapezoidal", "acceleration", {"rest_at_end": True}),
        ("hermite-simpson", "jerk", {}),
        # the peak objective's epigraph variable belongs to no point
        (
            "hermite-simpson",
            "acceleration",
            {"objective": "peak", "start": "rest", "end": "rest", "path_attitude_bound": 0.2},
        ),
        ("trapezoidal", "jerk", {"objective": "peak", "terminal_attitude_bound": 0.1}),
        pytest.param(
            "hermite-simpson", "acceleration", {"torque_limits": True}, marks=pytest.mark.slow
        ),
    ],
)
def test_assembled_derivatives_match_casadi_ad(model, capture, transcription, control, extra):
    """The NLP's gradient, constraint Jacobian and Lagrangian Hessian, assembled from the point
    kernels by the chain rule, equal CasADi's AD of the NLP's own objective and constraints."""
    settings = {"intervals": 4, "transcription": transcription, "control": control}
    options = PlannerOptions(**{**INTEGRAL, **settings, "weights": CostWeights(rest=3.0), **extra})
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    solver = nlp.structure.solver
    rng = np.random.default_rng(3)
    w = nlp.initial_guess("rest") + 0.1 * rng.normal(size=nlp.structure.variables.size)
    lam = rng.normal(size=nlp.structure.rows.size)
    x = cs.MX.sym("x", nlp.structure.variables.size)
    p = cs.MX.sym("p", nlp.structure.parameters.size)
    f, g = solver.get_function("nlp_f")(x, p), solver.get_function("nlp_g")(x, p)
    lf, lg = cs.MX.sym("lf"), cs.MX.sym("lg", nlp.structure.rows.size)
    refs = {
        "nlp_grad_f": (cs.Function("r", [x, p], [cs.gradient(f, x)]), (w, nlp.parameters), 1),
        "nlp_jac_g": (cs.Function("r", [x, p], [cs.jacobian(g, x)]), (w, nlp.parameters), 1),
        "nlp_hess_l": (
            cs.Function("r", [x, p, lf, lg], [cs.triu(cs.hessian(lf * f + cs.dot(lg, g), x)[0])]),
            (w, nlp.parameters, 0.7, lam),
            0,
        ),
    }
    for name, (ref, args, out) in refs.items():
        mine = np.array(
            cs.densify(
                solver.get_function(name)(*args)[out] if out else solver.get_function(name)(*args)
            )
        )
        expected = np.array(cs.densify(ref(*args)))
        np.testing.assert_allclose(
            mine, expected, rtol=0, atol=DERIVATIVE_TOLERANCE * max(1.0, np.abs(expected).max())
        )


# ---------------------------------------------------------------------------------- transcriptions
@pytest.mark.parametrize("name", ["hermite-simpson", "trapezoidal"])
def test_collocated_trajectory_is_the_integral_of_its_control(name):
    """The continuous balance motion: its velocity is the derivative of its position, and with
    control ``"acceleration"`` it passes through the nodes the transcription's equations give
    (Simpson's rule with the Hermite midpoint of the velocity, or the trapezoidal rule)."""
    rng = np.random.default_rng(5)
    tr, N, n, h = Transcription(name), 6, 2, 0.4
    U, Um = rng.normal(size=(n, N + 1)), rng.normal(size=(n, N))
    q, qd = np.zeros((n, N + 1)), np.zeros((n, N + 1))
    q[:, 0], qd[:, 0] = rng.normal(size=n), rng.normal(size=n)
    # nodes from the defects of q_dot = qd, qd_dot = u (both linear: solve interval by interval)
    for k in range(N):
        um = Um[:, k] if tr.has_midpoints else None
        if tr.has_midpoints:
            qd[:, k + 1] = qd[:, k] + h / 6 * (U[:, k] + 4 * um + U[:, k + 1])
            qd_m = 0.5 * (qd[:, k] + qd[:, k + 1]) + h / 8 * (U[:, k] - U[:, k + 1])
            q[:, k + 1] = q[:, k] + h / 6 * (qd[:, k] + 4 * qd_m + qd[:, k + 1])
        else:
            qd[:, k + 1] = qd[:, k] + h / 2 * (U[:, k] + U[:, k + 1])
            q[:, k + 1] = q[:, k] + h / 2 * (qd[:, k] + qd[:, k + 1])
    traj = CollocatedTrajectory(h, joint_chain_coefficients(tr, [q[:, :-1], qd[:, :-1]], U, Um, h))
    nodes = traj.sample(np.arange(N + 1) * h)
    np.testing.assert_allclose(nodes[0], q.T, rtol=0, atol=NODE_TOLERANCE)
    np.testing.assert_allclose(nodes[1], qd.T, rtol=0, atol=NODE_TOLERANCE)
    t = (
        np.arange(N)[:, None] + np.linspace(0.05, 0.95, 7)[None, :]
    ).ravel() * h  # off the nodes (kinks)
    eps = 1e-6
    fd = (traj.sample(t + eps)[0] - traj.sample(t - eps)[0]) / (2 * eps)
    np.testing.assert_allclose(traj.sample(t)[1], fd, rtol=0, atol=1e-7)
    fd2 = (traj.sample(t + eps)[1] - traj.sample(t - eps)[1]) / (2 * eps)
    np.testing.assert_allclose(traj.sample(t)[2], fd2, rtol=0, atol=1e-7)
    # Bernstein form and the monomial form used for sampling agree
    s = np.linspace(0, 1, 9)
    coefficients = joint_chain_coefficients(tr, [q[:, :-1], qd[:, :-1]], U, Um, h)[0]
    by_bernstein = bernstein_basis(len(coefficients) - 1, s) @ np.array(
        [c[0, 2] for c in coefficients]
    )
    np.testing.assert_allclose(traj.sample(h * (2 + s))[0][:, 0], by_bernstein, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["hermite-simpson", "trapezoidal"])
def test_exact_joint_chain_against_the_transcription(name):
    """With control ``"acceleration"`` the exact joint equations are the transcription's own,
    except the Hermite midpoint of the position, off by ``h^2 (u_k - 2 u_m + u_k+1) / 96``."""
    rng = np.random.default_rng(11)
    tr, N, n, h = Transcription(name), 5, 2, 0.3
    U, Um = rng.normal(size=(n, N + 1)), rng.normal(size=(n, N))
    q0, v0 = rng.normal(size=(n, N)), rng.normal(size=(n, N))
    levels = joint_chain_coefficients(tr, [q0, v0], U, Um, h)
    ends = np.vstack([bernstein_value(level, 1.0) for level in levels[:2]])
    mids = np.vstack([bernstein_value(level, 0.5) for level in levels[:2]])
    starts = np.vstack([q0, v0])
    for k in range(N):  # each interval on its own: its start, its exact end and midpoint
        X = np.column_stack([starts[:, k], ends[:, k]])
        F = np.vstack([X[n:], U[:, k : k + 2]])
        Fm = np.r_[mids[n:, k], Um[:, k]][:, None]
        for defect_name, defect in tr.defects(X, mids[:, k : k + 1], F, Fm, h):
            expected = np.zeros(2 * n)
            if defect_name == "Hermite midpoint":
                expected[:n] = h**2 / 96 * (U[:, k] - 2 * Um[:, k] + U[:, k + 1])
            np.testing.assert_allclose(defect[:, 0], expected, rtol=0, atol=ALGEBRA_TOLERANCE)
            if defect_name == "Hermite midpoint":
                assert np.abs(expected).max() > 1e3 * ALGEBRA_TOLERANCE
    # and a quadratic through bounded values at the start, middle and end can overshoot them
    assert bernstein_value([1.0, 2.0 * 1.0 - 0.5 * (1.0 - 1.0), -1.0], 0.25) == pytest.approx(1.25)


# ---------------------------------------------------------------------------------- plans
def test_no_worse_than_an_analytic_law_that_stays_inside_the_limits(model, capture, in_plane):
    t = np.linspace(0.0, in_plane.duration, 1001)
    law = _near_exact_law(capture.robot, in_plane, capture.q_B0, t)
    assert law.violations == []
    assert (
        phase_one(capture.robot, in_plane, capture.q_B0, t_eval=t).max_drift > 1000 * law.max_drift
    )
    plan = build_balance_nlp(
        model, in_plane, capture.q_B0, PlannerOptions(**INTEGRAL, intervals=30)
    ).solve()
    assert plan.violations == []
    assert plan.max_drift <= law.max_drift + DRIFT_TOLERANCE
    assert plan.final_drift <= law.final_drift + DRIFT_TOLERANCE


def test_capture_task_meets_every_limit_and_beats_phase_one(capture, capture_plan, capture_law):
    plan = capture_plan
    assert isinstance(plan, BalanceResult) and plan.method == "optimal"
    assert plan.solver.status == "Solve_Succeeded"
    # the analytic law breaks the limits on this task
    law = capture_law
    assert any(v.kind == "position" and v.worst_excess > 1.0 for v in law.violations)
    # the plan meets every limit on the re-simulation's fine grid (all joints)
    assert plan.violations == []
    assert plan.t[1] - plan.t[0] <= 0.01 + 1e-12
    lim = capture.robot.limits.subset(capture.robot.balance_indices)
    assert np.all(np.abs(plan.q_ddot_B) <= lim.acceleration + 1e-6)
    phase1 = phase_one(capture.robot, capture.mission, capture.q_B0, t_eval=plan.t)
    assert plan.max_drift * DRIFT_REDUCTION_10S <= phase1.max_drift
    assert plan.final_drift * 50 <= phase1.final_drift
    report = plan.solver.checks.as_dict()
    # the NLP's own attitude at the nodes is the re-simulated one to 0.1 % of the drift
    assert report["attitude_defect_max_rad"] < COLLOCATION_RELATIVE_ERROR * plan.max_drift
    assert report["joint_defect_max"] < NODE_TOLERANCE
    assert report["max_momentum_residual"] < 1e-6  # relative, finite-difference floor ~1e-8
    # every constraint kind holds on the re-simulated motion too
    assert report["constraint_violations"] == []
    assert len(plan.solver.last.history["inf_pr"]) == plan.solver.solves[-1].iterations + 1


def test_a_plan_is_typed_and_its_files_details_are_built_from_it(capture_plan):
    """The solve writes no dict: ``info`` holds the replay's entries alone, the solver's
    report the rest, and :meth:`BalanceResult.details` joins them in the files' order."""
    plan = capture_plan
    assert list(plan.info) == ["integration", "h0"]
    details = plan.details()
    assert list(details) == [
        "integration", "h0", "resimulation", "status", "success", "iterations", "objective",
        "max_constraint_violation", "max_violation_at", "wall_time_s", "kernels", "history",
        "intervals", "transcription", "control", "horizon_s", "options", "refinement",
        "total_iterations", "total_solve_time_s",
    ]  # fmt: skip
    last = plan.solver.solves[-1]
    assert (details["status"], details["iterations"]) == (last.status, last.iterations)
    assert details["resimulation"] == plan.solver.checks.as_dict()
    assert details["total_iterations"] == sum(s.iterations for s in plan.solver.solves)
    assert details["refinement"] == plan.solver.refinement and plan.solver.stages is None


def test_capture_task_limits_hold_on_the_whole_continuous_plan(
    model, capture, capture_plan, inside_hull
):
    """Every Bernstein coefficient of the plan's position, velocity and acceleration on every
    interval is inside the limits, so the continuous motion is (convex hull), not only the
    samples."""
    nlp = build_balance_nlp(
        model, capture.mission, capture.q_B0, PlannerOptions(**INTEGRAL, intervals=50)
    )
    inside_hull(nlp, capture_plan)
    lim = nlp.limits
    # the velocity limits are active: the hull is what holds the motion in
    assert np.abs(capture_plan.q_dot_B).max() > lim.velocity.min() - 1e-3


@pytest.mark.slow
def test_capture_task_in_20_s_is_five_times_better_than_phase_one(model, capture):
    mission = PointToPoint(CAPTURE_MISSION_START, CAPTURE_MISSION_GOAL, 20.0)
    slow = dataclasses.replace(capture, mission=mission)
    t = np.linspace(0.0, mission.duration, 2001)
    law = _near_exact_law(slow.robot, mission, slow.q_B0, t)
    assert any(v.kind == "position" and v.worst_excess > 1.0 for v in law.violations)
    plan = build_balance_nlp(
        model, mission, slow.q_B0, PlannerOptions(**INTEGRAL, intervals=60)
    ).solve()
    assert plan.violations == []
    phase1 = phase_one(slow.robot, mission, slow.q_B0, t_eval=plan.t)
    assert plan.max_drift * DRIFT_REDUCTION_20S <= phase1.max_drift


@pytest.mark.slow
def test_hard_terminal_attitude_bound_met_in_resimulation(model, capture):
    free = PlannerOptions(**INTEGRAL, intervals=100, weights=CostWeights(terminal=0.0))
    unbounded = build_balance_nlp(model, capture.mission, capture.q_B0, free).solve()
    bound = 0.5 * unbounded.final_drift
    bounded = build_balance_nlp(
        model,
        capture.mission,
        capture.q_B0,
        dataclasses.replace(free, terminal_attitude_bound=bound),
    ).solve()
    assert bounded.final_drift <= bound + TERMINAL_TOLERANCE
    assert bounded.violations == []
    assert bounded.solver.checks.constraint_violations == ()


def test_rest_at_end_and_prescribed_final_configuration(model, capture):
    q_f = capture.q_B0 + np.array([0.2, -0.1, 0.1])
    options = PlannerOptions(
        **INTEGRAL, intervals=30, rest_at_end=True, final_configuration=tuple(q_f)
    )
    plan = build_balance_nlp(model, capture.mission, capture.q_B0, options).solve("rest")
    np.testing.assert_allclose(plan.q_B[-1], q_f, rtol=0, atol=NODE_TOLERANCE)
    np.testing.assert_allclose(plan.q_dot_B[-1], 0.0, rtol=0, atol=NODE_TOLERANCE)
    np.testing.assert_allclose(plan.q_B[0], capture.q_B0, rtol=0, atol=0)
    np.testing.assert_allclose(plan.q_dot_B[0], 0.0, rtol=0, atol=0)
    assert plan.solver.checks.constraint_violations == ()


@pytest.mark.parametrize(
    "transcription, control",
    [("trapezoidal", "acceleration"), ("hermite-simpson", "jerk"), ("trapezoidal", "jerk")],
)
def test_other_transcriptions_plan_within_limits(
    model, capture, capture_plan, transcription, control
):
    options = PlannerOptions(**INTEGRAL, intervals=50, transcription=transcription, control=control)
    plan = build_balance_nlp(model, capture.mission, capture.q_B0, options).solve("rest")
    assert plan.violations == []
    assert (
        plan.solver.last.problem["transcription"] == transcription
        and plan.solver.last.problem["control"] == control
    )
    assert plan.solver.checks.joint_defect_max < NODE_TOLERANCE  # through every node
    phase1 = phase_one(capture.robot, capture.mission, capture.q_B0, t_eval=plan.t)
    assert plan.max_drift * DRIFT_REDUCTION_10S <= phase1.max_drift
    if (
        control == "acceleration"
    ):  # the same objective as the default: the same optimum, to within the grids
        assert abs(plan.max_drift - capture_plan.max_drift) < 2e-3


@pytest.mark.slow
def test_torque_limits_hold_at_the_collocation_points(capture):
    limits = {
        j: {"acceleration": 2.0, "effort": 0.5}
        for j in ("balance_joint1", "balance_joint2", "balance_joint3")
    }
    torque_model = PlannerModel(paper_robot(limits=limits), compile=False)
    nlp = build_balance_nlp(
        torque_model,
        capture.mission,
        capture.q_B0,
        PlannerOptions(**INTEGRAL, intervals=20, torque_limits=True),
    )
    plan = nlp.solve("rest")
    sol = plan.solver.solution
    tau = torque_model.balance_torque_fun().map(nlp.point_times.size)
    Z, V = np.hstack([sol.X, sol.Xm]), np.hstack([sol.U, sol.Um])
    torques = np.array(tau(Z, V, nlp.mission_samples))
    assert np.abs(torques).max() <= 0.5 + 1e-6
    # the re-simulation's torque check sees at least the torques at the points: with a lower
    # effort limit it reports what the points exceed it by, or more (between the points)
    lowered = dataclasses.replace(nlp.limits, effort=np.full(3, 0.25))
    problem = BalanceProblem(torque_model, capture.mission, capture.q_B0, nlp.options)
    problem.limits = lowered
    check = TorqueLimit("acceleration", False).check(problem, plan)
    assert check.unit == "N m" and check.amount >= np.abs(torques).max() - 0.25 - 1e-9
    # and without the constraint the same task needs more torque: the bound is active
    free = build_balance_nlp(
        torque_model, capture.mission, capture.q_B0, PlannerOptions(**INTEGRAL, intervals=20)
    ).solve("rest")
    sol = free.solver.solution
    assert (
        np.abs(
            np.array(
                tau(np.hstack([sol.X, sol.Xm]), np.hstack([sol.U, sol.Um]), nlp.mission_samples)
            )
        ).max()
        > 0.5 + 1e-3
    )


def test_same_task_same_plan(model, capture, capture_plan):
    again = build_balance_nlp(
        model, capture.mission, capture.q_B0, PlannerOptions(**INTEGRAL, intervals=50)
    ).solve()
    for field in ("q_B", "q_dot_B", "q_ddot_B", "quaternion", "omega"):
        np.testing.assert_array_equal(getattr(again, field), getattr(capture_plan, field))
    for name in ("X", "Xm", "U", "Um"):
        np.testing.assert_array_equal(
            getattr(again.solver.solution, name), getattr(capture_plan.solver.solution, name)
        )


def test_nlp_is_inspectable_and_reused_for_another_mission(model, capture, in_plane):
    options = PlannerOptions(**INTEGRAL, intervals=50)
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    other = build_balance_nlp(model, in_plane, capture.q_B0, options)
    assert other.structure is nlp.structure and other.build_time == 0.0
    assert not np.array_equal(other.parameters, nlp.parameters)
    N, n_x, n_u = 50, model.n_x("acceleration"), model.n_u
    assert nlp.structure.variables.size == (2 * N + 1) * (n_x + n_u)
    assert [b.name for b in nlp.structure.rows.blocks[:2]] == [
        "collocation (Hermite midpoint)",
        "collocation (Simpson)",
    ]
    w, g = np.clip(np.zeros(nlp.lbx.size), nlp.lbx, nlp.ubx), np.zeros(nlp.lbg.size)
    g[0] = 0.5  # the collocation rows are equalities
    assert nlp.largest_violation(w, g)[:4] == (
        "collocation (Hermite midpoint): attitude phi_x",
        0.0,
        0.5,
        "rad",
    )
    g[n_x * N + n_x + 5] = 1.0
    assert nlp.largest_violation(w, g)[4] == (
        "collocation (Simpson): balance_joint3 position on the interval 0.200-0.400 s"
    )
    # the initial state is fixed by the bounds, the limits are bounds of the other nodes
    X_lo = nlp.unpack(nlp.lbx).X
    np.testing.assert_array_equal(X_lo[:, 0], np.r_[0, 0, 0, capture.q_B0, 0, 0, 0])
    np.testing.assert_array_equal(X_lo[3:6, 1], capture.robot.limits.lower[3:])


def test_structure_key_and_parameter_layout(model, capture):
    """The structure key is named and hashable and tells structures apart; the parameter vector
    is packed and unpacked by one layout, field by field."""
    options = PlannerOptions(
        **INTEGRAL,
        intervals=10,
        path_attitude_bound=0.2,
        terminal_attitude_bound=0.05,
        weights=CostWeights(rest=2.0),
        rest_configuration=tuple(capture.q_B0 + 0.1),
    )
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    key = nlp.structure.key
    assert (key.intervals, key.transcription, key.control) == (
        10,
        "hermite-simpson",
        "acceleration",
    )
    assert key.joint_limits == ("acceleration", "position", "velocity")
    assert key.path_attitude_bound and key.terminal_attitude_bound and not key.torque_limits
    assert model.nlp_cache[key] is nlp.structure
    assert StructureKey.of(nlp.limits, options) == key
    assert StructureKey.of(nlp.limits, dataclasses.replace(options, control="jerk")) != key
    p = cs.SX.sym("p", nlp.structure.parameters.size)
    fields = vars(nlp.structure.parameters.unpack(p, SimpleNamespace))
    unpack = cs.Function("unpack", [p], list(fields.values()))
    values = dict(zip(fields, (np.array(v) for v in unpack(nlp.parameters))))
    assert values["h"] == nlp.h and values["terminal_weight"] == options.weights.terminal
    np.testing.assert_array_equal(values["running_weights"].ravel(), [100.0, 300.0, 1e-3, 2.0])
    assert values["path_scale"] == 1 / 0.2**2 and values["terminal_scale"] == 1 / 0.05**2
    np.testing.assert_array_equal(values["q_rest"].ravel(), capture.q_B0 + 0.1)
    np.testing.assert_array_equal(values["mission"], nlp.mission_samples)
    q_M, q_dot_M, q_ddot_M = capture.mission.sample(nlp.point_times)
    h0_rows = np.zeros((nlp.point_times.size, 6))  # the momentum h0, zero here
    np.testing.assert_array_equal(values["mission"], np.hstack([q_M, q_dot_M, q_ddot_M, h0_rows]).T)


def test_constraint_checks_agree_with_the_result(model, capture, capture_law):
    """Each constraint kind's check on a motion (the analytic law's, which breaks the position
    limits) finds the worst violation that ``result.violations`` and the drift report."""
    law = capture_law
    bound = 0.5 * law.max_drift
    options = PlannerOptions(
        **INTEGRAL,
        intervals=10,
        path_attitude_bound=bound,
        terminal_attitude_bound=bound,
        rest_at_end=True,
        final_configuration=tuple(capture.q_B0),
    )
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    found = {term.name: term.check(nlp, law) for term in nlp.structure.terms}
    for kind in ("position", "velocity", "acceleration"):
        expected = [v for v in law.violations if v.kind == kind and v.joint in nlp.balance_joints]
        check = found[f"{kind} limit"]
        if not expected:
            assert check is None
            continue
        worst = max(expected, key=lambda v: v.worst_excess)
        assert check.amount == worst.worst_excess
        assert check.constraint == f"{kind} limit of {worst.joint}"
        assert worst.t_start <= check.time <= worst.t_end
    assert found["position limit"].amount > 1.0
    path = found["path attitude bound"]
    assert path.amount == pytest.approx(law.max_drift - bound, rel=0, abs=1e-15)
    assert path.time == law.t[np.argmax(law.angle)]
    terminal = found["terminal attitude bound"]
    assert terminal.amount == pytest.approx(law.final_drift - bound, rel=0, abs=1e-15)
    assert terminal.time == law.t[-1]
    end = found["end conditions"]
    q_end_error = np.abs(law.q_B[-1] - capture.q_B0)
    assert end.amount == max(q_end_error.max(), np.abs(law.q_dot_B[-1]).max())
    assert found["initial state"] is None and found["collocation"] is None
    assert str(path) == f"path attitude bound at t = {path.time:.3f} s, by {path.amount:.4g} rad"


# ---------------------------------------------------------------------------------- failures
def test_infeasible_problem_names_status_and_constraint(capture):
    limits = {
        j: {"acceleration": 2.0, "velocity": 0.05}
        for j in ("balance_joint1", "balance_joint2", "balance_joint3")
    }
    slow = PlannerModel(paper_robot(limits=limits), compile=False)
    options = PlannerOptions(
        **INTEGRAL,
        intervals=20,
        rest_at_end=True,
        final_configuration=tuple(capture.q_B0 + [0, 0, 1.0]),
    )
    with pytest.raises(
        PlannerSolverError,
        match=r"^Ipopt stopped with status 'Infeasible_Problem_Detected' after "
        r"\d+ iterations; largest constraint violation: collocation \(Simpson\): balance_joint3 "
        r"position on the interval \d+\.\d{3}-\d+\.\d{3} s, by \d\.\d+(e-\d+)? rad$",
    ) as info:
        build_balance_nlp(slow, capture.mission, capture.q_B0, options).solve("rest")
    err = info.value
    assert (
        err.status == "Infeasible_Problem_Detected" and "balance_joint3 position" in err.constraint
    )
    assert isinstance(err.result, BalanceResult) and err.result.solver.success is False
    assert err.violation == pytest.approx(err.result.solver.last.violation[2], rel=0, abs=0)


def test_iteration_limit_raises_with_the_best_iterate(model, capture):
    options = PlannerOptions(**INTEGRAL, intervals=20, max_iterations=2)
    with pytest.raises(
        PlannerSolverError,
        match=r"^Ipopt stopped with status 'Maximum_Iterations_Exceeded' after 2 "
        r"iterations; largest constraint violation: .+ by .+",
    ) as info:
        build_balance_nlp(model, capture.mission, capture.q_B0, options).solve("rest")
    assert info.value.result.solver.solves[-1].iterations == 2


def test_limits_no_plan_can_meet_raise_before_solving(model, capture):
    bad = capture.q_B0.copy()
    bad[1] = 2.0
    with pytest.raises(
        InfeasibleLimitsError,
        match=re.escape(
            "balance joint 'balance_joint2': initial configuration q_B0 is 2 rad, outside its position limits "
            "[-1.5708, 1.5708] rad"
        ),
    ):
        build_balance_nlp(model, capture.mission, bad, PlannerOptions(**INTEGRAL, intervals=10))
    with pytest.raises(
        InfeasibleLimitsError,
        match=re.escape(
            "balance joint 'balance_joint1': final_configuration is -3 rad, outside its position limits "
            "[-2.9671, 2.9671] rad"
        ),
    ):
        build_balance_nlp(
            model,
            capture.mission,
            capture.q_B0,
            PlannerOptions(**INTEGRAL, intervals=10, final_configuration=(-3.0, 0.0, 0.0)),
        )


@pytest.mark.parametrize(
    "cls, kwargs, message",
    [
        (PlannerOptions, {"intervals": 1}, "planner option 'intervals': must be at least 2, got 1"),
        (
            PlannerOptions,
            {"transcription": "euler"},
            (
                "planner option 'transcription': expected one of 'hermite-simpson', "
                "'trapezoidal', got 'euler' (a string)"
            ),
        ),
        (
            PlannerOptions,
            {"control": "torque"},
            (
                "planner option 'control': expected one of 'acceleration', 'jerk', got 'torque' "
                "(a string)"
            ),
        ),
        (CostWeights, {"omega": -1.0}, "planner weight 'omega': must be at least 0, got -1"),
        (
            PlannerOptions,
            {"weights": {"omega": -1.0}},
            "planner option 'weights.omega': must be at least 0, got -1",
        ),
        (
            PlannerOptions,
            {"terminal_attitude_bound": 0.0},
            "planner option 'terminal_attitude_bound': must be greater than 0 rad, got 0",
        ),
        (
            PlannerOptions,
            {"rest_configuration": np.array([0.0, np.nan, 0.0])},
            "planner option 'rest_configuration[1]': expected a number, got NaN",
        ),
    ],
)
def test_bad_options(cls, kwargs, message):
    with pytest.raises(InputError) as info:
        cls(**kwargs)
    assert str(info.value) == message


def test_bad_sizes(model, capture):
    with pytest.raises(InputError, match=re.escape("q_B0 has 2 values, the balance joints are 3")):
        build_balance_nlp(
            model, capture.mission, [0.0, 0.1], PlannerOptions(**INTEGRAL, intervals=10)
        )
    with pytest.raises(
        InputError, match=re.escape("planner option 'horizon' (5.0 s) is shorter than the mission")
    ):
        build_balance_nlp(
            model,
            capture.mission,
            capture.q_B0,
            PlannerOptions(**INTEGRAL, intervals=10, horizon=5.0),
        )


# ---------------------------------------------------------------------------------- compilation
def test_compiled_kernels_match_and_are_cached(tmp_path):
    x = cs.SX.sym("x", 3)
    fun = cs.Function("planner_test_kernel", [x], [cs.sin(x) * cs.dot(x, x)])
    if codegen.find_compiler() is None:
        pytest.skip("no C compiler")
    out, out2 = compile_functions([fun], tmp_path), compile_functions([fun], tmp_path)
    (compiled,), (again,) = out.functions, out2.functions
    assert out.compile_time > 0.0 and out2.compile_time == 0.0 and out.library == out2.library
    v = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(np.array(compiled(v)), np.array(fun(v)), rtol=0, atol=1e-15)
    np.testing.assert_allclose(
        np.array(again.map(4)(np.tile(v[:, None], 4)))[:, 2],
        np.array(fun(v)).ravel(),
        rtol=0,
        atol=1e-15,
    )


def test_without_a_compiler_the_kernels_fall_back(monkeypatch, capture, caplog):
    monkeypatch.setattr(codegen, "find_compiler", lambda: None)
    fallback = PlannerModel(capture.robot, compile=True)
    with caplog.at_level(logging.WARNING, logger="balance_opt.optimal.model"):
        kernels = point_kernels(fallback)
    assert not kernels.compiled
    assert "balance kernels not compiled (no C compiler found" in caplog.text
    assert not PlannerModel(capture.robot, compile="auto").compile


@pytest.mark.parametrize(("variable", "threads"), [(None, 1), ("2", 2)])
def test_ipopt_runs_with_one_blas_thread_unless_told(variable, threads):
    """CasADi's OpenBLAS starts a thread per core; once a planner NLP is built it has one
    (the second core is the worker processes'), unless OPENBLAS_NUM_THREADS sets it. In a fresh
    process: the plugin loads its OpenBLAS only once."""
    import os
    from pathlib import Path

    if not Path("/proc/self/maps").exists():
        pytest.skip("reads the libraries the process mapped from /proc")
    import subprocess
    import sys

    script = (
        "from balance_opt.optimal import nlp\n"
        "from balance_opt.app.scenarios import capture_task\n"
        "from balance_opt.optimal.model import PlannerModel\n"
        "from balance_opt.optimal.options import PlannerOptions\n"
        "from balance_opt.optimal.solve import build_balance_nlp\n"
        "cap = capture_task()\n"
        "model = PlannerModel(cap.robot, compile=False)\n"
        "build_balance_nlp(model, cap.mission, cap.q_B0, PlannerOptions(intervals=4))\n"
        # the instance Ipopt uses: the file the process mapped (a copy under another name
        # would be another instance)
        "import ctypes\n"
        "maps = {l.split()[-1] for l in open('/proc/self/maps') if 'casadi-tp-openblas' in l}\n"
        "assert len(maps) == 1, maps\n"
        "print(ctypes.CDLL(maps.pop()).openblas_get_num_threads())\n"
    )
    if (os.cpu_count() or 1) < 2:
        pytest.skip("OpenBLAS starts one thread on one CPU anyway")
    unset = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
    env = {k: v for k, v in os.environ.items() if k not in unset}
    if variable is not None:
        env["OPENBLAS_NUM_THREADS"] = variable
    out = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.split()[-1] == str(threads)


def test_a_fine_peak_plan_goes_through_coarser_grids_with_its_own_ipopt_options():
    """Up to PEAK_GRID_INTERVALS the epigraph stage solves on the plan's grid alone with
    PEAK_IPOPT; above, first on the grids of a plan INNER_COARSENING times coarser (never
    below PEAK_GRID_INTERVALS), and the plan's grid gets PEAK_FINE_IPOPT; the other stages
    keep theirs; ``optimal.ipopt`` still has the last word."""
    from balance_opt.optimal.nlp import ipopt_options_for
    from balance_opt.optimal.options import (
        PEAK_FINE_IPOPT,
        PEAK_GRID_INTERVALS,
        PEAK_IPOPT,
        PEAK_STAGES,
    )

    peak = PEAK_STAGES[-1]
    assert peak.name == "peak" and PEAK_GRID_INTERVALS == 100
    assert all(s.fine_above is None for s in PEAK_STAGES[:-1])
    assert peak.grids(100, "hermite-simpson") == [100]
    assert peak.grids(40, "trapezoidal") == [40]
    assert peak.grids(101, "hermite-simpson") == [100, 101]
    assert peak.grids(400, "hermite-simpson") == [100, 400]
    assert peak.grids(1000, "hermite-simpson") == [100, 250, 1000]
    assert peak.grids(400, "trapezoidal") == [100, 200, 400]
    for n in (50, PEAK_GRID_INTERVALS):
        coarse = ipopt_options_for("peak", PlannerOptions(intervals=n))
        assert coarse["mu_init"] == PEAK_IPOPT["mu_init"] and "mumps_pivot_order" not in coarse
    fine = ipopt_options_for("peak", PlannerOptions(intervals=400))
    assert {k: fine[k] for k in PEAK_FINE_IPOPT} == PEAK_FINE_IPOPT
    assert "mu_init" not in ipopt_options_for("smooth", PlannerOptions(intervals=400))
    mine = PlannerOptions(intervals=400, ipopt={"mu_init": 0.05})
    assert ipopt_options_for("peak", mine)["mu_init"] == 0.05
