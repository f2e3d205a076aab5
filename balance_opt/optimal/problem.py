"""One balance planning problem's numeric data (the mission, the initial configuration, the
horizon and the options, checked against the robot before anything is built) and where
everything sits in its NLP's vectors."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from balance_opt.errors import InfeasibleLimitsError, InputError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion import retiming
from balance_opt.motion.result import LIMIT_TOLERANCE
from balance_opt.optimal.collision import collision_setup, restarted
from balance_opt.optimal.collocation import Transcription
from balance_opt.optimal.exact_rows import at_rest
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import PlannerOptions, Stage


def limited_kinds(options, limits) -> dict[str, bool]:
    """Which limit constraints the planner adds: asked for, and finite for some balance joint."""
    return {
        "acceleration": options.acceleration_limits
        and bool(np.isfinite(limits.acceleration).any()),
        "velocity": options.velocity_limits and bool(np.isfinite(limits.velocity).any()),
        "position": options.position_limits
        and bool((np.isfinite(limits.lower) | np.isfinite(limits.upper)).any()),
        "torque": options.torque_limits and bool(np.isfinite(limits.effort).any()),
        "jerk": options.jerk_limits and bool(np.isfinite(limits.jerk).any()),
    }


@dataclass(frozen=True)
class StructureKey:
    """What two problems must share to share one compiled NLP (everything else is numeric data)."""

    intervals: int
    transcription: str
    control: str
    joint_limits: tuple[str, ...]
    torque_limits: bool
    objective: str
    path_attitude_bound: bool
    terminal_attitude_bound: bool
    tolerance: float
    max_iterations: int
    ipopt: tuple[tuple[str, str], ...]
    momentum: bool = False
    between_points: bool = True
    collision: str = ""
    #: a free mission timing: its path's key (:class:`~balance_opt.motion.retiming.MissionPath`)
    timing: str = ""
    #: the peak objective's stages (their Ipopt options are the structure's)
    stages: tuple[Stage, ...] = ()
    #: the exact rows' pairs (:attr:`~balance_opt.optimal.collision.CollisionSetup.exact_key`)
    exact: str = ""
    #: the drift priced over the last seconds (``PlannerOptions.late_drift``)
    late_drift: bool = False

    @classmethod
    def of(
        cls,
        limits,
        options,
        momentum: bool = False,
        collision: str = "",
        timing: str = "",
        exact: str = "",
    ) -> StructureKey:
        enforced = limited_kinds(options, limits)
        joints = ("position", "velocity", "acceleration", "jerk")
        return cls(
            intervals=int(options.intervals),
            transcription=options.transcription,
            control=options.control,
            joint_limits=tuple(sorted(kind for kind in joints if enforced[kind])),
            torque_limits=enforced["torque"],
            objective="peak" if options.objective == "time" else options.objective,
            path_attitude_bound=options.path_attitude_bound is not None
            and options.objective not in ("peak", "time"),
            terminal_attitude_bound=options.terminal_attitude_bound is not None,
            tolerance=options.tolerance,
            max_iterations=int(options.max_iterations),
            ipopt=tuple(sorted((k, repr(v)) for k, v in options.ipopt.items())),
            momentum=bool(momentum),
            collision=collision if options.collision_avoidance else "",
            timing=timing,
            stages=options.stages,
            exact=exact if options.collision_avoidance else "",
            late_drift=options.late_drift is not None,
        )


@dataclass(frozen=True)
class Bounds:
    """The numbers of a problem's NLP that its solve lowers or sets, never in place: the
    refinement (:mod:`balance_opt.optimal.refine`) makes a new problem with new bounds
    (:meth:`~balance_opt.optimal.solve.BalanceNLP.with_bounds`), so a problem solved twice
    gives the same plan twice.

    Attributes:
        path: the path attitude bound the NLP enforces at the points [rad] (``None``: none).
        terminal: the same for the terminal attitude bound.
        torque_factor: factor on the effort limits at each point (n_B, n_points), read-only.
        peak_reference: the drift ``c`` of the smooth peak stage [rad].
        collision: lower bound of each collision row at each point (n_c, n_points) [m], or
            ``None`` without collision avoidance; read-only: at first
            :meth:`~balance_opt.optimal.collision.CollisionSetup.start_bounds`, raised by
            the refinement where the re-simulated motion came too close.
        exact: the exact rows' linearisation
            (:class:`~balance_opt.optimal.exact_rows.Linearisation`; ``None`` without exact
            rows): at first with the balance arm at its start
            (:func:`~balance_opt.optimal.exact_rows.at_rest`), then at each plan the refinement
            finds too close.
        mission_factor: with a free mission timing, factor on the mission joints' velocity
            and acceleration limits at each point (2 n_M, n_points: the rates, then the
            accelerations), read-only; ``None``: the limits (lowered by the refinement where
            the re-simulated motion breaks them between the points).
    """

    path: float | None
    terminal: float | None
    torque_factor: np.ndarray
    peak_reference: float = 1.0
    collision: np.ndarray | None = None
    mission_factor: np.ndarray | None = None
    exact: Any = None

    def __post_init__(self):
        for name in ("torque_factor", "collision", "mission_factor"):
            value = getattr(self, name)
            if value is not None:
                value = np.array(value, dtype=float)
                value.flags.writeable = False
                object.__setattr__(self, name, value)


@dataclass(frozen=True)
class StartState:
    """Where a re-plan starts (:mod:`balance_opt.control.replan`): the balance arm in the middle
    of a motion and the base turned, instead of the arm at rest at ``q_B0`` and the base at its
    initial attitude. The problem's ``q_B0`` is the balance joints' positions there.

    Attributes:
        velocity, acceleration: the balance joints' rates [rad/s] and accelerations [rad/s^2]
            there (n_B,): the commanded motion stays continuous at the switch.
        attitude: the base's rotation vector ``log R`` there [rad] (3,); the drift stays
            measured from the attitude at ``t = 0``.
        peak: the largest drift of the motion before the start [rad]: the peak objective's
            epigraph variable is at least this (the objective stays the whole motion's peak).
        prepared: the same problem built before the motion from the planned start, whose
            collision rows (and so NLP structure) the re-plan keeps
            (:func:`~balance_opt.optimal.collision.restarted`); ``None``: chosen from this start.
    """

    velocity: np.ndarray
    acceleration: np.ndarray
    attitude: np.ndarray
    peak: float = 0.0
    prepared: Any = None


class BalanceProblem:
    """The numeric data of one balance planning problem, checked against the robot before
    anything is built: the mission arm's motion (``sample(t) -> q, q_dot, q_ddot``,
    ``duration``), the balance arm starting at rest at ``q_B0`` [rad], within the limits of
    ``robot`` (default: the model's robot; the model's kinematics, possibly other limits), and
    ``h0``: the system's constant total momentum, world frame, the base starting at the
    identity, ``[linear (N s); angular about the CoM (N m s)]``, ``None`` for zero. ``start``:
    a :class:`StartState` to start from instead of rest (a re-plan; the mission then starts
    where the re-plan does).

    Attributes:
        horizon: the options' horizon, else the mission's duration [s].
        N, h: number of intervals and their length [s].
        point_times: times of the collocation points [s], nodes then midpoints.
        mission_samples: each point's data ``[q_M; q_dot_M; q_ddot_M; h0]`` (n_m, n_points).
        q_rest: configuration of the rest pull [rad] (``q_B0`` unless the options give one).
        collision: its :class:`~balance_opt.optimal.collision.CollisionSetup` or ``None``.
        bounds: the :class:`Bounds` its NLP enforces: the options' until the refinement
            makes a new problem with lower ones.

    Raises:
        InputError: sizes or options that do not fit the robot.
        InfeasibleLimitsError: ``q_B0`` or the final configuration outside the position limits.
    """

    def __init__(
        self,
        model: PlannerModel,
        mission,
        q_B0,
        options: PlannerOptions,
        robot: FloatingRobot | None = None,
        h0=None,
        start: StartState | None = None,
    ):
        self.model = model
        self.start = start
        self.robot = robot = model.robot if robot is None else robot
        self.mission = mission
        self.options = options
        if robot.joint_names != model.robot.joint_names:
            raise InputError(f"robot {robot.name} is not the robot of the planner model")
        if getattr(mission, "dof", None) != model.n_M:
            raise InputError(
                f"mission trajectory has {getattr(mission, 'dof', '?')} joints, "
                f"the mission arm of {robot.name} has {model.n_M}"
            )
        self.q_B0 = q_B0 = np.asarray(q_B0, dtype=float).ravel()
        self.limits = robot.limits.subset(robot.balance_indices)
        self.balance_joints = names = tuple(robot.joint_names[i] for i in robot.balance_indices)
        if q_B0.size != model.n_B:
            raise InputError(
                f"q_B0 has {q_B0.size} values, the balance joints are {model.n_B} ({', '.join(names)})"
            )
        self.horizon = horizon = float(options.horizon or mission.duration)  # None or > 0
        self.free_timing = options.timing == "free"
        # the mission as the planner starts from: the given one, or its path at the given
        # timing stretched to the horizon (a free timing, balance_opt.optimal.timing)
        self.timed_mission = mission
        if self.free_timing:
            self.mission_path = path = retiming.MissionPath(mission)
            self.mission_limits = retiming.mission_limits(robot)
            self.path_rate_limits = retiming.path_rate_limits(path, self.mission_limits)
            self.timed_mission = retiming.initial_timing(path, horizon)
        elif horizon < mission.duration:
            raise InputError(
                f"planner option 'horizon' ({horizon} s) is shorter than the mission ({mission.duration} s)"
            )
        self._check_configurations()
        q_M0 = np.atleast_2d(mission.sample(np.zeros(1))[0])[0]
        q0 = np.concatenate([q_M0, q_B0])
        if start is not None and start.prepared is not None:
            collision = restarted(start.prepared.collision, model, options, q0)
        else:
            collision = collision_setup(model, options, q0, robot)
        self.collision = collision
        self.N = options.intervals
        self.h = horizon / self.N
        self.transcription = Transcription(options.transcription)
        self.control = options.control
        self.point_times = self.transcription.point_taus(self.N) * self.h
        q_M, q_dot_M, q_ddot_M = self.timed_mission.sample(self.point_times)
        self.h0 = np.zeros(6) if h0 is None else np.asarray(h0, dtype=float).ravel()
        if self.h0.size != 6 or not np.all(np.isfinite(self.h0)):
            raise InputError(
                f"momentum h0 must be 6 finite values [linear; angular], got {self.h0.tolist()}"
            )
        h0_rows = np.broadcast_to(self.h0, (self.point_times.size, self.h0.size))
        self.mission_samples = np.hstack([q_M, q_dot_M, q_ddot_M, h0_rows]).T
        self.q_rest = (
            q_B0 if options.rest_configuration is None else np.array(options.rest_configuration)
        )
        collision_bound = None
        if collision is not None:
            start = collision.start_bounds(options.collision_margin)
            collision_bound = np.tile(start[:, None], self.point_times.size)
        self.bounds = Bounds(
            options.path_attitude_bound,
            options.terminal_attitude_bound,
            np.ones((model.n_B, self.point_times.size)),
            collision=collision_bound,
        )
        if collision is not None and collision.exact:
            self.bounds = dataclasses.replace(self.bounds, exact=at_rest(self))

    def _check_configurations(self) -> None:
        options, lim, n_B = self.options, self.limits, self.model.n_B
        for what, values in (
            ("initial configuration q_B0", self.q_B0),
            ("final_configuration", options.final_configuration),
            ("rest_configuration", options.rest_configuration),
        ):
            if values is None:
                continue
            values = np.asarray(values, dtype=float)
            if values.size != n_B:
                raise InputError(
                    f"planner option '{what}' has {values.size} values, the balance joints are {n_B}"
                )
            if not options.position_limits or what == "rest_configuration":
                continue
            for j, name in enumerate(self.balance_joints):
                if (
                    not lim.lower[j] - LIMIT_TOLERANCE
                    <= values[j]
                    <= lim.upper[j] + LIMIT_TOLERANCE
                ):
                    raise InfeasibleLimitsError(
                        f"balance joint '{name}': {what} is {values[j]:.6g} rad, outside its position limits "
                        f"[{lim.lower[j]:.6g}, {lim.upper[j]:.6g}] rad"
                    )
