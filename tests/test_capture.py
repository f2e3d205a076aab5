"""Capturing an active target (issue 16): a non-zero total momentum in the optimal planner, and
the capture itself (momentum conserved through it, no jump for a target moving with the end
effector, the optimal plan against the law, the task section's errors).

The planner's base rate with a momentum ``h0`` is checked against the analytic law's rollout
(a different code path: numeric Pinocchio, the quaternion integrated by the law's own
integrator), and a whole optimal plan with ``h0`` against an attitude recomputed here from the
exported joint motion alone, with numeric Pinocchio and nothing of the planner.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.analytic.rollout import rollout
from balance_opt.app.capture import plan_task
from balance_opt.app.pipeline import run_task, simulate
from balance_opt.errors import InputError
from balance_opt.model.capture import Target, attach_target, capture_state
from balance_opt.model.maps import NumericMaps
from balance_opt.motion.so3 import rotvec_from_quaternion
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.report.outputs import solver_metrics
from balance_opt.tasks.task import load_task

#: A total momentum [N s; N m s] that turns the paper robot's base by several degrees in 10 s.
H0 = np.array([0.3, -0.2, 0.1, 2.0, -1.5, 3.0])
#: Planner base rate against the law's at the same state [rad/s] (both numeric Pinocchio to
#: round-off).
RATE_TOLERANCE = 1e-9
#: NLP attitude at the nodes against the re-simulated one, relative to the drift (Hermite-Simpson
#: at N = 25 with this momentum: ~2e-3).
COLLOCATION_RELATIVE_ERROR = 5e-3
#: Independent attitude (RK4 at twice the exported step) against the exported one [rad].
ATTITUDE_TOLERANCE = 1e-6


def _points(result, h0):
    """Planner states and point data of a result's samples: ``x = [log R; q_B; q_dot_B]``,
    ``m = [q_M; q_dot_M; q_ddot_M; h0]``."""
    phi = rotvec_from_quaternion(result.quaternion)
    X = np.hstack([phi, result.q_B, result.q_dot_B]).T
    h0_rows = np.broadcast_to(h0, (result.t.size, 6))
    m = np.hstack([result.q_M, result.q_dot_M, result.q_ddot_M, h0_rows]).T
    return X, result.q_ddot_B.T, m


def test_planner_base_rate_with_momentum_matches_the_law_rollout(model, capture):
    """Along the law's rollout with ``h0`` (whose base rate includes ``R^T L0``), the planner's
    dynamics give the law's base rate at the law's attitude: the momentum turns with the base."""
    t = np.linspace(0.0, capture.mission.duration, 41)
    law = rollout(
        capture.robot, capture.mission, capture.q_B0, BalanceLawOptions(h0=tuple(H0)), t_eval=t
    )
    assert np.max(law.angle) > 0.05  # the momentum turns the base: the term matters
    X, U, m = _points(law, H0)
    _, omega = model.dynamics_fun("acceleration").map(t.size)(X, U, m)
    np.testing.assert_allclose(np.array(omega).T, law.omega, rtol=0, atol=RATE_TOLERANCE)
    # without the momentum the planner's rate differs by the momentum's share
    _, omega0 = model.dynamics_fun("acceleration").map(t.size)(X, U, _points(law, 0 * H0)[2])
    assert np.max(np.abs(np.array(omega0).T - law.omega)) > 1e-3


@pytest.mark.slow
def test_torques_with_momentum_reproduce_the_accelerations_in_forward_dynamics(model):
    """Joint torques of the free-floating inverse dynamics with a momentum ``h_b`` (base axes):
    Pinocchio's ABA from the state whose base twist carries that momentum gives back the
    joint accelerations, and that state's centroidal momentum is ``h_b``."""
    rng = np.random.default_rng(5)
    robot = model.robot
    tau_fun = model.torque_fun(True)
    data = robot.model.createData()
    lim = robot.limits
    for _ in range(5):
        q = rng.uniform(np.maximum(lim.lower, -2.0), np.minimum(lim.upper, 2.0))
        q_dot, q_ddot, h_b = (rng.normal(size=n) for n in (robot.n, robot.n, 6))
        tau = np.array(tau_fun(q, q_dot, q_ddot, h_b)).ravel()
        qp = robot.pin_q(q)
        A = pin.computeCentroidalMap(robot.model, data, qp)  # base at the identity: base axes
        v_arm = robot.pin_v(q_dot)
        v = robot.pin_v(q_dot, np.linalg.solve(A[:, :6], h_b - A[:, 6:] @ v_arm[6:]))
        np.testing.assert_allclose(A @ v, h_b, rtol=0, atol=1e-9)
        tau_full = np.zeros(robot.model.nv)
        tau_full[robot.pin_v_indices] = tau
        a = pin.aba(robot.model, data, qp, v, tau_full)
        np.testing.assert_allclose(a[robot.pin_v_indices], q_ddot, rtol=0, atol=1e-9)


def _independent_attitude(robot, t, q, q_dot, h0) -> np.ndarray:
    """Base rotation matrices (every other sample) integrated from the joint motion alone: at
    each sample the base twist solves ``A_G(q, R) [v_b; q_dot] = h0`` (Pinocchio's centroidal
    map in world axes, the whole 6 x 6 base block), RK4 on ``R_dot = R [omega]_x`` with the
    odd samples as midpoints, re-orthonormalised after each step."""
    model, data = robot.model, robot.model.createData()

    def omega(k, R):
        qp = robot.pin_q(q[k], pin.SE3(R, np.zeros(3)))
        A = pin.computeCentroidalMap(model, data, qp)
        v = robot.pin_v(q_dot[k])
        v_b = np.linalg.solve(A[:, :6], h0 - A[:, 6:] @ v[6:])
        return v_b[3:]

    def rate(R, w):
        return R @ pin.skew(w)

    R = np.eye(3)
    out = [R]
    for k in range(0, t.size - 2, 2):
        dt = t[k + 2] - t[k]
        k1 = rate(R, omega(k, R))
        k2 = rate(R + 0.5 * dt * k1, omega(k + 1, R + 0.5 * dt * k1))
        k3 = rate(R + 0.5 * dt * k2, omega(k + 1, R + 0.5 * dt * k2))
        k4 = rate(R + dt * k3, omega(k + 2, R + dt * k3))
        R = R + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
        out.append(R)
    return np.array(out)


@pytest.mark.slow
def test_optimal_plan_with_momentum_matches_an_independent_attitude(model, capture):
    """An optimal plan with ``h0``: Ipopt succeeds, the NLP's attitude agrees with the
    re-simulation, and the exported attitude is the one recomputed here from the exported
    joint motion; another ``h0`` reuses the compiled NLP."""
    options = PlannerOptions(intervals=25, objective="integral")
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options, h0=H0)
    plan = nlp.solve()
    assert plan.details()["success"]
    defect = plan.solver.checks.attitude_defect_max_rad
    assert defect < COLLOCATION_RELATIVE_ERROR * plan.max_drift
    # the residual's floor is its finite differences': ~1e-7 on smooth motion, up to ~1e-5 at
    # a sample next to the peak plan's acceleration switches (7.5e-6 here); an attitude that
    # did not follow the momentum gives a residual of order one
    assert np.max(plan.momentum_residual) < 3e-5
    t, q, q_dot = plan.t, np.hstack([plan.q_M, plan.q_B]), np.hstack([plan.q_dot_M, plan.q_dot_B])
    cols = np.r_[capture.robot.mission_indices, capture.robot.balance_indices]
    arm_q, arm_qd = np.empty_like(q), np.empty_like(q_dot)
    arm_q[:, cols], arm_qd[:, cols] = q, q_dot
    n = (t.size - 1) // 2 * 2 + 1
    R_ref = _independent_attitude(capture.robot, t[:n], arm_q[:n], arm_qd[:n], H0)
    R_out = np.array([pin.Quaternion(*qq[[3, 0, 1, 2]]).matrix() for qq in plan.quaternion[:n:2]])
    err = [np.linalg.norm(pin.log3(a.T @ b)) for a, b in zip(R_ref, R_out)]
    assert max(err) < ATTITUDE_TOLERANCE
    # the momentum turned the base: without the balance arm's help the drift would be larger
    assert np.linalg.norm(pin.log3(R_ref[-1])) > 1e-3
    # every non-zero h0 shares one structure (the value is a parameter); zero momentum has its
    # own, without the momentum terms
    cached = len(model.nlp_cache)
    other = build_balance_nlp(model, capture.mission, capture.q_B0, options, h0=-H0)
    assert other.structure is nlp.structure and nlp.structure.key.momentum
    assert len(model.nlp_cache) == cached
    still = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    assert not still.structure.key.momentum


# ---------------------------------------------------------------------------------- the capture
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "capture_tumbling_target.yaml"
#: Momentum about a fixed world point before and after the capture, relative [-].
CAPTURE_TOLERANCE = 1e-12
#: Simulated momentum against the one each phase should keep, relative (rk4, 10 ms).
SIMULATION_TOLERANCE = 1e-6


@pytest.fixture(scope="module")
def example():
    return load_task(EXAMPLE)


def _momentum_about_origin(robot, q_pin, v) -> np.ndarray:
    """``[p; L about the world origin]`` of a robot state, from Pinocchio's centroidal momentum."""
    model, data = robot.model, robot.model.createData()
    hg = pin.computeCentroidalMomentum(model, data, q_pin, v)
    return np.r_[hg.linear, hg.angular + np.cross(data.com[0], hg.linear)]


def _target_momentum_about_origin(robot, target, q_pin) -> np.ndarray:
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, q_pin)
    ee = data.oMf[model.getFrameId(robot.mission.ee_frame)]
    c = ee.act(target.com)
    p = target.mass * target.linear_velocity
    I_w = ee.rotation @ target.inertia @ ee.rotation.T
    return np.r_[p, I_w @ target.angular_velocity + np.cross(c, p)]


def _check_conserved(task, q, q_dot, quaternion, twist_before, twist_after):
    """Robot + free target before, robot with the target after: the same momentum about the
    world origin (the base placed away from it: a reference point that matters)."""
    base = pin.SE3(pin.Quaternion(*np.r_[quaternion[3], quaternion[:3]]).matrix(), np.r_[1, -2, 3])
    robot, after = task.robot, task.robot_after_capture
    before = _momentum_about_origin(
        robot, robot.pin_q(q, base), robot.pin_v(q_dot, twist_before)
    ) + _target_momentum_about_origin(robot, task.target, robot.pin_q(q, base))
    now = _momentum_about_origin(after, after.pin_q(q, base), after.pin_v(q_dot, twist_after))
    scale = np.linalg.norm(before)
    np.testing.assert_allclose(now, before, rtol=0, atol=CAPTURE_TOLERANCE * scale)


def test_capture_conserves_the_total_momentum_in_the_plan(example):
    """The analytic plan's state at the capture with the base twists it reports: robot plus
    target before equals the robot with the target after, to round-off."""
    plan = plan_task(example, "analytic")
    k = int(np.flatnonzero(plan.t <= example.target.time)[-1])
    robot = example.robot
    q, q_dot = np.empty(robot.n), np.empty(robot.n)
    q[robot.mission_indices], q[robot.balance_indices] = plan.q_M[k], plan.q_B[k]
    q_dot[robot.mission_indices], q_dot[robot.balance_indices] = plan.q_dot_M[k], plan.q_dot_B[k]
    info = plan.details()["capture"]
    assert np.linalg.norm(info["omega_jump"]) > 1e-3  # a real jump
    _check_conserved(
        example,
        q,
        q_dot,
        plan.quaternion[k],
        np.array(info["base_twist_before"]),
        np.array(info["base_twist_after"]),
    )
    np.testing.assert_allclose(plan.omega[k], info["base_twist_before"][3:], atol=1e-9)
    assert np.max(plan.momentum_residual) < 1e-8
    # with the joint rates continuous (the balance arm held; the law's own rates jump at the
    # capture, and the base rate with them), the next sample's base rate is the jump's
    held = plan_task(example, "mission-only")
    after = held.details()["capture"]["base_twist_after"][3:]
    np.testing.assert_allclose(held.omega[k + 1], after, rtol=0, atol=5e-4)  # 10 ms later
    assert np.max(np.abs(held.omega[k + 1] - held.omega[k])) > 5e-3


def test_target_at_rest_relative_to_the_end_effector_gives_no_jump(example):
    """A target that already moves with the end effector (its CoM at the gripper point's
    velocity, its rotation the end effector's) is captured without any base twist jump."""
    rng = np.random.default_rng(3)
    robot, h0 = example.robot, np.array([0.2, -0.1, 0.3, 1.0, -0.5, 0.8])
    q = np.r_[example.mission.start, example.q_B0] + rng.normal(scale=0.2, size=robot.n)
    q_dot = rng.normal(scale=0.3, size=robot.n)
    quaternion = np.array([0.1, -0.2, 0.05, 0.97]) / np.linalg.norm([0.1, -0.2, 0.05, 0.97])
    R = pin.Quaternion(*np.r_[quaternion[3], quaternion[:3]]).matrix()
    twist = NumericMaps(robot).base_twist(q, q_dot, np.r_[R.T @ h0[:3], R.T @ h0[3:]])
    model, data = robot.model, robot.model.createData()
    qp, v = robot.pin_q(q, pin.SE3(R, np.zeros(3))), robot.pin_v(q_dot, twist)
    pin.forwardKinematics(model, data, qp, v)
    pin.updateFramePlacements(model, data)
    frame = model.getFrameId(robot.mission.ee_frame)
    vel = pin.getFrameVelocity(model, data, frame, pin.LOCAL_WORLD_ALIGNED)
    com = np.array([0.25, 0.1, -0.05])
    point = data.oMf[frame].rotation @ com
    target = Target(
        1.0,
        50.0,
        [2.0, 0.1, 0.0, 2.5, 0.0, 3.0],
        com,
        vel.linear + np.cross(vel.angular, point),
        vel.angular,
    )
    state = capture_state(robot, attach_target(robot, target), target, q, q_dot, quaternion, h0)
    np.testing.assert_allclose(state.twist_after, state.twist_before, rtol=0, atol=1e-12)
    moving = dataclasses.replace(target, angular_velocity=vel.angular + [0.0, 0.0, 0.05])
    jumped = capture_state(robot, attach_target(robot, moving), moving, q, q_dot, quaternion, h0)
    assert np.linalg.norm(jumped.omega_jump) > 1e-4


@pytest.mark.slow
def test_simulation_conserves_the_momentum_through_the_capture(example):
    """Forward dynamics of the analytic plan: the impulse gives the robot with the target the
    momentum robot and target had (round-off), each phase keeps its own (integrator
    tolerance), and the simulated base rate jumps by the plan's jump."""
    plan = plan_task(example, "analytic")
    sim = simulate(example, plan)
    k = int(np.flatnonzero(sim.t <= example.target.time)[-1])
    info = sim.info["capture"]
    _check_conserved(
        example,
        example.robot.arm_q(sim.q_pin[k]),
        example.robot.arm_v(sim.v[k]),
        sim.q_pin[k, 3:7],
        np.array(info["base_twist_before"]),
        np.array(info["base_twist_after"]),
    )
    assert np.max(sim.momentum_residual) < SIMULATION_TOLERANCE
    np.testing.assert_allclose(sim.h0[k + 1], info["momentum_after"])
    np.testing.assert_allclose(
        info["omega_jump"], plan.details()["capture"]["omega_jump"], rtol=0, atol=1e-4
    )


def test_capture_section_errors_name_the_key(tmp_path):
    text = EXAMPLE.read_text()
    bad_time = tmp_path / "late.yaml"
    bad_time.write_text(text.replace("time: 5.0 ", "time: 12.0"))
    line = next(i for i, s in enumerate(bad_time.read_text().splitlines(), 1) if "time: 12" in s)
    with pytest.raises(InputError) as err:
        load_task(bad_time)
    assert str(err.value) == (
        f"{bad_time}:{line}: capture.time: must be before the end of the mission (10 s), got 12 s"
    )
    flat = tmp_path / "flat.yaml"
    flat.write_text(text.replace("[2.083, 0, 0, 2.083, 0, 2.083]", "[1.0, 0, 0, 1.0, 0, 3.0]"))
    with pytest.raises(InputError, match=r"capture\.inertia: target inertia is not physical"):
        load_task(flat)
    no_capture = tmp_path / "no_capture.yaml"
    body = text[: text.index("capture:")] + text[text.index("limits:") :]
    ignore = "optimal:\n  collision: {ignore: [[balance_link3, capture_target]]}\n"
    no_capture.write_text(body + ignore)
    message = r"optimal\.collision\.ignore: capture_target is the captured target"
    with pytest.raises(InputError, match=message):
        load_task(no_capture)


@pytest.mark.slow
def test_optimal_capture_plan_no_worse_than_the_law_within_limits(example):
    """On the example the analytic law stays within the limits but at the capture, where its
    balance rates step (an acceleration no arm performs: counted, tests/test_planner_pairs.py);
    the optimal plan, through the same capture, keeps the base at least as still and within
    every limit, its balance joints at rest at the capture (continuous rates)."""
    law = plan_task(example, "analytic")
    assert law.violations and all(v.step is not None for v in law.violations)
    plan = plan_task(example, "optimal")
    assert plan.details()["success"] and not plan.violations
    assert plan.max_drift <= law.max_drift + 1e-6
    # the reported solver work is both phases' (each: its stages and its refinement)
    before = (
        sum(s["iterations"] for s in plan.details()["stages"])
        + plan.solver.refinement["iterations"]
    )
    after = plan.details()["after_capture"]
    after_total = sum(s["iterations"] for s in after["stages"]) + after["refinement"]["iterations"]
    assert solver_metrics(plan.details())["iterations"] == before + after_total
    k = int(np.flatnonzero(plan.t <= example.target.time)[-1])
    np.testing.assert_allclose(plan.q_dot_B[k], 0.0, atol=1e-9)
    # the residual's floor is its finite differences': ~1e-7 on smooth motion, up to ~1e-5 at
    # a sample next to the peak plan's acceleration switches (7.5e-6 here); an attitude that
    # did not follow the momentum gives a residual of order one
    assert np.max(plan.momentum_residual) < 3e-5


@pytest.mark.slow
def test_run_writes_the_capture_block_report_and_figure(tmp_path):
    """``run_task`` (what ``balance-opt compare`` runs) on the example: the ``capture`` block per
    method and per simulation, the simulated jump close to the plan's, the drift before the
    capture equal to the plan's own attitude at that time, the figure and the report section.

    The simulation tracks with computed torque: under the default PD gains the optimal plan's
    fast balance motion lags by up to 0.02 rad, and the jump, which depends on the joint rates
    at the capture, then differs from the plan's by some 30 %."""
    tracked = tmp_path / "tracked.yaml"
    tracked.write_text(EXAMPLE.read_text() + "\nsimulation: {controller: computed-torque}\n")
    example = load_task(tracked)
    run = run_task(example, simulate=True, output_dir=tmp_path / "out")
    assert run.ok
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    block = metrics["capture"]
    assert set(block["methods"]) == {"mission-only", "analytic", "optimal"}
    assert set(block["simulated"]) == set(block["methods"])
    for name, m in block["methods"].items():
        sim = block["simulated"][name]
        np.testing.assert_allclose(sim["omega_jump_rad_s"], m["omega_jump_rad_s"], atol=1e-3)
        result = run.results[name]
        k = int(np.flatnonzero(result.t <= example.target.time)[-1])
        assert m["drift_at_capture_rad"] == pytest.approx(float(result.angle[k]), abs=1e-12)
        assert m["max_drift_after_rad"] >= m["final_drift_since_capture_rad"]
    assert (tmp_path / "out" / "capture.png").is_file()
    report = (tmp_path / "out" / "report.html").read_text()
    assert f"Capture at t = {example.target.time:g} s" in report


def test_a_mission_only_run_of_a_capture_task_draws_the_mission_arms_capture(tmp_path, capsys):
    """``plan --method mission-only`` on a capture task: no balance plan to show, so the capture
    figure shows the mission arm alone (it once had no curve and raised)."""
    from balance_opt.cli import main

    out = tmp_path / "out"
    code = main(["plan", str(EXAMPLE), "--method", "mission-only", "--output", str(out), "-q"])
    assert code == 0, capsys.readouterr().err
    assert (out / "capture.png").is_file()
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["capture"]["methods"]) == {"mission-only"}


def test_the_targets_box_has_its_mass_and_inertia_and_rides_on_the_end_effector(paper):
    """The target's volume is the uniform box of its mass and inertia (Pinocchio's box inertia
    gives the inertia back), on the mission end effector at the target's CoM."""
    turn = pin.rpy.rpyToMatrix(0.3, -0.5, 0.8)
    inertia = turn @ np.diag([2.0, 3.0, 4.0]) @ turn.T
    zero = np.zeros(3)
    target = Target(5.0, 50.0, inertia, [0.3, 0.1, 0.0], zero, zero)
    sides, axes = target.box()
    box = pin.Inertia.FromBox(target.mass, *sides)
    np.testing.assert_allclose(axes @ box.inertia @ axes.T, inertia, atol=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0)

    from balance_opt.geometry.robot_geometry import RobotGeometry
    from balance_opt.model.capture import TARGET_LINK

    after = attach_target(paper, target)
    geometry = RobotGeometry(after)
    (k,) = [i for i in range(geometry.geometry_model.ngeoms) if geometry.link(i) == TARGET_LINK]
    obj = geometry.geometry_model.geometryObjects[k]
    np.testing.assert_allclose(2.0 * np.asarray(obj.geometry.halfSide), sides, atol=1e-12)
    q = np.random.default_rng(2).uniform(-1.0, 1.0, after.n)
    geometry.place(q)
    model, data = after.model, after.model.createData()
    pin.framesForwardKinematics(model, data, after.pin_q(q))
    held = data.oMf[model.getFrameId(after.mission.ee_frame)] * pin.SE3(axes, target.com)
    np.testing.assert_allclose(geometry.geometry_data.oMg[k].homogeneous, held.homogeneous,
                               atol=1e-12)  # fmt: skip
    # the target is part of the end effector's body: checked against the base, the other arm
    # and the links before the one that holds it (not adjacent: it meets none at a joint)
    pairs = {frozenset(p.links) for p in geometry.pairs if TARGET_LINK in p.links}
    others = ("base_link", "balance_link3", "mission_link1", "mission_link2")
    assert {frozenset((link, TARGET_LINK)) for link in others} <= pairs
    assert frozenset(("mission_link3", TARGET_LINK)) not in pairs
    # a task's ignore pair of the target holds after the capture and is no error before it
    ignore = [["balance_link3", TARGET_LINK]]
    assert ("balance_link3", TARGET_LINK) in RobotGeometry(after, ignore=ignore).ignored
    assert RobotGeometry(paper, ignore=ignore).ignored.get(("balance_link3", TARGET_LINK)) is None
    # the planner's second phase keeps the balance arm's links off it
    from balance_opt.optimal.collision import collision_setup
    from balance_opt.optimal.model import PlannerModel

    setup = collision_setup(PlannerModel(after), PlannerOptions(), load_task(EXAMPLE).q0)
    rowed = {p.links for p in setup.pairs if setup.owner[p.index] is not None}
    assert {("balance_link2", TARGET_LINK), ("balance_link3", TARGET_LINK)} <= rowed


@pytest.mark.parametrize("moments", [(3.0, 3.0, 3.0), (2.0, 3.0, 3.0), (2.0, 2.0, 3.0)])
def test_equal_moments_give_the_box_the_end_effectors_axes(moments):
    """Where the inertia leaves the box's axes free (equal moments), it takes the end
    effector's; a unique axis stays the inertia's."""
    turn = pin.rpy.rpyToMatrix(0.3, -0.5, 0.8)
    zero = np.zeros(3)
    target = Target(5.0, 50.0, turn @ np.diag(moments) @ turn.T, zero, zero, zero)
    sides, axes = target.box()
    box = pin.Inertia.FromBox(target.mass, *sides)
    np.testing.assert_allclose(axes @ box.inertia @ axes.T, target.inertia, atol=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    if len(set(moments)) == 1:
        np.testing.assert_allclose(axes, np.eye(3), atol=1e-12)
    else:
        odd = turn[:, [moments.count(m) for m in moments].index(1)]
        free = [k for k in range(3) if not np.isclose(abs(axes[:, k] @ odd), 1.0)]
        assert len(free) == 2  # the unique axis is one of the box's
        # the other two are the end-effector axes' projections: one lies in an axis plane
        assert any(np.isclose(np.abs(axes[:, free]), 0.0, atol=1e-12).any(axis=0))


def test_the_check_after_the_capture_starts_at_the_capture():
    """The motion after the capture starts at its time: a sample a rounding error before it
    counts, a grid without it gets the interpolated configuration."""
    from balance_opt.app.run_studies import _from_capture

    t = np.arange(0, 11) * 0.1
    q = np.column_stack([t, 2 * t])
    t_c = t[4] + 2e-16
    t_after, q_after = _from_capture(t, q, t_c)
    assert t_after[0] == t[4] and len(t_after) == 7
    t_after, q_after = _from_capture(t, q, 0.45)
    np.testing.assert_allclose(t_after[:2], [0.45, 0.5])
    np.testing.assert_allclose(q_after[0], [0.45, 0.9])


def _big_target_task(tmp_path, time):
    """The example with a 1.2 m cube held 0.6 m beyond the gripper, captured at ``time``: the
    cube reaches into the base from t = 6.2 s on."""
    import yaml

    doc = yaml.safe_load(EXAMPLE.read_text())
    side, mass = 1.2, 50.0
    moment = mass * 2 * side**2 / 12
    doc["capture"].update(time=time, inertia=[moment, 0, 0, moment, 0, moment], com=[0.6, 0, 0])
    path = tmp_path / f"big_target_{time:g}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return load_task(path)


def _target_base_distance(task, result) -> np.ndarray:
    """coal's distance between the target's box on the end effector and the base's cube at every
    sample of a plan, from Pinocchio's frame placements (whether captured or not)."""
    import coal

    robot = task.robot
    model, data = robot.model, robot.model.createData()
    ee = model.getFrameId(robot.mission.ee_frame)
    sides, axes = task.target.box()
    base = model.getFrameId("base_link")
    out = []
    for k in range(result.t.size):
        pin.framesForwardKinematics(model, data, robot.pin_q(np.r_[result.q_M[k], result.q_B[k]]))
        M = data.oMf[ee] * pin.SE3(axes, task.target.com)
        B = data.oMf[base]
        found = coal.DistanceResult()
        coal.distance(
            coal.Box(*sides), coal.Transform3s(M.rotation, M.translation),
            coal.Box(1.0, 1.0, 1.0), coal.Transform3s(B.rotation, B.translation),
            coal.DistanceRequest(), found,
        )  # fmt: skip
        out.append(found.min_distance)
    return np.array(out)


@pytest.mark.slow
def test_the_clearance_check_holds_the_target_from_the_capture_on(tmp_path):
    """A target too big for the capture configuration: the check finds it in the base where coal
    does on the plan, from the capture on and never before, whichever comes first: the moment
    it first touches or the capture."""
    for time, first in ((5.0, None), (8.0, 8.0)):
        task = _big_target_task(tmp_path, time)
        run = run_task(task, methods=("mission-only",), simulate=False)
        report = run.clearance["mission-only"][0]
        result = run.results["mission-only"]
        exact = _target_base_distance(task, result)
        after = result.t >= time
        (pair,) = [p for p in report.pairs if p.pair == "base_link / capture_target"]
        assert pair.distance == pytest.approx(exact[after].min(), abs=1e-3)
        assert pair.time >= time
        pen = report.first_penetration
        assert pen.pair == "base_link / capture_target"
        touch = result.t[np.flatnonzero(exact < 0.0)[0]]  # it touches between two samples
        if first is None:
            assert touch - 0.02 <= pen.time <= touch
        else:
            assert touch < time and pen.time == pytest.approx(first)
        assert not report.collision_free
