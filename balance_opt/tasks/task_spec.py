"""The task-file format: a tree of frozen dataclasses rooted at :class:`TaskSpec`, the single
source of the validator, the JSON Schema and the reference table."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.config.schema import json_schema, reference_markdown
from balance_opt.config.typed_config import setting
from balance_opt.dynamics.options import ClosedLoopOptions, SimulationOptions
from balance_opt.geometry.keep_out import KeepOutZone
from balance_opt.motion.options import IntegrationOptions, RobustnessOptions
from balance_opt.optimal.options import GUESSES, TIMINGS, PlannerOptions

#: Values of ``robot.backend``: ``auto`` and :data:`balance_opt.model.symbolic.BACKENDS` (not
#: imported: loading a task does not import CasADi).
SYMBOLIC_BACKENDS = ("auto", "pinocchio", "adam")

SCHEMA_ID = "https://balance-opt.invalid/task.schema.json"
#: What a task's ``name`` may be: it names the default output folder ``results/<name>``, so no
#: path separator, no leading dot (``..``, hidden folders) and no spaces.
NAME_PATTERN = (
    r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}",
    "letters, digits, '.', '_' and '-', starting with a letter or a digit, at most 100 characters",
)


@dataclass(frozen=True, kw_only=True)
class RobotSpec:
    """Which URDF: exactly one of ``urdf``, ``shipped`` or ``example``; and the symbolic backend
    that turns it into CasADi expressions (:mod:`balance_opt.model.symbolic`)."""

    __exactly_one__ = ("urdf", "shipped", "example")

    urdf: str | None = setting(None, doc="path of a URDF file, relative to the task file")
    shipped: str | None = setting(
        None, doc="name of a URDF shipped with balance-opt (folder urdf/), e.g. paper_robot.urdf"
    )
    example: str | None = setting(
        None,
        doc="name of an example-robot-data robot, e.g. baxter, talos, ur5, panda "
        "(`balance-opt robots` lists them)",
    )
    srdf: str | None = setting(
        None,
        doc="path of an SRDF file, relative to the task file, whose disable_collisions pairs "
        "the clearance check and the collision avoidance leave out (default: NAME.srdf beside "
        "NAME.urdf, or the SRDF shipped with an example-robot-data robot; without one, the "
        "pairs are computed: `balance-opt inspect TASK --write-srdf FILE` writes them)",
    )
    packages: tuple[str, ...] = setting(
        (),
        doc="folders, relative to the task file, searched first for the URDF's package://NAME/... "
        "meshes: each holds NAME/ or is named NAME (then ROS_PACKAGE_PATH, the URDF's folder and "
        "the three above it, the installed example-robot-data)",
        item="folder",
    )
    backend: Literal[SYMBOLIC_BACKENDS] = setting(
        "auto",
        doc="symbolic backend of the optimal planner's momentum maps: pinocchio (Pinocchio's "
        "CasADi interface, through a bridge compiled once per machine with a C++ compiler), adam, "
        "or auto (pinocchio where the bridge builds, else adam); --backend overrides it",
    )


@dataclass(frozen=True, kw_only=True)
class ArmsSpec:
    """Which joints move: the mission arm, the balance arm(s), and where the rest is locked."""

    mission: tuple[str, ...] = setting(
        doc="joint names of the mission arm, in order", min_items=1, item="joint"
    )
    balance: tuple[str, ...] | tuple[tuple[str, ...], ...] = setting(
        doc="joint names of the balance arm, or a list of such lists for several balance arms",
        min_items=1,
        item="joint",
    )
    locked: dict[str, float] = setting(
        factory=dict,
        unit="rad or m",
        doc="positions of locked joints; every other joint in no arm is locked at 0",
    )
    ee_frames: dict[str, str] = setting(
        factory=dict,
        doc="end-effector link per arm (mission, balance, balance2, ...); "
        "default: the last link of the arm's chain",
    )


@dataclass(frozen=True, kw_only=True)
class InitialSpec:
    """The state at t = 0. The mission arm starts where its trajectory starts."""

    balance: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        per="balance joint",
        doc="balance joint positions at t = 0, in the order of arms.balance "
        "(default: 0, moved inside the limits)",
    )
    momentum: tuple[float, ...] = setting(
        (0.0,) * 6,
        unit="N s; N m s",
        min_items=6,
        max_items=6,
        doc="total momentum h0 of the system, world frame, [linear; angular about the centre of mass]",
    )


def _timing():
    """Every mission type's ``timing`` (one declaration, last among its keys)."""
    return setting(
        TIMINGS[0],
        doc="given: the trajectory as given; free: its path, the timing planned by the optimal "
        "planner together with the balance arm (mission joints within their velocity and "
        "acceleration limits; the analytic law keeps the given timing)",
    )


@dataclass(frozen=True, kw_only=True)
class PtpMission:
    """Point to point, rest to rest, quintic time law (the paper's PTP)."""

    type: Literal["ptp"] = setting("ptp", doc="point to point")
    start: tuple[float, ...] = setting(
        unit="rad", per="mission joint", doc="mission joint positions at t = 0", min_items=1
    )
    goal: tuple[float, ...] = setting(
        unit="rad", per="mission joint", doc="mission joint positions at the end", min_items=1
    )
    duration: float = setting(unit="s", exclusive_minimum=0.0, doc="duration of the move")
    timing: Literal[TIMINGS] = _timing()


@dataclass(frozen=True, kw_only=True)
class ViaMission:
    """Through via points, smooth (C4), at rest at the first and last."""

    type: Literal["via"] = setting("via", doc="via points")
    times: tuple[float, ...] = setting(
        unit="s", minimum=0.0, min_items=2, doc="time of each point: the first 0, increasing"
    )
    points: tuple[tuple[float, ...], ...] = setting(
        unit="rad", per="mission joint", min_items=2, doc="mission joint positions at each time"
    )
    timing: Literal[TIMINGS] = _timing()


@dataclass(frozen=True, kw_only=True)
class CsvMission:
    """Read from a CSV file: a time column and one column per mission joint, by name."""

    type: Literal["csv"] = setting("csv", doc="CSV file")
    file: str = setting(doc="path of the CSV file, relative to the task file")
    time_column: str = setting("time", doc="name of the time column [s]")
    timing: Literal[TIMINGS] = _timing()


@dataclass(frozen=True, kw_only=True)
class CartesianMission:
    """A goal pose of the mission end effector, solved to joint angles by inverse kinematics,
    then reached point to point."""

    type: Literal["cartesian"] = setting("cartesian", doc="Cartesian goal")
    start: tuple[float, ...] = setting(
        unit="rad", per="mission joint", doc="mission joint positions at t = 0", min_items=1
    )
    position: tuple[float, ...] = setting(
        unit="m",
        min_items=3,
        max_items=3,
        doc="goal position of the end effector, initial base frame",
    )
    orientation: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        min_items=3,
        max_items=3,
        doc="goal roll, pitch, yaw of the end effector, initial base frame (default: free)",
    )
    duration: float = setting(unit="s", exclusive_minimum=0.0, doc="duration of the move")
    timing: Literal[TIMINGS] = _timing()


MissionSpec = PtpMission | ViaMission | CsvMission | CartesianMission


@dataclass(frozen=True, kw_only=True)
class CaptureSpec:
    """A moving target captured by the mission end effector during the mission: from the
    capture time on it is rigidly attached there, and the system carries its momentum."""

    time: float = setting(
        unit="s", exclusive_minimum=0.0, doc="capture time, strictly inside the mission"
    )
    mass: float = setting(unit="kg", exclusive_minimum=0.0, doc="mass of the target")
    inertia: tuple[float, ...] = setting(
        unit="kg m^2",
        min_items=6,
        max_items=6,
        doc="inertia of the target about its centre of mass, axes of the mission end-effector "
        "frame: ixx, ixy, ixz, iyy, iyz, izz",
    )
    com: tuple[float, ...] = setting(
        (0.0, 0.0, 0.0),
        unit="m",
        min_items=3,
        max_items=3,
        doc="centre of mass of the target in the mission end-effector frame",
    )
    linear_velocity: tuple[float, ...] = setting(
        (0.0, 0.0, 0.0),
        unit="m/s",
        min_items=3,
        max_items=3,
        doc="velocity of the target's centre of mass just before the capture, world frame",
    )
    angular_velocity: tuple[float, ...] = setting(
        (0.0, 0.0, 0.0),
        unit="rad/s",
        min_items=3,
        max_items=3,
        doc="angular velocity of the target just before the capture, world frame",
    )


@dataclass(frozen=True, kw_only=True)
class LimitSpec:
    """Overrides of one joint's limits; keys left out keep the URDF's value."""

    lower: float | None = setting(None, unit="rad", finite=False, doc="lowest position")
    upper: float | None = setting(None, unit="rad", finite=False, doc="highest position")
    velocity: float | None = setting(
        None, unit="rad/s", exclusive_minimum=0.0, finite=False, doc="largest speed"
    )
    acceleration: float | None = setting(
        None,
        unit="rad/s^2",
        exclusive_minimum=0.0,
        finite=False,
        doc="largest acceleration (URDF has none: unlimited)",
    )
    effort: float | None = setting(
        None, unit="N m", exclusive_minimum=0.0, finite=False, doc="largest torque"
    )
    jerk: float | None = setting(
        None,
        unit="rad/s^3",
        exclusive_minimum=0.0,
        finite=False,
        doc="largest jerk, held by the optimal planner on the whole motion (URDF has none: "
        "unlimited)",
    )


@dataclass(frozen=True, kw_only=True)
class AnalyticSpec:
    """The analytic balance law (Eq. 31, 32) and the integration of its rollout."""

    law: BalanceLawOptions = setting(
        factory=BalanceLawOptions, inline=True, doc="the balance law's settings"
    )
    integration: IntegrationOptions = setting(
        factory=IntegrationOptions, inline=True, doc="how the rollout is integrated"
    )


@dataclass(frozen=True, kw_only=True)
class OptimalSpec:
    """The optimal planner: direct collocation solved by Ipopt, and where it starts from."""

    planner: PlannerOptions = setting(
        factory=PlannerOptions, inline=True, doc="the planner's settings"
    )
    initial_guess: Literal[GUESSES] = setting(
        GUESSES[0],
        after="horizon",
        doc="initial guess: the analytic law clipped to the limits, or the rest configuration",
    )


@dataclass(frozen=True, kw_only=True)
class OutputsSpec:
    """Which files ``balance-opt plan`` writes."""

    csv: bool = setting(True, doc="trajectories as CSV, one file per method")
    npz: bool = setting(True, doc="trajectories as NumPy .npz, one file per method")
    plots: bool = setting(True, doc="figures as PNG")
    report: bool = setting(True, doc="self-contained HTML report (report.html)")
    animation: bool = setting(
        True, doc="the 3D scene of the plans (scene.html), shown in the report"
    )


@dataclass(frozen=True, kw_only=True)
class TaskSpec:
    """A balance-opt task: robot, arms, start, mission, limits and the options of each method."""

    name: str | None = setting(
        None,
        pattern=NAME_PATTERN,
        doc="short name used in reports and as the default output folder (default: the file name)",
    )
    description: str | None = setting(None, doc="free text shown in the report")
    robot: RobotSpec = setting(doc="the robot's URDF")
    arms: ArmsSpec = setting(doc="mission and balance arms")
    mission: MissionSpec = setting(doc="the mission arm's trajectory")
    initial: InitialSpec = setting(factory=InitialSpec, doc="state at t = 0")
    capture: CaptureSpec | None = setting(
        None, doc="a target captured during the mission (default: none)"
    )
    limits: dict[str, LimitSpec] = setting(
        factory=dict, doc="limit overrides, by joint name (NAME: a joint of an arm)"
    )
    keep_out: tuple[KeepOutZone, ...] = setting(
        (),
        doc="keep-out zones fixed on robot frames that the arms' links must stay out of "
        "(docs/collision.md)",
    )
    analytic: AnalyticSpec = setting(factory=AnalyticSpec, doc="the analytic balance law")
    optimal: OptimalSpec = setting(factory=OptimalSpec, doc="the optimal planner")
    simulation: SimulationOptions = setting(
        factory=SimulationOptions, doc="the forward-dynamics simulation"
    )
    robustness: RobustnessOptions = setting(
        factory=RobustnessOptions, doc="drift under model error (perturbed masses and inertias)"
    )
    closed_loop: ClosedLoopOptions = setting(
        factory=ClosedLoopOptions,
        doc="closed loop: re-planning from the measured state on perturbed models (--closed-loop)",
    )
    outputs: OutputsSpec = setting(factory=OutputsSpec, doc="files to write")


def task_json_schema() -> dict:
    """JSON Schema (draft 2020-12) of task files, for editors (``balance-opt validate --schema``)."""
    return json_schema(TaskSpec, "balance-opt task file", SCHEMA_ID)


def task_reference_markdown() -> str:
    """Reference table of every task-file key (type, default, meaning), as in the README."""
    return reference_markdown(TaskSpec)
