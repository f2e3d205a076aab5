"""One balance planning problem's numeric data: the mission, the initial configuration, the
horizon and the options, checked against the robot before anything is built."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.errors import InfeasibleLimitsError, InputError, SolverError
from balance_opt.model.robot import FloatingRobot
from balance_opt.optimal.collocation import Transcription
from balance_opt.optimal.collision import COLLISION_ALLOWANCE, COLLISION_SLACK
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import PlannerOptions
from balance_opt.result import LIMIT_TOLERANCE


def check_problem(
    model: PlannerModel,
    mission,
    q_B0,
    options: PlannerOptions,
    robot: FloatingRobot | None = None,
) -> tuple[np.ndarray, float]:
    """Check a problem's sizes and configurations against the robot."""
    robot = model.robot if robot is None else robot
    if robot.joint_names != model.robot.joint_names:
        raise InputError(f"robot {robot.name} is not the robot of the planner model")
    if getattr(mission, "dof", None) != model.n_M:
        raise InputError(
            f"mission trajectory has {getattr(mission, 'dof', '?')} joints, "
            f"the mission arm of {robot.name} has {model.n_M}"
        )
    q_B0 = np.asarray(q_B0, dtype=float).ravel()
    names = [robot.joint_names[i] for i in robot.balance_indices]
    if q_B0.size != model.n_B:
        raise InputError(
            f"q_B0 has {q_B0.size} values, the balance joints are {model.n_B} ({', '.join(names)})"
        )
    horizon = float(mission.duration if options.horizon is None else options.horizon)
    if horizon < mission.duration:
        raise InputError(
            f"planner option 'horizon' ({horizon} s) is shorter than the mission ({mission.duration} s)"
        )
    lim = robot.limits.subset(robot.balance_indices)
    for what, values in (
        ("initial configuration q_B0", q_B0),
        ("final_configuration", options.final_configuration),
    ):
        if values is None:
            continue
        values = np.asarray(values, dtype=float)
        if values.size != model.n_B:
            raise InputError(
                f"planner option '{what}' has {values.size} values, the balance joints are {model.n_B}"
            )
        if not options.position_limits:
            continue
        for j, name in enumerate(names):
            if not lim.lower[j] - LIMIT_TOLERANCE <= values[j] <= lim.upper[j] + LIMIT_TOLERANCE:
                raise InfeasibleLimitsError(
                    f"balance joint '{name}': {what} is {values[j]:.6g} rad, outside its position limits "
                    f"[{lim.lower[j]:.6g}, {lim.upper[j]:.6g}] rad"
                )
    if options.rest_configuration is not None and len(options.rest_configuration) != model.n_B:
        raise InputError(
            f"planner option 'rest_configuration' has {len(options.rest_configuration)} values, "
            f"the balance joints are {model.n_B}"
        )
    return q_B0, horizon


def momentum_of(h0) -> np.ndarray:
    """A total momentum ``[linear; angular]`` (6,) [N s; N m s] as a float array (zero for
    ``None``)."""
    h0 = np.zeros(6) if h0 is None else np.asarray(h0, dtype=float).ravel()
    if h0.size != 6 or not np.all(np.isfinite(h0)):
        raise InputError(
            f"momentum h0 must be 6 finite values [linear; angular], got {h0.tolist()}"
        )
    return h0


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
            ``None`` without collision avoidance; read-only.
    """

    path: float | None
    terminal: float | None
    torque_factor: np.ndarray
    peak_reference: float = 1.0
    collision: np.ndarray | None = None

    def __post_init__(self):
        for name in ("torque_factor", "collision"):
            value = getattr(self, name)
            if value is not None:
                value = np.array(value, dtype=float)
                value.flags.writeable = False
                object.__setattr__(self, name, value)


class BalanceProblem:
    """The numeric data of one balance planning problem.

    Args:
        model: the robot's planner model.
        mission: the mission arm's motion (``sample(t) -> q, q_dot, q_ddot``, ``duration``).
        q_B0: initial balance configuration [rad], checked by :func:`check_problem`.
        options: the planner settings.
        horizon: planning horizon [s], from :func:`check_problem`.
        h0: the system's constant total momentum, world frame (the base starts at the
            identity), ``[linear (N s); angular about the CoM (N m s)]``; ``None`` for zero.
        collision: its collision avoidance
            (:class:`~balance_opt.optimal.collision.CollisionSetup`), or ``None``.

    Attributes:
        model, robot, mission, q_B0, options, horizon: as given (``robot`` is the model's).
        N, h: number of intervals and their length [s].
        transcription, control: the collocation scheme and the control input.
        point_times: times of the collocation points [s], nodes then midpoints.
        mission_samples: each point's data ``[q_M; q_dot_M; q_ddot_M; h0]`` (n_m, n_points).
        q_rest: configuration of the rest pull [rad] (``q_B0`` unless the options give one).
        limits: the balance joints' limits.
        bounds: the :class:`Bounds` its NLP enforces (``path_bound``, ``terminal_bound``,
            ``torque_factor``, ``peak_reference`` read them): the options' until the
            refinement makes a new problem with lower ones.
        balance_joints: their names.
        collision: as given.
        collision_bound: lower bound of each collision row at each point (n_c, n_points) [m]:
            the margin plus :data:`COLLISION_ALLOWANCE`, lower for a row that starts closer
            (its value at ``t = 0`` less :data:`COLLISION_SLACK`: the arm starts there, at
            rest), raised by the refinement where the re-simulated motion came too close.
    """

    def __init__(
        self,
        model: PlannerModel,
        mission,
        q_B0: np.ndarray,
        options: PlannerOptions,
        horizon: float,
        robot: FloatingRobot | None = None,
        h0=None,
        collision=None,
    ):
        self.model = model
        # The task's robot: the model's kinematics, possibly other limits.
        self.robot = model.robot if robot is None else robot
        self.mission = mission
        self.q_B0 = q_B0
        self.options = options
        self.horizon = horizon
        self.N = options.intervals
        self.h = horizon / self.N
        self.transcription = Transcription(options.transcription)
        self.control = options.control
        self.point_times = self.transcription.point_taus(self.N) * self.h
        q_M, q_dot_M, q_ddot_M = mission.sample(self.point_times)
        self.h0 = momentum_of(h0)
        h0_rows = np.broadcast_to(self.h0, (self.point_times.size, self.h0.size))
        self.mission_samples = np.hstack([q_M, q_dot_M, q_ddot_M, h0_rows]).T
        self.q_rest = (
            q_B0 if options.rest_configuration is None else np.array(options.rest_configuration)
        )
        self.limits = self.robot.limits.subset(self.robot.balance_indices)
        self.balance_joints = tuple(self.robot.joint_names[i] for i in self.robot.balance_indices)
        self.collision = collision
        collision_bound = None
        if collision is not None:
            start = np.minimum(
                options.collision_margin + COLLISION_ALLOWANCE,
                collision.initial_rows - COLLISION_SLACK,
            )
            collision_bound = np.tile(start[:, None], self.point_times.size)
        self.bounds = Bounds(
            options.path_attitude_bound,
            options.terminal_attitude_bound,
            np.ones((model.n_B, self.point_times.size)),
            collision=collision_bound,
        )
        # the last clearance check and the result it checked (the refinement reads it)
        self.last_clearance = None

    @property
    def collision_bound(self) -> np.ndarray | None:
        return self.bounds.collision

    @property
    def path_bound(self) -> float | None:
        return self.bounds.path

    @property
    def terminal_bound(self) -> float | None:
        return self.bounds.terminal

    @property
    def torque_factor(self) -> np.ndarray:
        return self.bounds.torque_factor

    @property
    def peak_reference(self) -> float:
        return self.bounds.peak_reference


class PlannerSolverError(SolverError):
    """Ipopt did not solve the balance NLP."""

    def __init__(
        self, message: str, status: str, result, constraint: str, time: float, violation: float
    ):
        super().__init__(message, status, result)
        self.constraint = constraint
        self.time = time
        self.violation = violation
