"""Task files: one YAML file says which robot, which arms, which mission and which options.

The format is the tree of frozen dataclasses below, rooted at :class:`TaskSpec`; it is the single
source of truth for the validator, the JSON Schema (:func:`task_json_schema`, ``balance-opt
validate --schema``) and the README's reference table (:func:`task_reference_markdown`).

Loading happens in two steps, both at the boundary, before any planning:

1. :func:`typed_config.from_data` checks types, required and unknown keys and value ranges;
2. :func:`load_task` resolves files (URDF, CSV, relative to the task file), builds the robot
   (unknown joints), the mission trajectory (lengths, durations, CSV contents) and checks that
   the limits can be met at all (start inside the limits, mission within its own limits).

Every error is an :class:`~balance_opt.errors.InputError` whose message starts with
``FILE:LINE: KEY.PATH:``.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.dynamics.options import CONTROLLERS, SimulationOptions
from balance_opt.dynamics.options import INTEGRATORS as SIMULATION_INTEGRATORS
from balance_opt.errors import (
    ArmError,
    InfeasibleLimitsError,
    InputError,
    JointError,
    TrajectoryError,
    URDFLoadError,
)
from balance_opt.io.typed_config import from_data, json_schema, reference_markdown, setting
from balance_opt.io.yaml_lines import TaskFileError, YamlDocument, load_yaml
from balance_opt.model.robot import LIMIT_KEYS, FloatingRobot
from balance_opt.motion.options import INTEGRATION_METHODS, IntegrationOptions
from balance_opt.motion.trajectories import CsvTrajectory, JointTrajectory, PointToPoint, ViaPoints
from balance_opt.optimal.collocation import TRANSCRIPTIONS
from balance_opt.optimal.options import CONTROLS, GUESSES, CostWeights, PlannerOptions
from balance_opt.result import LIMIT_TOLERANCE, find_limit_violations

log = logging.getLogger(__name__)

#: Samples per second used to check a mission trajectory against its limits [1/s].
LIMIT_CHECK_RATE = 200.0
#: Fewest samples used to check a mission trajectory against its limits.
LIMIT_CHECK_MIN_SAMPLES = 501
#: Spacing of the samples a task's results are written at [s] (the libraries' default is 1 ms:
#: ten times more rows than a report needs).
TASK_OUTPUT_STEP = 0.01
SCHEMA_ID = "https://balance-opt.invalid/task.schema.json"


class TaskLimitsError(TaskFileError, InfeasibleLimitsError):
    """Limits that no plan can meet, located in the task file."""


class TaskTrajectoryError(TaskFileError, TrajectoryError):
    """A mission trajectory that cannot be built, located in the task file."""


# =========================================================================================== format
@dataclass(frozen=True, kw_only=True)
class RobotSpec:
    """Which URDF: exactly one of ``urdf``, ``shipped`` or ``example``."""

    __exactly_one__ = ("urdf", "shipped", "example")

    urdf: str | None = setting(None, doc="path of a URDF file, relative to the task file")
    shipped: str | None = setting(
        None, doc="name of a URDF shipped with balance-opt (folder urdf/), e.g. paper_robot.urdf"
    )
    example: str | None = setting(None, doc="name of an example-robot-data robot, e.g. baxter")


@dataclass(frozen=True, kw_only=True)
class ArmsSpec:
    """Which joints move: the mission arm, the balance arm(s), and where the rest is locked."""

    mission: tuple[str, ...] = setting(doc="joint names of the mission arm, in order", min_items=1)
    balance: tuple[str, ...] | tuple[tuple[str, ...], ...] = setting(
        doc="joint names of the balance arm, or a list of such lists for several balance arms",
        min_items=1,
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


@dataclass(frozen=True, kw_only=True)
class PtpMission:
    """Point to point, rest to rest, quintic time law (the paper's PTP)."""

    type: Literal["ptp"] = setting("ptp", doc="point to point")
    start: tuple[float, ...] = setting(
        unit="rad", doc="mission joint positions at t = 0", min_items=1
    )
    goal: tuple[float, ...] = setting(
        unit="rad", doc="mission joint positions at the end", min_items=1
    )
    duration: float = setting(unit="s", exclusive_minimum=0.0, doc="duration of the move")


@dataclass(frozen=True, kw_only=True)
class ViaMission:
    """Through via points, smooth (C4), at rest at the first and last."""

    type: Literal["via"] = setting("via", doc="via points")
    times: tuple[float, ...] = setting(
        unit="s", minimum=0.0, min_items=2, doc="time of each point: the first 0, increasing"
    )
    points: tuple[tuple[float, ...], ...] = setting(
        unit="rad", min_items=2, doc="mission joint positions at each time"
    )


@dataclass(frozen=True, kw_only=True)
class CsvMission:
    """Read from a CSV file: a time column and one column per mission joint, by name."""

    type: Literal["csv"] = setting("csv", doc="CSV file")
    file: str = setting(doc="path of the CSV file, relative to the task file")
    time_column: str = setting("time", doc="name of the time column [s]")


@dataclass(frozen=True, kw_only=True)
class CartesianMission:
    """A goal pose of the mission end effector, solved to joint angles by inverse kinematics,
    then reached point to point."""

    type: Literal["cartesian"] = setting("cartesian", doc="Cartesian goal")
    start: tuple[float, ...] = setting(
        unit="rad", doc="mission joint positions at t = 0", min_items=1
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


MissionSpec = PtpMission | ViaMission | CsvMission | CartesianMission


@dataclass(frozen=True, kw_only=True)
class LimitSpec:
    """Overrides of one joint's limits; keys left out keep the URDF's value."""

    lower: float | None = setting(None, unit="rad", doc="lowest position")
    upper: float | None = setting(None, unit="rad", doc="highest position")
    velocity: float | None = setting(None, unit="rad/s", exclusive_minimum=0.0, doc="largest speed")
    acceleration: float | None = setting(
        None,
        unit="rad/s^2",
        exclusive_minimum=0.0,
        doc="largest acceleration (URDF has none: unlimited)",
    )
    effort: float | None = setting(None, unit="N m", exclusive_minimum=0.0, doc="largest torque")


def _default(cls, name: str):
    """Default of field ``name`` of the option dataclass ``cls``: the library's own, so that a
    task file and a Python call with no options do the same thing."""
    f = cls.__dataclass_fields__[name]
    return f.default_factory() if f.default is MISSING else f.default


@dataclass(frozen=True, kw_only=True)
class AnalyticSpec:
    """The analytic balance law (Eq. 31, 32; :class:`~balance_opt.analytic.law.BalanceLawOptions`)
    and the integration of its rollout (:class:`~balance_opt.motion.options.IntegrationOptions`)."""

    damping_threshold: float = setting(
        _default(BalanceLawOptions, "damping_threshold"),
        minimum=0.0,
        doc="sigma_min(J_wB) below which damped least squares replaces the exact solve (0: always exact)",
    )
    max_damping: float = setting(
        _default(BalanceLawOptions, "max_damping"),
        minimum=0.0,
        doc="damping at a singular J_wB (lambda_max)",
    )
    null_space_gain: float = setting(
        _default(BalanceLawOptions, "null_space_gain"),
        minimum=0.0,
        unit="1/s",
        doc="gain of the null-space pull toward null_space_goal (redundant balance arms)",
    )
    null_space_goal: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        doc="null-space goal, one value per balance joint (default: middle of each joint's range)",
    )
    attitude_gain: float = setting(
        _default(BalanceLawOptions, "attitude_gain"),
        minimum=0.0,
        unit="1/s",
        doc="gain K of the attitude feedback -K log(R_0^T R) (0: open loop)",
    )
    integrator: Literal[INTEGRATION_METHODS] = setting(
        _default(IntegrationOptions, "method"),
        doc="adaptive (DOP853, error-controlled) or rk4 (fixed step)",
    )
    rtol: float = setting(
        _default(IntegrationOptions, "rtol"),
        exclusive_minimum=0.0,
        doc="relative tolerance of the adaptive integrator",
    )
    atol: float = setting(
        _default(IntegrationOptions, "atol"),
        exclusive_minimum=0.0,
        doc="absolute tolerance of the adaptive integrator",
    )
    step: float | None = setting(
        None,
        unit="s",
        exclusive_minimum=0.0,
        doc="largest integration step (rk4 default: output_step)",
    )
    output_step: float = setting(
        TASK_OUTPUT_STEP, unit="s", exclusive_minimum=0.0, doc="spacing of the output samples"
    )

    def law_options(self, h0) -> BalanceLawOptions:
        """The law's options, with the task's initial momentum ``h0``."""
        return BalanceLawOptions(
            damping_threshold=self.damping_threshold,
            max_damping=self.max_damping,
            null_space_gain=self.null_space_gain,
            null_space_goal=self.null_space_goal,
            attitude_gain=self.attitude_gain,
            h0=tuple(float(x) for x in h0),
        )

    def integration_options(self) -> IntegrationOptions:
        return IntegrationOptions(
            method=self.integrator,
            rtol=self.rtol,
            atol=self.atol,
            step=self.step,
            output_step=self.output_step,
        )


@dataclass(frozen=True, kw_only=True)
class WeightsSpec:
    """Weights of the optimal planner's objective (:class:`~balance_opt.optimal.planner.CostWeights`)."""

    omega: float = setting(
        _default(CostWeights, "omega"),
        minimum=0.0,
        doc="base angular rate, integral of |omega_b|^2 (the paper's goal)",
    )
    terminal: float = setting(
        _default(CostWeights, "terminal"), minimum=0.0, doc="final attitude error |log R_T|^2"
    )
    smoothness: float = setting(
        _default(CostWeights, "smoothness"),
        minimum=0.0,
        doc="integral of the squared control (balance accelerations or jerks)",
    )
    rest: float = setting(
        _default(CostWeights, "rest"),
        minimum=0.0,
        doc="pull toward rest_configuration, integral of |q_B - q_rest|^2",
    )
    attitude: float = setting(
        _default(CostWeights, "attitude"),
        minimum=0.0,
        doc="attitude error along the path, integral of |log R|^2",
    )


@dataclass(frozen=True, kw_only=True)
class ConstraintsSpec:
    """Constraints of the optimal planner."""

    position_limits: bool = setting(
        _default(PlannerOptions, "position_limits"),
        doc="balance joints within their position limits (continuous motion)",
    )
    velocity_limits: bool = setting(
        _default(PlannerOptions, "velocity_limits"),
        doc="balance joints within their velocity limits",
    )
    acceleration_limits: bool = setting(
        _default(PlannerOptions, "acceleration_limits"),
        doc="balance joints within their acceleration limits",
    )
    torque_limits: bool = setting(
        _default(PlannerOptions, "torque_limits"),
        doc="balance joint torques (free-floating inverse dynamics) within their effort limits",
    )
    terminal_attitude_bound: float | None = setting(
        None,
        unit="rad",
        exclusive_minimum=0.0,
        doc="hard bound on the final attitude error |log R_T|",
    )
    path_attitude_bound: float | None = setting(
        None,
        unit="rad",
        exclusive_minimum=0.0,
        doc="hard bound on the attitude error |log R(t)| along the path",
    )
    rest_at_end: bool = setting(
        _default(PlannerOptions, "rest_at_end"), doc="balance arm at rest at the end"
    )
    final_configuration: tuple[float, ...] | None = setting(
        None, unit="rad", doc="prescribed final balance configuration, one value per balance joint"
    )


@dataclass(frozen=True, kw_only=True)
class OptimalSpec:
    """The optimal planner: direct collocation solved by Ipopt (:class:`~balance_opt.optimal.planner.PlannerOptions`)."""

    intervals: int = setting(
        _default(PlannerOptions, "intervals"), minimum=2, doc="collocation intervals N"
    )
    transcription: Literal[TRANSCRIPTIONS] = setting(
        _default(PlannerOptions, "transcription"), doc="collocation scheme"
    )
    control: Literal[CONTROLS] = setting(
        _default(PlannerOptions, "control"),
        doc="control input: balance joint accelerations or jerks",
    )
    horizon: float | None = setting(
        None,
        unit="s",
        exclusive_minimum=0.0,
        doc="planning horizon, at least the mission's duration (default: the mission's)",
    )
    initial_guess: Literal[GUESSES] = setting(
        GUESSES[0],
        doc="initial guess: the analytic law clipped to the limits, or the rest configuration",
    )
    weights: WeightsSpec = setting(factory=WeightsSpec, doc="objective weights")
    rest_configuration: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        doc="q_rest of the rest weight, one value per balance joint (default: initial.balance)",
    )
    constraints: ConstraintsSpec = setting(factory=ConstraintsSpec, doc="constraints")
    tolerance: float = setting(
        _default(PlannerOptions, "tolerance"),
        exclusive_minimum=0.0,
        doc="Ipopt's convergence tolerance (tol)",
    )
    max_iterations: int = setting(
        _default(PlannerOptions, "max_iterations"),
        minimum=0,
        doc="Ipopt's iteration limit (max_iter)",
    )
    resample_step: float = setting(
        _default(PlannerOptions, "resample_step"),
        unit="s",
        exclusive_minimum=0.0,
        doc="largest step of the fine grid the plan is re-simulated on",
    )
    ipopt: dict[str, int | float | str] = setting(
        factory=dict, doc="Ipopt options passed through, e.g. {print_level: 5}"
    )

    def planner_options(self, extra_ipopt: Mapping[str, Any] | None = None) -> PlannerOptions:
        """The planner's options; ``extra_ipopt`` (``--solver-option``) overrides ``ipopt``."""
        c = self.constraints
        return PlannerOptions(
            intervals=self.intervals,
            transcription=self.transcription,
            control=self.control,
            horizon=self.horizon,
            weights=CostWeights(
                **{f: getattr(self.weights, f) for f in WeightsSpec.__dataclass_fields__}
            ),
            rest_configuration=self.rest_configuration,
            position_limits=c.position_limits,
            velocity_limits=c.velocity_limits,
            acceleration_limits=c.acceleration_limits,
            torque_limits=c.torque_limits,
            terminal_attitude_bound=c.terminal_attitude_bound,
            path_attitude_bound=c.path_attitude_bound,
            rest_at_end=c.rest_at_end,
            final_configuration=c.final_configuration,
            tolerance=self.tolerance,
            max_iterations=self.max_iterations,
            resample_step=self.resample_step,
            ipopt={**self.ipopt, **(extra_ipopt or {})},
        )


@dataclass(frozen=True, kw_only=True)
class SimulationSpec:
    """The forward-dynamics check of each plan (:class:`~balance_opt.dynamics.simulation.SimulationOptions`)."""

    integrator: Literal[SIMULATION_INTEGRATORS] = setting(
        _default(SimulationOptions, "integrator"), doc="rk4 (fixed step dt) or dopri5 (adaptive)"
    )
    dt: float = setting(
        _default(SimulationOptions, "dt"),
        unit="s",
        exclusive_minimum=0.0,
        doc="integration step (dopri5: first step)",
    )
    rtol: float = setting(
        _default(SimulationOptions, "rtol"), exclusive_minimum=0.0, doc="dopri5 relative tolerance"
    )
    atol: float = setting(
        _default(SimulationOptions, "atol"), exclusive_minimum=0.0, doc="dopri5 absolute tolerance"
    )
    max_step: float = setting(
        _default(SimulationOptions, "max_step"),
        unit="s",
        exclusive_minimum=0.0,
        doc="dopri5 largest step",
    )
    output_dt: float | None = setting(
        TASK_OUTPUT_STEP,
        unit="s",
        exclusive_minimum=0.0,
        doc="time between output samples (none: every rk4 step)",
    )
    controller: Literal[CONTROLLERS] = setting(
        _default(SimulationOptions, "controller"),
        doc="joint controller: PD (the paper's) or computed torque + PD",
    )
    kp: float | tuple[float, ...] | None = setting(
        None,
        unit="N m/rad",
        minimum=0.0,
        doc="proportional gains, one or one per arm joint (default: from bandwidth)",
    )
    kd: float | tuple[float, ...] | None = setting(
        None,
        unit="N m s/rad",
        minimum=0.0,
        doc="derivative gains, one or one per arm joint (default: from bandwidth)",
    )
    bandwidth: float = setting(
        _default(SimulationOptions, "bandwidth"),
        unit="rad/s",
        exclusive_minimum=0.0,
        doc="natural frequency of the default gains",
    )
    damping_ratio: float = setting(
        _default(SimulationOptions, "damping_ratio"),
        exclusive_minimum=0.0,
        doc="damping ratio of the default gains",
    )
    clip_torque: bool = setting(
        _default(SimulationOptions, "clip_torque"),
        doc="saturate joint torques at their effort limits",
    )

    def simulation_options(self, h0) -> SimulationOptions:
        """The simulator's options, with the task's initial momentum ``h0``."""
        return SimulationOptions(
            integrator=self.integrator,
            dt=self.dt,
            rtol=self.rtol,
            atol=self.atol,
            max_step=self.max_step,
            output_dt=self.output_dt,
            controller=self.controller,
            kp=self.kp,
            kd=self.kd,
            bandwidth=self.bandwidth,
            damping_ratio=self.damping_ratio,
            clip_torque=self.clip_torque,
            h0=tuple(float(x) for x in h0),
        )


@dataclass(frozen=True, kw_only=True)
class OutputsSpec:
    """Which files ``balance-opt plan`` writes."""

    csv: bool = setting(True, doc="trajectories as CSV, one file per method")
    npz: bool = setting(True, doc="trajectories as NumPy .npz, one file per method")
    plots: bool = setting(True, doc="figures as PNG")
    report: bool = setting(True, doc="self-contained HTML report (report.html)")
    animation: bool = setting(
        True, doc="a 3D animation of the plans in the report (stick figure, inline script)"
    )


@dataclass(frozen=True, kw_only=True)
class TaskSpec:
    """A balance-opt task: robot, arms, start, mission, limits and the options of each method."""

    name: str | None = setting(None, doc="short name used in reports (default: the file name)")
    description: str | None = setting(None, doc="free text shown in the report")
    robot: RobotSpec = setting(doc="the robot's URDF")
    arms: ArmsSpec = setting(doc="mission and balance arms")
    mission: MissionSpec = setting(doc="the mission arm's trajectory")
    initial: InitialSpec = setting(factory=InitialSpec, doc="state at t = 0")
    limits: dict[str, LimitSpec] = setting(
        factory=dict, doc="limit overrides, by joint name (NAME: a joint of an arm)"
    )
    analytic: AnalyticSpec = setting(factory=AnalyticSpec, doc="the analytic balance law")
    optimal: OptimalSpec = setting(factory=OptimalSpec, doc="the optimal planner")
    simulation: SimulationSpec = setting(
        factory=SimulationSpec, doc="the forward-dynamics simulation"
    )
    outputs: OutputsSpec = setting(factory=OutputsSpec, doc="files to write")


# =========================================================================================== loaded task
@dataclass(frozen=True)
class Task:
    """A validated task, its robot and mission built, ready to plan.

    Attributes:
        spec: the typed content of the file.
        source: the file name as given (``"<dict>"`` for a task built from data).
        base_dir: folder that relative paths in the task are relative to.
        sha256: SHA-256 of the file's bytes (of the canonical JSON of the data for ``<dict>``).
        robot: the floating robot.
        mission: the mission arm's trajectory (its start is the mission start).
        q_B0: balance joint positions at t = 0 [rad].
        h0: initial momentum, world frame, [linear; angular] [N s; N m s].
        document: the parsed file with its line numbers (for locating errors found later).
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

    @property
    def name(self) -> str:
        """The task's name: ``name:`` in the file, else the file's stem."""
        if self.spec.name:
            return self.spec.name
        return Path(self.source).stem if self.source != "<dict>" else "task"

    @property
    def q0(self) -> np.ndarray:
        """Initial arm vector [rad]: mission start, then balance start."""
        return np.r_[self.mission.start, self.q_B0]

    @property
    def duration(self) -> float:
        """Duration of the mission [s]."""
        return float(self.mission.duration)

    def error(self, path, reason: str, cls=TaskFileError) -> TaskFileError:
        """An error located at key ``path`` of this task's file."""
        return cls(self.source, self.document.line_of(path), path, reason)


# =========================================================================================== loading
def _sha256_file(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def load_task(path: str | Path) -> Task:
    """Load, validate and build the task in the YAML file at ``path``: everything short of planning.

    Raises:
        InputError: (a :class:`TaskFileError` or subclass) naming the file, the line, the key
            path and what was expected.
    """
    path = Path(path)
    doc = load_yaml(path)
    return task_from_document(doc, path.parent, _sha256_file(path))


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
    """Validate a parsed document and build its robot and mission (see :func:`load_task`)."""
    if not isinstance(doc.data, dict):
        raise doc.error(
            (),
            f"expected a mapping of task keys ({', '.join(TaskSpec.__dataclass_fields__)}), "
            f"got {type(doc.data).__name__}",
        )
    spec: TaskSpec = from_data(TaskSpec, doc)
    robot = _build_robot(spec, doc, base_dir)
    mission = _build_mission(spec, doc, base_dir, robot)
    q_B0 = _initial_balance(spec, doc, robot)
    task = Task(
        spec,
        doc.source,
        base_dir,
        sha256,
        robot,
        mission,
        q_B0,
        np.asarray(spec.initial.momentum, dtype=float),
        doc,
    )
    _check_limits(task)
    _check_options(task)
    log.debug("task %s: %r, mission %.3g s", doc.source, robot, mission.duration)
    return task


def _urdf_path(spec: TaskSpec, doc: YamlDocument, base_dir: Path) -> Path:
    from balance_opt.model.library import example_robot_urdf, shipped_urdf

    r = spec.robot
    if r.urdf is not None:
        path = base_dir / r.urdf
        if not path.is_file():
            raise doc.error(("robot", "urdf"), f"no such URDF file: {path}")
        return path
    try:
        return shipped_urdf(r.shipped) if r.shipped is not None else example_robot_urdf(r.example)
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
    except JointError as exc:
        raise doc.error(_joint_path(doc, exc.joint, exc.reason), str(exc)) from None
    except ArmError as exc:
        path = ("arms", "ee_frames", exc.arm) if exc.arm in a.ee_frames else ("arms", exc.arm)
        if exc.arm.startswith("balance") and exc.arm not in a.ee_frames:
            path = ("arms", "balance")
        raise doc.error(path, str(exc)) from None


def _check_length(doc: YamlDocument, path: tuple, values, n: int, what: str) -> np.ndarray:
    if len(values) != n:
        raise doc.error(path, f"expected {n} values ({what}), got {len(values)}")
    return np.asarray(values, dtype=float)


def _build_mission(
    spec: TaskSpec, doc: YamlDocument, base_dir: Path, robot: FloatingRobot
) -> JointTrajectory:
    m = spec.mission
    n = robot.mission.dof
    what = f"one per mission joint: {', '.join(robot.mission.joints)}"
    try:
        if isinstance(m, PtpMission):
            start = _check_length(doc, ("mission", "start"), m.start, n, what)
            goal = _check_length(doc, ("mission", "goal"), m.goal, n, what)
            return PointToPoint(start, goal, m.duration)
        if isinstance(m, ViaMission):
            if len(m.times) != len(m.points):
                raise doc.error(
                    ("mission", "times"),
                    f"expected one time per point: {len(m.points)} points, {len(m.times)} times",
                )
            points = np.array(
                [
                    _check_length(doc, ("mission", "points", i), p, n, what)
                    for i, p in enumerate(m.points)
                ]
            )
            if m.times[0] != 0.0:
                raise doc.error(
                    ("mission", "times", 0), f"the first time must be 0 s, got {m.times[0]:g}"
                )
            for i in range(1, len(m.times)):
                if not m.times[i] > m.times[i - 1]:
                    raise doc.error(
                        ("mission", "times", i),
                        f"times must increase: {m.times[i]:g} s after {m.times[i - 1]:g} s",
                    )
            return ViaPoints(m.times, points)
        if isinstance(m, CsvMission):
            path = base_dir / m.file
            if not path.is_file():
                raise doc.error(("mission", "file"), f"no such CSV file: {path}")
            try:
                return CsvTrajectory(path, robot.mission.joints, time_column=m.time_column)
            except TrajectoryError as exc:
                raise TaskTrajectoryError(
                    doc.source, doc.line_of(("mission", "file")), ("mission", "file"), str(exc)
                ) from None
        if isinstance(m, CartesianMission):
            start = _check_length(doc, ("mission", "start"), m.start, n, what)
            return _cartesian_mission(m, doc, robot, start)
    except TrajectoryError as exc:
        if isinstance(exc, TaskFileError):
            raise
        raise TaskTrajectoryError(
            doc.source, doc.line_of(("mission",)), ("mission",), str(exc)
        ) from None
    raise AssertionError(f"unhandled mission type {type(m).__name__}")


def _cartesian_mission(
    m: CartesianMission, doc: YamlDocument, robot: FloatingRobot, start: np.ndarray
) -> JointTrajectory:
    """Inverse kinematics to the goal pose (base at its initial pose), then point to point."""
    import pinocchio as pin

    from balance_opt.motion.trajectories import cartesian_goal

    rotation = None if m.orientation is None else pin.rpy.rpyToMatrix(*m.orientation)
    try:
        return cartesian_goal(robot, start, m.position, m.duration, orientation=rotation)
    except TrajectoryError as exc:
        raise TaskTrajectoryError(
            doc.source, doc.line_of(("mission", "position")), ("mission", "position"), str(exc)
        ) from None


def _initial_balance(spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot) -> np.ndarray:
    nb = robot.balance_indices.size
    if spec.initial.balance is None:
        return robot.neutral()[robot.balance_indices]
    names = [robot.joint_names[i] for i in robot.balance_indices]
    return _check_length(
        doc,
        ("initial", "balance"),
        spec.initial.balance,
        nb,
        f"one per balance joint: {', '.join(names)}",
    )


def _limit_source(task: Task, joint: str, key: str) -> str:
    over = task.spec.limits.get(joint)
    return (
        f"limits.{joint}.{key}" if over is not None and getattr(over, key) is not None else "URDF"
    )


def _check_limits(task: Task) -> None:
    """Limits no plan can meet: a balance start outside the position limits, a mission that
    leaves its own position, velocity or acceleration limits."""
    robot, lim = task.robot, task.robot.limits
    for k, i in enumerate(robot.balance_indices):
        j, q = robot.joint_names[i], task.q_B0[k]
        if not lim.lower[i] - LIMIT_TOLERANCE <= q <= lim.upper[i] + LIMIT_TOLERANCE:
            key = "lower" if q < lim.lower[i] else "upper"
            raise task.error(
                ("initial", "balance", k) if task.spec.initial.balance else ("initial",),
                f"balance joint '{j}' starts at {q:g} rad, outside its position limits "
                f"[{lim.lower[i]:g}, {lim.upper[i]:g}] rad ({key} limit from "
                f"{_limit_source(task, j, key)}); no plan can meet them",
                TaskLimitsError,
            )
    mission = task.mission
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
        raise task.error(
            ("mission",),
            f"the mission trajectory leaves the limits of the mission arm, which "
            f"follows it as given: {v} (limit from "
            f"{_limit_source(task, v.joint, key)}); no plan can meet them",
            TaskLimitsError,
        )


def _check_options(task: Task) -> None:
    """Sizes of per-joint options, and the option objects of each method built once, so that
    their own checks fail here, located, rather than after planning started."""
    robot, spec = task.robot, task.spec
    n_B = robot.balance_indices.size
    names = ", ".join(robot.joint_names[i] for i in robot.balance_indices)
    per_balance = (
        (("analytic", "null_space_goal"), spec.analytic.null_space_goal),
        (("optimal", "rest_configuration"), spec.optimal.rest_configuration),
        (
            ("optimal", "constraints", "final_configuration"),
            spec.optimal.constraints.final_configuration,
        ),
    )
    for path, values in per_balance:
        if values is not None:
            _check_length(task.document, path, values, n_B, f"one per balance joint: {names}")
    for key in ("kp", "kd"):
        value = getattr(spec.simulation, key)
        if isinstance(value, tuple) and len(value) not in (1, robot.n):
            raise task.error(
                ("simulation", key),
                f"expected one gain or {robot.n} (one per arm joint: "
                f"{', '.join(robot.joint_names)}), got {len(value)}",
            )
    horizon = spec.optimal.horizon
    if horizon is not None and horizon < task.duration:
        raise task.error(
            ("optimal", "horizon"),
            f"the horizon ({horizon:g} s) is shorter than the mission ({task.duration:g} s)",
        )
    final = spec.optimal.constraints.final_configuration
    if final is not None and spec.optimal.constraints.position_limits:
        lim = robot.limits.subset(robot.balance_indices)
        for k, value in enumerate(final):
            if not lim.lower[k] - LIMIT_TOLERANCE <= value <= lim.upper[k] + LIMIT_TOLERANCE:
                j = robot.joint_names[robot.balance_indices[k]]
                raise task.error(
                    ("optimal", "constraints", "final_configuration", k),
                    f"balance joint '{j}' must end at {value:g} rad, outside its position limits "
                    f"[{lim.lower[k]:g}, {lim.upper[k]:g}] rad; no plan can meet them",
                    TaskLimitsError,
                )
    for section, build in (
        (
            "analytic",
            lambda: (spec.analytic.law_options(task.h0), spec.analytic.integration_options()),
        ),
        ("optimal", spec.optimal.planner_options),
        ("simulation", lambda: spec.simulation.simulation_options(task.h0)),
    ):
        try:
            build()
        except InputError as exc:
            raise task.error((section,), str(exc)) from None


def check_optimal_supported(task: Task) -> None:
    """The optimal planner assumes zero initial momentum (``nlp_model``): say so, located at
    ``initial.momentum``, before anything is computed."""
    if np.any(task.h0 != 0.0):
        raise task.error(
            ("initial", "momentum"),
            "the optimal planner assumes zero initial momentum; "
            "plan this task with --method analytic",
        )


# =========================================================================================== schema
def task_json_schema() -> dict:
    """JSON Schema (draft 2020-12) of task files, for editors (``balance-opt validate --schema``)."""
    return json_schema(TaskSpec, "balance-opt task file", SCHEMA_ID)


def task_reference_markdown() -> str:
    """Reference table of every task-file key (type, default, meaning), as in the README."""
    return reference_markdown(TaskSpec)


__all__ = [
    "AnalyticSpec",
    "ArmsSpec",
    "CartesianMission",
    "ConstraintsSpec",
    "CsvMission",
    "InitialSpec",
    "LimitSpec",
    "MissionSpec",
    "OptimalSpec",
    "OutputsSpec",
    "PtpMission",
    "RobotSpec",
    "SimulationSpec",
    "Task",
    "TaskFileError",
    "TaskLimitsError",
    "TaskSpec",
    "TaskTrajectoryError",
    "ViaMission",
    "WeightsSpec",
    "check_optimal_supported",
    "load_task",
    "task_from_dict",
    "task_from_document",
    "task_json_schema",
    "task_reference_markdown",
]
