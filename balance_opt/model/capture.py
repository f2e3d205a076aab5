"""Capturing a moving target (``docs/physics.md``, "Capture"): an inelastic impact that
attaches it rigidly to the mission end effector. :func:`attach_target` builds the robot after
the capture as a new URDF with the target as a fixed link, so every backend handles it
unchanged; :func:`capture_state` gives the momentum across the capture."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError
from balance_opt.model.meshes import resolved_urdf
from balance_opt.model.robot import FloatingRobot

#: Name of the target's link and of its fixed joint in the robot after the capture.
TARGET_LINK = "capture_target"
TARGET_JOINT = "capture_target_joint"


@dataclass(frozen=True)
class Target:
    """A rigid target captured by the mission end effector.

    Attributes:
        time: capture time [s].
        mass: its mass [kg].
        inertia: its inertia about its CoM (3, 3) [kg m^2], in the axes of the mission
            end-effector frame at the capture (where it stays attached).
        com: its CoM in the mission end-effector frame (3,) [m].
        linear_velocity: its CoM's velocity just before the capture, world frame (3,) [m/s].
        angular_velocity: its angular velocity just before, world frame (3,) [rad/s].
    """

    time: float
    mass: float
    inertia: np.ndarray
    com: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray

    def __post_init__(self):
        I = np.asarray(self.inertia, dtype=float)
        if I.shape == (6,):  # ixx, ixy, ixz, iyy, iyz, izz
            I = np.array([[I[0], I[1], I[2]], [I[1], I[3], I[4]], [I[2], I[4], I[5]]])
        object.__setattr__(self, "inertia", I)
        for name in ("com", "linear_velocity", "angular_velocity"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))
        if not self.mass > 0:
            raise InputError(f"target mass must be positive, got {self.mass}")
        if I.shape != (3, 3) or not np.allclose(I, I.T):
            raise InputError("target inertia must be a symmetric 3 x 3 matrix (or its 6 values)")
        eig = np.linalg.eigvalsh(I)
        if eig[0] <= 0 or eig[2] > eig[0] + eig[1] + 1e-12 * eig[2]:
            raise InputError(
                "target inertia is not physical: its principal moments "
                f"{', '.join(f'{e:.6g}' for e in eig)} kg m^2 must be positive and satisfy the "
                "triangle inequality"
            )

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The target's volume: side lengths (3,) [m] of the uniform box with its mass and
        inertia, and its principal axes (3, 3) in the mission end-effector frame (right-handed)."""
        moments, axes = np.linalg.eigh(self.inertia)
        equal = np.isclose(moments[:, None], moments[None, :], rtol=1e-9, atol=0.0)
        # equal moments leave the axes free within their plane (or all of them free): there the
        # box takes the end effector's axes, so that a cube's inertia gives the aligned cube
        if equal.all():
            axes = np.eye(3)
        elif equal.sum() == 5:
            odd = int(np.flatnonzero(equal.sum(axis=1) == 1)[0])
            a = axes[:, odd]
            e = np.eye(3)[np.argmin(np.abs(a))]
            b = (e - (e @ a) * a) / np.linalg.norm(e - (e @ a) * a)
            first, second = (i for i in range(3) if i != odd)
            axes[:, first], axes[:, second] = b, np.cross(a, b)
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1
        sides = np.sqrt(np.maximum(6.0 * (moments.sum() - 2.0 * moments) / self.mass, 0.0))
        return sides, axes


def _urdf_text(robot: FloatingRobot) -> str:
    """The robot's own URDF text (its file), or the locked one for a robot built from text."""
    path = Path(robot.source)
    if robot.source != "<URDF string>" and path.is_file():
        return path.read_text()
    if robot.followers:
        raise InputError("a robot with mimic joints built from URDF text cannot take a target")
    return robot.locked_urdf


def attached_urdf(robot: FloatingRobot, target: Target) -> str:
    """The robot's URDF with the target as the fixed link :data:`TARGET_LINK` under the mission
    end-effector link, origin at the target's CoM; its box is a ``<collision>`` element, or a
    ``<visual>`` one when the robot's geometry comes from visual elements."""
    # the new URDF is text of no file: its meshes are found now, from the robot's file (one
    # not found stays as it is: the geometry built from the new URDF names it)
    text = resolved_urdf(_urdf_text(robot), robot.source, robot.packages, strict=False)
    root = ET.fromstring(text)
    link = ET.SubElement(root, "link", name=TARGET_LINK)
    sides, axes = target.box()
    kind = "collision" if root.find("link/collision") is not None else "visual"
    volume = ET.SubElement(link, kind, name=TARGET_LINK)
    rpy = pin.rpy.matrixToRpy(axes)
    ET.SubElement(volume, "origin", xyz="0 0 0", rpy=" ".join(repr(float(v)) for v in rpy))
    size = " ".join(repr(float(v)) for v in sides)
    ET.SubElement(ET.SubElement(volume, "geometry"), "box", size=size)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=repr(float(target.mass)))
    I = target.inertia
    ET.SubElement(
        inertial,
        "inertia",
        **{
            k: repr(float(v))
            for k, v in zip(
                ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
                (I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]),
            )
        },
    )
    joint = ET.SubElement(root, "joint", name=TARGET_JOINT, type="fixed")
    ET.SubElement(joint, "parent", link=robot.mission.ee_frame)
    ET.SubElement(joint, "child", link=TARGET_LINK)
    ET.SubElement(joint, "origin", xyz=" ".join(repr(float(v)) for v in target.com), rpy="0 0 0")
    return ET.tostring(root, encoding="unicode")


def attach_target(robot: FloatingRobot, target: Target) -> FloatingRobot:
    """The robot after the capture: same arms, locks, limits and end-effector frames, with the
    target rigidly attached to the mission end effector."""
    keys = ("lower", "upper", "velocity", "acceleration", "effort")
    limits = {
        j: {k: float(getattr(robot.limits, k)[i]) for k in keys}
        for i, j in enumerate(robot.joint_names)
        if robot.joint_type(j) != "continuous"
    }
    balance = [list(arm.joints) for arm in robot.balance_arms]
    return FloatingRobot(
        attached_urdf(robot, target),
        list(robot.mission.joints),
        balance,
        locked=robot.locked,
        limits=limits,
        ee_frames={arm.name: arm.ee_frame for arm in robot.arms},
        packages=robot.packages,
        keep_out=robot.keep_out,
    )


@dataclass(frozen=True)
class CaptureState:
    """The system just before and just after the capture (joint motion continuous).

    Attributes:
        h_before, h_after: total momentum, world frame, [linear; angular about the CoM of the
            system of the moment] [N s; N m s] (before: the robot alone).
        h_target: the target's own momentum [linear; angular about its CoM], world frame.
        twist_before, twist_after: base twist [linear; angular], base frame [m/s; rad/s].
        target_com: the target's CoM relative to the base origin, world axes [m].
        ee_impulse: the impulse the target gives the mission end effector, base-frame axes,
            ``[linear (N s); angular about the end effector's origin (N m s)]``.
        base_impulse: ``N^{-T} ee_impulse`` (Eq. 25 in impulse form; Moore-Penrose with fewer
            than six arm joints), base frame [N s; N m s].
        base_momentum_jump: the base body's own momentum change ``I_b (v_after - v_before)``,
            base frame, angular part about the base origin [N s; N m s]: the impulse the arm's
            root joints give the base with the joints held through the impact.
    """

    h_before: np.ndarray
    h_after: np.ndarray
    h_target: np.ndarray
    twist_before: np.ndarray
    twist_after: np.ndarray
    target_com: np.ndarray
    ee_impulse: np.ndarray
    base_impulse: np.ndarray
    base_momentum_jump: np.ndarray

    def as_dict(self, t_c: float) -> dict:
        """The capture's numbers as plain data (a result's ``info["capture"]``)."""
        return {
            "time_s": float(t_c),
            "momentum_before": self.h_before.tolist(),
            "momentum_after": self.h_after.tolist(),
            "target_momentum": self.h_target.tolist(),
            "base_twist_before": self.twist_before.tolist(),
            "base_twist_after": self.twist_after.tolist(),
            "omega_jump": self.omega_jump.tolist(),
            "ee_impulse": self.ee_impulse.tolist(),
            "base_impulse_coupling": self.base_impulse.tolist(),
            "base_momentum_jump": self.base_momentum_jump.tolist(),
        }

    @property
    def omega_jump(self) -> np.ndarray:
        """Jump of the base angular velocity, base frame (3,) [rad/s]."""
        return self.twist_after[3:] - self.twist_before[3:]


def _to_base(R: np.ndarray, h: np.ndarray) -> np.ndarray:
    return np.r_[R.T @ h[:3], R.T @ h[3:]]


def capture_state(
    robot: FloatingRobot,
    after: FloatingRobot,
    target: Target,
    q,
    q_dot,
    quaternion,
    h_before,
) -> CaptureState:
    """The momentum and base twists across the capture: the target's momentum about the common
    CoM adds to the robot's (reduced mass ``mu = m_r m_t / (m_r + m_t)``:
    ``L_after = L_r + I_t omega_t + mu (c_t - c_r) x (v_t - p_r / m_r)``, ``p_after = p_r +
    m_t v_t``); the joint rates do not jump, the base twists solve ``A_G v = R^T h``.

    Args:
        robot, after: the robot before and after the capture (:func:`attach_target`).
        target: the target.
        q, q_dot: arm positions and rates at the capture [rad, rad/s].
        quaternion: base attitude (x, y, z, w) at the capture.
        h_before: the robot's momentum before, world frame (6,).
    """
    from balance_opt.model.maps import NumericMaps

    q, q_dot = np.asarray(q, dtype=float), np.asarray(q_dot, dtype=float)
    h_before = np.asarray(h_before, dtype=float)
    R = pin.Quaternion(np.asarray(quaternion, dtype=float)).matrix()  # (x, y, z, w), as so3
    base = pin.SE3(R, np.zeros(3))
    model, data = robot.model, robot.model.createData()
    qp = robot.pin_q(q, base)
    c_r = pin.centerOfMass(model, data, qp)
    pin.framesForwardKinematics(model, data, qp)
    ee = data.oMf[model.getFrameId(robot.mission.ee_frame)]
    c_t = ee.act(target.com)
    I_t = ee.rotation @ target.inertia @ ee.rotation.T
    m_r, m_t = robot.total_mass, target.mass
    mu = m_r * m_t / (m_r + m_t)
    v_t, w_t = target.linear_velocity, target.angular_velocity
    h_target = np.r_[m_t * v_t, I_t @ w_t]
    rel = np.cross(c_t - c_r, v_t - h_before[:3] / m_r)
    h_after = np.r_[h_before[:3] + h_target[:3], h_before[3:] + h_target[3:] + mu * rel]
    maps = NumericMaps(robot)
    twist_before = maps.base_twist(q, q_dot, _to_base(R, h_before))
    twist_after = NumericMaps(after).base_twist(q, q_dot, _to_base(R, h_after))
    # the end effector's twist after (world axes), which the target takes
    pin.forwardKinematics(model, data, qp, robot.pin_v(q_dot, twist_after))
    v_ee = pin.getFrameVelocity(
        model, data, model.getFrameId(robot.mission.ee_frame), pin.LOCAL_WORLD_ALIGNED
    )
    arm = c_t - ee.translation
    dp = m_t * (v_ee.linear + np.cross(v_ee.angular, arm) - v_t)
    dL = I_t @ (v_ee.angular - w_t)
    impulse = _to_base(R, np.r_[-dp, -dL + np.cross(arm, -dp)])
    base_impulse = maps.force_map(q, impulse)
    jump = model.inertias[1].matrix() @ (twist_after - twist_before)
    return CaptureState(
        h_before, h_after, h_target, twist_before, twist_after, c_t, impulse, base_impulse, jump
    )
