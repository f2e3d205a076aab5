"""The floating robot model: loading, joint maps, locked joints, limits and input errors."""

import re

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.errors import ArmError, JointError, URDFLoadError
from balance_opt.model.library import (
    PAPER_BALANCE_JOINTS,
    PAPER_MISSION_JOINTS,
    baxter_floating,
    shipped_urdf,
)
from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot
from balance_opt.model.symbolic import SymbolicMaps

ATOL = 1e-9
N_RANDOM = 10

_LIMIT = '<limit lower="{lo}" upper="{hi}" velocity="{v}" effort="{e}"/>'


def _link(name, mass, com, diag):
    return (
        f'<link name="{name}"><inertial><origin xyz="{com}" rpy="0.1 -0.2 0.3"/><mass value="{mass}"/>'
        f'<inertia ixx="{diag[0]}" ixy="0.01" ixz="-0.02" iyy="{diag[1]}" iyz="0.005" izz="{diag[2]}"/>'
        "</inertial></link>"
    )


def _joint(name, jtype, parent, child, xyz, rpy="0 0 0", axis="0 0 1", limit=""):
    return (
        f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="{axis}"/>{limit}</joint>'
    )


#: A small robot with every joint type the model handles (physical inertias: positive definite,
#: within the triangle inequality): a continuous joint (Pinocchio stores
#: it as (cos, sin)), a prismatic arm joint, unaligned axes, and two joints to lock (a revolute
#: one with an unnormalised axis, and a prismatic one).
TOY_URDF = "".join(
    [
        '<?xml version="1.0"?>\n<robot name="toy">',
        _link("base", 50.0, "0.01 -0.02 0.03", (4.0, 5.0, 6.0)),
        _link("l1", 2.0, "0 0 0.2", (0.05, 0.05, 0.03)),
        _link("l2", 1.5, "0.25 0 0", (0.04, 0.045, 0.045)),
        '<link name="l_tool"/>',
        _link("r1", 2.5, "0 0.1 0.15", (0.06, 0.05, 0.04)),
        _link("r2", 1.0, "0.1 0 0", (0.04, 0.045, 0.045)),
        _link("sensor", 3.0, "0.1 0.1 0.1", (0.04, 0.05, 0.05)),
        _link("payload", 4.0, "0 0 -0.05", (0.05, 0.05, 0.05)),
        _joint(
            "l1_yaw",
            "revolute",
            "base",
            "l1",
            "0.3 0.2 0.1",
            limit=_LIMIT.format(lo=0.2, hi=1.5, v=2, e=10),
        ),
        _joint(
            "l2_spin",
            "continuous",
            "l1",
            "l2",
            "0 0 0.4",
            rpy="0.1 0.2 0.3",
            axis="0 1 0",
            limit='<limit velocity="3" effort="5"/>',
        ),
        _joint("l_tool_fixed", "fixed", "l2", "l_tool", "0.5 0 0"),
        _joint(
            "r1_roll",
            "revolute",
            "base",
            "r1",
            "-0.3 0.1 0.1",
            rpy="0 0 2.0",
            axis="1 0 0",
            limit=_LIMIT.format(lo=-2, hi=2, v=1.5, e=10),
        ),
        _joint(
            "r2_slide",
            "prismatic",
            "r1",
            "r2",
            "0 0 0.3",
            axis="1 0 0",
            limit=_LIMIT.format(lo=-0.1, hi=0.2, v=0.5, e=50),
        ),
        _joint(
            "tilt",
            "revolute",
            "base",
            "sensor",
            "0 0 0.5",
            rpy="0.3 0 0",
            axis="0 2 2",
            limit=_LIMIT.format(lo=-1, hi=1, v=1, e=1),
        ),
        _joint(
            "slider",
            "prismatic",
            "base",
            "payload",
            "0.1 -0.4 0",
            axis="1 1 0",
            limit=_LIMIT.format(lo=0, hi=0.3, v=1, e=1),
        ),
        "</robot>",
    ]
)
TOY_ARMS = {"mission": ["l2_spin", "l1_yaw"], "balance": ["r1_roll", "r2_slide"]}
TOY_LOCKED = {"tilt": 0.4, "slider": 0.1}


def _toy(**kwargs):
    kwargs.setdefault("mission", TOY_ARMS["mission"])
    kwargs.setdefault("balance", TOY_ARMS["balance"])
    kwargs.setdefault("locked", TOY_LOCKED)
    return FloatingRobot(TOY_URDF, **kwargs)


def _paper(**kwargs):
    kwargs.setdefault("mission", PAPER_MISSION_JOINTS)
    kwargs.setdefault("balance", PAPER_BALANCE_JOINTS)
    return FloatingRobot(shipped_urdf(), **kwargs)


def _random_q(robot, rng):
    lower = np.where(np.isfinite(robot.limits.lower), robot.limits.lower, -np.pi)
    upper = np.where(np.isfinite(robot.limits.upper), robot.limits.upper, np.pi)
    return rng.uniform(lower, upper)


def _full_q(robot, q):
    """Configuration of the FULL Pinocchio model: arm joints at q, locked joints at their
    positions, set by joint name (independent of the robot's own index maps)."""
    model = robot.full_model
    qf = pin.neutral(model)
    for name, value in [*zip(robot.joint_names, q), *robot.locked.items()]:
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:
            qf[joint.idx_q : joint.idx_q + 2] = [np.cos(value), np.sin(value)]
        else:
            qf[joint.idx_q] = value
    return qf


def _body_placements(model, qp):
    data = model.createData()
    pin.framesForwardKinematics(model, data, qp)
    return {f.name: data.oMf[i].copy() for i, f in enumerate(model.frames) if f.type == pin.BODY}


# ------------------------------------------------------------------------------------ loading
def test_path_str_and_text_load_the_same_robot():
    path = shipped_urdf()
    robots = [
        _paper(),
        FloatingRobot(str(path), PAPER_MISSION_JOINTS, PAPER_BALANCE_JOINTS),
        FloatingRobot(path.read_text(), PAPER_MISSION_JOINTS, PAPER_BALANCE_JOINTS),
    ]
    assert [r.source for r in robots] == [str(path), str(path), "<URDF string>"]
    q = _random_q(robots[0], np.random.default_rng(1))
    A = [NumericMaps(r).centroidal_momentum_matrix(q) for r in robots]
    for r, A_r in zip(robots[1:], A[1:]):
        assert r.joint_names == robots[0].joint_names
        assert r.model.names.tolist() == robots[0].model.names.tolist()
        np.testing.assert_allclose(A_r, A[0], rtol=0, atol=0)


def test_free_flyer_root_and_zero_gravity(paper, baxter):
    for robot in (paper, baxter):
        assert robot.model.joints[1].shortname() == "JointModelFreeFlyer"
        assert robot.model.names[1] == "root_joint"
        np.testing.assert_array_equal(robot.model.gravity.vector, np.zeros(6))
        assert robot.model.nv == 6 + robot.n  # every other movable joint is locked away


def test_string_with_xml_declaration_and_toy_structure():
    robot = _toy()
    assert robot.source == "<URDF string>"
    assert robot.name == "toy"
    assert robot.joint_names == ("l2_spin", "l1_yaw", "r1_roll", "r2_slide")
    assert robot.locked == TOY_LOCKED
    # the most distal joint's child (l2_spin, named first), then through fixed joints only
    assert [a.ee_frame for a in robot.arms] == ["l_tool", "r2"]
    assert robot.total_mass == pytest.approx(64.0, abs=1e-12)


# ------------------------------------------------------------------------------ joint maps
def test_joint_index_maps_follow_user_order():
    mission = ["mission_joint3", "mission_joint1", "mission_joint2"]
    balance = ["balance_joint2", "balance_joint3", "balance_joint1"]
    robot = _paper(mission=mission, balance=balance)
    assert robot.joint_names == tuple(mission + balance)
    for i, name in enumerate(mission + balance):
        assert robot.joint_index(name) == i
        assert robot.pin_v_indices[i] == robot.model.joints[robot.model.getJointId(name)].idx_v
    np.testing.assert_array_equal(robot.mission_indices, [0, 1, 2])
    np.testing.assert_array_equal(robot.balance_indices, [3, 4, 5])
    assert robot.arm("balance").joints == tuple(balance)
    with pytest.raises(JointError, match=r"joint 'base_link' in .*: is in no arm"):
        robot.joint_index("base_link")
    with pytest.raises(
        ArmError, match=r"arm 'balance2' of .*: no such arm \(arms: mission, balance\)"
    ):
        robot.arm("balance2")


@pytest.mark.parametrize(
    "name, link, axis",
    [
        ("mission_joint1", "mission_link1", (0, 0, 1)),
        ("balance_joint3", "balance_link3", (0, 0, 1)),
    ],
)
def test_arm_vector_entry_moves_the_joint_of_that_name(name, link, axis):
    """Setting one entry of q rotates the named joint's child link by that angle about the
    joint axis, and nothing upstream of it."""
    robot = _paper(
        mission=["mission_joint3", "mission_joint1", "mission_joint2"],
        balance=["balance_joint3", "balance_joint2", "balance_joint1"],
    )
    q = np.zeros(robot.n)
    home = _body_placements(robot.model, robot.pin_q(q))
    q[robot.joint_index(name)] = 0.7
    moved = _body_placements(robot.model, robot.pin_q(q))
    expected = home[link].rotation @ pin.exp3(0.7 * np.array(axis, dtype=float))
    np.testing.assert_allclose(moved[link].rotation, expected, rtol=0, atol=ATOL)
    np.testing.assert_allclose(moved[link].translation, home[link].translation, rtol=0, atol=ATOL)
    for other in ("base_link", "mission_link1" if link.startswith("balance") else "balance_link1"):
        assert moved[other].isApprox(home[other])


@pytest.mark.parametrize("make", [_paper, _toy], ids=["paper", "toy"])
def test_pin_q_pin_v_round_trip(make):
    robot = make()
    rng = np.random.default_rng(7)
    for _ in range(N_RANDOM):
        q = _random_q(robot, rng)
        q_dot = rng.normal(size=robot.n)
        base = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))
        twist = rng.normal(size=6)
        qp = robot.pin_q(q, base)
        assert qp.shape == (robot.model.nq,)
        np.testing.assert_allclose(qp[:7], pin.SE3ToXYZQUAT(base), rtol=0, atol=0)
        np.testing.assert_allclose(robot.arm_q(qp), q, rtol=0, atol=ATOL)
        v = robot.pin_v(q_dot, twist)
        np.testing.assert_array_equal(v[:6], twist)
        np.testing.assert_array_equal(robot.arm_v(v), q_dot)
        np.testing.assert_array_equal(robot.pin_v(q_dot)[:6], np.zeros(6))


def test_continuous_joint_angle_wraps():
    robot = _toy()
    q = np.array([2 * np.pi + 0.3, 0.5, 0.0, 0.0])
    qp = robot.pin_q(q)
    l2 = robot.model.joints[robot.model.getJointId("l2_spin")]
    assert l2.nq == 2
    np.testing.assert_allclose(
        qp[l2.idx_q : l2.idx_q + 2], [np.cos(0.3), np.sin(0.3)], rtol=0, atol=ATOL
    )
    assert robot.arm_q(qp)[0] == pytest.approx(0.3, abs=ATOL)


# --------------------------------------------------------------------------- locked joints
LOCKED_CASES = {
    "paper_mission_joint3": lambda: _paper(
        mission=PAPER_MISSION_JOINTS[:2], locked={"mission_joint3": 0.7}
    ),
    "baxter_head_pan": lambda: baxter_floating(
        locked={"head_pan": 0.3, "l_gripper_l_finger_joint": 0.01}
    ),
    # adam cannot take the prismatic arm joint r2_slide (test_maps.py): lock it too
    "toy": lambda: _toy(balance=["r1_roll"], locked={**TOY_LOCKED, "r2_slide": 0.05}),
}


@pytest.fixture(scope="module", params=sorted(LOCKED_CASES))
def locked_robot(request):
    return request.param, LOCKED_CASES[request.param]()


def test_locked_joints_are_listed_with_their_positions(locked_robot):
    name, robot = locked_robot
    full_joints = set(robot.full_model.names[2:])  # every movable joint but the free flyer
    assert set(robot.locked) == full_joints - set(robot.joint_names)
    expected = {
        "paper_mission_joint3": {"mission_joint3": 0.7, "balance_joint3": None},
        "baxter_head_pan": {
            "head_pan": 0.3,
            "l_gripper_l_finger_joint": 0.01,
            "r_gripper_l_finger_joint": 0.0,
        },
        "toy": {**TOY_LOCKED, "r2_slide": 0.05},
    }[name]
    for joint, value in expected.items():
        if value is None:
            assert joint not in robot.locked
        else:
            assert robot.locked[joint] == value


def test_reduced_model_matches_full_model_with_locked_joints(locked_robot):
    """Frame placements and the centroidal map restricted to the free joints are those of the
    FULL Pinocchio model with the locked joints held at their positions."""
    _, robot = locked_robot
    full, reduced = robot.full_model, robot.model
    assert full.nv == reduced.nv + sum(full.joints[full.getJointId(j)].nv for j in robot.locked)
    full_cols = np.r_[0:6, [full.joints[full.getJointId(j)].idx_v for j in robot.joint_names]]
    rng = np.random.default_rng(3)
    for _ in range(N_RANDOM):
        q = _random_q(robot, rng)
        base = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))
        qr, qf = robot.pin_q(q, base), _full_q(robot, q)
        qf[:7] = qr[:7]
        frames_r, frames_f = _body_placements(reduced, qr), _body_placements(full, qf)
        assert frames_r.keys() == frames_f.keys()
        for frame, placement in frames_r.items():
            np.testing.assert_allclose(
                placement.homogeneous, frames_f[frame].homogeneous, rtol=0, atol=ATOL, err_msg=frame
            )
        A_f = pin.computeCentroidalMap(full, full.createData(), qf)[:, full_cols]
        A_r = pin.computeCentroidalMap(reduced, reduced.createData(), qr)[
            :, np.r_[0:6, robot.pin_v_indices]
        ]
        np.testing.assert_allclose(A_r, A_f, rtol=0, atol=ATOL)


def test_locked_position_is_not_ignored(locked_robot):
    """The same robot locked at zero has a different centroidal map (so the test above can fail)."""
    name, robot = locked_robot
    at_zero = {
        "paper_mission_joint3": lambda: _paper(mission=PAPER_MISSION_JOINTS[:2]),
        "baxter_head_pan": baxter_floating,
        "toy": lambda: _toy(balance=["r1_roll"], locked={}),
    }[name]()
    q = _random_q(robot, np.random.default_rng(4))
    difference = NumericMaps(robot).centroidal_momentum_matrix(q) - NumericMaps(
        at_zero
    ).centroidal_momentum_matrix(q)
    assert np.abs(difference).max() > 1e-3


def test_locked_urdf_is_the_same_robot(locked_robot):
    """``locked_urdf`` (locked joints turned into fixed ones, the symbolic backends' input)
    loaded by Pinocchio, and the symbolic maps built from it, give the numeric model's A_G."""
    _, robot = locked_robot
    model = pin.buildModelFromXML(robot.locked_urdf, pin.JointModelFreeFlyer())
    assert model.nv == 6 + robot.n
    cols = [model.joints[model.getJointId(j)].idx_v for j in robot.joint_names]
    symbolic = SymbolicMaps(robot)
    rng = np.random.default_rng(5)
    for _ in range(3):
        q = _random_q(robot, rng)
        qp = pin.neutral(model)
        for name, value in zip(robot.joint_names, q):
            joint = model.joints[model.getJointId(name)]
            qp[joint.idx_q : joint.idx_q + joint.nq] = (
                [np.cos(value), np.sin(value)] if joint.nq == 2 else value
            )
        A_locked = pin.computeCentroidalMap(model, model.createData(), qp)[:, np.r_[0:6, cols]]
        A = NumericMaps(robot).centroidal_momentum_matrix(q)
        np.testing.assert_allclose(A_locked, A, rtol=0, atol=ATOL)
        A_symbolic = np.array(symbolic.centroidal_momentum_matrix_fun()(q))
        np.testing.assert_allclose(A_symbolic, A, rtol=0, atol=ATOL)


# ---------------------------------------------------------------------------------- limits
def test_limits_from_the_urdf():
    robot = _toy()
    lim = robot.limits
    np.testing.assert_array_equal(lim.lower, [-np.inf, 0.2, -2, -0.1])
    np.testing.assert_array_equal(lim.upper, [np.inf, 1.5, 2, 0.2])
    np.testing.assert_array_equal(lim.velocity, [3, 2, 1.5, 0.5])
    np.testing.assert_array_equal(lim.effort, [5, 10, 10, 50])
    np.testing.assert_array_equal(lim.acceleration, np.full(4, np.inf))
    # neutral() clips zero into the limits
    np.testing.assert_array_equal(robot.neutral(), [0, 0.2, 0, 0])
    sub = lim.subset(robot.balance_indices)
    np.testing.assert_array_equal(sub.upper, [2, 0.2])


def test_limit_overrides():
    overrides = {
        "mission_joint2": {"upper": 1.0, "acceleration": 0.5},
        "balance_joint1": {"lower": -1.0, "velocity": 0.3, "effort": 7},
    }
    robot = _paper(limits=overrides)
    reference = _paper().limits
    i, k = robot.joint_index("mission_joint2"), robot.joint_index("balance_joint1")
    for key in ("lower", "upper", "velocity", "acceleration", "effort"):
        expected = getattr(reference, key).copy()
        for joint, index in (("mission_joint2", i), ("balance_joint1", k)):
            expected[index] = overrides[joint].get(key, expected[index])
        np.testing.assert_array_equal(getattr(robot.limits, key), expected, err_msg=key)


# ---------------------------------------------------------------------------------- errors
def _write(tmp_path, text):
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    return path


M, B = list(PAPER_MISSION_JOINTS), list(PAPER_BALANCE_JOINTS)
PAPER = re.escape(str(shipped_urdf()))

ERRORS = {
    "unknown joint": (
        dict(mission=["mission_joint1", "mision_joint2"]),
        JointError,
        (
            rf"joint 'mision_joint2' in {PAPER}: no such joint in the URDF \(arm 'mission'\); "
            r"did you mean 'mission_joint2'"
        ),
    ),
    "joint named twice": (
        dict(mission=["mission_joint1", "mission_joint2", "mission_joint1"]),
        JointError,
        rf"joint 'mission_joint1' in {PAPER}: is named twice in arm 'mission'",
    ),
    "joint in two arms": (
        dict(balance=["balance_joint1", "mission_joint2"]),
        JointError,
        rf"joint 'mission_joint2' in {PAPER}: is named in two arms, 'mission' and 'balance'",
    ),
    "joint in two balance arms": (
        dict(balance=[B, ["balance_joint1"]]),
        JointError,
        r"joint 'balance_joint1' in .*: is named in two arms, 'balance' and 'balance2'",
    ),
    "fixed joint in an arm": (
        dict(mission=["mission_joint1", "mission_ee_fixed"]),
        JointError,
        (
            rf"joint 'mission_ee_fixed' in {PAPER}: is a fixed joint and cannot be an arm joint "
            r"\(arm 'mission'\)"
        ),
    ),
    "mission arm with no joints": (
        dict(mission=[]),
        ArmError,
        rf"arm 'mission' of {PAPER}: has no joints",
    ),
    "second balance arm with no joints": (
        dict(balance=[B, []]),
        ArmError,
        r"arm 'balance2' of .*: has no joints",
    ),
    "no balance arm": (dict(balance=[]), ArmError, r"arm 'balance' of .*: no balance arm given"),
    "arm given as a string": (
        dict(mission="mission_joint1"),
        ArmError,
        (
            r"arm 'mission' of .*: joints must be a list of joint names, got the string "
            r"'mission_joint1'"
        ),
    ),
    "unknown limit key": (
        dict(limits={"mission_joint2": {"snap": 3}}),
        JointError,
        (
            rf"joint 'mission_joint2' in {PAPER}: unknown limit 'snap'; expected one of lower, "
            r"upper, velocity, acceleration, effort, jerk"
        ),
    ),
    "limit for a joint in no arm": (
        dict(limits={"base_link": {"upper": 1}}),
        JointError,
        r"joint 'base_link' in .*: limit override for a joint that is in no arm",
    ),
    "lower limit above upper": (
        dict(limits={"balance_joint3": {"lower": 2.6}}),
        JointError,
        r"joint 'balance_joint3' in .*: lower limit 2.6 is above upper limit 2.5",
    ),
    "non-positive velocity limit": (
        dict(limits={"balance_joint3": {"velocity": 0}}),
        JointError,
        r"joint 'balance_joint3' in .*: velocity limit must be positive, got 0$",
    ),
    "unknown locked joint": (
        dict(mission=M[:2], locked={"mission_joint_3": 0.2}),
        JointError,
        (
            rf"joint 'mission_joint_3' in {PAPER}: locked joint is not in the URDF; "
            r"did you mean 'mission_joint3'"
        ),
    ),
    "locked arm joint": (
        dict(locked={"mission_joint3": 0.2}),
        JointError,
        r"joint 'mission_joint3' in .*: is both an arm joint and a locked joint",
    ),
    "locked fixed joint": (
        dict(locked={"balance_ee_fixed": 0.2}),
        JointError,
        r"joint 'balance_ee_fixed' in .*: is a fixed joint and cannot be locked",
    ),
    "locked position not a number": (
        dict(mission=M[:2], locked={"mission_joint3": "up"}),
        JointError,
        r"joint 'mission_joint3' in .*: locked position must be a number, got 'up'",
    ),
    "unknown end-effector frame": (
        dict(ee_frames={"mission": "mission_hand"}),
        ArmError,
        r"arm 'mission' of .*: end-effector frame 'mission_hand' is not a link",
    ),
    "end effector of a missing arm": (
        dict(ee_frames={"balance2": "balance_ee"}),
        ArmError,
        (
            r"arm 'balance2' of .*: end-effector frame given for an arm that does not "
            r"exist \(arms: mission, balance\)"
        ),
    ),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_input_errors_name_the_culprit(case):
    kwargs, error, message = ERRORS[case]
    with pytest.raises(error, match=message):
        _paper(**kwargs)


def test_an_unknown_joint_is_matched_against_movable_joints_only():
    """Panda's ``panda_joint8`` is fixed (no arm joint can be): not offered for a typo."""
    from balance_opt.model.library import example_urdf

    arm = [f"panda_joint{i}" for i in range(1, 8)]
    with pytest.raises(
        JointError,
        match=r"no such joint in the URDF \(arm 'balance'\); did you mean 'panda_joint7'",
    ) as caught:
        FloatingRobot(example_urdf("panda"), arm[:3], arm[3:6] + ["panda_jiont7"])
    assert "panda_joint8" not in str(caught.value)


def test_a_joint_locked_outside_its_limits_is_refused():
    """Panda's panda_joint4 ranges over [-3.0718, -0.0698] rad: locked at the default 0 (in no
    arm) or at a value given, the robot could not be there."""
    from balance_opt.model.library import example_urdf

    arm = [f"panda_joint{i}" for i in range(1, 8)]
    limits = r"outside its position limits \[-3\.0718, -0\.0698\] rad; lock it inside them"
    with pytest.raises(
        JointError,
        match=r"joint 'panda_joint4' in .*: is in no arm and locked at 0 rad \(the default\), "
        + limits,
    ):
        FloatingRobot(example_urdf("panda"), arm[:3], arm[4:])
    with pytest.raises(
        JointError, match=r"joint 'panda_joint4' in .*: locked at 0\.5 rad, " + limits
    ):
        FloatingRobot(example_urdf("panda"), arm[:3], arm[4:], locked={"panda_joint4": 0.5})
    held = FloatingRobot(example_urdf("panda"), arm[:3], arm[4:], locked={"panda_joint4": -1.5})
    assert held.locked["panda_joint4"] == -1.5


URDF_ERRORS = {
    "not XML": (
        '<robot name="x"><link name="a"></robot>',
        r"XML parse error: mismatched tag: line 1",
    ),
    "not a robot": ("<model/>", r"root element is <model>, expected <robot>"),
    "joint without child": (
        (
            '<robot name="x"><link name="a"/><joint name="j" type="fixed"><parent link="a"/>'
            "</joint></robot>"
        ),
        r"a <joint> lacks a name, parent or child",
    ),
    "mass not a number": (
        TOY_URDF.replace('<mass value="2.0"/>', '<mass value="two"/>'),
        r"link 'l1': <inertial> <mass value=...> is 'two', not a number",
    ),
    "missing child link": (
        TOY_URDF.replace('<child link="payload"/>', '<child link="cargo"/>'),
        r"joint 'slider': its child link 'cargo' is not a <link> of the file",
    ),
    "urdfdom rejects it": (
        TOY_URDF.replace(_LIMIT.format(lo=-2, hi=2, v=1.5, e=10), ""),
        (
            r"Pinocchio could not build a model: .*\(urdfdom: Joint \[r1_roll\] is of type "
            r"REVOLUTE but it does not specify limits"
        ),
    ),
}


@pytest.mark.parametrize("case", sorted(URDF_ERRORS))
@pytest.mark.parametrize("as_file", [True, False], ids=["file", "string"])
def test_urdf_errors_name_the_file(case, as_file, tmp_path):
    text, reason = URDF_ERRORS[case]
    urdf = _write(tmp_path, text) if as_file else text
    source = re.escape(str(urdf)) if as_file else "<URDF string>"
    with pytest.raises(URDFLoadError, match=rf"cannot load URDF {source}: {reason}"):
        FloatingRobot(urdf, TOY_ARMS["mission"], TOY_ARMS["balance"])


def test_missing_file_is_named(tmp_path):
    path = tmp_path / "nowhere" / "robot.urdf"
    with pytest.raises(
        URDFLoadError, match=rf"cannot load URDF {re.escape(str(path))}: no such file"
    ):
        FloatingRobot(path, M, B)
    with pytest.raises(
        URDFLoadError, match=rf"cannot load URDF {re.escape(str(path))}: no such file"
    ):
        FloatingRobot(str(path), M, B)
