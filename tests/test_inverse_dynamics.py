"""Free-floating inverse dynamics against independent computations: a closed form for two
coaxial wheels on a base, Pinocchio's ABA at the same state, and a forward-dynamics integration
driven by the torques (joints follow the motion, momentum stays constant)."""

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.dynamics.inverse_dynamics import free_floating_torques, plan_joint_torques
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import quaternion_from_rotvec

_WHEEL = """
  <link name="{name}"><inertial><origin xyz="0 0 0"/><mass value="{m}"/>
    <inertia ixx="{a}" iyy="{a}" izz="{c}" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="{name}_joint" type="{kind}"><parent link="base"/><child link="{name}"/>
    <origin xyz="0 0 0"/><axis xyz="0 0 1"/>{limit}</joint>"""

#: A base with two wheels on its z axis, every CoM at the base origin: w1 revolute with an
#: effort limit of 1.5 N m, w2 continuous with no limit at all (its effort limit is inf).
WHEELS = f"""<robot name="wheels">
  <link name="base"><inertial><origin xyz="0 0 0"/><mass value="50"/>
    <inertia ixx="4" iyy="5" izz="6" ixy="0" ixz="0" iyz="0"/></inertial></link>
  {_WHEEL.format(name="w1", m=2.0, a=0.3, c=0.5, kind="revolute",
                 limit='<limit lower="-100" upper="100" velocity="10" effort="1.5"/>')}
  {_WHEEL.format(name="w2", m=3.0, a=0.5, c=0.8, kind="continuous", limit="")}
</robot>"""  # fmt: skip


def _motion(n, t, seed):
    """A smooth motion of n joints: positions, rates, accelerations (T, n) as functions of t."""
    rng = np.random.default_rng(seed)
    a, w, p = rng.uniform(-0.5, 0.5, n), rng.uniform(0.5, 2.0, n), rng.uniform(0, 6, n)
    t = np.atleast_1d(t)[:, None]
    return (
        a * np.sin(w * t + p),
        a * w * np.cos(w * t + p),
        -a * w**2 * np.sin(w * t + p),
    )


def test_two_coaxial_wheels_closed_form():
    robot = FloatingRobot(WHEELS, ["w1_joint"], ["w2_joint"])
    t = np.linspace(0, 3, 31)
    q, qd, qdd = _motion(2, t, 0)
    ident = free_floating_torques(robot, q, qd, qdd)
    c1, c2, Ib = 0.5, 0.8, 6.0  # about z: the base rotates about z only, every CoM at the origin
    wdot = -(c1 * qdd[:, 0] + c2 * qdd[:, 1]) / (Ib + c1 + c2)
    np.testing.assert_allclose(ident.base_acceleration[:, 5], wdot, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ident.tau[:, 0], c1 * (wdot + qdd[:, 0]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ident.tau[:, 1], c2 * (wdot + qdd[:, 1]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ident.base_acceleration[:, :5], 0, rtol=0, atol=1e-12)


def test_aba_with_these_torques_gives_the_joint_accelerations(paper):
    t = np.linspace(0, 4, 9)
    q, qd, qdd = _motion(paper.n, t, 1)
    ident = free_floating_torques(paper, q, qd, qdd)
    data = paper.model.createData()
    for k in range(t.size):
        tau = np.zeros(paper.model.nv)
        tau[paper.pin_v_indices] = ident.tau[k]
        v = paper.pin_v(qd[k], ident.base_twist[k])
        a = pin.aba(paper.model, data, paper.pin_q(q[k]), v, tau)
        np.testing.assert_allclose(a[paper.pin_v_indices], qdd[k], rtol=0, atol=1e-10)
        np.testing.assert_allclose(a[:6], ident.base_acceleration[k], rtol=0, atol=1e-10)


def _world_momentum(model, data, qp, v):
    """Centroidal momentum [linear; angular], world frame."""
    return pin.computeCentroidalMomentum(model, data, qp, v).vector.copy()


@pytest.mark.parametrize(
    "h0",
    [
        np.zeros(6),
        pytest.param(np.array([0.3, -0.2, 0.1, 0.5, -0.4, 0.8]), marks=pytest.mark.slow),
    ],
)
def test_forward_dynamics_driven_by_the_torques_follows_the_motion(paper, h0):
    """RK4 (joint space exact, base on SE(3) through pin.integrate) of ABA with the torques of
    the prescribed motion at each stage time: the simulated joints follow the motion and the
    momentum stays h0."""
    model, data = paper.model, paper.model.createData()
    sel = paper.pin_v_indices
    base0 = pin.SE3(pin.rpy.rpyToMatrix(0.2, -0.1, 0.3), np.array([0.1, 0.0, -0.2]))

    def torque(t, qp):
        q, qd, qdd = _motion(paper.n, t, 2)
        quat = qp[None, 3:7]
        return free_floating_torques(paper, q, qd, qdd, quat, h0)

    def deriv(t, qp, v):
        tau = np.zeros(model.nv)
        tau[sel] = torque(t, qp).tau[0]
        return v, pin.aba(model, data, qp, v, tau)

    q0, qd0, _ = _motion(paper.n, 0.0, 2)
    qp = paper.pin_q(q0[0], base0)
    v = paper.pin_v(qd0[0], torque(0.0, qp).base_twist[0])
    np.testing.assert_allclose(_world_momentum(model, data, qp, v), h0, rtol=0, atol=1e-12)
    dt, steps = 2e-3, 250
    for i in range(steps):
        t = i * dt
        k1 = deriv(t, qp, v)
        k2 = deriv(t + dt / 2, pin.integrate(model, qp, dt / 2 * k1[0]), v + dt / 2 * k1[1])
        k3 = deriv(t + dt / 2, pin.integrate(model, qp, dt / 2 * k2[0]), v + dt / 2 * k2[1])
        k4 = deriv(t + dt, pin.integrate(model, qp, dt * k3[0]), v + dt * k3[1])
        qp = pin.integrate(model, qp, dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]))
        v = v + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    q1, qd1, _ = _motion(paper.n, steps * dt, 2)
    np.testing.assert_allclose(paper.arm_q(qp), q1[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(v[sel], qd1[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(_world_momentum(model, data, qp, v), h0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(v[:6], torque(steps * dt, qp).base_twist[0], rtol=0, atol=1e-9)


def test_plan_joint_torques_orders_columns_by_the_plan(paper):
    t = np.linspace(0, 2, 5)
    q, qd, qdd = _motion(paper.n, t, 3)
    M, B = paper.mission_indices, paper.balance_indices
    res = BalanceResult.from_arm_vectors(
        paper, "x", t, q, qd, qdd, quaternion_from_rotvec(np.zeros((5, 3))),
        np.zeros((5, 3)), np.zeros(5), np.ones(5),
    )  # fmt: skip
    assert res.q_M.shape[1] == M.size and res.q_B.shape[1] == B.size
    np.testing.assert_array_equal(
        plan_joint_torques(res, paper), free_floating_torques(paper, q, qd, qdd).tau
    )


def test_mimic_joints_against_pinocchio_native_mimic_model():
    """A robot with a mimic finger on the mission arm, a locked joint with a mimic of its own,
    prismatic and continuous joints: Pinocchio's own mimic model (no degree of freedom for a
    mimic joint), driven by the base motion and torques found, needs no wrench on the base,
    gives the torques found, and holds zero momentum."""
    from test_joints import BALANCE, LOCKED, MISSION, URDF, _native_cols, _native_q

    robot = FloatingRobot(URDF, MISSION, BALANCE, locked=LOCKED)
    assert robot.followers
    native = pin.buildModelFromXML(URDF, pin.JointModelFreeFlyer(), True)
    native.gravity = pin.Motion.Zero()
    data, sel = native.createData(), _native_cols(native, robot.joint_names)
    rng = np.random.default_rng(7)
    q = rng.uniform(-0.25, 0.25, (4, robot.n))
    qd, qdd = rng.normal(size=(4, robot.n)), rng.normal(size=(4, robot.n))
    ident = free_floating_torques(robot, q, qd, qdd)
    for k in range(4):
        v, a = np.zeros(native.nv), np.zeros(native.nv)
        v[sel], a[sel] = (
            np.r_[ident.base_twist[k], qd[k]],
            np.r_[ident.base_acceleration[k], qdd[k]],
        )
        qn = _native_q(native, robot.joint_names, q[k])
        f = pin.rnea(native, data, qn, v, a)[sel]
        np.testing.assert_allclose(f[:6], 0, rtol=0, atol=1e-10)
        np.testing.assert_allclose(f[6:], ident.tau[k], rtol=0, atol=1e-10)
        h = pin.computeCentroidalMomentum(native, data, qn, v).vector
        np.testing.assert_allclose(h, 0, rtol=0, atol=1e-10)
