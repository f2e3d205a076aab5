"""Task files: one YAML file says which robot, which arms, which mission and which options.
Every error is a :class:`TaskFileError` (``FILE:LINE: KEY.PATH: ...``); what depends on the
robot, the mission or another value is checked once they are built
(:mod:`balance_opt.tasks.checks`)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.config.typed_config import from_data
from balance_opt.config.yaml_lines import TaskFileError, YamlDocument, load_yaml
from balance_opt.errors import (
    ArmError,
    InputError,
    JointError,
    TrajectoryError,
    URDFLoadError,
)
from balance_opt.model.capture import TARGET_LINK
from balance_opt.model.limits import LIMIT_KEYS, LimitOverrideError
from balance_opt.model.meshes import MeshNotFoundError, geometry_kind, resolved_urdf
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.trajectories import CsvTrajectory, JointTrajectory, PointToPoint, ViaPoints
from balance_opt.optimal.options import PlannerOptions
from balance_opt.tasks.checks import (
    TaskTrajectoryError,
    check_capture,
    check_keep_out,
    check_lengths,
    check_limits,
    check_problem_size,
    check_time_grids,
    check_timing,
    robot_key,
)
from balance_opt.tasks.task_spec import (
    CartesianMission,
    CsvMission,
    PtpMission,
    TaskSpec,
    ViaMission,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Task:
    """A validated task, its robot and mission built, ready to plan.

    Attributes:
        spec: the typed content of the file, with the initial momentum ``h0`` set in the law's
            (``spec.analytic.law``) and the simulation's (``spec.simulation``) options.
        source: the file name as given (``"<dict>"`` for a task built from data).
        base_dir: folder that relative paths in the task are relative to.
        sha256: SHA-256 of the file's bytes (of the canonical JSON of the data for ``<dict>``).
        robot: the floating robot.
        mission: the mission arm's trajectory (its start is the mission start).
        q_B0: balance joint positions at t = 0 [rad].
        h0: initial momentum, world frame, [linear; angular] [N s; N m s].
        document: the parsed file with its line numbers (for locating errors found later).
        target: the target captured during the mission (``capture:``), or ``None``.
    """

    spec: TaskSpec
    source: str
    base_dir: Path
    sha256: str
    robot: FloatingRobot = field(repr=False)
    mission: JointTrajectory = field(repr=False)
    q_B0: np.ndarray = field(repr=False)
    h0: np.ndarray = field(repr=False)
    document: YamlDocument = field(repr=False, compare=False)
    target: Any = field(default=None, repr=False)

    @property
    def name(self) -> str:
        """The task's name: ``name:`` in the file, else the file's stem."""
        if self.spec.name:
            return self.spec.name
        return Path(self.source).stem if self.source != "<dict>" else "task"

    @cached_property
    def robot_after_capture(self) -> FloatingRobot | None:
        """The robot with the target attached (:func:`~balance_opt.model.capture.attach_target`),
        built on first use and kept with the task; ``None`` without a capture."""
        from balance_opt.model.capture import attach_target

        return None if self.target is None else attach_target(self.robot, self.target)

    @property
    def q0(self) -> np.ndarray:
        """Initial arm vector [rad]: mission start, then balance start."""
        return np.r_[self.mission.start, self.q_B0]

    @property
    def duration(self) -> float:
        """Duration of the mission [s]."""
        return float(self.mission.duration)

    @property
    def cartesian_goal(self) -> dict[str, float] | None:
        """For a Cartesian mission, the mission joints' goal found by inverse kinematics
        [rad or m], by joint name; ``None`` for the other missions."""
        if self.spec.mission.type != "cartesian":
            return None
        return dict(zip(self.robot.mission.joints, map(float, self.mission.qf)))

    def planner_options(self, extra_ipopt: Mapping[str, Any] | None = None) -> PlannerOptions:
        """The planner's options, ``extra_ipopt`` (``--solver-option``) over ``optimal.ipopt``."""
        planner = self.spec.optimal.planner
        if not extra_ipopt:
            return planner
        return dataclasses.replace(planner, ipopt={**planner.ipopt, **extra_ipopt})

    def __repr__(self) -> str:  # short for notebooks: the spec alone is pages long
        arms = "; ".join(f"{a.name} {a.dof} joints" for a in self.robot.arms)
        return (
            f"Task(name={self.name!r}, source={self.source!r}, robot {self.robot.name} "
            f"({arms}), mission {self.spec.mission.type} {self.duration:g} s)"
        )


def load_task(path: str | Path) -> Task:
    """Load, validate and build the task in the YAML file at ``path``: everything short of planning.

    Raises:
        InputError: (a :class:`TaskFileError` or subclass) naming the file, the line, the key
            path and what was expected.
    """
    path = Path(path)
    doc = load_yaml(path)
    return task_from_document(doc, path.parent, hashlib.sha256(path.read_bytes()).hexdigest())


def task_from_dict(
    data: Mapping[str, Any], base_dir: str | Path = ".", source: str = "<dict>"
) -> Task:
    """Build a task from plain data (a task file's content); relative paths from ``base_dir``,
    errors name ``source`` and the key path (no line)."""
    data = json.loads(json.dumps(data))  # plain, detached copy
    doc = YamlDocument(data, source, {})
    digest = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()
    return task_from_document(doc, Path(base_dir), digest)


def task_from_document(doc: YamlDocument, base_dir: Path, sha256: str) -> Task:
    """Validate a parsed document, resolve its files, build its robot and mission and check
    what depends on them (the ``check_*`` below)."""
    if not isinstance(doc.data, dict):
        raise doc.error(
            (),
            f"expected a mapping of task keys ({', '.join(TaskSpec.__dataclass_fields__)}), "
            f"got {type(doc.data).__name__}",
        )
    if "task" in doc.data:  # a sweep file names its base task there; no task file has that key
        raise doc.error(("task",), "this is a sweep file, not a task file: use balance-opt sweep")
    spec = _completed(from_data(TaskSpec, doc), doc, base_dir)
    robot = _build_robot(spec, doc, base_dir)
    check_lengths(spec, doc, robot)
    check_problem_size(spec, doc, robot)
    mission = _build_mission(spec, doc, base_dir, robot)
    check_time_grids(spec, doc, float(mission.duration))
    balance = spec.initial.balance
    q_B0 = robot.neutral()[robot.balance_indices] if balance is None else np.array(balance)
    check_limits(spec, doc, robot, mission, q_B0)
    target = check_capture(spec, doc, float(mission.duration))
    check_timing(spec, doc, robot)
    check_keep_out(spec, doc, robot, mission, q_B0)
    ignore = spec.optimal.planner.collision_ignore
    if target is None and any(TARGET_LINK in pair for pair in ignore):
        raise doc.error(
            ("optimal", "collision", "ignore"),
            f"{TARGET_LINK} is the captured target, and this task has no capture section",
        )
    h0 = np.array(spec.initial.momentum)
    task = Task(spec, doc.source, base_dir, sha256, robot, mission, q_B0, h0, doc, target)
    log.debug("task %s: %r, mission %.3g s", doc.source, robot, mission.duration)
    return task


def _completed(spec: TaskSpec, doc: YamlDocument, base_dir: Path) -> TaskSpec:
    """``spec`` with ``initial.momentum`` as the ``h0`` of the law and of the simulation,
    ``optimal.ipopt`` checked against Ipopt's option list, and ``robot.srdf`` (checked to exist)
    as the planner's collision SRDF, an absolute path."""
    planner = spec.optimal.planner
    if planner.ipopt:
        from balance_opt.solvers.ipopt_options import check_ipopt_options

        ipopt = check_ipopt_options(
            planner.ipopt, lambda name, problem: doc.error(("optimal", "ipopt", name), problem)
        )
        planner = dataclasses.replace(planner, ipopt=ipopt)
    if spec.robot.srdf is not None:
        path = (base_dir / spec.robot.srdf).resolve()
        if not path.is_file():
            raise doc.error(("robot", "srdf"), f"no such SRDF file: {path}")
        planner = dataclasses.replace(planner, collision_srdf=str(path))
    if spec.mission.timing != planner.timing:
        planner = dataclasses.replace(planner, timing=spec.mission.timing)
    h0 = spec.initial.momentum
    return dataclasses.replace(
        spec,
        analytic=dataclasses.replace(
            spec.analytic, law=dataclasses.replace(spec.analytic.law, h0=h0)
        ),
        simulation=dataclasses.replace(spec.simulation, h0=h0),
        optimal=dataclasses.replace(spec.optimal, planner=planner),
    )


def _joint_path(doc: YamlDocument, joint: str, reason: str = "") -> tuple:
    """Key path where ``joint`` is named in the (validated) task: under ``limits`` or
    ``arms.locked`` first when the ``reason`` is about a limit or a lock, else in the arms."""
    arms = doc.data["arms"]
    candidates = []
    for key in ("mission", "balance"):
        for i, item in enumerate(arms[key]):
            if item == joint:
                candidates.append(("arms", key, i))
            elif isinstance(item, list) and joint in item:
                candidates.append(("arms", key, i, item.index(joint)))
    locked = ("arms", "locked", joint) if joint in arms.get("locked", {}) else None
    limits = ("limits", joint) if joint in doc.data.get("limits", {}) else None
    if locked and "lock" in reason:
        candidates.insert(0, locked)
    elif limits and "limit" in reason:
        candidates.insert(0, limits)
    candidates += [p for p in (locked, limits) if p]
    return candidates[0] if candidates else ("arms",)


def _build_robot(spec: TaskSpec, doc: YamlDocument, base_dir: Path) -> FloatingRobot:
    from balance_opt.model.library import example_urdf, shipped_urdf

    r = spec.robot
    key = robot_key(r)
    if key == "urdf":
        urdf = base_dir / r.urdf
        if not urdf.is_file():
            raise doc.error(("robot", "urdf"), f"no such URDF file: {urdf}")
    else:
        try:
            urdf = shipped_urdf(r.shipped) if key == "shipped" else example_urdf(r.example)
        except InputError as exc:
            raise doc.error(("robot", key), str(exc)) from None
    limits = {
        j: {k: getattr(lim, k) for k in LIMIT_KEYS if getattr(lim, k) is not None}
        for j, lim in spec.limits.items()
    }
    packages = [(base_dir / p).resolve() for p in r.packages]
    for i, folder in enumerate(packages):
        if not folder.is_dir():
            raise doc.error(("robot", "packages", i), f"no such folder: {folder}")
    a = spec.arms
    balance = list(a.balance) if isinstance(a.balance[0], str) else [list(b) for b in a.balance]
    try:
        return FloatingRobot(
            urdf,
            list(a.mission),
            balance,
            locked=a.locked,
            limits=limits,
            ee_frames=a.ee_frames,
            packages=packages,
        )
    except URDFLoadError as exc:
        raise doc.error(("robot", key), str(exc)) from None
    except LimitOverrideError as exc:
        raise doc.error(("limits", exc.joint, exc.key), str(exc)) from None
    except JointError as exc:
        raise doc.error(_joint_path(doc, exc.joint, exc.reason), str(exc)) from None
    except ArmError as exc:
        path = ("arms", "ee_frames", exc.arm) if exc.arm in a.ee_frames else ("arms", exc.arm)
        if exc.arm.startswith("balance") and exc.arm not in a.ee_frames:
            path = ("arms", "balance")
        raise doc.error(path, str(exc)) from None


def _via_points(m: ViaMission, doc: YamlDocument) -> ViaPoints:
    if len(m.times) != len(m.points):
        raise doc.error(
            ("mission", "times"),
            f"expected one time per point: {len(m.points)} points, {len(m.times)} times",
        )
    if m.times[0] != 0.0:
        raise doc.error(("mission", "times", 0), f"the first time must be 0 s, got {m.times[0]:g}")
    for i in range(1, len(m.times)):
        if not m.times[i] > m.times[i - 1]:
            raise doc.error(
                ("mission", "times", i),
                f"times must increase: {m.times[i]:g} s after {m.times[i - 1]:g} s",
            )
    return ViaPoints(m.times, np.array(m.points))


def _build_mission(
    spec: TaskSpec, doc: YamlDocument, base_dir: Path, robot: FloatingRobot
) -> JointTrajectory:
    """The mission trajectory (a Cartesian goal solved by inverse kinematics)."""
    m = spec.mission
    key = {CsvMission: "file", CartesianMission: "position"}.get(type(m))
    try:
        if isinstance(m, PtpMission):
            return PointToPoint(np.array(m.start), np.array(m.goal), m.duration)
        if isinstance(m, ViaMission):
            return _via_points(m, doc)
        if isinstance(m, CsvMission):
            path = base_dir / m.file
            if not path.is_file():
                raise doc.error(("mission", "file"), f"no such CSV file: {path}")
            return CsvTrajectory(path, robot.mission.joints, time_column=m.time_column)
        import pinocchio as pin

        from balance_opt.motion.trajectories import cartesian_goal

        rotation = None if m.orientation is None else pin.rpy.rpyToMatrix(*m.orientation)
        return cartesian_goal(
            robot, np.array(m.start), m.position, m.duration, orientation=rotation
        )
    except TrajectoryError as exc:
        where = ("mission",) if key is None else ("mission", key)
        raise doc.error(where, str(exc), TaskTrajectoryError) from None


def check_methods(task: Task, methods) -> None:
    """What the planning ``methods`` need of the task beyond its loading: the meshes of the
    optimal planner's collision avoidance, found; no torque limits (adam-robotics inverse
    dynamics) and no adam backend with a prismatic model joint.

    Raises:
        TaskFileError: located at the key the method cannot work with, naming the way out.
    """
    robot = task.robot
    if "optimal" in methods and task.spec.optimal.planner.collision_avoidance:
        _check_meshes(task)
    prismatic = [j for j in robot.model_joint_names if robot.joint_type(j) == "prismatic"]
    if "optimal" not in methods or not prismatic:
        return
    joint = prismatic[0]
    if task.spec.optimal.planner.torque_limits:
        raise task.document.error(
            ("optimal", "constraints", "torque_limits"),
            f"torque limits are computed with adam-robotics, which cannot handle the prismatic "
            f"joint '{joint}'; turn them off, lock the joint, or plan with --method analytic",
        )
    backend = task.spec.robot.backend
    if backend == "auto":
        from balance_opt.model.symbolic import available_backends  # imports CasADi

        if "pinocchio" in available_backends():
            return
        why = (
            "the only symbolic backend here (no pinocchio.casadi, no C++ toolchain for the bridge)"
        )
    elif backend == "adam":
        why = "robot.backend"
    else:
        return
    raise task.document.error(
        _joint_path(task.document, joint),
        f"joint '{joint}' is prismatic, which the adam backend ({why}) cannot handle; lock "
        "it, use the pinocchio backend, or plan with --method analytic",
    )


def _check_meshes(task: Task) -> None:
    """The collision geometry's meshes found before anything is planned, a mesh found nowhere
    located at the key that tells where meshes are (other methods plan without them)."""
    robot, spec = task.robot, task.spec.robot
    try:
        resolved_urdf(
            robot.locked_urdf, robot.source, robot.packages, geometry_kind(robot.locked_urdf)
        )
    except MeshNotFoundError as exc:
        key = "packages" if spec.packages else robot_key(spec)
        raise task.document.error(
            ("robot", key),
            f"{exc}; or plan without collision avoidance (optimal.collision.avoid: false)",
        ) from None


def start_error(task: Task, reason: str, balance: bool) -> TaskFileError:
    """``reason``, a start in collision (found when the optimal planner sets up its collision
    avoidance, where the geometry is built), located at the key that sets the start:
    ``initial.balance`` when a pair the balance arm moves is in contact (``balance``), else
    the mission's start."""
    spec, doc = task.spec, task.document
    if balance and spec.initial.balance is None:  # the key to add: no line of its own
        reason += " (not given: the balance arm starts at zero, inside its limits)"
        return TaskFileError(
            doc.source, doc.lines.get(("initial",)), ("initial", "balance"), reason
        )
    if balance:
        return doc.error(("initial", "balance"), reason)
    m = spec.mission
    key = {CsvMission: ("mission", "file"), ViaMission: ("mission", "points", 0)}.get(
        type(m), ("mission", "start")
    )
    return doc.error(key, reason)
