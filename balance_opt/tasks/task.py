"""Task files: one YAML file says which robot, which arms, which mission and which options.

Every error is an :class:`~balance_opt.errors.InputError` whose message starts with
``FILE:LINE: KEY.PATH:``. Loading imports neither CasADi nor the planner."""

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
from balance_opt.errors import ArmError, InputError, JointError, TrajectoryError, URDFLoadError
from balance_opt.model.arms import LIMIT_KEYS
from balance_opt.model.robot import FloatingRobot, LimitOverrideError
from balance_opt.motion.trajectories import CsvTrajectory, JointTrajectory, PointToPoint, ViaPoints
from balance_opt.optimal.options import PlannerOptions
from balance_opt.tasks.task_checks import (
    TaskTrajectoryError,
    check_capture,
    check_lengths,
    check_limits,
    check_problem_size,
    check_time_grids,
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
        """The planner's options; ``extra_ipopt`` (``--solver-option``) overrides
        ``optimal.ipopt``."""
        planner = self.spec.optimal.planner
        if not extra_ipopt:
            return planner
        return dataclasses.replace(planner, ipopt={**planner.ipopt, **extra_ipopt})

    def error(self, path, reason: str, cls=TaskFileError) -> TaskFileError:
        """An error located at key ``path`` of this task's file."""
        return self.document.error(path, reason, cls)

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
    """Build a task from plain data (the content of a task file as dicts and lists).

    Relative paths are taken from ``base_dir``. Errors name ``source`` and the key path (no line).
    """
    data = json.loads(json.dumps(data))  # plain, detached copy
    doc = YamlDocument(data, source, {})
    digest = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()
    return task_from_document(doc, Path(base_dir), digest)


def task_from_document(doc: YamlDocument, base_dir: Path, sha256: str) -> Task:
    """Validate a parsed document (types, keys, ranges: :func:`~balance_opt.config.typed_config.from_data`),
    resolve its files, build its robot and mission, check the per-joint lists and the limits
    (:mod:`balance_opt.tasks.task_checks`) and set the initial momentum in the options.
    """
    if not isinstance(doc.data, dict):
        raise doc.error(
            (),
            f"expected a mapping of task keys ({', '.join(TaskSpec.__dataclass_fields__)}), "
            f"got {type(doc.data).__name__}",
        )
    if "task" in doc.data and "task" not in TaskSpec.__dataclass_fields__:
        # a sweep file names its base task under ``task``; no task file has that key
        raise doc.error(("task",), "this is a sweep file, not a task file: use balance-opt sweep")
    spec: TaskSpec = _with_srdf(_with_checked_ipopt(from_data(TaskSpec, doc), doc), doc, base_dir)
    robot = _build_robot(spec, doc, base_dir)
    check_lengths(spec, doc, robot)
    check_problem_size(spec, doc, robot)
    mission = _build_mission(spec, doc, base_dir, robot)
    check_time_grids(spec, doc, float(mission.duration))
    q_B0 = (
        robot.neutral()[robot.balance_indices]
        if spec.initial.balance is None
        else np.array(spec.initial.balance)
    )
    check_limits(spec, doc, robot, mission, q_B0)
    target = check_capture(spec, doc, float(mission.duration))
    task = Task(
        _with_momentum(spec),
        doc.source,
        base_dir,
        sha256,
        robot,
        mission,
        q_B0,
        np.array(spec.initial.momentum),
        doc,
        target,
    )
    log.debug("task %s: %r, mission %.3g s", doc.source, robot, mission.duration)
    return task


def _with_checked_ipopt(spec: TaskSpec, doc: YamlDocument) -> TaskSpec:
    """``spec`` with ``optimal.ipopt`` checked against Ipopt's own option list and its values
    in the types Ipopt wants (CasADi is imported only when the list is not cached yet)."""
    planner = spec.optimal.planner
    if not planner.ipopt:
        return spec
    from balance_opt.optimal.ipopt_options import check_ipopt_options

    ipopt = check_ipopt_options(
        planner.ipopt, lambda name, problem: doc.error(("optimal", "ipopt", name), problem)
    )
    optimal = dataclasses.replace(spec.optimal, planner=dataclasses.replace(planner, ipopt=ipopt))
    return dataclasses.replace(spec, optimal=optimal)


def _with_srdf(spec: TaskSpec, doc: YamlDocument, base_dir: Path) -> TaskSpec:
    """``spec`` with ``robot.srdf`` (checked to exist) as the planner's collision SRDF, an
    absolute path: the run's clearance check reads it from there too."""
    if spec.robot.srdf is None:
        return spec
    path = (base_dir / spec.robot.srdf).resolve()
    if not path.is_file():
        raise doc.error(("robot", "srdf"), f"no such SRDF file: {path}")
    planner = dataclasses.replace(spec.optimal.planner, collision_srdf=str(path))
    return dataclasses.replace(spec, optimal=dataclasses.replace(spec.optimal, planner=planner))


def _with_momentum(spec: TaskSpec) -> TaskSpec:
    """``spec`` with ``initial.momentum`` as the ``h0`` of the law and of the simulation."""
    h0 = spec.initial.momentum
    analytic = dataclasses.replace(spec.analytic, law=dataclasses.replace(spec.analytic.law, h0=h0))
    simulation = dataclasses.replace(spec.simulation, h0=h0)
    return dataclasses.replace(spec, analytic=analytic, simulation=simulation)


def _urdf_path(spec: TaskSpec, doc: YamlDocument, base_dir: Path) -> Path:
    from balance_opt.model.catalog import example_urdf
    from balance_opt.model.library import shipped_urdf

    r = spec.robot
    if r.urdf is not None:
        path = base_dir / r.urdf
        if not path.is_file():
            raise doc.error(("robot", "urdf"), f"no such URDF file: {path}")
        return path
    try:
        return shipped_urdf(r.shipped) if r.shipped is not None else example_urdf(r.example)
    except InputError as exc:
        raise doc.error(
            ("robot", "shipped" if r.shipped is not None else "example"), str(exc)
        ) from None


def _joint_path(doc: YamlDocument, joint: str, reason: str = "") -> tuple:
    """Key path where ``joint`` is named in the task: under ``limits`` or ``arms.locked`` first
    when the ``reason`` is about a limit or a lock, else in the arms."""
    data = doc.data
    arms = data.get("arms") if isinstance(data.get("arms"), dict) else {}
    candidates = []
    for key in ("mission", "balance"):
        value = arms.get(key)
        for i, item in enumerate(value if isinstance(value, list) else []):
            if item == joint:
                candidates.append(("arms", key, i))
            elif isinstance(item, list) and joint in item:
                candidates.append(("arms", key, i, item.index(joint)))
    locked = (
        ("arms", "locked", joint)
        if isinstance(arms.get("locked"), dict) and joint in arms["locked"]
        else None
    )
    limits = (
        ("limits", joint)
        if isinstance(data.get("limits"), dict) and joint in data["limits"]
        else None
    )
    if locked and "lock" in reason:
        candidates.insert(0, locked)
    elif limits and "limit" in reason:
        candidates.insert(0, limits)
    candidates += [p for p in (locked, limits) if p]
    return candidates[0] if candidates else ("arms",)


def _build_robot(spec: TaskSpec, doc: YamlDocument, base_dir: Path) -> FloatingRobot:
    urdf = _urdf_path(spec, doc, base_dir)
    limits = {
        j: {k: getattr(lim, k) for k in LIMIT_KEYS if getattr(lim, k) is not None}
        for j, lim in spec.limits.items()
    }
    a = spec.arms
    balance = list(a.balance) if isinstance(a.balance[0], str) else [list(b) for b in a.balance]
    try:
        return FloatingRobot(
            urdf, list(a.mission), balance, locked=a.locked, limits=limits, ee_frames=a.ee_frames
        )
    except URDFLoadError as exc:
        key = next(k for k in ("urdf", "shipped", "example") if getattr(spec.robot, k) is not None)
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
    """The mission trajectory (list lengths per mission joint already checked); a Cartesian
    goal is solved by inverse kinematics (base at its initial pose), then reached point to
    point."""
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
    """What the planning ``methods`` need of the task beyond its loading, checked before
    anything is computed (``balance-opt validate`` checks those of ``plan``'s default methods).

    The optimal planner cannot handle torque limits on a robot with a prismatic model joint
    (their inverse dynamics come from adam-robotics, which mishandles prismatic joints), nor a
    prismatic model joint where the symbolic backend is adam (``robot.backend: adam``, or
    ``auto`` with neither ``pinocchio.casadi`` nor a C++ toolchain for the Pinocchio-CasADi
    bridge).

    Raises:
        TaskFileError: located at the key the method cannot work with, naming the way out.
    """
    robot = task.robot
    prismatic = [j for j in robot.model_joint_names if robot.joint_type(j) == "prismatic"]
    if "optimal" not in methods or not prismatic:
        return
    joint = prismatic[0]
    if task.spec.optimal.planner.torque_limits:
        raise task.error(
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
    raise task.error(
        _joint_path(task.document, joint),
        f"joint '{joint}' is prismatic, which the adam backend ({why}) cannot handle; lock "
        "it, use the pinocchio backend, or plan with --method analytic",
    )
