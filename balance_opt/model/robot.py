"""Floating-base robot model: a URDF with a free-flyer root, arms assigned by joint names.

The robot's *arm vector* ``q`` (and ``q_dot``, ``q_ddot``) holds the joints of every arm in the
order the user named them: the mission arm first, then each balance arm. Every other movable
joint is locked at a fixed position. Pinocchio orders joints differently (depth-first over the
kinematic tree), so conversions always go through joint names, never through positions.

Two views of the same robot are kept:

* ``robot.model``: a numeric Pinocchio model (free-flyer root, zero gravity) reduced by
  ``pin.buildReducedModel`` with the locked joints at their positions;
* ``robot.locked_urdf``: the URDF text with each locked joint turned into a fixed joint whose
  origin holds the locked position; symbolic backends (adam) are built from it.

Building the two by different routes is deliberate: the tests compare them.
"""

from __future__ import annotations

import difflib
import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from balance_opt.errors import ArmError, JointError, URDFLoadError

MOVABLE_TYPES = ("revolute", "continuous", "prismatic")
LIMIT_KEYS = ("lower", "upper", "velocity", "acceleration", "effort")


@dataclass(frozen=True)
class JointLimits:
    """Limits of the arm joints, in arm order.

    Attributes:
        lower: lowest position [rad or m] (``-inf`` for continuous joints).
        upper: highest position [rad or m].
        velocity: largest speed [rad/s or m/s].
        acceleration: largest acceleration [rad/s^2]; URDF has none, so ``inf`` unless set.
        effort: largest torque [N m] or force [N].
    """

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    effort: np.ndarray

    def subset(self, indices) -> JointLimits:
        """The limits of the joints at ``indices`` of the arm vector."""
        return JointLimits(*(getattr(self, k)[indices] for k in LIMIT_KEYS))


@dataclass(frozen=True)
class Arm:
    """One arm: its role, its joints (in the user's order) and its end-effector frame.

    Attributes:
        name: ``"mission"``, or the balance arm's name (``"balance"``, ``"balance2"``, ...).
        joints: joint names in the order the user gave.
        indices: positions of these joints in the robot's arm vector.
        ee_frame: name of the end-effector frame (a URDF link).
    """

    name: str
    joints: tuple[str, ...]
    indices: np.ndarray = field(repr=False)
    ee_frame: str

    @property
    def dof(self) -> int:
        return len(self.joints)


@dataclass(frozen=True)
class _UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    element: ET.Element = field(repr=False)


def _read_urdf(urdf: str | Path) -> tuple[str, str]:
    """Return (text, source name) for a URDF given as a path or as XML text."""
    if isinstance(urdf, Path) or not str(urdf).lstrip().startswith("<"):
        path = Path(urdf)
        if not path.is_file():
            raise URDFLoadError(str(path), "no such file")
        try:
            return path.read_text(), str(path)
        except (OSError, UnicodeDecodeError) as exc:
            raise URDFLoadError(str(path), str(exc)) from exc
    return str(urdf), "<URDF string>"


def _parse_joints(text: str, source: str) -> tuple[ET.Element, dict[str, _UrdfJoint]]:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise URDFLoadError(source, f"XML parse error: {exc}") from exc
    if root.tag != "robot":
        raise URDFLoadError(source, f"root element is <{root.tag}>, expected <robot>")
    joints: dict[str, _UrdfJoint] = {}
    for el in root.findall("joint"):
        name = el.get("name")
        parent, child = el.find("parent"), el.find("child")
        if name is None or parent is None or child is None:
            raise URDFLoadError(
                source, f"a <joint> lacks a name, parent or child: {ET.tostring(el)[:80]!r}"
            )
        joints[name] = _UrdfJoint(
            name, el.get("type", ""), parent.get("link"), child.get("link"), el
        )
    _check_inertials(root, source)
    return root, joints


def _check_inertials(root: ET.Element, source: str) -> None:
    """Raise if a link's mass, inertia or inertial origin is not a number: urdfdom (under
    Pinocchio) drops such an ``<inertial>`` with a message on stderr and loads the link
    massless, which would silently change every momentum map."""
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        fields = [("mass", "value")] + [
            ("inertia", k) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        ]
        for tag, attr in fields:
            el = inertial.find(tag)
            text = None if el is None else el.get(attr)
            try:
                float(text)
            except (TypeError, ValueError):
                raise URDFLoadError(
                    source,
                    f"link '{link.get('name')}': <inertial> <{tag} {attr}=...> "
                    f"is {text!r}, not a number",
                ) from None
        origin = inertial.find("origin")
        for attr in ("xyz", "rpy"):
            text = "0 0 0" if origin is None else origin.get(attr, "0 0 0")
            try:
                ok = len([float(v) for v in text.split()]) == 3
            except ValueError:
                ok = False
            if not ok:
                raise URDFLoadError(
                    source,
                    f"link '{link.get('name')}': <inertial> <origin {attr}=...> "
                    f"is {text!r}, not three numbers",
                )


def _origin(el: ET.Element) -> pin.SE3:
    origin = el.find("origin")
    xyz = np.zeros(3)
    rpy = np.zeros(3)
    if origin is not None:
        xyz = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()])
        rpy = np.array([float(v) for v in origin.get("rpy", "0 0 0").split()])
    return pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)


def _axis(el: ET.Element) -> np.ndarray:
    axis = el.find("axis")
    vec = (
        np.array([1.0, 0.0, 0.0])
        if axis is None
        else np.array([float(v) for v in axis.get("xyz", "1 0 0").split()])
    )
    return vec / np.linalg.norm(vec)


def _lock_joints(
    root: ET.Element, joints: dict[str, _UrdfJoint], locked: Mapping[str, float]
) -> str:
    """URDF text in which each locked joint is a fixed joint at its locked position."""
    root = ET.fromstring(ET.tostring(root))  # work on a copy
    by_name = {el.get("name"): el for el in root.findall("joint")}
    for name, value in locked.items():
        el = by_name[name]
        motion = (
            pin.SE3(np.eye(3), _axis(el) * value)
            if joints[name].type == "prismatic"
            else pin.SE3(pin.exp3(_axis(el) * value), np.zeros(3))
        )
        placement = _origin(el) * motion
        rpy = pin.rpy.matrixToRpy(placement.rotation)
        for tag in ("origin", "axis", "limit", "mimic", "dynamics", "safety_controller"):
            for child in el.findall(tag):
                el.remove(child)
        el.set("type", "fixed")
        ET.SubElement(
            el,
            "origin",
            xyz=" ".join(repr(float(v)) for v in placement.translation),
            rpy=" ".join(repr(float(v)) for v in rpy),
        )
    return ET.tostring(root, encoding="unicode")


def _suggest(name: str, candidates) -> str:
    close = difflib.get_close_matches(name, list(candidates), n=3)
    return f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""


class FloatingRobot:
    """A URDF robot on a free-flying base, with one mission arm and one or more balance arms.

    Args:
        urdf: path to a URDF file, or the URDF's XML text.
        mission: joint names of the mission arm.
        balance: joint names of the balance arm, or a list of such lists for several balance arms.
        locked: positions of locked joints [rad or m]; every movable joint that is in no arm and
            not named here is locked at 0.
        limits: overrides of joint limits, ``{joint: {"lower": ..., "upper": ..., "velocity": ...,
            "acceleration": ..., "effort": ...}}``; keys left out keep the URDF's value.
        ee_frames: end-effector frame per arm name (``"mission"``, ``"balance"``, ``"balance2"``
            ...); by default the last link reached from the arm's most distal joint (the
            deepest in the kinematic tree, whatever the order the joints were named in) through
            fixed joints, while that chain does not branch.

    Raises:
        URDFLoadError: the URDF cannot be read, parsed or loaded by Pinocchio.
        JointError: a joint is unknown, named twice, in two arms, fixed, or of an unsupported
            type; a lock or a limit override names a wrong joint or key.
        ArmError: an arm has no joints, or a named end-effector frame does not exist.
    """

    def __init__(
        self,
        urdf: str | Path,
        mission: Sequence[str],
        balance: Sequence[str] | Sequence[Sequence[str]],
        locked: Mapping[str, float] | None = None,
        limits: Mapping[str, Mapping[str, float]] | None = None,
        ee_frames: Mapping[str, str] | None = None,
    ):
        text, self.source = _read_urdf(urdf)
        root, self._urdf_joints = _parse_joints(text, self.source)
        self.name = root.get("name", "robot")

        for arm, joints in (("mission", mission), ("balance", balance)):
            if isinstance(joints, str):  # list("j1") would be the joints 'j', '1'
                raise ArmError(
                    arm,
                    self.source,
                    f"joints must be a list of joint names, got the string {joints!r}",
                )
        balance_lists = (
            [list(balance)]
            if balance and isinstance(balance[0], str)
            else [list(b) for b in balance]
        )
        if not balance_lists:
            raise ArmError("balance", self.source, "no balance arm given")
        arm_specs = [("mission", list(mission))]
        for k, joints in enumerate(balance_lists):
            arm_specs.append(("balance" if k == 0 else f"balance{k + 1}", joints))
        self._check_arm_joints(arm_specs)

        self.joint_names: tuple[str, ...] = tuple(j for _, js in arm_specs for j in js)
        self.locked = self._check_locked(locked or {})
        self.locked_urdf = _lock_joints(root, self._urdf_joints, self.locked)

        self.model, self.full_model = self._build_pinocchio(text)

        self._joint_ids = [self.model.getJointId(j) for j in self.joint_names]
        self._pin_idx_q = np.array([self.model.joints[i].idx_q for i in self._joint_ids])
        self._pin_idx_v = np.array([self.model.joints[i].idx_v for i in self._joint_ids])
        self._pin_nq = np.array([self.model.joints[i].nq for i in self._joint_ids])

        ee_frames = dict(ee_frames or {})
        self.arms: tuple[Arm, ...] = tuple(self._make_arms(arm_specs, ee_frames))
        unknown_arms = set(ee_frames) - {a.name for a in self.arms}
        if unknown_arms:
            name = sorted(unknown_arms)[0]
            raise ArmError(
                name,
                self.source,
                f"end-effector frame given for an arm that does not exist "
                f"(arms: {', '.join(a.name for a in self.arms)})",
            )
        self.limits = self._make_limits(limits or {})

    # ----------------------------------------------------------------------------- checks
    def _check_arm_joints(self, arm_specs) -> None:
        owner: dict[str, str] = {}
        for arm, joints in arm_specs:
            if not joints:
                raise ArmError(arm, self.source, "has no joints")
            for j in joints:
                if not isinstance(j, str):
                    raise ArmError(arm, self.source, f"joint names must be strings, got {j!r}")
                if j not in self._urdf_joints:
                    raise JointError(
                        j,
                        self.source,
                        f"no such joint in the URDF (arm '{arm}')" + _suggest(j, self._urdf_joints),
                    )
                jtype = self._urdf_joints[j].type
                if jtype == "fixed":
                    raise JointError(
                        j, self.source, f"is a fixed joint and cannot be an arm joint (arm '{arm}')"
                    )
                if jtype not in MOVABLE_TYPES:
                    raise JointError(
                        j,
                        self.source,
                        f"has type '{jtype}'; arm joints must be one of "
                        f"{', '.join(MOVABLE_TYPES)} (arm '{arm}')",
                    )
                if j in owner:
                    where = "twice in arm" if owner[j] == arm else f"in two arms, '{owner[j]}' and"
                    raise JointError(j, self.source, f"is named {where} '{arm}'")
                owner[j] = arm

    def _check_locked(self, locked: Mapping[str, float]) -> dict[str, float]:
        out = {}
        for j, value in locked.items():
            if j not in self._urdf_joints:
                raise JointError(
                    j,
                    self.source,
                    "locked joint is not in the URDF" + _suggest(j, self._urdf_joints),
                )
            if j in self.joint_names:
                raise JointError(j, self.source, "is both an arm joint and a locked joint")
            if self._urdf_joints[j].type not in MOVABLE_TYPES:
                raise JointError(
                    j, self.source, f"is a {self._urdf_joints[j].type} joint and cannot be locked"
                )
            try:
                out[j] = float(value)
            except (TypeError, ValueError):
                raise JointError(
                    j, self.source, f"locked position must be a number, got {value!r}"
                ) from None
        for j, uj in self._urdf_joints.items():
            if uj.type in MOVABLE_TYPES and j not in self.joint_names and j not in out:
                out[j] = 0.0
        return out

    def _build_pinocchio(self, text: str):
        try:
            full = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        except Exception as exc:  # Pinocchio raises ValueError or RuntimeError, with C++ text
            raise URDFLoadError(self.source, f"Pinocchio could not build a model: {exc}") from exc
        full.gravity = pin.Motion.Zero()
        q_ref = pin.neutral(full)
        lock_ids = []
        for j, value in self.locked.items():
            if not full.existJointName(j):  # e.g. a mimic joint Pinocchio folded away
                continue
            jid = full.getJointId(j)
            jm = full.joints[jid]
            if jm.nq == 2:  # continuous joint stored as (cos, sin)
                q_ref[jm.idx_q : jm.idx_q + 2] = [math.cos(value), math.sin(value)]
            else:
                q_ref[jm.idx_q] = value
            lock_ids.append(jid)
        reduced = pin.buildReducedModel(full, sorted(lock_ids), q_ref) if lock_ids else full.copy()
        reduced.gravity = pin.Motion.Zero()
        return reduced, full

    def _depth(self, joint: str) -> int:
        """Number of joints from the URDF's root link down to ``joint`` (inclusive)."""
        parent_joint = {uj.child: uj for uj in self._urdf_joints.values()}
        depth, link = 0, self._urdf_joints[joint].child
        while link in parent_joint and depth <= len(parent_joint):
            depth, link = depth + 1, parent_joint[link].parent
        return depth

    def _default_ee_frame(self, joints: Sequence[str]) -> str:
        depths = [self._depth(j) for j in joints]
        last_joint = joints[max(i for i, d in enumerate(depths) if d == max(depths))]
        link = self._urdf_joints[last_joint].child
        while True:
            children = [j for j in self._urdf_joints.values() if j.parent == link]
            if len(children) != 1 or children[0].type != "fixed":
                return link
            link = children[0].child

    def _make_arms(self, arm_specs, ee_frames):
        arms, start = [], 0
        for name, joints in arm_specs:
            frame = ee_frames.get(name) or self._default_ee_frame(joints)
            if not self.model.existFrame(frame):
                raise ArmError(
                    name,
                    self.source,
                    f"end-effector frame '{frame}' is not a link of the URDF"
                    + _suggest(frame, [f.name for f in self.model.frames]),
                )
            arms.append(Arm(name, tuple(joints), np.arange(start, start + len(joints)), frame))
            start += len(joints)
        return arms

    def _make_limits(self, overrides: Mapping[str, Mapping[str, float]]) -> JointLimits:
        values = {k: np.full(self.n, np.inf) for k in LIMIT_KEYS}
        values["lower"] = -values["lower"]
        for i, j in enumerate(self.joint_names):
            if self._pin_nq[i] == 1:
                values["lower"][i] = self.model.lowerPositionLimit[self._pin_idx_q[i]]
                values["upper"][i] = self.model.upperPositionLimit[self._pin_idx_q[i]]
            values["velocity"][i] = self.model.velocityLimit[self._pin_idx_v[i]]
            values["effort"][i] = self.model.effortLimit[self._pin_idx_v[i]]
        for j, over in overrides.items():
            if j not in self.joint_names:
                raise JointError(
                    j,
                    self.source,
                    "limit override for a joint that is in no arm" + _suggest(j, self.joint_names),
                )
            for key, value in over.items():
                if key not in LIMIT_KEYS:
                    raise JointError(
                        j,
                        self.source,
                        f"unknown limit '{key}'; expected one of {', '.join(LIMIT_KEYS)}",
                    )
                values[key][self.joint_names.index(j)] = float(value)
        for i, j in enumerate(self.joint_names):
            if not values["lower"][i] <= values["upper"][i]:
                raise JointError(
                    j,
                    self.source,
                    f"lower limit {values['lower'][i]} is above upper limit {values['upper'][i]}",
                )
            for key in ("velocity", "acceleration", "effort"):
                if not values[key][i] > 0:
                    raise JointError(
                        j, self.source, f"{key} limit must be positive, got {values[key][i]}"
                    )
        return JointLimits(**values)

    # ----------------------------------------------------------------------------- structure
    @property
    def n(self) -> int:
        """Number of arm joints (all arms)."""
        return len(self.joint_names)

    @property
    def mission(self) -> Arm:
        return self.arms[0]

    @property
    def balance_arms(self) -> tuple[Arm, ...]:
        return self.arms[1:]

    @property
    def mission_indices(self) -> np.ndarray:
        return self.mission.indices

    @property
    def balance_indices(self) -> np.ndarray:
        """Arm-vector indices of every balance joint, balance arms stacked in order."""
        return np.concatenate([a.indices for a in self.balance_arms])

    @property
    def balance_arm_columns(self) -> dict[str, np.ndarray]:
        """Columns of each balance arm in ``J_wB`` (balance arms stacked in order)."""
        out, start = {}, 0
        for arm in self.balance_arms:
            out[arm.name] = np.arange(start, start + arm.dof)
            start += arm.dof
        return out

    @property
    def total_mass(self) -> float:
        """Mass of the whole system [kg]."""
        return float(sum(inertia.mass for inertia in self.model.inertias))

    def joint_index(self, name: str) -> int:
        """Position of joint ``name`` in the arm vector."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise JointError(
                name, self.source, "is in no arm" + _suggest(name, self.joint_names)
            ) from None

    def arm(self, name: str) -> Arm:
        for a in self.arms:
            if a.name == name:
                return a
        raise ArmError(
            name, self.source, f"no such arm (arms: {', '.join(a.name for a in self.arms)})"
        )

    def neutral(self) -> np.ndarray:
        """The zero arm configuration, moved inside the position limits where zero is outside."""
        return np.clip(np.zeros(self.n), self.limits.lower, self.limits.upper)

    # ----------------------------------------------------------------------------- conversions
    def pin_q(self, q, base: pin.SE3 | None = None) -> np.ndarray:
        """Pinocchio configuration from the arm vector ``q`` and the base pose (identity by default)."""
        q = np.asarray(q, dtype=float)
        qp = pin.neutral(self.model)
        if base is not None:
            qp[:7] = pin.SE3ToXYZQUAT(base)
        one = self._pin_nq == 1
        qp[self._pin_idx_q[one]] = q[one]
        for i in np.flatnonzero(~one):
            qp[self._pin_idx_q[i] : self._pin_idx_q[i] + 2] = [math.cos(q[i]), math.sin(q[i])]
        return qp

    def pin_v(self, q_dot, base_twist=None) -> np.ndarray:
        """Pinocchio velocity from arm joint rates and the base twist (local frame, zero by default)."""
        v = np.zeros(self.model.nv)
        if base_twist is not None:
            v[:6] = base_twist
        v[self._pin_idx_v] = q_dot
        return v

    def arm_q(self, q_pin) -> np.ndarray:
        """Arm vector from a Pinocchio configuration."""
        q = np.empty(self.n)
        for i, (iq, nq) in enumerate(zip(self._pin_idx_q, self._pin_nq)):
            q[i] = q_pin[iq] if nq == 1 else math.atan2(q_pin[iq + 1], q_pin[iq])
        return q

    def arm_v(self, v_pin) -> np.ndarray:
        """Arm joint rates (or accelerations, torques) from a Pinocchio tangent vector."""
        return np.asarray(v_pin)[self._pin_idx_v]

    @property
    def pin_v_indices(self) -> np.ndarray:
        """Index of each arm joint in Pinocchio's velocity vector (6 and up)."""
        return self._pin_idx_v.copy()

    def __repr__(self) -> str:
        arms = "; ".join(f"{a.name}: {', '.join(a.joints)}" for a in self.arms)
        return f"FloatingRobot({self.name!r}, {arms})"
