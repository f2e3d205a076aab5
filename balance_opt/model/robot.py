"""Floating-base robot model: a URDF with a free-flyer root, arms assigned by joint names.

The *arm vector* ``q`` holds the joints of every arm in the order the user named them, mission
arm first; every other movable joint is locked. Pinocchio orders joints depth-first, so
conversions always go through joint names. A mimic joint whose driver is an arm joint is a
*follower*: it stays movable and its momentum goes into its driver's column (``velocity_map``);
the *model joints* are the arm joints, then the followers.

``robot.model`` (Pinocchio, reduced with ``pin.buildReducedModel``) and ``robot.locked_urdf``
(locked joints turned fixed, followers' ``<mimic>`` tags removed; the symbolic backends read it)
are built by different routes on purpose: the tests compare them.
"""

from __future__ import annotations

import contextlib
import logging
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from balance_opt.config.typed_config import suggest
from balance_opt.errors import ArmError, JointError, URDFLoadError
from balance_opt.model.joints import (
    MOVABLE_TYPES,
    Mimic,
    lock_joints,
    mimic_matrix,
    parse_mimic,
    resolve_mimics,
)
from balance_opt.model.limits import JointLimits, joint_limits
from balance_opt.model.urdf_checks import check_base_mass, check_urdf_physics, pinocchio_model

log = logging.getLogger(__name__)

#: A balance arm whose links have less than this fraction of the robot's mass and of its
#: inertia moves nothing: it is refused.
MASSLESS = 1e-9


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
class UrdfJoint:
    """A ``<joint>`` of a URDF; ``mimic``: ``(driver, multiplier, offset)`` of a movable joint."""

    name: str
    type: str
    parent: str
    child: str
    mimic: tuple[str, float, float] | None = None

    def __str__(self) -> str:
        kind = self.type if self.mimic is None else f"{self.type}, mimics {self.mimic[0]}"
        return f"{self.name} ({kind})"


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


def parse_urdf(text: str, source: str) -> tuple[ET.Element, dict[str, UrdfJoint], list[str]]:
    """The root element of URDF ``text``, its joints by name and the warnings of
    :func:`~balance_opt.model.urdf_checks.check_urdf_physics` (which raises for a non-physical
    file)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise URDFLoadError(source, f"XML parse error: {exc}") from exc
    if root.tag != "robot":
        raise URDFLoadError(source, f"root element is <{root.tag}>, expected <robot>")
    joints: dict[str, UrdfJoint] = {}
    for el in root.findall("joint"):
        name = el.get("name")
        parent, child = el.find("parent"), el.find("child")
        if name is None or parent is None or child is None:
            raise URDFLoadError(
                source, f"a <joint> lacks a name, parent or child: {ET.tostring(el)[:80]!r}"
            )
        joints[name] = UrdfJoint(
            name,
            el.get("type", ""),
            parent.get("link"),
            child.get("link"),
            parse_mimic(el, source) if el.get("type") in MOVABLE_TYPES else None,
        )
    return root, joints, check_urdf_physics(root, source)


@contextlib.contextmanager
def urdf_warnings_shown() -> Iterator[None]:
    """Within the block, robots are built without logging their URDF's warnings (implausible
    values), for the many robots a sweep builds from one file whose warnings were shown once."""
    before = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(before)


class FloatingRobot:
    """A URDF robot on a free-flying base, with one mission arm and one or more balance arms.

    Args:
        urdf: path to a URDF file, or the URDF's XML text.
        mission: joint names of the mission arm.
        balance: joint names of the balance arm, or a list of such lists for several balance arms.
        locked: positions of locked joints [rad or m]; every movable joint that is in no arm and
            not named here is locked at 0, except mimic joints, which follow their driver.
        limits: overrides of joint limits, ``{joint: {"lower": ..., "upper": ..., "velocity": ...,
            "acceleration": ..., "effort": ..., "jerk": ...}}``; keys left out keep the URDF's
            value (acceleration and jerk: unlimited).
        ee_frames: end-effector frame per arm name (``"mission"``, ``"balance"``, ``"balance2"``
            ...); by default the last link reached from the arm's most distal joint (the
            deepest in the kinematic tree, whatever the order the joints were named in) through
            fixed joints, while that chain does not branch.
        packages: folders searched first for the URDF's ``package://`` meshes
            (:mod:`~balance_opt.model.meshes`; the task file's ``robot.packages``), kept as
            ``packages`` for whatever loads the robot's geometry.
        keep_out: keep-out zones fixed on its frames (the task file's ``keep_out``), kept as
            ``keep_out`` for whatever loads the robot's geometry
            (:mod:`~balance_opt.geometry.keep_out`).

    Raises:
        URDFLoadError: the URDF cannot be read, parsed or loaded by Pinocchio.
        JointError: a joint is unknown, named twice, in two arms, fixed, a mimic joint, or of an
            unsupported type; a lock or a limit override names a wrong joint or key.
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
        packages: Sequence[str | Path] = (),
        keep_out: Sequence = (),
    ):
        text, self.source = _read_urdf(urdf)
        self.packages: tuple[Path, ...] = tuple(Path(p) for p in packages)
        self.keep_out: tuple = tuple(keep_out)
        root, self._urdf_joints, warnings = parse_urdf(text, self.source)
        for warning in warnings:
            log.warning("URDF %s: %s", self.source, warning)
        self.mimics: dict[str, Mimic] = resolve_mimics(self._urdf_joints, self.source)
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
        #: mimic joints that follow an arm joint, in URDF order
        self.followers: dict[str, Mimic] = {
            j: m for j, m in self.mimics.items() if m.driver in self.joint_names
        }
        #: the arm joints, then the followers: the movable joints of ``model``
        self.model_joint_names: tuple[str, ...] = self.joint_names + tuple(self.followers)
        self.locked_urdf = lock_joints(root, self._urdf_joints, self.locked, self.followers)

        self.model, self.full_model = self._build_pinocchio(text)
        self._check_locked_limits(set(locked or {}))

        ids = [self.model.getJointId(j) for j in self.model_joint_names]
        self._model_idx_q = np.array([self.model.joints[i].idx_q for i in ids], dtype=int)
        self._model_idx_v = np.array([self.model.joints[i].idx_v for i in ids], dtype=int)
        self._model_nq = np.array([self.model.joints[i].nq for i in ids], dtype=int)
        self._joint_ids = ids[: len(self.joint_names)]
        self._pin_idx_q = self._model_idx_q[: self.n]
        self._pin_idx_v = self._model_idx_v[: self.n]
        self._pin_nq = self._model_nq[: self.n]
        self._mimic_E, self._mimic_e = mimic_matrix(self.joint_names, self.followers)
        # G: Pinocchio velocity per [base twist; arm joint rates]
        self._G = np.zeros((self.model.nv, 6 + self.n))
        self._G[:6, :6] = np.eye(6)
        self._G[self._model_idx_v, 6:] = self._mimic_E

        ee_frames = dict(ee_frames or {})
        self.arms: tuple[Arm, ...] = tuple(self._make_arms(arm_specs, ee_frames))
        unknown_arms = set(ee_frames) - {a.name for a in self.arms}
        if unknown_arms:
            name = min(unknown_arms)
            raise ArmError(
                name,
                self.source,
                f"end-effector frame given for an arm that does not exist "
                f"(arms: {', '.join(a.name for a in self.arms)})",
            )
        self.limits = self._make_limits(limits or {})
        for arm in self.balance_arms:
            self._check_moves_mass(arm)

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
                        f"no such joint in the URDF (arm '{arm}')"
                        + suggest(
                            j, [n for n, u in self._urdf_joints.items() if u.type in MOVABLE_TYPES]
                        ),
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
                if j in self.mimics:
                    m = self.mimics[j]
                    raise JointError(
                        j,
                        self.source,
                        f"is a mimic joint following '{m.driver}' (multiplier {m.multiplier:g}, "
                        f"offset {m.offset:g}) and cannot be an arm joint (arm '{arm}'); name "
                        f"its driver '{m.driver}' in an arm and '{j}' moves with it",
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
                    "locked joint is not in the URDF" + suggest(j, self._urdf_joints),
                )
            if j in self.joint_names:
                raise JointError(j, self.source, "is both an arm joint and a locked joint")
            if self._urdf_joints[j].type not in MOVABLE_TYPES:
                raise JointError(
                    j, self.source, f"is a {self._urdf_joints[j].type} joint and cannot be locked"
                )
            if j in self.mimics:
                raise JointError(
                    j,
                    self.source,
                    f"is a mimic joint following '{self.mimics[j].driver}' and cannot be locked "
                    f"on its own; lock its driver '{self.mimics[j].driver}'",
                )
            try:
                out[j] = float(value)
            except (TypeError, ValueError):
                raise JointError(
                    j, self.source, f"locked position must be a number, got {value!r}"
                ) from None
        for j, uj in self._urdf_joints.items():
            if uj.type in MOVABLE_TYPES and j not in self.joint_names and j not in self.mimics:
                out.setdefault(j, 0.0)
        for j, m in self.mimics.items():  # a locked driver locks its mimics
            if m.driver not in self.joint_names:
                out[j] = m.multiplier * out[m.driver] + m.offset
        return out

    def _check_locked_limits(self, given: set[str]) -> None:
        """Every locked joint (but a mimic: its driver is checked) inside its URDF position
        limits: the robot cannot be held where its joints do not go (Panda's panda_joint4,
        locked at the default 0, is past its upper limit -0.07 rad)."""
        full = self.full_model
        for j, value in self.locked.items():
            if j in self.mimics or not full.existJointName(j):
                continue
            jm = full.joints[full.getJointId(j)]
            if jm.nq != 1:  # continuous: no limits
                continue
            lo, hi = full.lowerPositionLimit[jm.idx_q], full.upperPositionLimit[jm.idx_q]
            if lo - 1e-9 <= value <= hi + 1e-9 or not (np.isfinite(lo) and np.isfinite(hi)):
                continue
            unit = "m" if self._urdf_joints[j].type == "prismatic" else "rad"
            where = (
                f"locked at {value:g} {unit}"
                if j in given
                else f"is in no arm and locked at {value:g} {unit} (the default)"
            )
            raise JointError(
                j,
                self.source,
                f"{where}, outside its position limits [{lo:g}, {hi:g}] {unit}; lock it inside "
                f"them (arms.locked) or put it in an arm",
            )

    def _build_pinocchio(self, text: str):
        full = pinocchio_model(text, self.source)
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
        warning = check_base_mass(reduced, self.source)
        if warning:
            log.warning("URDF %s: %s", self.source, warning)
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
                    + suggest(frame, [f.name for f in self.model.frames]),
                )
            arms.append(Arm(name, tuple(joints), np.arange(start, start + len(joints)), frame))
            start += len(joints)
        return arms

    def _make_limits(self, overrides: Mapping[str, Mapping[str, float]]) -> JointLimits:
        indices = (self._pin_nq, self._pin_idx_q, self._pin_idx_v)
        return joint_limits(
            self.model, self.joint_names, self.followers, indices, overrides, self.source
        )

    def _check_moves_mass(self, arm: Arm) -> None:
        """Refuse a balance arm that moves no mass and no inertia: its motion would change
        nothing, and every plan would equal the mission arm alone."""
        model = self.model
        # every body below a joint of the arm
        moved = sorted(set().union(*(model.subtrees[self._joint_ids[i]] for i in arm.indices)))
        mass = sum(model.inertias[b].mass for b in moved)
        inertia = sum(float(np.trace(model.inertias[b].inertia)) for b in moved)
        scale = sum(float(np.trace(model.inertias[b].inertia)) for b in range(model.njoints))
        if mass <= MASSLESS * self.total_mass and inertia <= MASSLESS * scale:
            raise ArmError(
                arm.name,
                self.source,
                f"moves no mass: the links below its joints ({', '.join(arm.joints)}) weigh "
                f"{mass:.3g} kg (of {self.total_mass:.4g} kg); a massless balance arm cannot "
                "balance anything (check their <inertial> elements)",
            )

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
    def mimic_matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """``(E, e)``: positions of the model joints (``model_joint_names``: arm joints, then
        followers) are ``E q + e``, their rates ``E q_dot`` [rad or m]."""
        return self._mimic_E.copy(), self._mimic_e.copy()

    @property
    def velocity_map(self) -> np.ndarray:
        """``G`` (nv x (6+n)): Pinocchio's velocity is ``G [base twist; q_dot]``; a Pinocchio
        matrix over velocities becomes one over [base; arm joints] as ``X G`` (each follower's
        column added, times its multiplier, into its driver's) and a generalized force ``f``
        becomes ``G^T f``."""
        return self._G.copy()

    @property
    def model_v_indices(self) -> np.ndarray:
        """Index of each model joint (arm joints, then followers) in Pinocchio's velocity."""
        return self._model_idx_v.copy()

    def arm_columns(self, X: np.ndarray) -> np.ndarray:
        """``X G``: a Pinocchio matrix (..., nv) over velocities as one over [base twist; arm
        joint rates] (..., 6+n), followers' columns folded into their drivers'."""
        if not self.followers:  # a plain selection: cheaper, and bit for bit the same
            return X[..., np.r_[0:6, self._pin_idx_v]]
        return X @ self._G

    @property
    def joint_units(self) -> tuple[str, ...]:
        """Unit of each arm joint's position, in arm order: ``"m"`` for prismatic joints, else
        ``"rad"`` (rates and accelerations per s and s^2, efforts N or N m)."""
        return tuple(
            "m" if self._urdf_joints[j].type == "prismatic" else "rad" for j in self.joint_names
        )

    @property
    def total_mass(self) -> float:
        """Mass of the whole system [kg]."""
        return float(sum(inertia.mass for inertia in self.model.inertias))

    def joint_type(self, name: str) -> str:
        """The URDF type of joint ``name`` (``"revolute"``, ``"prismatic"``, ``"fixed"``, ...)."""
        return self._urdf_joints[name].type

    def joint_index(self, name: str) -> int:
        """Position of joint ``name`` in the arm vector."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise JointError(
                name, self.source, "is in no arm" + suggest(name, self.joint_names)
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
        """Pinocchio configurations (..., nq) of arm vectors (..., n) and the base pose
        (identity by default), followers placed by their drivers."""
        q = np.asarray(q, dtype=float)
        if self.followers:
            q = q @ self._mimic_E.T + self._mimic_e
        qp = np.tile(pin.neutral(self.model), q.shape[:-1] + (1,))
        if base is not None:
            qp[..., :7] = pin.SE3ToXYZQUAT(base)
        one, idx = self._model_nq == 1, self._model_idx_q
        qp[..., idx[one]] = q[..., one]
        if not one.all():  # continuous joints stored as (cos, sin)
            qp[..., idx[~one]] = np.cos(q[..., ~one])
            qp[..., idx[~one] + 1] = np.sin(q[..., ~one])
        return qp

    def pin_v(self, q_dot, base_twist=None) -> np.ndarray:
        """Pinocchio velocities (..., nv) of arm joint rates (..., n) and the base twist (local
        frame, zero by default), followers moving with their drivers."""
        q_dot = np.asarray(q_dot, dtype=float)
        v = np.zeros(q_dot.shape[:-1] + (self.model.nv,))
        if base_twist is not None:
            v[..., :6] = base_twist
        v[..., self._model_idx_v] = q_dot @ self._mimic_E.T
        return v

    def arm_q(self, q_pin) -> np.ndarray:
        """Arm vector from a Pinocchio configuration."""
        q = np.empty(self.n)
        for i, (iq, nq) in enumerate(zip(self._pin_idx_q, self._pin_nq)):
            q[i] = q_pin[iq] if nq == 1 else math.atan2(q_pin[iq + 1], q_pin[iq])
        return q

    def arm_v(self, v_pin) -> np.ndarray:
        """Arm joint rates (or accelerations) from a Pinocchio tangent vector; a generalized
        force maps to the arm joints as ``velocity_map.T @ f`` instead."""
        return np.asarray(v_pin)[self._pin_idx_v]

    @property
    def pin_v_indices(self) -> np.ndarray:
        """Index of each arm joint in Pinocchio's velocity vector (6 and up)."""
        return self._pin_idx_v.copy()

    def __repr__(self) -> str:
        arms = "; ".join(f"{a.name}: {', '.join(a.joints)}" for a in self.arms)
        return f"FloatingRobot({self.name!r}, {arms})"
