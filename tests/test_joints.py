"""Every joint type Pinocchio's URDF parser handles, against numeric Pinocchio (issue 12, point 2).

The robot below has a revolute mission joint with an rpy origin, a fixed joint in the middle of
each arm, a continuous mission joint, a finger that mimics the first mission joint (multiplier
0.7, offset 0.2), a revolute, a prismatic and a continuous balance joint, and a locked joint
with a mimic of its own. The reference is Pinocchio's own mimic support
(``buildModelFromXML(..., mimic=True)``, where a mimic joint has no degree of freedom of its
own): balance-opt builds its models without it, so the two routes are independent.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from balance_opt.errors import JointError
from balance_opt.model import coupling
from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot, Mimic
from balance_opt.model.summary import robot_summary


def _link(name, m, com):
    return (
        f'<link name="{name}_link"><inertial><origin xyz="{com}" rpy="0.1 0.2 0.3"/>'
        f'<mass value="{m}"/><inertia ixx="{0.02 * m}" ixy="0.001" ixz="0" iyy="{0.03 * m}" '
        f'iyz="0.002" izz="{0.025 * m}"/></inertial></link>'
    )


def _joint(name, kind, parent, child, xyz, rpy, axis="0 0 1", mimic=None):
    s = (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}_link"/>'
        f'<child link="{child}_link"/><origin xyz="{xyz}" rpy="{rpy}"/>'
    )
    if kind != "fixed":
        s += f'<axis xyz="{axis}"/>'
    if kind in ("revolute", "prismatic"):
        lo, hi = ("-0.3", "0.3") if kind == "prismatic" else ("-2.5", "2.5")
        s += f'<limit lower="{lo}" upper="{hi}" velocity="1.5" effort="50"/>'
    elif kind == "continuous":
        s += '<limit velocity="2.0" effort="50"/>'
    if mimic:
        s += f'<mimic joint="{mimic[0]}" multiplier="{mimic[1]}" offset="{mimic[2]}"/>'
    return s + "</joint>"


URDF = (
    '<robot name="jointy">'
    + _link("base", 40.0, "0.01 -0.02 0.03")
    + _link("m1", 2.0, "0 0 0.1")
    + _joint("m1", "revolute", "base", "m1", "0.3 0 0.2", "0.1 -0.2 0.3", "0 1 0")
    + _link("m_mid", 0.5, "0.05 0 0")
    + _joint("m_fix", "fixed", "m1", "m_mid", "0 0 0.3", "0.2 0.1 0")
    + _link("m2", 1.5, "0.1 0 0")
    + _joint("m2", "continuous", "m_mid", "m2", "0.1 0 0", "0 0.3 -0.1", "1 0 0")
    + _link("tool", 0.3, "0.05 0.01 0")
    + _joint("tool_fix", "fixed", "m2", "tool", "0.3 0 0", "0 0 0.4")
    + _link("finger", 1.0, "0.05 0.02 0.01")
    + _joint("finger", "revolute", "m2", "finger", "0.2 0.05 0", "0.3 0 0", mimic=("m1", 0.7, 0.2))
    + _link("b1", 3.0, "0 0.1 0")
    + _joint("b1", "revolute", "base", "b1", "-0.3 0.1 0", "0 0 1.2")
    + _link("b2", 2.0, "0 0 0.1")
    + _joint("b2", "prismatic", "b1", "b2", "0 0.2 0", "0.4 0 0", "0 1 0")
    + _link("b_mid", 0.4, "0 0 0.05")
    + _joint("b_fix", "fixed", "b2", "b_mid", "0 0 0.2", "0 -0.5 0")
    + _link("b3", 1.5, "0.1 0.1 0")
    + _joint("b3", "continuous", "b_mid", "b3", "0 0 0.1", "0.2 0.2 0.2")
    + _link("l1", 1.0, "0 0 0.1")
    + _joint("l1", "revolute", "base", "l1", "0 -0.3 0", "0 0 0", "1 0 0")
    + _link("l2", 1.0, "0 0 0.1")
    + _joint("l2", "revolute", "l1", "l2", "0 0 0.2", "0 0.1 0", "0 1 0", mimic=("l1", -2.0, 0.1))
    + "</robot>"
)
MISSION, BALANCE, LOCKED = ["m1", "m2"], ["b1", "b2", "b3"], {"l1": 0.3}


@pytest.fixture(scope="module")
def robot():
    return FloatingRobot(URDF, MISSION, BALANCE, locked=LOCKED)


@pytest.fixture(scope="module")
def native():
    """Pinocchio's own model, mimic joints as Pinocchio implements them."""
    model = pin.buildModelFromXML(URDF, pin.JointModelFreeFlyer(), True)
    model.gravity = pin.Motion.Zero()
    return model


def _native_q(model, names, q, quaternion=(0, 0, 0, 1), position=(0, 0, 0)):
    """Native configuration: the named joints at ``q``, the locked ones at their positions."""
    qn = pin.neutral(model)
    qn[:7] = [*position, *quaternion]
    for name, value in [*zip(names, q), *LOCKED.items()]:
        jm = model.joints[model.getJointId(name)]
        qn[jm.idx_q : jm.idx_q + jm.nq] = [value] if jm.nq == 1 else [np.cos(value), np.sin(value)]
    return qn


def _native_cols(model, names):
    return np.r_[0:6, [model.joints[model.getJointId(n)].idx_v for n in names]]


def _random_q(robot, rng):
    lo = np.where(np.isfinite(robot.limits.lower), robot.limits.lower, -np.pi)
    hi = np.where(np.isfinite(robot.limits.upper), robot.limits.upper, np.pi)
    return rng.uniform(lo, hi)


# ------------------------------------------------------------------------- the model
def test_mimic_joints_follow_their_driver(robot):
    assert robot.followers == {"finger": Mimic("m1", 0.7, 0.2)}
    assert robot.locked == {"l1": 0.3, "l2": pytest.approx(-2.0 * 0.3 + 0.1)}
    assert robot.model_joint_names == ("m1", "m2", "b1", "b2", "b3", "finger")
    q = np.array([0.4, 2.0, -0.3, 0.1, -2.9])
    qp, vp = robot.pin_q(q), robot.pin_v(np.arange(1.0, 6.0))
    finger = robot.model.joints[robot.model.getJointId("finger")]
    assert qp[finger.idx_q] == pytest.approx(0.7 * 0.4 + 0.2)
    assert vp[finger.idx_v] == pytest.approx(0.7 * 1.0)
    assert "finger" not in robot_summary(robot).split("locked:")[1]


def test_mimic_joint_refused_in_an_arm_or_locked():
    with pytest.raises(JointError) as exc:
        FloatingRobot(URDF, ["m1", "finger"], BALANCE)
    assert str(exc.value) == (
        "joint 'finger' in <URDF string>: is a mimic joint following 'm1' (multiplier 0.7, "
        "offset 0.2) and cannot be an arm joint (arm 'mission'); name its driver 'm1' in an "
        "arm and 'finger' moves with it"
    )
    with pytest.raises(JointError, match="'l2' .*is a mimic joint following 'l1' and cannot be"):
        FloatingRobot(URDF, MISSION, BALANCE, locked={"l2": 0.1})


def test_follower_limits_narrow_their_driver():
    """finger = 2 m1 + 0.2 within [-2.5, 2.5] rad and 1.5 rad/s: m1 within [-1.35, 1.15] rad
    and 0.75 rad/s."""
    text = URDF.replace('multiplier="0.7" offset="0.2"', 'multiplier="2.0" offset="0.2"')
    lim = FloatingRobot(text, MISSION, BALANCE, locked=LOCKED).limits
    assert (lim.lower[0], lim.upper[0], lim.velocity[0]) == pytest.approx((-1.35, 1.15, 0.75))


def test_units_of_prismatic_joints(robot):
    assert robot.joint_units == ("rad", "rad", "rad", "m", "rad")
    line = next(ln for ln in robot_summary(robot).splitlines() if ln.strip().startswith("b2 "))
    assert line.endswith("[m, m/s, m/s^2, N]")
    lim = robot.limits
    assert (lim.lower[[1, 4]] == -np.inf).all() and (lim.upper[[1, 4]] == np.inf).all()
    assert (lim.lower[3], lim.upper[3]) == (-0.3, 0.3)


# ------------------------------------------------------------------------- numeric maps
def test_numeric_maps_match_pinocchio_mimic_model(robot, native):
    """A_G and J_base at seeded random configurations, against Pinocchio's own mimic model:
    continuous (cos, sin), prismatic, fixed joints mid-chain, rpy origins, both mimics."""
    maps, data = NumericMaps(robot), native.createData()
    cols = _native_cols(native, robot.joint_names)
    rng = np.random.default_rng(12)
    for _ in range(10):
        q = _random_q(robot, rng)
        A_ref = pin.computeCentroidalMap(native, data, _native_q(native, robot.joint_names, q))
        A_ref = A_ref[:, cols]
        A = maps.centroidal_momentum_matrix(q)
        assert np.abs(A - A_ref).max() < 1e-12 * max(1.0, np.abs(A_ref).max())
        J_ref = coupling.base_jacobian(A_ref)
        assert np.abs(maps.base_jacobian(q) - J_ref).max() < 1e-12


def test_mimic_changes_the_maps(robot):
    """The finger's momentum is in m1's column: the finger locked where it is (the old
    behaviour locked it at 0) gives the same maps but for m1's column."""
    text = URDF.replace('<mimic joint="m1" multiplier="0.7" offset="0.2"/>', "")
    q = np.array([0.4, 2.0, -0.3, 0.1, -2.9])
    frozen = FloatingRobot(text, MISSION, BALANCE, locked={**LOCKED, "finger": 0.7 * 0.4 + 0.2})
    A, A0 = NumericMaps(robot).angular_maps(q)[1], NumericMaps(frozen).angular_maps(q)[1]
    assert np.abs(A[:, 0] - A0[:, 0]).max() > 1e-2  # m1's column gains the finger's
    np.testing.assert_allclose(A[:, 1:], A0[:, 1:], atol=1e-12)


# ------------------------------------------------------------------------- symbolic maps
def _check_symbolic(sym, robot, seed):
    maps = NumericMaps(robot)
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(5):
        q = _random_q(robot, rng)
        A = np.array(sym.centroidal_momentum_matrix_fun()(q))
        worst = max(worst, np.abs(A - maps.centroidal_momentum_matrix(q)).max())
        J_base = np.array(sym.base_jacobian_fun()(q))
        worst = max(worst, np.abs(J_base - maps.base_jacobian(q)).max())
    return worst


@pytest.mark.slow  # builds the Pinocchio-CasADi bridge on a cold cache (~2 min)
def test_pinocchio_backend_matches_numeric(robot):
    from balance_opt.model.symbolic import SymbolicMaps

    sym = SymbolicMaps(robot, "pinocchio")
    assert _check_symbolic(sym, robot, 1) < 1e-11


def test_adam_backend_matches_numeric_with_mimic():
    from balance_opt.model.symbolic import SymbolicMaps

    robot = FloatingRobot(URDF, MISSION, ["b1", "b3"], locked={**LOCKED, "b2": 0.1})
    assert _check_symbolic(SymbolicMaps(robot, "adam"), robot, 2) < 1e-11


def test_adam_backend_names_the_prismatic_joint(robot):
    from balance_opt.model.symbolic import SymbolicMaps

    with pytest.raises(JointError) as exc:
        SymbolicMaps(robot, "adam")
    assert str(exc.value) == (
        "joint 'b2' in <URDF string>: is prismatic, which the 'adam' backend cannot handle "
        "(adam-robotics 0.5); lock it, or use backend='pinocchio'"
    )


# ------------------------------------------------------------------------- simulation
class _Wave:
    """Desired joint motion ``q0 + a (1 - cos w t)``, starting at rest."""

    def __init__(self, q0, a, w, duration):
        self.q0, self.a, self.w = (np.asarray(x, dtype=float) for x in (q0, a, w))
        self.duration = duration

    def sample(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
        c, s = np.cos(self.w * t), np.sin(self.w * t)
        return self.q0 + self.a * (1 - c), self.a * self.w * s, self.a * self.w**2 * c


def _reference_attitude(native, names, plan, kp, kd, duration):
    """Final base quaternion of the PD-tracked motion integrated on Pinocchio's own mimic
    model: state (base position, quaternion, joint positions, base twist, joint rates), the
    locked joint held by dropping its column (a plain selection), scipy's DOP853."""
    data, n = native.createData(), len(names)
    sel = _native_cols(native, names)

    def rhs(t, y):
        p, quat, q, v_r = y[:3], y[3:7] / np.linalg.norm(y[3:7]), y[7 : 7 + n], y[7 + n :]
        qn = _native_q(native, names, q, quat, p)
        v = np.zeros(native.nv)
        v[sel] = v_r
        qd, qd_dot, _ = (x[0] for x in plan(t))
        tau = np.zeros(native.nv)
        tau[sel[6:]] = kp * (qd - q) + kd * (qd_dot - v_r[6:])
        M = pin.crba(native, data, qn)
        M = np.triu(M) + np.triu(M, 1).T
        f = (tau - pin.nonLinearEffects(native, data, qn, v))[sel]
        a_r = np.linalg.solve(M[np.ix_(sel, sel)], f)
        R = pin.Quaternion(quat[3], *quat[:3]).toRotationMatrix()
        w = v_r[3:6]
        quat_dot = 0.5 * np.r_[quat[3] * w + np.cross(quat[:3], w), -quat[:3] @ w]
        return np.r_[R @ v_r[:3], quat_dot, v_r[6:], a_r]

    q0 = plan(0.0)[0][0]
    y0 = np.r_[np.zeros(3), 0, 0, 0, 1, q0, np.zeros(6 + n)]
    sol = solve_ivp(rhs, (0, duration), y0, method="DOP853", rtol=1e-12, atol=1e-13)
    quat = sol.y[3:7, -1]
    return quat / np.linalg.norm(quat)


@pytest.mark.slow
def test_simulation_with_a_mimic_finger_matches_pinocchio(robot, native):
    """Forward dynamics with the finger following m1: momentum kept, and the attitude equal to
    an integration on Pinocchio's own mimic model (crba, nonLinearEffects)."""
    from balance_opt.dynamics.options import SimulationOptions
    from balance_opt.dynamics.simulation import simulate

    duration = 1.0
    mission = _Wave([0.3, 1.0], [0.8, 1.5], [3.0, 4.0], duration)
    balance = _Wave([-0.2, 0.05, 2.5], [0.5, 0.1, -1.2], [2.5, 3.5, 3.0], duration)
    kp, kd = np.array([400.0, 300, 500, 800, 200]), np.array([40.0, 30, 50, 80, 20])
    opts = SimulationOptions(
        integrator="dopri5",
        rtol=1e-12,
        atol=1e-14,
        kp=tuple(kp),
        kd=tuple(kd),
        output_dt=0.05,
        feedforward=False,  # the reference integrates PD alone
    )
    sim = simulate(robot, mission, balance, opts)
    assert np.abs(sim.momentum - sim.h0).max() < 1e-9
    assert np.ptp(sim.q[:, 0]) > 0.5  # m1, and with it the finger, did move

    def plan(t):
        qm, qb = mission.sample(t), balance.sample(t)
        return tuple(np.concatenate([m, b], axis=1) for m, b in zip(qm, qb))

    ref = _reference_attitude(native, robot.joint_names, plan, kp, kd, duration)
    R_sim = pin.Quaternion(*np.roll(sim.quaternion[-1], 1)).toRotationMatrix()
    R_ref = pin.Quaternion(*np.roll(ref, 1)).toRotationMatrix()
    err = np.linalg.norm(pin.log3(R_sim.T @ R_ref))
    assert err < 1e-8
    assert np.linalg.norm(pin.log3(R_ref)) > 1e-2  # the base did turn


# ------------------------------------------------------------------------- planners
@pytest.mark.slow
def test_plans_with_prismatic_and_continuous_balance_joints():
    """Analytic and optimal (N = 20) plans on the robot with a prismatic and a continuous balance
    joint (and the mimic finger): the analytic law keeps the momentum exactly but ignores the
    limits; the optimal plan meets them (re-simulated with numeric Pinocchio)."""
    from balance_opt.analytic.rollout import rollout
    from balance_opt.motion.replay import phase_one
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    limits = {"b2": {"lower": -0.05, "upper": 0.05, "velocity": 0.2}, "b3": {"velocity": 1.0}}
    robot = FloatingRobot(URDF, MISSION, BALANCE, locked=LOCKED, limits=limits)
    mission, q_B0 = PointToPoint([0.0, 0.0], [1.2, 2.5], 4.0), np.array([0.2, 0.0, 3.0])

    analytic = rollout(robot, mission, q_B0)
    maps = NumericMaps(robot)
    q, q_dot = np.c_[analytic.q_M, analytic.q_B], np.c_[analytic.q_dot_M, analytic.q_dot_B]
    Ag = maps.centroidal(q, analytic.quaternion)
    L = np.matvec(Ag[:, 3:], maps.velocities(q_dot, analytic.omega))
    assert np.abs(L).max() < 1e-12
    assert {(v.joint, v.kind) for v in analytic.violations} >= {("b2", "position")}

    model = PlannerModel(robot, compile=False)
    plan = build_balance_nlp(model, mission, q_B0, PlannerOptions(intervals=20)).solve()
    assert plan.violations == []
    tol = 1e-6
    assert np.abs(plan.q_B[:, 1]).max() < 0.05 + tol  # prismatic [m]
    assert np.abs(plan.q_dot_B[:, 1]).max() < 0.2 + tol  # [m/s]
    assert np.abs(plan.q_dot_B[:, 2]).max() < 1.0 + tol  # continuous, unbounded position
    assert plan.solver.checks.max_momentum_residual < 1e-5
    assert np.abs(plan.q_B[:, 1]).max() > 0.05 - 1e-3  # the prismatic limit is active
    # so tight a stroke leaves the balance arm little: a drift below Phase I's, not far below
    assert plan.max_drift < phase_one(robot, mission, q_B0).max_drift


def test_planner_torques_with_a_mimic_finger(native):
    """The planner's joint torques (adam, reduced by the mimic map) against the free-floating
    inverse dynamics of Pinocchio's own mimic model, at zero momentum."""
    from balance_opt.optimal.model import PlannerModel

    robot = FloatingRobot(URDF, MISSION, ["b1", "b3"], locked={**LOCKED, "b2": 0.1})
    torque = PlannerModel(robot, compile=False).torque_fun()
    data, sel = native.createData(), _native_cols(native, robot.joint_names)
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, q_dot, q_ddot = _random_q(robot, rng), rng.normal(size=4), rng.normal(size=4)
        qn = _native_q(native, robot.joint_names, q)
        qn[native.joints[native.getJointId("b2")].idx_q] = 0.1
        A = pin.computeCentroidalMap(native, data, qn)[:, sel]
        nu = np.r_[coupling.base_jacobian(A) @ q_dot, q_dot]
        v = np.zeros(native.nv)
        v[sel] = nu
        M = pin.crba(native, data, qn)
        M = (np.triu(M) + np.triu(M, 1).T)[np.ix_(sel, sel)]
        h = pin.nonLinearEffects(native, data, qn, v)[sel]
        a_b = -np.linalg.solve(M[:6, :6], M[:6, 6:] @ q_ddot + h[:6])
        ref = M[6:, :6] @ a_b + M[6:, 6:] @ q_ddot + h[6:]
        np.testing.assert_allclose(np.array(torque(q, q_dot, q_ddot)).ravel(), ref, atol=1e-10)


def test_torque_limits_name_a_prismatic_joint(robot):
    from balance_opt.optimal.model import PlannerModel

    with pytest.raises(JointError, match="'b2' .*is prismatic.*plan without torque limits"):
        PlannerModel(robot, compile=False).torque_fun()
