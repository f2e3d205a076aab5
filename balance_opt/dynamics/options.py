"""Settings of the forward-dynamics simulation, declared once for Python calls and the
``simulation`` section of task files (:func:`~balance_opt.config.typed_config.setting`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from balance_opt.config.typed_config import check_settings, setting
from balance_opt.errors import InputError

#: Default integration step [s].
DEFAULT_DT = 1e-3
#: Default spacing of the output samples [s] (100 Hz, what a report needs).
DEFAULT_OUTPUT_DT = 0.01
#: Default closed-loop bandwidth of each joint's PD loop [rad/s] and its damping ratio.
DEFAULT_BANDWIDTH = 20.0
DEFAULT_DAMPING_RATIO = 1.0
INTEGRATORS = ("rk4", "dopri5")
CONTROLLERS = ("pd", "computed-torque")


@dataclass(frozen=True)
class SimulationOptions:
    """Settings of the forward-dynamics simulation of a plan.

    ``rtol`` and ``atol`` apply per component of the tangent increment, configuration
    components scaled as if of unit size. ``output_dt`` is rounded to a whole number of
    ``"rk4"`` steps; ``None`` outputs every ``"rk4"`` step (``"dopri5"``: every 0.01 s). The
    default gains are ``kp = M_ii bandwidth^2`` and ``kd = 2 damping_ratio bandwidth M_ii``,
    ``M_ii`` the joint's diagonal inertia at the start.
    """

    integrator: Literal[INTEGRATORS] = setting(
        INTEGRATORS[0], doc="rk4 (fixed step dt) or dopri5 (adaptive)"
    )
    dt: float = setting(
        DEFAULT_DT,
        unit="s",
        exclusive_minimum=0.0,
        doc="integration step (dopri5: first step)",
    )
    rtol: float = setting(1e-10, exclusive_minimum=0.0, doc="dopri5 relative tolerance")
    atol: float = setting(1e-12, exclusive_minimum=0.0, doc="dopri5 absolute tolerance")
    max_step: float = setting(0.05, unit="s", exclusive_minimum=0.0, doc="dopri5 largest step")
    output_dt: float | None = setting(
        DEFAULT_OUTPUT_DT,
        unit="s",
        exclusive_minimum=0.0,
        doc="time between output samples (none: every rk4 step)",
    )
    controller: Literal[CONTROLLERS] = setting(
        CONTROLLERS[0], doc="joint controller: PD (the paper's) or computed torque + PD"
    )
    # PD alone trails a plan by about q_ddot / kp: the check would judge the controller, not
    # the plan.
    feedforward: bool = setting(
        True,
        doc="PD controller: add the plan's own torques (free-floating inverse dynamics of the "
        "planned motion) as feedforward; false: PD alone",
    )
    kp: float | tuple[float, ...] | None = setting(
        None,
        unit="N m/rad",
        minimum=0.0,
        per="arm joint",
        doc="proportional gains, one or one per arm joint (default: from bandwidth)",
    )
    kd: float | tuple[float, ...] | None = setting(
        None,
        unit="N m s/rad",
        minimum=0.0,
        per="arm joint",
        doc="derivative gains, one or one per arm joint (default: from bandwidth)",
    )
    bandwidth: float = setting(
        DEFAULT_BANDWIDTH,
        unit="rad/s",
        exclusive_minimum=0.0,
        doc="natural frequency of the default gains",
    )
    damping_ratio: float = setting(
        DEFAULT_DAMPING_RATIO, exclusive_minimum=0.0, doc="damping ratio of the default gains"
    )
    clip_torque: bool = setting(False, doc="saturate joint torques at their effort limits")
    h0: tuple[float, ...] | None = setting(
        None,
        in_file=False,
        unit="N s; N m s",
        min_items=6,
        max_items=6,
        doc="the system's momentum [linear; angular about the CoM], world axes (default: zero)",
    )

    def __post_init__(self):
        check_settings(self, "simulation option")


#: What the re-planning controller assumes the system's momentum is at a re-plan.
REPLAN_MOMENTA = ("zero", "measured")
#: The floor of a re-plan's peak (its epigraph variable's lower bound): the largest drift so far
#: ("measured"), or the largest drift so far capped at the first plan's peak ("plan").
PEAK_FLOORS = ("measured", "plan")


@dataclass(frozen=True)
class ClosedLoopOptions:
    """The closed-loop study (:mod:`balance_opt.control.flight`,
    ``docs/executable-plans.md``): each plan flown on ``samples`` perturbed true models in forward dynamics, the balance arm
    re-planned every ``period`` from the measured state with the nominal model.
    ``perturbation`` and ``seed`` unset take the ``robustness`` section's, so that open and
    closed loop are compared on the same true models.
    """

    period: float = setting(
        0.5, unit="s", exclusive_minimum=0.0, doc="control period: time between two re-plans"
    )
    samples: int = setting(20, minimum=1, doc="perturbed true models")
    perturbation: float | None = setting(
        None,
        minimum=0.0,
        doc="relative size of the model error (default: robustness.perturbation)",
    )
    seed: int | None = setting(
        None, minimum=0, doc="seed of the perturbations (default: robustness.seed)"
    )
    margin: float = setting(
        0.06,
        minimum=0.0,
        doc="fraction by which the closed-loop plans (first plan and re-plans) tighten the "
        "balance joints' velocity and acceleration limits, for the joint controllers' tracking "
        "error on the true robot",
    )
    position_margin: float = setting(
        0.002,
        unit="rad",
        minimum=0.0,
        doc="distance by which the closed-loop plans keep the balance joints inside their "
        "position limits (at most a quarter of a joint's range), for the tracking error",
    )
    jerk: float | None = setting(
        15.0,
        unit="rad/s^3",
        exclusive_minimum=0.0,
        doc="largest jerk of the balance joints in the closed-loop plans (the robot's own if "
        "lower; null: the robot's): a re-plan that turns the acceleration faster is tracked "
        "with an overshoot on the true robot",
    )
    # a study setting, not a task's: docs/executable-plans.md says why zero is kept
    momentum: Literal[REPLAN_MOMENTA] = setting(
        REPLAN_MOMENTA[0],
        in_file=False,
        doc="momentum a re-plan assumes: zero (the true system's) or the nominal model's "
        "from the measured rates",
    )

    # a study setting, not a task's: docs/executable-plans.md says why "measured" is kept
    peak_floor: Literal[PEAK_FLOORS] = setting(
        PEAK_FLOORS[0],
        in_file=False,
        doc="a re-plan's peak floor: the drift so far (measured), or the drift so far capped "
        "at the first plan's peak (plan)",
    )

    end_period: float | None = setting(
        0.2,
        unit="s",
        exclusive_minimum=0.0,
        doc="control period over the motion's last end_window seconds, where a re-plan's "
        "correction has the least time left (null: period throughout)",
    )
    end_window: float = setting(
        3.0, unit="s", minimum=0.0, doc="the motion's last seconds, re-planned every end_period"
    )

    @property
    def margins(self) -> tuple[float, float, float | None]:
        """``(margin, position_margin, jerk)``: the arguments of
        :func:`~balance_opt.control.replan.margined` after the robot."""
        return self.margin, self.position_margin, self.jerk

    def __post_init__(self):
        check_settings(self, "closed-loop option")
        if self.margin >= 1.0:
            raise InputError(
                f"closed-loop option 'margin' must be < 1 (a fraction of the limits), "
                f"got {self.margin:g}"
            )
