"""Checks of a task that need its robot and mission, each located in the task file.

:func:`~balance_opt.io.typed_config.from_data` checks what a value can be checked against
alone (types, bounds, list lengths fixed by the format). What depends on the robot or the
mission is checked here, once the robot and the mission are built:

* :func:`check_lengths`: every list declared ``per="... joint"`` has one value per such joint;
* :func:`check_limits`: limits no plan can meet (a balance start or a prescribed final
  configuration outside the position limits, a mission that leaves its own limits) and a
  planning horizon shorter than the mission.
"""

from __future__ import annotations

import numpy as np

from balance_opt.errors import InfeasibleLimitsError, TrajectoryError
from balance_opt.io.task_spec import TaskSpec
from balance_opt.io.typed_config import walk_settings
from balance_opt.io.yaml_lines import TaskFileError, YamlDocument
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.trajectories import JointTrajectory
from balance_opt.result import LIMIT_TOLERANCE, find_limit_violations

#: Samples per second used to check a mission trajectory against its limits [1/s].
LIMIT_CHECK_RATE = 200.0
#: Fewest samples used to check a mission trajectory against its limits.
LIMIT_CHECK_MIN_SAMPLES = 501


class TaskLimitsError(TaskFileError, InfeasibleLimitsError):
    """Limits that no plan can meet, located in the task file."""


class TaskTrajectoryError(TaskFileError, TrajectoryError):
    """A mission trajectory that cannot be built, located in the task file."""


def _joints_per_kind(robot: FloatingRobot) -> dict[str, list[str]]:
    """The joints a ``per=`` declaration counts: mission, balance (arms stacked) or all arms."""
    return {
        "mission joint": list(robot.mission.joints),
        "balance joint": [robot.joint_names[i] for i in robot.balance_indices],
        "arm joint": list(robot.joint_names),
    }


def check_lengths(spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot) -> None:
    """Every list of the task declared with one value per joint of a kind (``per=``) has that
    many values; a list of such lists (via points) is checked item by item.

    Raises:
        TaskFileError: ``"expected 3 values (one per balance joint: ...), got 2"``.
    """
    joints = _joints_per_kind(robot)
    for path, value, meta in walk_settings(spec):
        kind = meta.get("per")
        if kind is None or not isinstance(value, tuple):
            continue  # not per joint, not given, or one value for every joint (kp: 5)
        nested = bool(value) and isinstance(value[0], tuple)
        items = [((*path, i), v) for i, v in enumerate(value)] if nested else [(path, value)]
        names = joints[kind]
        for where, values in items:
            if len(values) != len(names):
                raise doc.error(
                    where,
                    f"expected {len(names)} values (one per {kind}: {', '.join(names)}), "
                    f"got {len(values)}",
                )


def _limit_source(spec: TaskSpec, joint: str, key: str) -> str:
    over = spec.limits.get(joint)
    return (
        f"limits.{joint}.{key}" if over is not None and getattr(over, key) is not None else "URDF"
    )


def _check_start(spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot, q_B0) -> None:
    lim = robot.limits
    for k, i in enumerate(robot.balance_indices):
        j, q = robot.joint_names[i], q_B0[k]
        if not lim.lower[i] - LIMIT_TOLERANCE <= q <= lim.upper[i] + LIMIT_TOLERANCE:
            key = "lower" if q < lim.lower[i] else "upper"
            raise doc.error(
                ("initial", "balance", k) if spec.initial.balance else ("initial",),
                f"balance joint '{j}' starts at {q:g} rad, outside its position limits "
                f"[{lim.lower[i]:g}, {lim.upper[i]:g}] rad ({key} limit from "
                f"{_limit_source(spec, j, key)}); no plan can meet them",
                TaskLimitsError,
            )


def _check_mission(
    spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot, mission: JointTrajectory
) -> None:
    lim = robot.limits
    t = np.linspace(
        0.0,
        mission.duration,
        max(LIMIT_CHECK_MIN_SAMPLES, int(mission.duration * LIMIT_CHECK_RATE)),
    )
    q, qd, qdd = mission.sample(t)
    idx = robot.mission_indices
    violations = find_limit_violations(t, robot.mission.joints, q, qd, qdd, lim.subset(idx))
    if violations:
        v = violations[0]
        key = {"position": "lower", "velocity": "velocity", "acceleration": "acceleration"}[v.kind]
        if v.kind == "position":
            col = robot.mission.joints.index(v.joint)
            key = "upper" if q[:, col].max() > lim.upper[idx[col]] else "lower"
        raise doc.error(
            ("mission",),
            f"the mission trajectory leaves the limits of the mission arm, which "
            f"follows it as given: {v} (limit from "
            f"{_limit_source(spec, v.joint, key)}); no plan can meet them",
            TaskLimitsError,
        )


def _check_planner(
    spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot, duration: float
) -> None:
    planner = spec.optimal.planner
    if planner.horizon is not None and planner.horizon < duration:
        raise doc.error(
            ("optimal", "horizon"),
            f"the horizon ({planner.horizon:g} s) is shorter than the mission ({duration:g} s)",
        )
    final = planner.final_configuration
    if final is not None and planner.position_limits:
        lim = robot.limits.subset(robot.balance_indices)
        for k, value in enumerate(final):
            if not lim.lower[k] - LIMIT_TOLERANCE <= value <= lim.upper[k] + LIMIT_TOLERANCE:
                j = robot.joint_names[robot.balance_indices[k]]
                raise doc.error(
                    ("optimal", "constraints", "final_configuration", k),
                    f"balance joint '{j}' must end at {value:g} rad, outside its position limits "
                    f"[{lim.lower[k]:g}, {lim.upper[k]:g}] rad; no plan can meet them",
                    TaskLimitsError,
                )


def check_limits(
    spec: TaskSpec,
    doc: YamlDocument,
    robot: FloatingRobot,
    mission: JointTrajectory,
    q_B0: np.ndarray,
) -> None:
    """Limits no plan can meet, and a horizon shorter than the mission (see the module
    docstring).

    Raises:
        TaskLimitsError: limits no plan can meet, naming the limit's source (``limits.J.KEY``
            or URDF).
        TaskFileError: ``optimal.horizon`` shorter than the mission.
    """
    _check_start(spec, doc, robot, q_B0)
    _check_mission(spec, doc, robot, mission)
    _check_planner(spec, doc, robot, float(mission.duration))
