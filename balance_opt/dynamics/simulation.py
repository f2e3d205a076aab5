"""Forward-dynamics simulation of the free-floating robot: the check every balance plan goes
through (``docs/physics.md``, "Forces on the base"; ``docs/executable-plans.md``).

No gravity, no external wrench: the momentum ``h0`` is constant. ``pin.aba`` (with mimic
followers, ``a = G (G^T M G)^{-1} G^T (tau - h)``) under a controller that tracks *all* arm
joints: ``"pd"`` (the paper's Phase I), by default plus the plan's own inverse-dynamics torques,
or ``"computed-torque"``. Integrated on the manifold by :mod:`balance_opt.dynamics.rkmk`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from balance_opt.dynamics.inverse_dynamics import free_floating_torques, symmetric
from balance_opt.dynamics.options import SimulationOptions
from balance_opt.dynamics.rkmk import dopri5, rk4
from balance_opt.dynamics.wrenches import arm_wrenches_on_base
from balance_opt.errors import DivergenceError, InputError, TrajectoryError
from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.momentum_check import MOMENTUM_SCALE_FLOOR
from balance_opt.motion.result import AttitudeHistory, BalanceResult
from balance_opt.motion.trajectories import PointToPoint, SampledTrajectory, arm_samples

log = logging.getLogger(__name__)

#: Relative momentum residual above which a simulation warns that its step is too long.
MOMENTUM_WARNING = 1e-6
#: Relative momentum residual above which a simulation has diverged: its motion is no longer the
#: robot's.
MOMENTUM_DIVERGED = 1e-3
#: ``|lambda| h`` the fixed RK4 step keeps for the joint PD loop's fastest mode: RK4 is stable up
#: to 2.78 on the negative real axis; the margin covers configurations between the samples.
RK4_STABLE = 2.0
#: Most RK4 sub-steps a simulation takes per ``dt`` to stay stable (past it the divergence guard
#: stops a run that blows up).
MAX_SUBSTEPS = 16
#: Divergence guard: a joint this far outside its position range [rad], or this many times
#: faster than its velocity limit, is no motion of the robot.
DIVERGED_POSITION = 1.0
DIVERGED_RATE = 10.0


# --------------------------------------------------------------------------------- trajectories
def _as_trajectory(value, dof: int, what: str) -> tuple[Any, float]:
    """``(trajectory, duration)`` from a trajectory, a plan (its ``what`` part, interpolated by
    :meth:`SampledTrajectory.from_result`) or a position to hold (duration 0)."""
    duration = None
    if isinstance(value, BalanceResult):
        value = SampledTrajectory.from_result(value, what)
    elif not hasattr(value, "sample"):
        q = np.asarray(value, dtype=float).ravel()
        value, duration = PointToPoint(q, q, 1.0), 0.0  # rests at q for ever
    got = np.reshape(value.sample(np.zeros(1))[0], (1, -1)).shape[1]
    if got != dof:
        raise TrajectoryError(
            f"the {what} trajectory has {got} joints, the robot's {what} "
            f"{'arm has' if what == 'mission' else 'arms have'} {dof}"
        )
    return value, float(value.duration if duration is None else duration)


class _ArmPlan:
    """Mission and balance trajectories stacked into the robot's arm vector; with
    ``feedforward``, also the plan's own joint torques (inverse dynamics) for the momentum
    ``h0`` (world frame) and the planned ``attitude`` (``(t, quaternion)``, nearest sample;
    identity when ``None``)."""

    def __init__(
        self, robot: FloatingRobot, mission, balance, feedforward, h0, attitude, model=None
    ):
        self.robot = robot
        self.model = robot if model is None else model  # what the controller knows
        self.mission, d_M = _as_trajectory(mission, robot.mission.dof, "mission")
        self.balance, d_B = _as_trajectory(balance, robot.balance_indices.size, "balance")
        self.duration = max(d_M, d_B)
        self.feedforward, self._h0, self._attitude = feedforward, h0, attitude

    def sample(self, t):
        """``(q, q_dot, q_ddot)`` (T, n) at times ``t``, and the plan's torques if any."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = arm_samples(self.robot, self.mission.sample, self.balance.sample, t)
        if not self.feedforward:
            return tuple(out)
        quaternion = None
        if self._attitude is not None and np.any(self._h0):
            times, quaternions = self._attitude
            nearest = np.clip(np.searchsorted(times, t), 0, len(times) - 1)
            quaternion = np.asarray(quaternions)[nearest]
        ffd = free_floating_torques(self.model, *out, quaternion=quaternion, h0=self._h0)
        return (*out, ffd.tau)


# --------------------------------------------------------------------------------- options
def _per_joint(value, default: np.ndarray, name: str) -> np.ndarray:
    """One gain per arm joint, ``default`` where none is given (``SimulationOptions`` checked
    that they are finite and non-negative, not how many there are)."""
    if value is None:
        return default
    n = default.size
    arr = np.asarray(value, dtype=float)
    arr = np.full(n, arr) if arr.ndim == 0 else arr
    if arr.shape != (n,):
        raise InputError(
            f"simulation option '{name}' needs one value per arm joint ({n}), got {arr.size}"
        )
    return arr.copy()


# --------------------------------------------------------------------------------- result
@dataclass
class SimulationResult(AttitudeHistory):
    """A simulated motion, sampled at the output times.

    Attributes:
        t: sample times (T,) [s].
        joint_names: arm joints, arm order (mission first); the robot's ``mission_indices``
            and ``balance_indices`` select each part.
        q, q_dot, q_ddot: simulated joint motion (T, n) [rad, rad/s, rad/s^2].
        q_des, q_dot_des, q_ddot_des: the planned joint motion at the same times.
        tau: joint torques (T, n) [N m].
        q_pin, v, a: Pinocchio state and ABA accelerations (T, nq), (T, nv), (T, nv); the base
            twist and acceleration in the base frame.
        momentum: the system's momentum (T, 6) ``[linear; angular about the CoM]``, world axes
            [N s, N m s].
        h0: the momentum it should keep (6,).
        momentum_scale: ``(linear, angular)`` scale the residual is relative to: the largest
            momentum the joints carry, each joint's counted apart
            (``max_t sum_j |A_j[:, j] q_dot_j|``), plus ``|h0|``.
        arm_wrenches: ``{arm: (T, 6)}``, ``[force; torque]`` each arm exerts ON the base, base
            axes, torque about the base origin [N, N m] (paper Fig. 4).
        info: options, step counts, wall time; plain data.
    """

    robot: FloatingRobot = field(repr=False)
    t: np.ndarray
    joint_names: tuple[str, ...]
    q: np.ndarray
    q_dot: np.ndarray
    q_ddot: np.ndarray
    q_des: np.ndarray
    q_dot_des: np.ndarray
    q_ddot_des: np.ndarray
    tau: np.ndarray
    q_pin: np.ndarray
    v: np.ndarray
    a: np.ndarray
    momentum: np.ndarray
    h0: np.ndarray
    momentum_scale: tuple[float, float]
    arm_wrenches: dict[str, np.ndarray]
    info: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        """A few lines, like a plan's (the arrays are attributes)."""
        duration = float(self.t[-1] - self.t[0]) if self.t.size else 0.0
        lines = [
            f"SimulationResult(robot={self.robot.name!r}, {len(self.joint_names)} joints)",
            f"  time       {duration:.4g} s, {self.t.size} samples",
        ]
        if self.t.size:
            lines += [
                f"  drift      peak {float(self.angle.max()):.4g} rad, "
                f"final {float(self.angle[-1]):.4g} rad",
                f"  tracking   max error {self.max_tracking_error:.3g} rad",
                f"  torques    up to {float(np.abs(self.tau).max()):.4g} N m",
                f"  momentum   max relative residual {float(self.momentum_residual.max()):.3g}",
            ]
        return "\n".join(lines)

    @property
    def quaternion(self) -> np.ndarray:
        """Base attitude (T, 4), (x, y, z, w)."""
        return self.q_pin[:, 3:7]

    @property
    def omega(self) -> np.ndarray:
        """Base angular velocity (T, 3), base frame [rad/s]."""
        return self.v[:, 3:6]

    @property
    def max_tracking_error(self) -> float:
        """Largest joint tracking error over the motion [rad]."""
        return float(np.abs(self.q_des - self.q).max())

    @property
    def total_wrench(self) -> np.ndarray:
        """Sum of the arms' wrenches on the base (T, 6) [N, N m]; equals the base's Newton-Euler
        wrench ``I_b a_b + v_b x* I_b v_b``."""
        return sum(self.arm_wrenches.values())

    @property
    def momentum_residual(self) -> np.ndarray:
        """Relative momentum residual (T,): the larger of ``|p - p0| / scale_p`` and
        ``|L - L0| / scale_L`` (see ``momentum_scale``)."""
        err = self.momentum - self.h0
        lin = np.linalg.norm(err[:, :3], axis=1) / self.momentum_scale[0]
        ang = np.linalg.norm(err[:, 3:], axis=1) / self.momentum_scale[1]
        return np.maximum(lin, ang)

    def as_balance_result(self, method: str = "simulation") -> BalanceResult:
        """The simulated motion as a :class:`BalanceResult` (angular momentum residual,
        ``sigma_min`` recomputed along the simulated path)."""
        maps = NumericMaps(self.robot)
        info = dict(self.info)
        info.update(
            max_tracking_error_rad=self.max_tracking_error,
            max_relative_momentum_residual=float(self.momentum_residual.max()),
        )
        return BalanceResult.from_arm_vectors(
            self.robot,
            method,
            self.t.copy(),
            self.q,
            self.q_dot,
            self.q_ddot,
            self.quaternion.copy(),
            self.omega.copy(),
            np.linalg.norm(self.momentum[:, 3:] - self.h0[..., 3:], axis=1)
            / self.momentum_scale[1],
            maps.balance_sigma_min(*maps.angular_maps(self.q)),
            info,
        )


# --------------------------------------------------------------------------------- dynamics
def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """``idx`` as a slice when its entries are consecutive, else as it is."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


class _Dynamics:
    """``(q, v, planned joint state) -> (a, tau)`` with one reused Pinocchio data."""

    def __init__(
        self, robot: FloatingRobot, kp, kd, controller: str, clip_torque: bool, start: float = 0.0
    ):
        self.robot = robot
        self.start = start  # the motion's time at t = 0 here: a divergence's time is the motion's
        self.model = robot.model
        self.data = robot.model.createData()
        self.idx_v = robot.pin_v_indices
        jids = [robot.model.getJointId(j) for j in robot.joint_names]
        self.idx_q = np.array([robot.model.joints[j].idx_q for j in jids])
        # slices where the indices run on (the usual case): a view, no gather per call
        self._v, self._q = _as_slice(self.idx_v), _as_slice(self.idx_q)
        self.revolute_only = all(robot.model.joints[j].nq == 1 for j in jids)
        self.kp, self.kd = kp, kd
        self.computed_torque = controller == "computed-torque"
        self.effort = robot.limits.effort if clip_torque else None
        self.tau_full = np.zeros(robot.model.nv)
        self.acc = np.zeros(robot.model.nv)
        self.G = robot.velocity_map if robot.followers else None
        limits = robot.limits
        self.lower, self.upper = limits.lower, limits.upper
        self.rate_limit = limits.velocity

    def check(self, t: float, q, v, q_des, v_des) -> None:
        """Stop (:class:`DivergenceError`) a state at ``t`` that is no motion of the robot: not
        finite, a joint :data:`DIVERGED_POSITION` outside its range and its plan ``q_des``, or
        :data:`DIVERGED_RATE` times faster than its velocity limit and its plan's rate
        ``v_des`` (a plan that leaves its limits, the analytic law's, is tracked, not
        stopped)."""
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise DivergenceError(self.start + t, "non-finite state")
        position = self.joint_positions(q)
        lower, upper = np.minimum(self.lower, q_des), np.maximum(self.upper, q_des)
        outside = np.maximum(lower - position, position - upper)
        rate = np.abs(v[self._v])
        bound = DIVERGED_RATE * np.maximum(self.rate_limit, np.abs(v_des))
        names = self.robot.joint_names
        if outside.max() > DIVERGED_POSITION:
            j = int(np.argmax(outside))
            raise DivergenceError(
                self.start + t,
                f"joint {names[j]} {outside[j]:.3g} rad outside its range and its plan",
            )
        if np.any(rate > bound):
            j = int(np.argmax(rate / bound))
            raise DivergenceError(
                self.start + t,
                f"joint {names[j]} at {rate[j]:.3g} rad/s, over {DIVERGED_RATE:g} times its "
                f"velocity limit and its plan's rate",
            )

    def joint_positions(self, q):
        return q[self._q] if self.revolute_only else self.robot.arm_q(q)

    def __call__(self, q, v, qd, vd, ad, tau_d=None):
        """``tau_d``: the plan's own torques at this instant, when the plan carries them."""
        e = qd - self.joint_positions(q)
        if not self.revolute_only:  # continuous joints: shortest way round
            e = (e + np.pi) % (2 * np.pi) - np.pi
        tau = self.kp * e + self.kd * (vd - v[self._v])
        if self.computed_torque:
            tau = tau + self.feedforward(q, v, ad)
        elif tau_d is not None:
            tau = tau + tau_d
        if self.effort is not None:
            tau = np.clip(tau, -self.effort, self.effort)
        self.tau_full[self._v] = tau
        if self.G is None:
            return pin.aba(self.model, self.data, q, v, self.tau_full), tau
        G = self.G  # mimic joints driven by their drivers: reduced coordinates
        M = symmetric(pin.crba(self.model, self.data, q))
        f = G.T @ (self.tau_full - pin.nonLinearEffects(self.model, self.data, q, v))
        return G @ np.linalg.solve(G.T @ M @ G, f), tau

    def feedforward(self, q, v, ad):
        """Joint torques of the free-floating inverse dynamics for joint accelerations ``ad``."""
        M = pin.crba(self.model, self.data, q)
        if self.G is not None:  # followers accelerate with their drivers
            self.acc[:] = self.G[:, 6:] @ ad
        else:
            self.acc[self.idx_v] = ad
        tau0 = pin.rnea(self.model, self.data, q, v, self.acc)
        # M_bb is the composite inertia of the whole system in the base frame
        a_b = -np.linalg.solve(self.data.Ycrb[1].matrix(), tau0[:6])
        if self.G is not None:  # generalized forces on the arm joints: G^T (tau0 + M_:b a_b)
            return self.G[:, 6:].T @ (tau0 + symmetric(M)[:, :6] @ a_b)
        return tau0[self.idx_v] + M[:6, self.idx_v].T @ a_b


def _gains(robot: FloatingRobot, q0: np.ndarray, opts: SimulationOptions) -> tuple:
    """The PD gains ``(kp, kd)`` per joint: the options', or by default (SimulationOptions) from
    M_ii, the joint-space inertia's diagonal at the start ``q0`` (a driver's including its
    followers')."""
    M = symmetric(pin.crba(robot.model, robot.model.createData(), robot.pin_q(q0)))
    G = robot.velocity_map
    m_ii = np.einsum("vi,vw,wi->i", G, M, G)[6:]
    w, zeta = opts.bandwidth, opts.damping_ratio
    kp = _per_joint(opts.kp, m_ii * w**2, "kp")
    kd = _per_joint(opts.kd, 2.0 * zeta * w * m_ii, "kd")
    return kp, kd


def _fastest_mode(dyn: _Dynamics, q_arm: np.ndarray) -> float:
    """The largest ``|eigenvalue|`` [1/s] of the joints' PD loop linearized at the arm
    configurations ``q_arm`` (T, n): the joints' free-floating inertia (the base's rows
    eliminated: nothing pushes on it) against the gains."""
    robot, data = dyn.robot, dyn.robot.model.createData()
    G, n = robot.velocity_map, dyn.kp.size
    fastest = 0.0
    for q in q_arm:
        M = G.T @ symmetric(pin.crba(robot.model, data, robot.pin_q(q))) @ G
        inverse = np.linalg.inv(M[6:, 6:] - M[6:, :6] @ np.linalg.solve(M[:6, :6], M[:6, 6:]))
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-inverse * dyn.kp, -inverse * dyn.kd]])
        fastest = max(fastest, float(np.abs(np.linalg.eigvals(A)).max()))
    return fastest


def _integrate(dyn: _Dynamics, plan: _ArmPlan, x0, t_end: float, opts: SimulationOptions):
    """The motion from ``x0`` to ``t_end`` with the options' integrator, sampled every
    ``output_dt``: ``(t, Q, V, A, TAU, stats)``. RK4 takes as many sub-steps per ``dt`` (at
    most :data:`MAX_SUBSTEPS`) as keep the PD loop's fastest mode along the plan stable: light
    distal links under the default gains are faster than ``1 / dt``."""
    if opts.integrator == "rk4":
        output_dt = opts.output_dt or opts.dt
        stride = max(1, round(output_dt / opts.dt))
        times = np.arange(0.0, t_end + output_dt / 2, output_dt)
        q_arm = arm_samples(dyn.robot, plan.mission.sample, plan.balance.sample, times)[0]
        need = _fastest_mode(dyn, q_arm) * opts.dt / RK4_STABLE
        substeps = int(min(MAX_SUBSTEPS, max(1, math.ceil(need))))
        out = rk4(dyn, plan, x0, t_end, opts.dt / substeps, stride * substeps)
        out[-1]["substeps"] = substeps
        return out
    return dopri5(dyn, plan, x0, t_end, opts, opts.output_dt or 0.01)


# --------------------------------------------------------------------------------- entry points
def simulate(
    robot: FloatingRobot,
    mission,
    balance,
    options: SimulationOptions | None = None,
    *,
    duration: float | None = None,
    initial_state: tuple[np.ndarray, np.ndarray] | None = None,
    attitude: tuple[np.ndarray, np.ndarray] | None = None,
    model: FloatingRobot | None = None,
    start: float = 0.0,
) -> SimulationResult:
    """Simulate the free-floating robot tracking a mission and a balance trajectory.

    Args:
        mission: the mission arm's planned motion: a
            :class:`~balance_opt.motion.trajectories.JointTrajectory`, a :class:`BalanceResult`
            (its mission part, interpolated), or a position (n_M,) [rad] to hold.
        balance: the balance arms' planned motion, same forms (n_B joints, balance arms
            stacked in order).
        duration: simulated time [s]; the longer of the two trajectories by default.
        initial_state: Pinocchio ``(q, v)`` to start from instead of the plan's start with the
            twist of ``options.h0`` (after a capture's impulse, say).
        attitude: the plan's base attitude, ``(t, quaternion)`` samples, for the feedforward
            torques under a non-zero ``options.h0`` (identity by default).
        model: the robot as the controller knows it (the plan's feedforward torques; the
            computed torque is refused with another), ``robot`` by default: ``robot`` is the
            truth that is integrated (a perturbed model, in the closed loop).
        start: the time [s] of the whole motion at which this part of it starts (a period of
            the closed loop, the motion after a capture), for a divergence's time.

    Returns:
        The simulated motion, with outputs computed at ``options.output_dt``.

    Raises:
        TrajectoryError: a trajectory has the wrong number of joints, or there is nothing to
            simulate (zero duration).
        InputError: gains of the wrong size.
    """
    opts = options or SimulationOptions()
    started = time.perf_counter()
    h0 = np.zeros(6) if opts.h0 is None else np.asarray(opts.h0, dtype=float)
    feedforward = opts.feedforward and opts.controller == "pd"
    if model is not None and model is not robot and opts.controller == "computed-torque":
        raise InputError("the computed-torque controller takes the simulated robot's own model")
    plan = _ArmPlan(robot, mission, balance, feedforward, h0, attitude, model)
    t_end = float(plan.duration if duration is None else duration)
    if not t_end > 0:
        raise TrajectoryError(
            f"nothing to simulate: duration {t_end} s (give 'duration' or a moving trajectory)"
        )
    q0, qd0 = (x[0] for x in plan.sample(np.zeros(1))[:2])
    kp, kd = _gains(robot, q0, opts)
    dyn = _Dynamics(robot, kp, kd, opts.controller, opts.clip_torque, start)
    if initial_state is None:  # the plan's start, the base twist of the momentum h0
        twist = NumericMaps(robot).base_twist(q0, qd0, h0)  # the base starts at the identity
        initial_state = robot.pin_q(q0), robot.pin_v(qd0, twist)
    x0 = initial_state

    t, Q, V, A, TAU, stats = _integrate(dyn, plan, x0, t_end, opts)
    integrated = time.perf_counter()

    result = _postprocess(robot, dyn, plan, t, Q, V, A, TAU, h0)
    done = time.perf_counter()
    result.info.update(
        integrator=opts.integrator,
        controller=opts.controller,
        feedforward=plan.feedforward,
        duration_s=t_end,
        kp=kp.tolist(),
        kd=kd.tolist(),
        clip_torque=opts.clip_torque,
        wall_time_integration_s=integrated - started,
        wall_time_outputs_s=done - integrated,
        wall_time_s=done - started,
        **stats,
    )
    _log_run(result)
    return result


def divergence(result: SimulationResult) -> str | None:
    """Why a simulation is not a motion of the robot, or ``None``: its state stops being finite,
    or it lost more than :data:`MOMENTUM_DIVERGED` of the momentum the physics conserves."""
    finite = np.all(np.isfinite(result.q_pin), axis=1) & np.all(np.isfinite(result.v), axis=1)
    if not finite.all():
        return f"non-finite state from t = {float(result.t[np.argmin(finite)]):.4g} s"
    residual = result.momentum_residual
    if residual.max() > MOMENTUM_DIVERGED:
        first = float(result.t[np.argmax(residual > MOMENTUM_DIVERGED)])
        return (
            f"relative momentum residual {float(residual.max()):.3g}, above "
            f"{MOMENTUM_DIVERGED:g} from t = {first:.4g} s"
        )
    return None


def _log_run(result: SimulationResult) -> None:
    """Log the run, with a warning when the step was too long to keep the momentum."""
    info = result.info
    residual = float(result.momentum_residual.max())
    if residual > MOMENTUM_WARNING:
        log.warning(
            "simulation lost momentum: relative residual %.3g > %.1g; the motion is too fast for "
            "the step (peak joint acceleration %.3g rad/s^2): shorten 'dt' or use 'dopri5'",
            residual,
            MOMENTUM_WARNING,
            float(np.abs(result.q_ddot).max()),
        )
    log.info(
        "simulated %.3g s with %s (%d steps) in %.3g s; max tracking error %.3g rad, "
        "max relative momentum residual %.3g",
        info["duration_s"],
        info["integrator"],
        info["steps"],
        info["wall_time_s"],
        result.max_tracking_error,
        residual,
    )


def simulate_plan(
    robot: FloatingRobot, plan: BalanceResult, options: SimulationOptions | None = None, **kwargs
) -> SimulationResult:
    """Simulate a plan (interpolated between its samples); keyword arguments to :func:`simulate`."""
    kwargs.setdefault("attitude", (plan.t, plan.quaternion))
    return simulate(robot, plan, plan, options, **kwargs)


def _postprocess(robot, dyn: _Dynamics, plan: _ArmPlan, t, Q, V, A, TAU, h0) -> SimulationResult:
    """Joint states, momentum and arm wrenches at the output samples."""
    model, data = robot.model, dyn.data
    T = t.size
    q = np.empty((T, robot.n))
    momentum = np.empty((T, 6))
    joint_momentum = np.empty((T, 2))
    cols = robot.pin_v_indices
    moving = robot.model_v_indices  # arm joints and the mimic joints following them
    for k in range(T):
        q[k] = dyn.joint_positions(Q[k])
        A_G = pin.computeCentroidalMap(model, data, Q[k])
        momentum[k] = A_G @ V[k]
        # each joint's own momentum, summed: arms that cancel each other (a balanced plan
        # tracked exactly) must not shrink the scale to nothing
        each = A_G[:, moving] * V[k, moving]
        joint_momentum[k] = [np.linalg.norm(e, axis=0).sum() for e in (each[:3], each[3:])]
    scale = tuple(
        max(float(joint_momentum[:, i].max() + np.linalg.norm(h0[s])), MOMENTUM_SCALE_FLOOR)
        for i, s in enumerate((slice(0, 3), slice(3, 6)))
    )
    q_des, q_dot_des, q_ddot_des = plan.sample(t)[:3]
    return SimulationResult(
        robot=robot,
        t=t,
        joint_names=robot.joint_names,
        q=q,
        q_dot=V[:, cols].copy(),
        q_ddot=A[:, cols].copy(),
        q_des=q_des,
        q_dot_des=q_dot_des,
        q_ddot_des=q_ddot_des,
        tau=TAU,
        q_pin=Q,
        v=V,
        a=A,
        momentum=momentum,
        h0=h0,
        momentum_scale=scale,
        arm_wrenches=arm_wrenches_on_base(robot, Q, V, A, data),
    )
