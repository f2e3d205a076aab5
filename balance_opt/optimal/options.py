"""Settings of the optimal balance planner: the objective's weights and the planner's options."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from balance_opt.errors import InputError
from balance_opt.optimal.collocation import TRANSCRIPTIONS

#: Control inputs of the collocation: balance joint accelerations, or jerks (accelerations
#: become states).
CONTROLS = ("acceleration", "jerk")
#: Ipopt return statuses that count as a solution.
SUCCESS_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: Default Ipopt options (``PlannerOptions.ipopt`` entries override them). Ipopt's monotone
#: barrier update (its default) took as many iterations as the adaptive one on the paper task
#: and less time per iteration; MUMPS's workspace at 100 % over its estimate (Ipopt's default
#: 1000 %) saves the system time of allocating it at every factorisation (Ipopt enlarges it when
#: MUMPS asks).
DEFAULT_IPOPT = {
    "print_level": 0,
    "sb": "yes",
    "linear_solver": "mumps",
    "hessian_approximation": "exact",
    "mumps_mem_percent": 100,
}
#: Initial guesses :meth:`BalanceNLP.solve` knows by name.
GUESSES = ("analytic", "rest")


@dataclass(frozen=True)
class CostWeights:
    """Weights of the planner's objective (Eq. 31 as a least-squares goal)::

        J = omega * int |omega_b|^2 dt + attitude * int |log R|^2 dt + terminal * |log R_T|^2
            + smoothness * int |u|^2 dt + rest * int |q_B - q_rest|^2 dt

    ``u`` is the control: balance joint accelerations [rad/s^2] (or jerks [rad/s^3]).

    Attributes:
        omega: weight of the base rate [1 per rad^2/s]. The paper's goal: the base stays still.
        terminal: weight of the final attitude error [1 per rad^2]: brings the attitude back.
        smoothness: weight of the control [1 per rad^2/s^3 (s^5 for jerk)]: small, it only
            regularises the balance motion.
        rest: weight of the pull toward ``PlannerOptions.rest_configuration``
            [1 per rad^2 s]; 0 (off) by default.
        attitude: weight of the attitude error along the path [1 per rad^2 s]: not the paper's
            (which only asks ``omega_b = 0``), but what keeps the largest drift small once the
            limits make ``omega_b = 0`` impossible (on the paper task it cuts the re-simulated
            maximum drift by 30 % against ``attitude = 0``; a terminal weight 10 times larger
            would buy a smaller final drift with a larger peak, and on a short fast move a peak
            above Phase I's).
    """

    omega: float = 100.0
    terminal: float = 100.0
    smoothness: float = 1e-3
    rest: float = 0.0
    attitude: float = 300.0

    def running(self) -> np.ndarray:
        """The running-cost weights in the order of :data:`balance_opt.optimal.model.RUNNING_WEIGHTS`."""
        return np.array([self.omega, self.attitude, self.smoothness, self.rest], dtype=float)


@dataclass(frozen=True)
class PlannerOptions:
    """Settings of the optimal balance planner.

    Attributes:
        intervals: number of collocation intervals ``N`` over the horizon.
        transcription: ``"hermite-simpson"`` (separated form, default) or ``"trapezoidal"``.
        control: ``"acceleration"`` (balance joint accelerations, default) or ``"jerk"`` (the
            accelerations become states, continuous in time).
        horizon: planning horizon [s]; ``None`` for the mission's duration. A longer horizon
            holds the mission arm at its goal and leaves the balance arm time to settle.
        weights: objective weights (:class:`CostWeights`).
        rest_configuration: ``q_rest`` [rad] of the rest pull, one value per balance joint;
            ``None`` for the initial configuration ``q_B0``.
        position_limits, velocity_limits, acceleration_limits: enforce the balance joints'
            limits (``robot.limits``: URDF or task overrides) on the continuous motion.
        torque_limits: enforce the balance joints' effort limits [N m] on the torques of the
            free-floating inverse dynamics, at the collocation points.
        terminal_attitude_bound: hard bound on ``|log R_T|`` [rad]; ``None`` for none.
        path_attitude_bound: hard bound on ``|log R(t)|`` [rad] at every collocation point;
            ``None`` for none.
        rest_at_end: require ``q_dot_B(T) = 0`` (and ``q_ddot_B(T) = 0`` with control ``"jerk"``).
        final_configuration: prescribed ``q_B(T)`` [rad]; ``None`` for a free end.
        tolerance: Ipopt's ``tol``.
        max_iterations: Ipopt's ``max_iter``.
        resample_step: largest step of the re-simulation grid [s] (the grid also holds every
            node).
        ipopt: extra Ipopt options, passed through (``{"print_level": 5}``, ...).
    """

    intervals: int = 100
    transcription: str = "hermite-simpson"
    control: str = "acceleration"
    horizon: float | None = None
    weights: CostWeights = field(default_factory=CostWeights)
    rest_configuration: tuple[float, ...] | None = None
    position_limits: bool = True
    velocity_limits: bool = True
    acceleration_limits: bool = True
    torque_limits: bool = False
    terminal_attitude_bound: float | None = None
    path_attitude_bound: float | None = None
    rest_at_end: bool = False
    final_configuration: tuple[float, ...] | None = None
    tolerance: float = 1e-8
    max_iterations: int = 1000
    resample_step: float = 0.01
    ipopt: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if (
            isinstance(self.intervals, bool)
            or not isinstance(self.intervals, (int, np.integer))
            or self.intervals < 2
        ):
            raise InputError(
                f"planner option 'intervals' must be an integer >= 2, got {self.intervals!r}"
            )
        if self.transcription not in TRANSCRIPTIONS:
            raise InputError(
                f"planner option 'transcription' must be one of {', '.join(TRANSCRIPTIONS)}, "
                f"got {self.transcription!r}"
            )
        if self.control not in CONTROLS:
            raise InputError(
                f"planner option 'control' must be one of {', '.join(CONTROLS)}, got {self.control!r}"
            )
        for f in dataclasses.fields(CostWeights):
            value = getattr(self.weights, f.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise InputError(
                    f"planner weight '{f.name}' must be a finite number >= 0, got {value!r}"
                )
        for name in (
            "horizon",
            "terminal_attitude_bound",
            "path_attitude_bound",
            "tolerance",
            "resample_step",
        ):
            value = getattr(self, name)
            if value is not None and not (
                isinstance(value, (int, float)) and math.isfinite(value) and value > 0
            ):
                raise InputError(
                    f"planner option '{name}' must be a finite number > 0, got {value!r}"
                )
        if not isinstance(self.max_iterations, (int, np.integer)) or self.max_iterations < 0:
            raise InputError(
                f"planner option 'max_iterations' must be an integer >= 0, got {self.max_iterations!r}"
            )
        for name in ("rest_configuration", "final_configuration"):
            value = getattr(self, name)
            if value is not None:
                arr = np.asarray(value, dtype=float).ravel()
                if not np.all(np.isfinite(arr)):
                    raise InputError(
                        f"planner option '{name}' has non-finite values: {arr.tolist()}"
                    )
                object.__setattr__(self, name, tuple(float(v) for v in arr))
        object.__setattr__(self, "ipopt", dict(self.ipopt))

    def as_dict(self) -> dict:
        """Plain data (for ``BalanceResult.info``)."""
        out = dataclasses.asdict(self)
        out["ipopt"] = dict(self.ipopt)
        return out
