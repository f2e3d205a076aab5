"""Closed loop: a re-plan from the middle of a motion, checked against an independent replay;
the closed-loop flight with no model error reproduces the plan; a failed re-plan keeps the plan
in force; the ``closed_loop:`` task keys."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from balance_opt.control.flight import fly_closed_loop, period_starts
from balance_opt.control.replan import (
    LATE_DRIFT,
    SOLVE_SHARE,
    STOPPED_VIOLATION,
    TERMINAL_FACTOR,
    Replanner,
    closed_loop_planner,
    margined,
)
from balance_opt.dynamics.options import ClosedLoopOptions
from balance_opt.dynamics.simulation import simulate_plan
from balance_opt.errors import InputError
from balance_opt.motion.replay import replay
from balance_opt.motion.result import find_limit_violations
from balance_opt.motion.so3 import (
    quaternion_from_rotvec,
    relative_rotation,
    rotation_angle,
)
from balance_opt.motion.trajectories import MissionWindow
from balance_opt.optimal.collision import collision_setup, restarted
from balance_opt.optimal.late_drift import late_weights
from balance_opt.optimal.problem import StartState
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.tasks.task import load_task

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: A coarse grid keeps the plan and its re-plans' NLPs quick to build.
INTERVALS = 50
PERIOD = 2.0  # 10 intervals of 0.2 s: re-plans from nodes 10, 20, 30, 40


@pytest.fixture(scope="module")
def planned():
    """The capture task's optimal plan on a coarse grid, its problem and its re-planner."""
    task = load_task(EXAMPLES / "capture_task.yaml")
    options = dataclasses.replace(task.spec.optimal.planner, intervals=INTERVALS)
    nlp = build_balance_nlp(task.robot, task.mission, task.q_B0, options, h0=task.h0)
    plan = nlp.solve("analytic")
    return task, nlp, plan, Replanner(nlp)


@pytest.mark.slow
def test_replan_from_a_mid_motion_state_matches_an_independent_replay(planned):
    task, nlp, plan, replanner = planned
    first = replanner.first(plan)
    node = 20
    # the base turned 20 mrad away from where the plan has it: a re-plan has to correct it
    _, _, _, phi = first.state(node)
    attitude = phi + np.array([0.02, -0.01, 0.005])
    out = replanner.replan(node, first, attitude, peak=plan.max_drift)
    assert out.success, out.status
    segment = out.segment
    # the balance arm starts where the plan in force has it (position, rate, acceleration)
    q, qd, qdd = (np.asarray(v)[0] for v in segment.trajectory.sample(np.zeros(1)))
    for got, want in zip((q, qd, qdd), first.state(node)[:3]):
        np.testing.assert_allclose(got, want, atol=1e-9)
    # replayed from the measured attitude by momentum conservation (numeric Pinocchio, RK4),
    # the re-planned joint motion turns the base as the planner's own states say
    t0 = node * nlp.h
    nodes = np.arange(nlp.N - node + 1) * nlp.h
    replayed = replay(
        task.robot,
        MissionWindow(task.mission, t0, task.duration),
        segment.trajectory,
        t_eval=nodes,
        attitude0=quaternion_from_rotvec(attitude),
    )
    planned_q = quaternion_from_rotvec(segment.solution.X[:3].T)
    error = rotation_angle(relative_rotation(planned_q, replayed.quaternion))
    assert error[0] < 1e-12
    # within the collocation's error on 0.2 s intervals, far below the 22 mrad the re-plan
    # corrects (a re-plan that ignored the measured attitude would be off by all of it)
    assert error.max() < 1e-4
    # and it corrects the offset: the final drift is well below the 22 mrad it started off by
    assert rotation_angle(replayed.quaternion[-1]) < 0.5 * np.linalg.norm(attitude - phi)


@pytest.mark.slow
def test_a_replan_from_a_node_whose_window_rounds_above_the_grid(planned):
    """From node 43 of 50 on 10 s, the mission window (10 - 8.6 s) rounds above 7 intervals of
    0.2 s: the re-plan's horizon covers it. With the plan's own state there, the re-plan
    keeps the plan's tail (Bellman)."""
    task, nlp, plan, replanner = planned
    node = 43
    assert task.duration - node * nlp.h > (nlp.N - node) * nlp.h
    first = replanner.first(plan)
    out = replanner.replan(node, first, first.state(node)[3], peak=plan.max_drift)
    assert out.success, out.status
    np.testing.assert_allclose(out.segment.solution.X, first.solution.X[:, node:], atol=1e-4)


@pytest.mark.slow
def test_the_closed_loops_price_of_the_final_drift_brings_a_replans_final_drift_down(planned):
    """From a state whose base has drifted further than planned, mid-motion, a re-plan at the
    open-loop plan's price of the final drift gives some of it up for the peak; at the closed
    loop's price (:func:`closed_loop_planner`) it plans a final drift far smaller. The first
    plan and the re-plans have that one objective: without model error the closed loop
    reproduces its first plan."""
    task, nlp, plan, replanner = planned
    assert closed_loop_planner(nlp.options, 1.0, None) is nlp.options
    priced = closed_loop_planner(nlp.options, late=None)
    assert priced.weights.peak_terminal == TERMINAL_FACTOR * nlp.options.weights.peak_terminal
    closed = build_balance_nlp(task.robot, task.mission, task.q_B0, priced, h0=task.h0)
    closed_plan = closed.solve(plan.solver.solution)
    node = 30
    first = replanner.first(plan)
    phi = first.state(node)[3]
    attitude, peak = 1.3 * phi, 1.3 * plan.max_drift  # 30 % further than planned
    finals = []
    for r in (replanner, Replanner(closed)):
        out = r.replan(node, first, attitude, peak=peak)
        assert out.success, out.status
        finals.append(float(np.linalg.norm(out.segment.solution.X[:3, -1])))
    assert finals[1] < 0.5 * finals[0], finals
    # without model error the closed loop at that price reproduces its own first plan
    open_loop, run = _flown_both_ways(task, Replanner(closed), closed_plan)
    assert run.failed == 0
    assert abs(run.max_drift - float(open_loop.angle.max())) < 1e-4
    assert abs(run.final_drift - float(open_loop.angle[-1])) < 1e-4


@pytest.mark.slow
def test_the_late_drift_brings_the_base_back_earlier_and_a_replan_keeps_its_tail(planned):
    """Priced over the last seconds (:mod:`~balance_opt.optimal.late_drift`), the drift is
    brought back earlier than at the closed loop's price of the final drift alone; its weight is
    a function of the time left to the end, so a re-plan from inside the window with the plan's
    own state keeps the plan's tail (a weight of the time since the start of its own problem
    would price the re-plan's tail later than the plan's: the tail would move)."""
    task, nlp, plan, _ = planned
    late = closed_loop_planner(nlp.options, late=(1e5, 3.0))
    assert late.late_drift == (1e5, 3.0)
    assert closed_loop_planner(nlp.options).late_drift == LATE_DRIFT
    plans = []
    for options in (dataclasses.replace(late, late_drift=None), late):
        closed = build_balance_nlp(task.robot, task.mission, task.q_B0, options, h0=task.h0)
        plans.append((closed, closed.solve(plan.solver.solution)))
    drift = [np.linalg.norm(p.solver.solution.X[:3], axis=0) for _, p in plans]
    one_second_before = nlp.N - round(1.0 / nlp.h)
    assert drift[1][one_second_before] < 0.5 * drift[0][one_second_before], drift
    closed, late_plan = plans[1]
    replanner = Replanner(closed)
    first = replanner.first(late_plan)
    node = 40  # 2 s before the end: inside the window
    out = replanner.replan(node, first, first.state(node)[3], peak=late_plan.max_drift)
    assert out.success, out.status
    np.testing.assert_allclose(out.segment.solution.X, first.solution.X[:, node:], atol=1e-4)
    # and without model error the closed loop with it reproduces its first plan
    open_loop, run = _flown_both_ways(task, replanner, late_plan, ClosedLoopOptions().end_period)
    assert run.failed == 0
    assert abs(run.max_drift - float(open_loop.angle.max())) < 1e-4
    assert abs(run.final_drift - float(open_loop.angle[-1])) < 1e-4


def test_the_late_drifts_weight_rises_over_its_window_only():
    to_go = np.array([5.0, 3.0, 2.0, 1.0, 0.0])
    np.testing.assert_allclose(late_weights(90.0, 3.0, to_go), [0.0, 0.0, 10.0, 40.0, 90.0])


def _flown_both_ways(task, replanner, plan, end_period=None):
    """The plan simulated open loop and flown closed loop, on the nominal robot (every re-plan
    applied, whatever its time), every ``PERIOD`` (every ``end_period`` over the last 3 s)."""
    open_loop = simulate_plan(task.robot, plan, task.spec.simulation)
    options = ClosedLoopOptions(period=PERIOD, end_period=end_period)
    run = fly_closed_loop(
        task.robot, replanner, plan, task.spec.simulation, options, deadline=math.inf
    )
    return open_loop, run


@pytest.mark.slow
def test_closed_loop_without_model_error_reproduces_the_plan(planned):
    task, nlp, plan, replanner = planned
    # the default end period, 0.2 s (an interval) over the last 3 s: from node 40 on
    open_loop, run = _flown_both_ways(task, replanner, plan, ClosedLoopOptions().end_period)
    assert [r.node for r in run.replans] == [10, 20, 30, *range(40, 49)]
    assert run.failed == 0
    assert abs(run.max_drift - float(open_loop.angle.max())) < 1e-4
    assert abs(run.final_drift - float(open_loop.angle[-1])) < 1e-4
    np.testing.assert_allclose(run.simulation.t, open_loop.t, atol=1e-12)


@pytest.mark.slow
def test_a_failed_replan_keeps_the_plan_in_force(planned):
    task, nlp, plan, _ = planned
    failing = Replanner(nlp, {"max_iter": 0})  # Ipopt stops before its first step
    open_loop, run = _flown_both_ways(task, failing, plan)
    assert len(run.replans) == 4 and run.failed == 4
    assert {r.status for r in run.replans} == {"Maximum_Iterations_Exceeded"}
    # the first plan flown to the end: the open-loop motion
    np.testing.assert_allclose(run.simulation.q, open_loop.q, atol=1e-9)
    np.testing.assert_allclose(run.simulation.quaternion, open_loop.quaternion, atol=1e-9)


@pytest.mark.slow
def test_a_replan_stopped_by_its_time_budget_is_late_and_keeps_the_plan(planned):
    task, nlp, plan, _ = planned
    # a budget no solve fits in: Ipopt stops at its wall-time limit every time; its iterate is
    # never applied (stopped_violation None)
    hurried = Replanner(nlp, budget=1e-9, stopped_violation=None)
    assert hurried.ipopt["max_wall_time"] == pytest.approx(SOLVE_SHARE * 1e-9)
    open_loop, run = _flown_both_ways(task, hurried, plan)
    assert {r.status for r in run.replans} == {"Maximum_WallTime_Exceeded"}
    assert all(r.out_of_time and not r.success for r in run.replans)
    assert run.late == 4 and run.failed == 0  # late, not failed
    np.testing.assert_allclose(run.simulation.quaternion, open_loop.quaternion, atol=1e-9)


@pytest.mark.slow
def test_a_stopped_replans_feasible_iterate_is_applied_and_flies_as_planned(planned):
    """A re-plan stopped by its time budget whose iterate keeps every constraint (here the
    warm start Ipopt had not yet left: the plan in force turned to the measured attitude) is
    applied, not late; replayed from the measured attitude it turns the base as it says. One
    whose iterate does not keep them (a tolerance no iterate meets) is late."""
    task, nlp, plan, _ = planned
    first = Replanner(nlp).first(plan)
    node = 20
    attitude = first.state(node)[3] + np.array([0.02, -0.01, 0.005])
    out = Replanner(nlp, budget=1e-9).replan(node, first, attitude, peak=plan.max_drift)
    assert out.stopped and out.status == "Maximum_WallTime_Exceeded"
    assert out.violation <= STOPPED_VIOLATION and out.success and not out.out_of_time
    t0 = node * nlp.h
    replayed = replay(
        task.robot,
        MissionWindow(task.mission, t0, task.duration),
        out.segment.trajectory,
        t_eval=np.arange(nlp.N - node + 1) * nlp.h,
        attitude0=quaternion_from_rotvec(attitude),
    )
    planned_q = quaternion_from_rotvec(out.segment.solution.X[:3].T)
    assert rotation_angle(relative_rotation(planned_q, replayed.quaternion)).max() < 1e-4
    strict = Replanner(nlp, budget=1e-9, stopped_violation=out.violation / 2)
    late = strict.replan(node, first, attitude, peak=plan.max_drift)
    assert late.out_of_time and not late.success
    assert late.violation == pytest.approx(out.violation)


@pytest.mark.slow
def test_a_replan_keeps_the_collision_rows_built_before_the_motion(planned):
    """From a start the plan in force has moved, a re-plan keeps the NLP structure built
    before the motion, its collision rows starting where a set-up from that start has them."""
    task, nlp, plan, replanner = planned
    first = replanner.first(plan)
    node = 30
    replanner.prepare(first, [node])
    prepared = replanner.prepared[node]
    q, qd, qdd, phi = first.state(node)
    moved = q + np.array([0.05, -0.1, 0.08])  # where another plan in force has the arm
    structures = len(nlp.model.nlp_cache)
    kept = replanner.problem(node, StartState(qd, qdd, phi, 0.0, prepared), moved)
    assert len(nlp.model.nlp_cache) == structures and kept.structure is prepared.structure
    fresh = replanner.problem(node, StartState(qd, qdd, phi), moved)  # chosen from this start
    assert fresh.collision.rows.key == prepared.collision.rows.key
    np.testing.assert_allclose(kept.lbg, fresh.lbg)
    # the balance link 3 folded back toward the base: its row starts 0.13 m nearer than at
    # the plan's start, and the rows kept start there as a set-up from there does
    q0 = np.concatenate([task.mission.sample(np.zeros(1))[0][0], [-1.302, 1.524, -2.3]])
    here = collision_setup(nlp.model, nlp.options, q0, nlp.robot)
    assert here.rows.key == nlp.collision.rows.key
    again = restarted(nlp.collision, nlp.model, nlp.options, q0)
    assert np.abs(here.initial_rows - nlp.collision.initial_rows).max() > 0.1
    np.testing.assert_allclose(again.initial_rows, here.initial_rows, atol=1e-12)
    assert again.threshold == pytest.approx(here.threshold, abs=1e-12)


TASK = """name: t
robot: {shipped: paper_robot.urdf}
arms:
  mission: [mission_joint1, mission_joint2, mission_joint3]
  balance: [balance_joint1, balance_joint2, balance_joint3]
initial: {balance: [0.0, 0.5, -1.0]}
mission: {type: ptp, start: [0.0, 0.3, -0.6], goal: [0.2, 0.4, -0.7], duration: 2.0}
closed_loop:
"""


@pytest.mark.parametrize(
    "entry, message",
    [
        ("period: 0", "closed_loop.period: must be greater than 0 s, got 0"),
        ("samples: 0", "closed_loop.samples: must be at least 1, got 0"),
        ("perturbation: -0.1", "closed_loop.perturbation: must be at least 0, got -0.1"),
        ("seed: -1", "closed_loop.seed: must be at least 0, got -1"),
        (
            "momentum: measured",
            "closed_loop.momentum: unknown key 'momentum'; expected one of period, samples, "
            "perturbation, seed, margin, position_margin, jerk, end_period, end_window",
        ),
        ("margin: -0.1", "closed_loop.margin: must be at least 0, got -0.1"),
        ("position_margin: -1", "closed_loop.position_margin: must be at least 0 rad, got -1"),
        ("jerk: 0", "closed_loop.jerk: must be greater than 0 rad/s^3, got 0"),
        ("end_period: 0", "closed_loop.end_period: must be greater than 0 s, got 0"),
        ("end_window: -1", "closed_loop.end_window: must be at least 0 s, got -1"),
    ],
)
def test_bad_closed_loop_values_name_file_line_and_key(tmp_path, entry, message):
    path = tmp_path / "task.yaml"
    path.write_text(TASK + f"  {entry}\n")
    with pytest.raises(InputError) as info:
        load_task(path)
    assert str(info.value) == f"{path}:9: {message}"


def test_closed_loop_defaults_follow_the_robustness_section(tmp_path):
    from balance_opt.app.closed_loop import resolved_options

    path = tmp_path / "task.yaml"
    path.write_text(
        TASK.replace("closed_loop:\n", "robustness: {perturbation: 0.2, seed: 7}\n")
        + "closed_loop: {samples: 3}\n"
    )
    options = resolved_options(load_task(path))
    assert (options.period, options.samples, options.perturbation, options.seed) == (
        0.5,
        3,
        0.2,
        7,
    )


def test_the_worst_runs_urdf_holds_its_true_robot():
    """``closed_loop_worst.urdf``: the URDF with the perturbed inertias, which Pinocchio reads
    back into the true robot's model (every joint's body, fixed links merged)."""
    import pinocchio as pin

    from balance_opt.app.closed_loop import perturbed_urdf, true_robots

    task = load_task(EXAMPLES / "capture_task.yaml")
    truth = true_robots(task.robot, ClosedLoopOptions(samples=2, perturbation=0.1, seed=0))[1]
    text = perturbed_urdf(task.robot, truth)
    model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    assert model.njoints == truth.model.njoints
    for i in range(1, model.njoints):
        assert model.names[i] == truth.model.names[i]
        read, true = model.inertias[i], truth.model.inertias[i]
        assert abs(read.mass - true.mass) < 1e-12 * true.mass
        np.testing.assert_allclose(read.lever, true.lever, atol=1e-12)
        np.testing.assert_allclose(read.inertia, true.inertia, atol=1e-12)
    # and it is not the nominal robot
    assert abs(model.inertias[1].mass - task.robot.model.inertias[1].mass) > 1e-6


def test_the_periods_shorten_over_the_motions_last_seconds():
    """Every 0.5 s, every 0.2 s from the first period's start inside the last 3 s, each a whole
    number of intervals; without an end period every 0.5 s to the end."""
    options = ClosedLoopOptions(period=0.5, end_period=0.2, end_window=3.0)
    assert period_starts(100, 0.1, options) == [*range(0, 70, 5), *range(70, 100, 2), 100]
    assert period_starts(100, 0.1, dataclasses.replace(options, end_period=None)) == [
        *range(0, 100, 5),
        100,
    ]
    # no period starts inside a window shorter than a period: the periods stay as they are
    short = dataclasses.replace(options, end_window=0.3)
    assert period_starts(100, 0.1, short) == [*range(0, 100, 5), 100]


def test_a_margin_of_one_or_more_is_refused(tmp_path):
    path = tmp_path / "task.yaml"
    path.write_text(TASK + "  margin: 1.0\n")
    with pytest.raises(InputError) as info:
        load_task(path)
    assert str(info.value) == (
        f"{path}:8: closed_loop: closed-loop option 'margin' must be < 1 (a fraction of the "
        "limits), got 1"
    )


def test_the_margin_tightens_the_balance_joints_rates_and_nothing_else():
    task = load_task(EXAMPLES / "capture_task.yaml")
    robot = task.robot
    assert margined(robot, 0.0) is robot
    tight = margined(robot, 0.05)
    balance = robot.balance_indices
    others = np.setdiff1d(np.arange(robot.n), balance)
    for kind in ("velocity", "acceleration"):
        np.testing.assert_allclose(
            getattr(tight.limits, kind)[balance], 0.95 * getattr(robot.limits, kind)[balance]
        )
        np.testing.assert_array_equal(
            getattr(tight.limits, kind)[others], getattr(robot.limits, kind)[others]
        )
    for kind in ("lower", "upper", "effort", "jerk"):
        np.testing.assert_array_equal(getattr(tight.limits, kind), getattr(robot.limits, kind))
    # the robot itself keeps its limits (the violation check uses them)
    assert robot.limits.acceleration[balance][0] == 2.0


def test_the_position_margin_and_the_jerk_bound_hold_the_balance_joints_only():
    task = load_task(EXAMPLES / "capture_task.yaml")
    robot = task.robot
    tight = margined(robot, 0.0, 0.002, 10.0)
    balance = robot.balance_indices
    others = np.setdiff1d(np.arange(robot.n), balance)
    limits, own = tight.limits, robot.limits
    np.testing.assert_allclose(limits.lower[balance], own.lower[balance] + 0.002)
    np.testing.assert_allclose(limits.upper[balance], own.upper[balance] - 0.002)
    np.testing.assert_array_equal(limits.jerk[balance], [10.0] * balance.size)
    for kind in ("lower", "upper", "jerk"):
        np.testing.assert_array_equal(getattr(limits, kind)[others], getattr(own, kind)[others])
    for kind in ("velocity", "acceleration", "effort"):
        np.testing.assert_array_equal(getattr(limits, kind), getattr(own, kind))
    # a margin wider than a quarter of a joint's range keeps half the range
    span = own.upper[balance] - own.lower[balance]
    wide = margined(robot, 0.0, 10.0).limits
    np.testing.assert_allclose(wide.upper[balance] - wide.lower[balance], 0.5 * span)


@pytest.mark.slow
def test_the_closed_loop_margins_keep_a_true_robot_inside_its_limits(planned):
    """Flown closed loop on a robot 10 % off, a plan that rides its limits leaves them (its
    joint controllers track it with a lag, largest where a re-plan turns the acceleration);
    with the margins (rates, accelerations, positions, jerk) the true motion stays inside the
    robot's own limits."""
    from balance_opt.app.closed_loop import true_robots

    task, nlp, plan, replanner = planned
    truth = true_robots(task.robot, ClosedLoopOptions(samples=4, perturbation=0.1, seed=0))[3]

    def violations(replanner, first, options):
        run = fly_closed_loop(
            truth, replanner, first, task.spec.simulation, options, deadline=math.inf
        )
        s = run.simulation
        limits = task.robot.limits
        return find_limit_violations(s.t, task.robot.joint_names, s.q, s.q_dot, s.q_ddot, limits)

    bare = ClosedLoopOptions(period=1.0, margin=0.0, position_margin=0.0, jerk=None)
    assert margined(task.robot, *bare.margins) is task.robot
    assert len(violations(replanner, plan, bare)) >= 3
    options = ClosedLoopOptions(period=1.0)
    robot = margined(task.robot, *options.margins)
    tight = build_balance_nlp(
        nlp.model, task.mission, task.q_B0, nlp.options, robot=robot, h0=task.h0
    )
    first = tight.solve(plan.solver.solution)
    assert violations(Replanner(tight), first, options) == []
