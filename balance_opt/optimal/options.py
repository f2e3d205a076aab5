"""Settings of the optimal balance planner: the objective's weights and the planner's options."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Literal

from balance_opt.config.typed_config import check_settings, setting
from balance_opt.optimal.collocation import TRANSCRIPTIONS

#: Control inputs of the collocation: balance joint accelerations, or jerks (accelerations
#: become states).
CONTROLS = ("acceleration", "jerk")
#: Ipopt return statuses that count as a solution.
SUCCESS_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
#: Default Ipopt options (``PlannerOptions.ipopt`` entries override them). MUMPS's workspace
#: at 100 % over its estimate saves allocating it at every factorisation.
DEFAULT_IPOPT = {
    "print_level": 0,
    "sb": "yes",
    "linear_solver": "mumps",
    "hessian_approximation": "exact",
    "mumps_mem_percent": 100,
}
#: Ipopt options of the peak objective's epigraph stage over :data:`DEFAULT_IPOPT`: it starts
#: near its plan, from the smooth stage's, and a small initial barrier parameter keeps it there.
PEAK_IPOPT = {"mu_init": 1e-3}
#: A peak plan on a grid finer than this many intervals is reached through the peak plan of a
#: coarser grid (:meth:`Stage.grids`): from the smooth stage, the epigraph's iterations grow with
#: the grid (the smooth plan's chatter, which the jerk term prices, grows with it), from its own
#: plan on a coarser grid they do not.
PEAK_GRID_INTERVALS = 100
#: Ipopt options of the epigraph stage over :data:`PEAK_IPOPT` on a grid finer than
#: :data:`PEAK_GRID_INTERVALS`. It starts from its own plan on a coarser grid: a smaller barrier
#: parameter than from the smooth stage keeps it near it (a larger one first pulls it away). On
#: these larger matrices the fill-reducing ordering MUMPS picks itself factorises slower than the
#: approximate minimum fill one (AMF; docs/performance.md, grid scaling).
PEAK_FINE_IPOPT = {"mu_init": 1e-5, "mumps_pivot_order": 2}
#: Ipopt options of the peak objective's smooth stage (its start is close: no globalisation).
SMOOTH_IPOPT = {"mu_strategy": "adaptive", "adaptive_mu_globalization": "never-monotone-mode"}
#: The peak objective's inner stages solve on a grid this many times coarser than the plan's
#: (:meth:`Stage.intervals`; a fine plan's coarsest, :meth:`Stage.grids`), by transcription: the
#: epigraph stage only needs the drift's shape from them. The trapezoidal rule has half the
#: points per interval. A fine plan's grids are as many times coarser than one another.
INNER_COARSENING = {"hermite-simpson": 4, "trapezoidal": 2}
#: Intervals of the inner stages' grid at least (the plan's own, if it has fewer).
INNER_MIN_INTERVALS = 10


@dataclass(frozen=True)
class Stage:
    """One stage of the peak objective (:func:`~balance_opt.optimal.refine.plan_peak`).

    Attributes:
        name: the stage, also its structure's objective: ``"integral"`` (the integral
            objective's plan, without attitude bounds), ``"smooth"`` (the drift's L16 norm),
            ``"peak"`` (the epigraph).
        coarse: on the inner grid (:data:`INNER_COARSENING`) rather than the plan's.
        between_points: with the joint-limit rows between the collocation points (an inner
            stage's plan is only a warm start: without them an iteration costs a third less).
        ipopt: its Ipopt options over :data:`DEFAULT_IPOPT`.
        fine_above: on a grid finer than this many intervals, the stage is solved first on the
            grids of :meth:`grids` (:data:`PEAK_GRID_INTERVALS`); ``None``: on the plan's only.
        fine_ipopt: its Ipopt options over ``ipopt`` on a grid finer than ``fine_above``.
    """

    name: str
    coarse: bool
    between_points: bool
    ipopt: tuple[tuple[str, object], ...] = ()
    fine_above: int | None = None
    fine_ipopt: tuple[tuple[str, object], ...] = ()

    def ipopt_at(self, N: int) -> dict:
        ipopt = dict(self.ipopt)
        if self.fine_above is not None and N > self.fine_above:
            ipopt.update(self.fine_ipopt)
        return ipopt

    def grids(self, N: int, transcription: str) -> list[int]:
        """The grids the stage is solved on for a plan of ``N`` intervals, coarsest first, each
        solve started from the last: ``[N]``, or on a grid finer than ``fine_above`` the grids
        of a plan :data:`INNER_COARSENING` times coarser (of ``fine_above`` intervals at
        least), then ``N``."""
        if self.fine_above is None or N <= self.fine_above:
            return [N]
        coarser = max(self.fine_above, -(-N // INNER_COARSENING[transcription]))
        return [*self.grids(coarser, transcription), N]

    def intervals(self, N: int, transcription: str) -> int:
        if not self.coarse:
            return N
        return min(N, max(INNER_MIN_INTERVALS, -(-N // INNER_COARSENING[transcription])))


#: The stages of the peak objective, in order, each warm started from the last.
PEAK_STAGES = (
    Stage("integral", True, False),
    Stage("smooth", True, False, tuple(SMOOTH_IPOPT.items())),
    Stage(
        "peak",
        False,
        True,
        tuple(PEAK_IPOPT.items()),
        PEAK_GRID_INTERVALS,
        tuple(PEAK_FINE_IPOPT.items()),
    ),
)
#: What a failed epigraph stage falls back on: the smooth peak as a plan of its own.
SMOOTH_PLAN = Stage("smooth", False, True, tuple(SMOOTH_IPOPT.items()))


#: Default weight of the balance joints' squared jerk [s^5/rad^2] (``CostWeights.jerk``): it
#: removes the chatter of the peak plan's bang-bang arcs for a small share of its peak.
JERK_DEFAULT = 1.0
#: Initial guesses :meth:`BalanceNLP.solve` knows by name.
GUESSES = ("analytic", "rest")
#: Objectives: the largest attitude error over the motion, or the integral of squared drift.
OBJECTIVES = ("peak", "integral", "time")
#: The mission's timing: the given trajectory's, or free along its path (optimal/timing.py).
TIMINGS = ("given", "free")
#: Conditions on the balance arm at the start and at the end of the plan: ``rest`` is zero
#: velocity and zero acceleration (no torque step), ``still`` zero velocity only, ``free``
#: nothing (the end only; the arm always starts at rest at ``q_B0``).
START_CONDITIONS = ("rest", "still")
END_CONDITIONS = ("free", "still", "rest")


@dataclass(frozen=True)
class CostWeights:
    """Weights of the optimal planner's objective.

    The ``integral`` objective is Eq. 31 as a least-squares goal::

        J = omega * int |omega_b|^2 dt + attitude * int |log R|^2 dt + terminal * |log R_T|^2
            + smoothness * int |u|^2 dt + rest * int |q_B - q_rest|^2 dt

    The ``peak`` objective prices the largest attitude error ``s = max_k |log R(t_k)|`` over
    the collocation points (an epigraph variable, ``|phi_k|^2 <= s^2``) and keeps the integral
    terms, scaled down by ``regularisation``, to make the plan smooth and unique::

        J = peak * s^2 + peak_terminal * |log R_T|^2
            + regularisation * (the integral terms + jerk * int |q_dddot_B|^2 dt)

    It is reached in stages (:func:`balance_opt.optimal.refine.plan_peak`): the integral
    objective's plan, then ``s^2`` replaced by the drift's L_16 norm (weighted so that it
    costs what ``peak * s^2`` does at the integral plan's peak), then the epigraph.

    ``u`` is the control: balance joint accelerations [rad/s^2] (or jerks [rad/s^3]). The
    weights' units make each term dimensionless: ``omega`` [s/rad^2], ``terminal``, ``peak`` and ``peak_terminal`` [1/rad^2],
    ``smoothness`` [s^3/rad^2] (jerk: [s^5/rad^2]), ``rest`` and ``attitude`` [1/(rad^2 s)],
    ``jerk`` [s^5/rad^2]. The jerk term is the exact integral over the continuous plan (a step of
    the acceleration between intervals, which only the trapezoidal rule with control
    ``"acceleration"`` has, counts as its size over ``h``: the jerk spread over one interval).

    Raises:
        InputError: a weight that is not a finite number >= 0 (``"planner weight 'omega': ..."``).
    """

    omega: float = setting(
        100.0, minimum=0.0, doc="base angular rate, integral of |omega_b|^2 (the paper's goal)"
    )
    terminal: float = setting(100.0, minimum=0.0, doc="final attitude error |log R_T|^2")
    # small: it only regularises the balance motion
    smoothness: float = setting(
        1e-3,
        minimum=0.0,
        doc="integral of the squared control (balance accelerations or jerks)",
    )
    rest: float = setting(
        0.0, minimum=0.0, doc="pull toward rest_configuration, integral of |q_B - q_rest|^2"
    )
    # Not the paper's (which only asks omega_b = 0), but what keeps the largest drift small once
    # the limits make omega_b = 0 impossible.
    attitude: float = setting(
        300.0, minimum=0.0, doc="attitude error along the path, integral of |log R|^2"
    )

    peak: float = setting(
        1e5, minimum=0.0, doc="largest attitude error, max |log R|^2 (peak objective only)"
    )
    # Priced like the peak, not above it: the final error is one of the points the peak bounds.
    peak_terminal: float = setting(
        1e5, minimum=0.0, doc="final attitude error |log R_T|^2 (peak objective only)"
    )
    regularisation: float = setting(
        1e-2,
        minimum=0.0,
        doc="factor on the omega, attitude, smoothness, rest and jerk terms (peak objective only)",
    )
    # The peak objective's plans are bang-bang with singular arcs: many accelerations give the
    # same peak, and without a price on their changes the solver stops on a chattering one.
    # Priced in the epigraph stage only (not in the inner stages: see BalanceNLP._set_bounds).
    jerk: float = setting(
        JERK_DEFAULT,
        minimum=0.0,
        doc="squared jerk of the balance joints on the continuous plan, integral of "
        "|q_dddot_B|^2, times regularisation (peak objective only)",
    )

    def __post_init__(self):
        check_settings(self, "planner weight")


@dataclass(frozen=True)
class PlannerOptions:
    """Settings of the optimal balance planner (direct collocation solved by Ipopt).

    The constraint switches and bounds are attributes of this class, written in task files
    under ``optimal.constraints``. Joint limits are ``robot.limits`` (the URDF's or the task's
    overrides), enforced on the continuous motion (see :mod:`balance_opt.optimal.collocation`);
    torque limits at the collocation points, on the torques of the free-floating inverse
    dynamics. With control ``"jerk"``, ``rest_at_end`` also asks ``q_ddot_B(T) = 0``. A horizon
    longer than the mission holds the mission arm at its goal and leaves the balance arm time
    to settle.

    Raises:
        InputError: a field that does not fit its declaration (``"planner option 'intervals':
            must be at least 2, got 1"``).
    """

    __sections__: ClassVar[dict[str, str]] = {
        "constraints": "constraints of the optimal planner",
        "collision": "collision avoidance between the robot's bodies (docs/collision.md)",
    }

    # 'peak': what users want (the stillest base); it solves in three stages (refine.plan_peak).
    objective: Literal[OBJECTIVES] = setting(
        "peak",
        doc="minimise the largest attitude error (peak), the integral of squared drift, or the "
        "duration (time: the shortest horizon whose peak plan keeps "
        "constraints.path_attitude_bound; needs mission.timing: free)",
    )
    intervals: int = setting(100, minimum=2, doc="collocation intervals N")
    transcription: Literal[TRANSCRIPTIONS] = setting(TRANSCRIPTIONS[0], doc="collocation scheme")
    control: Literal[CONTROLS] = setting(
        CONTROLS[0], doc="control input: balance joint accelerations or jerks"
    )
    horizon: float | None = setting(
        None,
        unit="s",
        exclusive_minimum=0.0,
        doc="planning horizon, at least the mission's duration (default: the mission's)",
    )
    weights: CostWeights = setting(factory=CostWeights, doc="objective weights")
    rest_configuration: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        per="balance joint",
        doc="q_rest of the rest weight, one value per balance joint (default: initial.balance)",
    )
    position_limits: bool = setting(
        True,
        section="constraints",
        doc="balance joints within their position limits (continuous motion)",
    )
    velocity_limits: bool = setting(
        True, section="constraints", doc="balance joints within their velocity limits"
    )
    acceleration_limits: bool = setting(
        True, section="constraints", doc="balance joints within their acceleration limits"
    )
    jerk_limits: bool = setting(
        True,
        section="constraints",
        doc="balance joints within their jerk limits (continuous motion; limits.<joint>.jerk)",
    )
    torque_limits: bool = setting(
        False,
        section="constraints",
        doc="balance joint torques (free-floating inverse dynamics) within their effort limits",
    )
    terminal_attitude_bound: float | None = setting(
        None,
        unit="rad",
        exclusive_minimum=0.0,
        section="constraints",
        doc="hard bound on the final attitude error |log R_T|",
    )
    path_attitude_bound: float | None = setting(
        None,
        unit="rad",
        exclusive_minimum=0.0,
        section="constraints",
        doc="hard bound on the attitude error |log R(t)| along the path",
    )
    # The arm is at rest before the plan: starting with an acceleration is a torque step.
    start: Literal[START_CONDITIONS] = setting(
        START_CONDITIONS[0],
        section="constraints",
        doc="balance arm at t = 0: rest (zero velocity and acceleration) or still (velocity only)",
    )
    # An arm still moving when the plan ends keeps turning the base: 'rest' leaves the robot
    # still, with no torque step at the end either.
    end: Literal[END_CONDITIONS] = setting(
        END_CONDITIONS[2],
        section="constraints",
        doc="balance arm at the end: rest (zero velocity and acceleration), still or free",
    )
    rest_at_end: bool = setting(
        False,
        section="constraints",
        doc="balance arm at rest at the end (the same as end: rest, kept for old task files)",
    )
    final_configuration: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        per="balance joint",
        section="constraints",
        doc="prescribed final balance configuration, one value per balance joint",
    )
    # On by default: a plan that drives a link through the base is no plan.
    collision_avoidance: bool = setting(
        True,
        key="avoid",
        section="collision",
        doc="keep the bodies the balance joints move apart from every other body by the margin",
    )
    collision_margin: float = setting(
        0.03,
        unit="m",
        minimum=0.0,
        key="margin",
        section="collision",
        doc="smallest distance between the balance arm's bodies and the others (exact geometry)",
    )
    collision_ignore: tuple[tuple[str, ...], ...] = setting(
        (),
        key="ignore",
        section="collision",
        doc="pairs of links never checked against each other, e.g. [[balance_link3, base_link]]",
    )
    collision_srdf: str | None = setting(
        None,
        in_file=False,  # the task's robot.srdf, resolved against the task file's folder
        section="collision",
        doc="SRDF whose disabled pairs are left out (default: the one shipped with an "
        "example-robot-data robot, if any)",
    )
    tolerance: float = setting(
        1e-8, exclusive_minimum=0.0, doc="Ipopt's convergence tolerance (tol)"
    )
    max_iterations: int = setting(1000, minimum=0, doc="Ipopt's iteration limit (max_iter)")
    resample_step: float = setting(
        0.01,
        unit="s",
        exclusive_minimum=0.0,
        doc="largest step of the fine grid the plan is re-simulated on",
    )
    starts: int = setting(
        1,
        minimum=1,
        doc="initial guesses tried (rest, analytic, smooth random ones); the best plan is kept",
    )
    seed: int = setting(0, minimum=0, doc="seed of the random initial guesses of starts")
    ipopt: dict[str, int | float | str] = setting(
        factory=dict, doc="Ipopt options passed through, e.g. {print_level: 5}"
    )
    timing: Literal[TIMINGS] = setting(
        TIMINGS[0],
        in_file=False,  # the task's mission.timing
        doc="the mission's timing: given, or free along its path, planned with the balance arm",
    )
    #: the peak objective's stages, in order (:func:`~balance_opt.optimal.refine.plan_peak`);
    #: not a task key
    stages: tuple[Stage, ...] = dataclasses.field(
        default=PEAK_STAGES, repr=False, metadata={"in_file": False}
    )
    #: the epigraph stage's drift priced over the motion's last seconds, ``(weight [1/(rad^2
    #: s)], window [s])`` (:mod:`~balance_opt.optimal.late_drift`: the closed loop's plans);
    #: ``None``: not priced. Not a task key
    late_drift: tuple[float, float] | None = dataclasses.field(
        default=None, metadata={"in_file": False}
    )

    def __post_init__(self):
        check_settings(self, "planner option")

    @property
    def end_condition(self) -> str:
        return "rest" if self.rest_at_end else self.end

    def as_dict(self) -> dict:
        """The options as written to ``metrics.json`` (the stages are the code's, the late
        drift the closed loop's)."""
        out = dataclasses.asdict(self)
        del out["stages"], out["late_drift"]
        return out
