"""The paper's robot (``urdf/paper_robot.urdf``) against Table 1, under the reading stated in
``urdf/paper_robot.md``: masses, inertias (with the parallel-axis transfers done here), link
lengths, mount points, joint axes and limits."""

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.model.library import shipped_urdf

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
