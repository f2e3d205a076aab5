"""URDF text of the paper's Table 1 robot under a chosen reading (:class:`Table1Reading`) of
what Table 1 leaves open: joint axes and mount points. Masses, lengths and central inertias are
Table 1's in every reading (link frames of ``urdf/paper_robot.md``)."""

from __future__ import annotations

from dataclasses import dataclass
from math import pi

#: Base: mass [kg], side of the cube [m], principal inertia [kg m^2] (Table 1).
BASE_MASS, BASE_SIDE, BASE_INERTIA = 300.0, 1.0, 50.0
#: Link length [m] and cylinder radius [m] (Table 1).
LINK_LENGTH, LINK_RADIUS = 0.5, 0.04
#: Per link: mass [kg], centre of mass in the link frame [m], central inertia diag [kg m^2]
#: (Table 1 read as in ``urdf/paper_robot.md``).
LINKS = (
    (5.0, (0.0, 0.0, 0.25), (0.1062, 0.1062, 0.16)),
    (5.0, (0.25, 0.0, 0.0), (0.004, 0.1062, 0.1062)),
    (5.5, (0.25, 0.0, 0.0), (0.0044, 0.1168, 0.1168)),
)
#: Joint origins in the parent link frame: xyz [m] and rpy [rad] (joint 1's is the mount).
JOINT2_ORIGIN = ((0.0, 0.0, LINK_LENGTH), (pi / 2, 0.0, 0.0))
JOINT3_ORIGIN = ((LINK_LENGTH, 0.0, 0.0), (0.0, 0.0, 0.0))
#: Position [rad], velocity [rad/s] and effort [N m] limits per joint (``paper_robot.md``).
LIMITS = ((2.9671, 1.0, 20.0), (1.5708, 1.0, 20.0), (2.5, 1.0, 20.0))
#: Link visuals and collision geometry (the same shapes): a cylinder along the link frame's z
#: (link 1) or x (links 2, 3); the base a cube.
_VISUAL_RPY = ("0 0 0", f"0 {pi / 2!r} 0", f"0 {pi / 2!r} 0")

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class ArmReading:
    """Where one arm sits on the base (joint 1's origin [m] and roll-pitch-yaw [rad] in the base
    frame, the base's centroid at the origin) and each joint's unit axis in its own frame."""

    mount_xyz: Vec3
    mount_rpy: Vec3
    axes: tuple[Vec3, Vec3, Vec3]


@dataclass(frozen=True)
class Table1Reading:
    """A reading of Table 1: a robot name and the mission and balance arms' mounts and axes."""

    name: str
    mission: ArmReading
    balance: ArmReading


_X = (1.0, 0.0, 0.0)
_Y = (0.0, 1.0, 0.0)
_Z = (0.0, 0.0, 1.0)

#: The shipped reading (``urdf/paper_robot.urdf``): yaw-pitch-pitch arms on the top face.
SHIPPED_READING = Table1Reading(
    "paper_robot",
    ArmReading((0.25, 0.0, 0.5), (0.0, 0.0, 0.0), (_Z, _Z, _Z)),
    ArmReading((-0.25, 0.0, 0.5), (0.0, 0.0, pi), (_Z, _Z, _Z)),
)

#: The reading chosen by the Fig. 5 study (``docs/paper_fig5_study.md``): each arm on the
#: centre of a side face, link 1 pointing out along the face normal; joint 1 turns about link 1's
#: x (transverse: the base's vertical), joint 2 about link 2's z (as shipped), joint 3 about
#: link 3's y (transverse, across joint 2's axis). The balance arm is the mission arm turned
#: half a turn about the base's y axis.
FIG5_READING = Table1Reading(
    "paper_robot_fig5",
    ArmReading((0.5, 0.0, 0.0), (0.0, pi / 2, 0.0), (_X, _Z, _Y)),
    ArmReading((-0.5, 0.0, 0.0), (0.0, -pi / 2, 0.0), (_X, _Z, _Y)),
)


def _num(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _link(name: str, k: int) -> str:
    mass, com, (ixx, iyy, izz) = LINKS[k]
    xyz = _num(com)
    return (
        f'  <link name="{name}">\n'
        f'    <inertial>\n      <origin xyz="{xyz}" rpy="0 0 0"/>\n'
        f'      <mass value="{mass!r}"/>\n'
        f'      <inertia ixx="{ixx!r}" ixy="0" ixz="0" iyy="{iyy!r}" iyz="0" izz="{izz!r}"/>\n'
        f"    </inertial>\n"
        + "".join(
            f'    <{tag}>\n      <origin xyz="{xyz}" rpy="{_VISUAL_RPY[k]}"/>\n'
            f'      <geometry><cylinder radius="{LINK_RADIUS!r}" length="{LINK_LENGTH!r}"/>'
            f"</geometry>\n    </{tag}>\n"
            for tag in ("visual", "collision")
        )
        + "  </link>\n"
    )


def _joint(name: str, parent: str, child: str, origin, axis: Vec3, limits) -> str:
    lower_upper, velocity, effort = limits
    return (
        f'  <joint name="{name}" type="revolute">\n'
        f'    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
        f'    <origin xyz="{_num(origin[0])}" rpy="{_num(origin[1])}"/>\n'
        f'    <axis xyz="{_num(axis)}"/>\n'
        f'    <limit lower="{-lower_upper!r}" upper="{lower_upper!r}" velocity="{velocity!r}" '
        f'effort="{effort!r}"/>\n  </joint>\n'
    )


def _arm(arm: str, reading: ArmReading) -> str:
    origins = ((reading.mount_xyz, reading.mount_rpy), JOINT2_ORIGIN, JOINT3_ORIGIN)
    parts = []
    parent = "base_link"
    for k in range(3):
        child = f"{arm}_link{k + 1}"
        parts.append(_link(child, k))
        parts.append(
            _joint(f"{arm}_joint{k + 1}", parent, child, origins[k], reading.axes[k], LIMITS[k])
        )
        parent = child
    parts.append(
        f'  <link name="{arm}_ee"/>\n  <joint name="{arm}_ee_fixed" type="fixed">\n'
        f'    <parent link="{parent}"/>\n    <child link="{arm}_ee"/>\n'
        f'    <origin xyz="{LINK_LENGTH!r} 0 0" rpy="0 0 0"/>\n  </joint>\n'
    )
    return "".join(parts)


def table1_urdf(reading: Table1Reading) -> str:
    """URDF text of the Table 1 robot under ``reading`` (see the module docstring)."""
    i = repr(BASE_INERTIA)
    base = (
        '  <link name="base_link">\n    <inertial>\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n'
        f'      <mass value="{BASE_MASS!r}"/>\n'
        f'      <inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/>\n'
        "    </inertial>\n"
        + "".join(
            f'    <{tag}>\n      <geometry><box size="{_num((BASE_SIDE,) * 3)}"/></geometry>\n'
            f"    </{tag}>\n"
            for tag in ("visual", "collision")
        )
        + "  </link>\n"
    )
    return (
        '<?xml version="1.0"?>\n'
        "<!-- The two-arm free-floating space robot of Huang, Xu & Liang, Table 1, generated by\n"
        f"     balance_opt.model.table1 (reading '{reading.name}'). -->\n"
        f'<robot name="{reading.name}">\n'
        + base
        + _arm("mission", reading.mission)
        + _arm("balance", reading.balance)
        + "</robot>\n"
    )
