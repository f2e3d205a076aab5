"""The paper's robot (``urdf/paper_robot.urdf``) against Table 1, under the reading stated in
``urdf/paper_robot.md``: masses, inertias (with the parallel-axis transfers done here), link
lengths, mount points, joint axes and limits; the Table 1 builder and the second reading
(``urdf/paper_robot_fig5.urdf``); and the paper's law on ``examples/paper_fig5.yaml``, checked
against an attitude this file recomputes itself."""

import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.interpolate import CubicSpline

from balance_opt.app.scenarios import capture_task, paper_fig5
from balance_opt.model.library import (
    PAPER_FIG5_ROBOT,
    paper_robot_fig5,
    shipped_urdf,
    table1_robot,
)
from balance_opt.model.maps import NumericMaps
from balance_opt.model.table1 import FIG5_READING, SHIPPED_READING, table1_urdf

#: Tolerance where no rounding is involved (float arithmetic only).
EXACT_ATOL = 1e-12
#: Table 1 and the URDF print inertias to 4 decimals [kg m^2]: one unit of the last decimal,
#: since a rounded central value transferred by m (L/2)^2 and rounded again may differ by up to
#: twice half a unit (link 3: 0.1168 + 5.5 * 0.25^2 = 0.46055, printed 0.4606).
ROUNDING_ATOL = 1e-4

RADIUS = 0.04  # [m], Table 1
LENGTH = 0.5  # [m], Table 1
BASE_MASS = 300.0  # [kg]
BASE_INERTIA = (50.0, 50.0, 50.0)  # [kg m^2]

#: Table 1 per link: mass [kg] and (Ixx, Iyy, Izz) [kg m^2] as printed.
TABLE_1 = {
    1: (5.0, (0.4187, 0.4187, 0.16)),
    2: (5.0, (0.004, 0.1062, 0.4187)),
    3: (5.5, (0.0044, 0.1168, 0.4606)),
}
#: The reading (paper_robot.md): each Table 1 value is taken about the link's centre of mass
#: ("centre") or about the origin of its proximal joint ("joint"), axes of the link frame.
READING = {
    1: ("joint", "joint", "joint"),  # Izz about the link axis: the same through both points
    2: ("centre", "centre", "joint"),  # Ixx axial, Iyy central, Izz about the pitch axis
    3: ("centre", "centre", "joint"),
}
#: Centre of mass of each link in its frame [m]: the middle of the link.
LINK_COM = {1: (0.0, 0.0, LENGTH / 2), 2: (LENGTH / 2, 0.0, 0.0), 3: (LENGTH / 2, 0.0, 0.0)}

ARMS = ("mission", "balance")
N_RANDOM = 20


def _joint_id(model, arm, k):
    return model.getJointId(f"{arm}_joint{k}")


def _inertia_about_origin(inertia: pin.Inertia) -> np.ndarray:
    """Rotational inertia about the joint frame's origin: I_c + m (|c|^2 1 - c c^T)."""
    c = inertia.lever
    return inertia.inertia + inertia.mass * (c @ c * np.eye(3) - np.outer(c, c))


@pytest.fixture(scope="module")
def urdf_links():
    """{link name: (mass, com xyz, (ixx, iyy, izz, ixy, ixz, iyz))} read from the URDF text."""
    root = ET.parse(shipped_urdf()).getroot()
    out = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        origin = inertial.find("origin")
        assert origin.get("rpy", "0 0 0").split() == ["0", "0", "0"], link.get("name")
        inertia = inertial.find("inertia")
        out[link.get("name")] = (
            float(inertial.find("mass").get("value")),
            np.array([float(v) for v in origin.get("xyz").split()]),
            tuple(float(inertia.get(k)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")),
        )
    return out


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize("k", [1, 2, 3])
def test_link_mass_and_inertia_match_table_1(paper, arm, k):
    inertia = paper.model.inertias[_joint_id(paper.model, arm, k)]
    mass, table = TABLE_1[k]
    assert inertia.mass == pytest.approx(mass, abs=EXACT_ATOL)
    np.testing.assert_allclose(inertia.lever, LINK_COM[k], rtol=0, atol=EXACT_ATOL)
    central = inertia.inertia
    about_joint = _inertia_about_origin(inertia)
    np.testing.assert_allclose(central - np.diag(np.diag(central)), 0, rtol=0, atol=EXACT_ATOL)
    read = [
        about_joint[i, i] if about == "joint" else central[i, i]
        for i, about in enumerate(READING[k])
    ]
    np.testing.assert_allclose(read, table, rtol=0, atol=ROUNDING_ATOL)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_central_inertias_are_the_cylinder_of_table_1(paper, k):
    """Transverse central inertia m(3r^2+L^2)/12 for every link, axial m r^2/2 for links 2, 3
    (link 1's Izz = 0.16 fits no cylinder and is taken as given: paper_robot.md)."""
    inertia = paper.model.inertias[_joint_id(paper.model, "mission", k)]
    m = TABLE_1[k][0]
    transverse = m * (3 * RADIUS**2 + LENGTH**2) / 12
    axial = m * RADIUS**2 / 2
    expected = (
        (transverse, transverse, TABLE_1[1][1][2]) if k == 1 else (axial, transverse, transverse)
    )
    np.testing.assert_allclose(np.diag(inertia.inertia), expected, rtol=0, atol=ROUNDING_ATOL)
    # and about the proximal joint, the cylinder's m(r^2/4 + L^2/3)
    about_joint = np.diag(_inertia_about_origin(inertia))
    proximal = m * (RADIUS**2 / 4 + LENGTH**2 / 3)
    np.testing.assert_allclose(
        about_joint[[0, 1] if k == 1 else [1, 2]], proximal, rtol=0, atol=ROUNDING_ATOL
    )


def test_base_mass_and_inertia(paper):
    base = paper.model.inertias[paper.model.getJointId("root_joint")]
    assert base.mass == pytest.approx(BASE_MASS, abs=EXACT_ATOL)
    np.testing.assert_allclose(base.lever, 0, rtol=0, atol=EXACT_ATOL)
    np.testing.assert_allclose(base.inertia, np.diag(BASE_INERTIA), rtol=0, atol=EXACT_ATOL)
    # a uniform cube of side 1 m: m s^2 / 6
    assert BASE_INERTIA[0] == pytest.approx(BASE_MASS * 1.0**2 / 6, abs=EXACT_ATOL)


def test_total_mass_is_331_kg(paper, urdf_links):
    assert paper.total_mass == pytest.approx(331.0, abs=EXACT_ATOL)
    assert sum(m for m, _, _ in urdf_links.values()) == pytest.approx(331.0, abs=EXACT_ATOL)


def test_pinocchio_reads_the_urdf_inertias(paper, urdf_links):
    model = paper.model
    for name, (mass, com, (ixx, iyy, izz, ixy, ixz, iyz)) in urdf_links.items():
        frame = model.frames[model.getFrameId(name, pin.BODY)]
        inertia = model.inertias[frame.parentJoint]
        assert frame.placement.isIdentity(), name  # every massive link is a joint's child
        assert inertia.mass == pytest.approx(mass, abs=EXACT_ATOL), name
        np.testing.assert_allclose(inertia.lever, com, rtol=0, atol=EXACT_ATOL, err_msg=name)
        expected = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        np.testing.assert_allclose(inertia.inertia, expected, rtol=0, atol=EXACT_ATOL, err_msg=name)


def test_inertias_are_physically_consistent(paper):
    for jid in range(1, paper.model.njoints):
        inertia = paper.model.inertias[jid]
        principal = np.linalg.eigvalsh(inertia.inertia)
        assert inertia.mass > 0
        assert principal.min() > 0, paper.model.names[jid]
        a, b, c = principal
        assert a + b >= c and a + c >= b and b + c >= a, paper.model.names[jid]


# Joint origins, axes (world = base frame at the identity) and end effectors at q = 0 [m].
HOME = {
    "mission": {
        "origins": [(0.25, 0, 0.5), (0.25, 0, 1.0), (0.75, 0, 1.0)],
        "axes": [(0, 0, 1), (0, -1, 0), (0, -1, 0)],
        "ee": (1.25, 0, 1.0),
    },
    "balance": {
        "origins": [(-0.25, 0, 0.5), (-0.25, 0, 1.0), (-0.75, 0, 1.0)],
        "axes": [(0, 0, 1), (0, 1, 0), (0, 1, 0)],
        "ee": (-1.25, 0, 1.0),
    },
}


def _kinematics(robot, q):
    """Joint origins, joint axes (world) and end-effector positions, keyed by arm."""
    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, robot.pin_q(q))
    pin.updateFramePlacements(model, data)
    out = {}
    for arm in ARMS:
        origins, axes = [], []
        for k in (1, 2, 3):
            jid = _joint_id(model, arm, k)
            origins.append(data.oMi[jid].translation.copy())
            J = pin.getJointJacobian(model, data, jid, pin.LOCAL_WORLD_ALIGNED)
            axes.append(J[3:, model.joints[jid].idx_v].copy())  # angular velocity per unit rate
        ee = data.oMf[model.getFrameId(f"{arm}_ee")].translation.copy()
        out[arm] = (np.array(origins), np.array(axes), ee, data)
    return out


def test_mount_points_axes_and_end_effectors_at_home(paper):
    for arm, (origins, axes, ee, _) in _kinematics(paper, np.zeros(paper.n)).items():
        np.testing.assert_allclose(
            origins, HOME[arm]["origins"], rtol=0, atol=EXACT_ATOL, err_msg=arm
        )
        np.testing.assert_allclose(axes, HOME[arm]["axes"], rtol=0, atol=EXACT_ATOL, err_msg=arm)
        np.testing.assert_allclose(ee, HOME[arm]["ee"], rtol=0, atol=EXACT_ATOL, err_msg=arm)
        assert paper.arm(arm).ee_frame == f"{arm}_ee"


def test_link_lengths_and_yaw_pitch_pitch_axes_at_random_configurations(paper):
    rng = np.random.default_rng(20240611)
    for _ in range(N_RANDOM):
        q = rng.uniform(paper.limits.lower, paper.limits.upper)
        for arm, (origins, axes, ee, data) in _kinematics(paper, q).items():
            points = np.vstack([origins, ee])
            np.testing.assert_allclose(
                np.linalg.norm(np.diff(points, axis=0), axis=1),
                LENGTH,
                rtol=0,
                atol=EXACT_ATOL,
                err_msg=arm,
            )
            # the yaw axis stays the base's +z; the pitch axes are horizontal and parallel
            np.testing.assert_allclose(axes[0], (0, 0, 1), rtol=0, atol=EXACT_ATOL)
            assert axes[0] @ axes[1] == pytest.approx(0, abs=EXACT_ATOL)
            np.testing.assert_allclose(axes[1], axes[2], rtol=0, atol=EXACT_ATOL)
            # links 2 and 3 move in the plane normal to the pitch axes
            for a, b in ((1, 2), (2, 3)):
                assert axes[1] @ (points[b] - points[a]) == pytest.approx(0, abs=EXACT_ATOL)
            # each link's centre of mass is the middle of the link
            for k in (1, 2, 3):
                jid = _joint_id(paper.model, arm, k)
                com = data.oMi[jid].act(paper.model.inertias[jid].lever)
                np.testing.assert_allclose(
                    com, (points[k - 1] + points[k]) / 2, rtol=0, atol=EXACT_ATOL
                )


LIMITS = {1: (2.9671, 1.0, 20.0), 2: (1.5708, 1.0, 20.0), 3: (2.5, 1.0, 20.0)}


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize("k", [1, 2, 3])
def test_joint_limits(paper, arm, k):
    i = paper.joint_index(f"{arm}_joint{k}")
    position, velocity, effort = LIMITS[k]
    lim = paper.limits
    assert (lim.lower[i], lim.upper[i]) == (-position, position)
    assert (lim.velocity[i], lim.effort[i]) == (velocity, effort)
    assert np.isinf(lim.acceleration[i])  # URDF has none: tasks set them


# ------------------------------------------------------------------------------ other readings
def _same_model(a, b):
    """Two Pinocchio models with the same bodies, joint placements and joint axes."""
    assert [n for n in a.names] == [n for n in b.names]
    for jid in range(1, a.njoints):
        ia, ib = a.inertias[jid], b.inertias[jid]
        assert ia.mass == ib.mass, a.names[jid]
        np.testing.assert_array_equal(ia.lever, ib.lever)
        np.testing.assert_array_equal(ia.inertia, ib.inertia)
        np.testing.assert_allclose(
            a.jointPlacements[jid].homogeneous, b.jointPlacements[jid].homogeneous, atol=1e-15
        )
        assert a.joints[jid].shortname() == b.joints[jid].shortname(), a.names[jid]


def test_builder_reproduces_the_shipped_reading(paper):
    """table1_urdf under the shipped reading is the shipped URDF, number for number."""
    _same_model(table1_robot(SHIPPED_READING).model, paper.model)
    rng = np.random.default_rng(7)
    built = table1_robot(SHIPPED_READING)
    for _ in range(5):
        q = rng.uniform(paper.limits.lower, paper.limits.upper)
        for arm, (origins, axes, ee, _) in _kinematics(built, q).items():
            ref = _kinematics(paper, q)[arm]
            np.testing.assert_allclose(origins, ref[0], rtol=0, atol=EXACT_ATOL)
            np.testing.assert_allclose(axes, ref[1], rtol=0, atol=EXACT_ATOL)
            np.testing.assert_allclose(ee, ref[2], rtol=0, atol=EXACT_ATOL)


def test_fig5_urdf_is_the_builders_output_with_table_1_bodies(paper):
    assert shipped_urdf(PAPER_FIG5_ROBOT).read_text() == table1_urdf(FIG5_READING)
    fig5 = paper_robot_fig5()
    for jid in range(1, paper.model.njoints):  # same bodies: only mounts and axes differ
        a, b = paper.model.inertias[jid], fig5.model.inertias[jid]
        assert (a.mass, a.lever.tolist(), a.inertia.tolist()) == (
            b.mass,
            b.lever.tolist(),
            b.inertia.tolist(),
        )
    assert fig5.total_mass == pytest.approx(331.0, abs=EXACT_ATOL)


def test_capture_task_starts_at_an_exactly_singular_j_wb():
    """The comment of examples/capture_task.yaml: J_wB's singular values at its start."""
    scenario = capture_task()
    _, J_wB = NumericMaps(scenario.robot).angular_jacobians(scenario.q0)
    s = np.linalg.svd(J_wB, compute_uv=False)
    np.testing.assert_allclose(s[:2], (0.090, 0.059), rtol=0, atol=6e-4)
    assert s[2] < 1e-15


# ------------------------------------------------------------------------------ Fig. 5
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: What the paper's Fig. 5 shows, asked of the law: final attitude error at least this many
#: times below the mission arm's alone.
FIG5_RATIO = 20.0
#: Balance joint limits of examples/paper_fig5.yaml: rate [rad/s] (URDF), acceleration [rad/s^2].
RATE_LIMIT, ACCELERATION_LIMIT = 1.0, 2.0


def _independent_attitude(robot, t, q):
    """Base rotation angle at the end [rad] and the base rates (T, 3) [rad/s] of an arm motion
    ``q`` (T, n) sampled at ``t``, recomputed here: joint rates from a cubic spline of the
    positions, the base rate from zero angular momentum with Pinocchio's centroidal map, the
    attitude by midpoint steps of the exponential map."""
    rates = CubicSpline(t, q)(t, 1)
    model, data = robot.model, robot.model.createData()
    omega = np.empty((len(t), 3))
    for k in range(len(t)):
        A = pin.computeCentroidalMap(model, data, robot.pin_q(q[k]))[3:]  # angular rows
        omega[k] = -np.linalg.solve(A[:, 3:6], A @ robot.pin_v(rates[k]))
    R = np.eye(3)
    for k in range(len(t) - 1):
        R = R @ pin.exp3((t[k + 1] - t[k]) * (omega[k] + omega[k + 1]) / 2)
    return float(np.linalg.norm(pin.log3(R))), omega


@pytest.fixture(scope="module")
def fig5():
    from balance_opt.app.pipeline import plan_analytic, plan_mission_only
    from balance_opt.tasks.task import load_task

    task = load_task(EXAMPLES / "paper_fig5.yaml")
    return task, plan_analytic(task), plan_mission_only(task)


def test_paper_fig5_example_is_the_scenario(fig5):
    task, _, _ = fig5
    scenario = paper_fig5()
    assert task.robot.name == scenario.robot.name == FIG5_READING.name
    np.testing.assert_array_equal(task.q_B0, scenario.q_B0)
    np.testing.assert_array_equal(task.mission.start, scenario.mission.start)
    np.testing.assert_array_equal(task.mission.end, scenario.mission.end)
    assert task.mission.duration == scenario.mission.duration
    assert replace(task.spec.analytic.law, h0=None) == scenario.law  # the task sets h0 = 0
    assert task.spec.analytic.law.damping_threshold == 0  # exact Eq. 31, no damping


def test_paper_law_does_what_fig5_shows(fig5):
    """Exact Eq. 31 leaves the base at least 20 times closer to its start than the mission arm
    alone, by an attitude recomputed here from the positions alone."""
    task, law, alone = fig5
    q_law = np.hstack([law.q_M, law.q_B])
    q_alone = np.hstack([alone.q_M, alone.q_B])
    drift_law, omega_law = _independent_attitude(task.robot, law.t, q_law)
    drift_alone, _ = _independent_attitude(task.robot, alone.t, q_alone)
    assert drift_alone > 0.02  # a disturbance Fig. 2 shows (over 1 degree)
    assert drift_alone / drift_law >= FIG5_RATIO, (drift_alone, drift_law)
    # the recomputation agrees with each rollout's own attitude
    assert drift_alone == pytest.approx(alone.final_drift, rel=1e-3)
    assert drift_law <= law.final_drift + 1e-4
    assert np.abs(omega_law).max() < 1e-3 * np.abs(alone.omega).max() + 1e-6


def test_paper_law_holds_the_balance_arms_limits_on_fig5(fig5):
    """Positions, rates and accelerations of the law's balance motion, differentiated here."""
    task, law, _ = fig5
    spline = CubicSpline(law.t, law.q_B)
    lim = task.robot.limits
    B = task.robot.balance_indices
    assert np.all(law.q_B >= lim.lower[B]) and np.all(law.q_B <= lim.upper[B])
    assert np.abs(spline(law.t, 1)).max() <= RATE_LIMIT
    assert np.abs(spline(law.t, 2)).max() <= ACCELERATION_LIMIT
    assert law.violations == []


def test_fig5_reading_at_home_is_as_its_file_says():
    """urdf/paper_robot_fig5.md: mounts, axes and the direction of the links at q = 0."""
    robot = paper_robot_fig5()
    kin = _kinematics(robot, np.zeros(robot.n))
    expected = {  # joint 1 origin, axes of joints 1-3, end effector (base frame, q = 0)
        "mission": ((0.5, 0, 0), [(0, 0, -1), (0, -1, 0), (1, 0, 0)], (1.0, 0, -1.0)),
        "balance": ((-0.5, 0, 0), [(0, 0, 1), (0, -1, 0), (-1, 0, 0)], (-1.0, 0, 1.0)),
    }
    for arm, (origin, axes, ee) in expected.items():
        origins, got_axes, got_ee, _ = kin[arm]
        np.testing.assert_allclose(origins[0], origin, rtol=0, atol=EXACT_ATOL)
        np.testing.assert_allclose(got_axes, axes, rtol=0, atol=EXACT_ATOL, err_msg=arm)
        np.testing.assert_allclose(got_ee, ee, rtol=0, atol=EXACT_ATOL, err_msg=arm)
