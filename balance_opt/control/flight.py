"""A plan flown closed loop (``docs/executable-plans.md``, "Closed loop"): forward dynamics of
the true robot (a perturbed model), the balance arm re-planned every period with the nominal
model from the measured state, the joint controllers tracking the newest plan.

Timing: the state measured at a period's start (joint positions and rates, base attitude and
rate) is turned into a re-plan that applies from there (or, ``delayed``, from the next period's
start, from a state predicted with the plan in force). The periods are ``period`` long, and
``end_period`` over the motion's last ``end_window`` seconds. A re-plan that fails, or that
took longer than its period on the machine that ran it, leaves the plan in force and is
counted; one that Ipopt stopped at its time budget (the replanner's ``budget``) applies its
iterate if it keeps every constraint, else it is late too. The simulation does not wait for
the clock: the same truth and plans give the same motion (a late re-plan is dropped by its
measured time, the only thing the machine changes).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from balance_opt.control.replan import Replanner, ReplanOutcome, Segment
from balance_opt.dynamics.options import ClosedLoopOptions, SimulationOptions
from balance_opt.dynamics.simulation import SimulationResult, simulate
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.so3 import (
    quaternion_from_rotvec,
    quaternion_multiply,
    relative_rotation,
    rotation_angle,
    rotvec_from_quaternion,
)
from balance_opt.motion.trajectories import MissionWindow


@dataclass
class ClosedLoopRun:
    """One closed-loop flight of a plan.

    Attributes:
        simulation: the true motion (forward dynamics of the true robot), the whole horizon.
        replans: every re-plan, in order.
        late: how many re-plans took longer than their period (dropped).
        period_s: the period before the end window (``end_period`` after it): a whole number of
            the plan's intervals [s].
        prepare_s: building the re-plans' NLPs before the motion [s].
    """

    simulation: SimulationResult
    replans: list[ReplanOutcome]
    late: int
    period_s: float
    prepare_s: float = 0.0
    info: dict = field(default_factory=dict)

    @property
    def failed(self) -> int:
        """Re-plans that failed (the plan in force kept), not for their time."""
        return sum(not r.success and not r.out_of_time for r in self.replans)

    @property
    def compute_s(self) -> np.ndarray:
        return np.array([r.compute_s for r in self.replans])

    @property
    def max_drift(self) -> float:
        return float(self.simulation.angle.max())

    @property
    def final_drift(self) -> float:
        return float(self.simulation.angle[-1])


def _joined(parts: list[SimulationResult], starts: list[float]) -> SimulationResult:
    """Simulations of consecutive periods as one (each part's first sample is the last's
    end, left out)."""
    arrays = {}
    first = parts[0]
    for f in dataclasses.fields(SimulationResult):
        value = getattr(first, f.name)
        if not isinstance(value, np.ndarray) or f.name == "h0":
            continue
        pieces = [getattr(p, f.name)[(1 if i else 0) :] for i, p in enumerate(parts)]
        arrays[f.name] = np.concatenate(pieces)
    arrays["t"] = np.concatenate(
        [p.t[(1 if i else 0) :] + s for i, (p, s) in enumerate(zip(parts, starts))]
    )
    wrenches = {
        arm: np.concatenate([p.arm_wrenches[arm][(1 if i else 0) :] for i, p in enumerate(parts)])
        for arm in first.arm_wrenches
    }
    scale = tuple(max(p.momentum_scale[i] for p in parts) for i in range(2))
    info = dict(first.info, segments=len(parts))
    return dataclasses.replace(
        first, **arrays, arm_wrenches=wrenches, momentum_scale=scale, info=info
    )


def _attitude_increment(segment: Segment, a: int, b: int) -> np.ndarray:
    """The plan's own base rotation from node ``a`` to node ``b`` (base axes), a quaternion."""
    X = segment.solution.X
    qa, qb = (quaternion_from_rotvec(X[:3, n - segment.node]) for n in (a, b))
    return relative_rotation(qa, qb)


def fly_closed_loop(
    truth: FloatingRobot,
    replanner: Replanner,
    plan,
    simulation: SimulationOptions | None = None,
    options: ClosedLoopOptions | None = None,
    prepared: bool = False,
    deadline: float | None = None,
    delayed: bool = False,
) -> ClosedLoopRun:
    """Fly the first ``plan`` of ``replanner``'s problem closed loop on the robot ``truth`` (the
    nominal robot perturbed, or itself): see the module docstring.

    Args:
        simulation: the forward-dynamics options (the gains of the nominal robot's, from the
            plan's start, whatever the truth).
        options: the period and the momentum a re-plan assumes.
        prepared: the re-plans' NLPs are built already (:meth:`Replanner.prepare`).
        deadline: compute time after which a re-plan is late [s] (default: its period;
            ``math.inf``: never, so that the motion does not depend on the machine at all).
        delayed: a re-plan applies a period after its measurement, from a predicted state
            (else at once: see the module docstring).
    """
    opts = options or ClosedLoopOptions()
    sim_opts = simulation or SimulationOptions()
    nlp = replanner.nlp
    period = max(1, round(opts.period / nlp.h)) * nlp.h
    bounds = period_starts(nlp.N, nlp.h, opts)  # the periods' first nodes, and the end
    lag = 1 if delayed else 0  # periods between a measurement and its plan
    # a re-plan has 2 intervals at least (the planner's smallest grid)
    switch_nodes = [n for n in bounds[1 + lag : -1] if nlp.N - n >= 2]
    # each re-plan's own period (shorter near the end with end_period): its compute time
    lengths = {a: (b - a) * nlp.h for a, b in itertools.pairwise(bounds) if a in switch_nodes}
    in_force = replanner.first(plan)
    prepare_s = 0.0
    if not prepared:
        h0 = nlp.h0 if opts.momentum == "zero" else np.r_[0.0, 0.0, 0.0, 1e-9, 0.0, 0.0]
        prepare_s = replanner.prepare(in_force, switch_nodes, h0, lengths)
    sim_opts = _with_nominal_gains(sim_opts, nlp, in_force)
    state, parts, starts = None, [], []
    replans, late, pending, limit = [], 0, None, period
    measured_peak = 0.0
    # with peak_floor "plan", the peak the first plan promised caps a re-plan's floor once the
    # truth has gone above it (the rest of the motion aimed back at it, not at the drift so far)
    cap = math.inf if opts.peak_floor == "measured" else _peak(in_force)
    data = nlp.robot.model.createData()  # the measured momentum's, in the nominal model
    for j in range(len(bounds) - 1):
        a, b = bounds[j], bounds[j + 1]
        t_a, t_b = a * nlp.h, b * nlp.h
        part = _fly_period(truth, nlp, in_force, sim_opts, state, t_a, t_b)
        parts.append(part)
        starts.append(t_a)
        state = (part.q_pin[-1].copy(), part.v[-1].copy())
        # from the attitude at t = 0 (a part's own angle is from its start)
        measured_peak = max(measured_peak, float(rotation_angle(part.quaternion).max()))
        # delayed, the re-plan computed during this period applies from t_b
        if pending is not None and pending.success and pending.compute_s <= limit:
            in_force = pending.segment
        pending = None
        c = bounds[min(j + 1 + lag, len(bounds) - 1)]
        if c in switch_nodes:  # measure at t_b, re-plan for node c
            limit = lengths[c] if deadline is None else deadline
            outcome = _replan(replanner, in_force, state, b, c, measured_peak, cap, opts, data)
            replans.append(outcome)
            late += outcome.out_of_time or (outcome.success and outcome.compute_s > limit)
            if delayed:
                pending = outcome
            elif outcome.success and outcome.compute_s <= limit:
                in_force = outcome.segment
    return ClosedLoopRun(_joined(parts, starts), replans, int(late), period, prepare_s)


def _fly_period(truth, nlp, in_force: Segment, sim_opts, state, t_a: float, t_b: float):
    """The truth's motion from ``state`` at ``t_a`` to ``t_b`` under the plan in force (a
    diverging one stopped, at the flight's own time)."""
    offset = in_force.node * nlp.h
    return simulate(
        truth,
        MissionWindow(nlp.mission, t_a, t_b),
        MissionWindow(in_force.trajectory, t_a - offset, t_b - offset),
        sim_opts,
        duration=t_b - t_a,
        initial_state=state,
        model=nlp.robot,
        start=t_a,
    )


def period_starts(N: int, h: float, options: ClosedLoopOptions) -> list[int]:
    """The first node of every period on a grid of ``N`` intervals of ``h`` [s], and ``N``:
    every ``options.period``, every ``options.end_period`` over the last ``end_window`` seconds
    (from the first period's start inside them), each a whole number of intervals."""
    m = max(1, round(options.period / h))
    starts = list(range(0, N, m))
    if options.end_period is not None:
        end = next((n for n in starts if (N - n) * h <= options.end_window + 1e-9), N)
        fine = max(1, round(options.end_period / h))
        starts = [n for n in starts if n < end] + list(range(end, N, fine))
    return starts + [N]


def _with_nominal_gains(sim_opts: SimulationOptions, nlp, in_force: Segment) -> SimulationOptions:
    """``sim_opts`` with the gains of the nominal robot at the plan's start (the options' own
    when given), kept for every period whatever the truth."""
    if sim_opts.kp is not None and sim_opts.kd is not None:
        return sim_opts
    probe = simulate(nlp.robot, nlp.mission, in_force.trajectory, sim_opts, duration=sim_opts.dt)
    return dataclasses.replace(sim_opts, kp=tuple(probe.info["kp"]), kd=tuple(probe.info["kd"]))


def _peak(segment: Segment) -> float:
    """A plan's largest drift over its nodes (and midpoints) [rad]."""
    s = segment.solution
    points = s.X[:3] if s.Xm is None else np.hstack([s.X[:3], s.Xm[:3]])
    return float(np.linalg.norm(points, axis=0).max())


def _replan(replanner, in_force: Segment, state, b: int, c: int, peak, cap, opts, data):
    """The re-plan from the state measured at node ``b`` for node ``c``, a period later: the
    attitude predicted by the plan in force's own increment over the period, the peak so far
    that and the predicted path's largest drift, at most ``cap``."""
    q_meas = state[0][3:7]
    path = [
        quaternion_multiply(q_meas, _attitude_increment(in_force, b, i)) for i in range(b, c + 1)
    ]
    peak = min(max(peak, float(np.max(rotation_angle(np.array(path))))), cap)
    h0 = None
    if opts.momentum == "measured":  # the nominal model's momentum at the measured state
        nominal = replanner.nlp.robot
        h0 = pin.computeCentroidalMap(nominal.model, data, state[0]) @ state[1]
        h0[:3] = 0.0
    return replanner.replan(c, in_force, rotvec_from_quaternion(path[-1]), peak, h0)
