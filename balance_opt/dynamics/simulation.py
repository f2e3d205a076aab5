"""Forward-dynamics simulation of the free-floating robot: the check every balance plan goes
through.

The system is the free-flyer base and its arms with no gravity, no external wrench, no
thrusters or wheels (``physics-notes.md``); its momentum is therefore constant. Accelerations
come from Pinocchio's articulated-body algorithm (``pin.aba``) with the joint torques of one of
two controllers that track the planned trajectories of *all* arm joints (mission and balance):

* ``"pd"``, the paper's Phase I controller: ``tau = K_p (q_d - q) + K_d (q_dot_d - q_dot)``;
* ``"computed-torque"``: the free-floating inverse dynamics of the planned joint accelerations
  plus the same PD terms. With the joint accelerations ``q_ddot_d`` given, the base
  acceleration follows from the base rows of ``M(q) [a_b; q_ddot_d] + h = [0; tau]``
  (the base is unactuated), ``a_b = -M_bb^{-1} (M_bj q_ddot_d + h_b)``, and the joint rows give
  the feed-forward torque.

Integration keeps the configuration on its manifold. Both integrators are Runge-Kutta-Munthe-Kaas
(RKMK) schemes: a step from ``q_n`` works in the local coordinates ``u`` with
``q = pin.integrate(q_n, u)``, where the velocity ``v`` (base twist in the base frame) maps to
``u_dot = dDifference(q_n, q) v`` exactly (``pin.dDifference``, the inverse right Jacobian of the
SE(3) exponential for the base). Plain RK in ``u`` is then exact to the method's order; mixing the
stage velocities without that map would cost two orders on the base rotation.

* ``"rk4"``: the classical fixed-step RK4 in that form. The planned trajectories are sampled at
  every stage time before the loop, vectorised.
* ``"dopri5"``: the Dormand-Prince 5(4) embedded pair in the same form, with error control on
  the tangent-space increments (``atol + rtol |x|`` per component, RMS norm) and steps that land
  on every output time.

The initial state is the planned joint state at ``t = 0`` and the base twist that gives the
system its initial momentum ``h0`` (zero by default):
``v_b = A_b^{-1} (h0 - A_j q_dot)`` (``J_base q_dot`` for ``h0 = 0``, paper Eq. 19, 26).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from balance_opt.dynamics.options import (
    DEFAULT_BANDWIDTH,
    DEFAULT_DAMPING_RATIO,
    SimulationOptions,
)
from balance_opt.dynamics.wrenches import arm_wrenches_on_base
from balance_opt.errors import InputError, TrajectoryError
from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.rollout import SampledTrajectory
from balance_opt.motion.so3 import (
    quaternion_conjugate,
    quaternion_multiply,
    rotation_angle,
    rpy_from_quaternion,
)
from balance_opt.motion.trajectories import PointToPoint
from balance_opt.result import BalanceResult

log = logging.getLogger(__name__)

#: Step-size control of the adaptive integrator: safety factor and bounds of the step ratio.
STEP_SAFETY = 0.9
STEP_GROWTH_MAX = 5.0
STEP_SHRINK_MIN = 0.2
#: Smallest step the adaptive integrator accepts before giving up [s].
MIN_STEP = 1e-10
#: Relative momentum residual above which a simulation warns that its step is too long.
MOMENTUM_WARNING = 1e-6
#: Momentum scale below which the residual is reported in absolute terms [N s, N m s].
MOMENTUM_SCALE_FLOOR = 1e-12


# Dormand-Prince 5(4): nodes, stage matrix, 5th-order weights (the solution) and 4th-order weights.
_DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
_DP_A = np.array(
    [
        [0, 0, 0, 0, 0, 0, 0],
        [1 / 5, 0, 0, 0, 0, 0, 0],
        [3 / 40, 9 / 40, 0, 0, 0, 0, 0],
        [44 / 45, -56 / 15, 32 / 9, 0, 0, 0, 0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0, 0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0, 0],
        [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0],
    ]
)
_DP_B5 = _DP_A[6]
_DP_B4 = np.array([5179 / 57600, 0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40])


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
    """Mission and balance trajectories stacked into the robot's arm vector."""

    def __init__(self, robot: FloatingRobot, mission, balance):
        self.robot = robot
        self.mission, d_M = _as_trajectory(mission, robot.mission.dof, "mission")
        self.balance, d_B = _as_trajectory(balance, robot.balance_indices.size, "balance")
        self.duration = max(d_M, d_B)

    def sample(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = [np.empty((t.size, self.robot.n)) for _ in range(3)]
        for traj, idx in (
            (self.mission, self.robot.mission_indices),
            (self.balance, self.robot.balance_indices),
        ):
            for o, s in zip(out, traj.sample(t)):
                o[:, idx] = np.reshape(s, (t.size, -1))
        return tuple(out)


# --------------------------------------------------------------------------------- options
def _per_joint(value, n: int, name: str) -> np.ndarray | None:
    if value is None:
        return None
    arr = (
        np.broadcast_to(np.asarray(value, dtype=float), (n,))
        if np.ndim(value) == 0
        else np.asarray(value, dtype=float)
    )
    if arr.shape != (n,):
        raise InputError(
            f"simulation option '{name}' needs one value per arm joint ({n}), got {arr.size}"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise InputError(
            f"simulation option '{name}' must be finite and non-negative, got {arr.tolist()}"
        )
    return arr.copy()


def default_gains(
    robot: FloatingRobot,
    q,
    bandwidth: float = DEFAULT_BANDWIDTH,
    damping_ratio: float = DEFAULT_DAMPING_RATIO,
) -> tuple[np.ndarray, np.ndarray]:
    """PD gains that give each joint, alone with the base held, the ``bandwidth`` [rad/s] and
    ``damping_ratio``: ``K_p = M_ii w^2``, ``K_d = 2 zeta w M_ii`` with ``M_ii`` the joint-space
    inertia's diagonal at arm configuration ``q`` [kg m^2].

    Returns:
        ``(kp, kd)`` in arm order [N m/rad, N m s/rad].
    """
    data = robot.model.createData()
    M = pin.crba(robot.model, data, robot.pin_q(q))
    m_ii = np.diag(M)[robot.pin_v_indices]
    return m_ii * bandwidth**2, 2.0 * damping_ratio * bandwidth * m_ii


# --------------------------------------------------------------------------------- result
@dataclass
class SimulationResult:
    """A simulated motion, sampled at the output times.

    Attributes:
        t: sample times (T,) [s].
        joint_names: arm joints, arm order (mission first); ``mission_indices`` and
            ``balance_indices`` select each part.
        q, q_dot, q_ddot: simulated joint motion (T, n) [rad, rad/s, rad/s^2].
        q_des, q_dot_des, q_ddot_des: the planned joint motion at the same times.
        tau: joint torques (T, n) [N m].
        q_pin, v, a: Pinocchio state and ABA accelerations (T, nq), (T, nv), (T, nv); the base
            twist and acceleration in the base frame.
        momentum: the system's momentum (T, 6) ``[linear; angular about the CoM]``, world axes
            [N s, N m s].
        h0: the momentum it should keep (6,).
        momentum_scale: ``(linear, angular)`` scale the residual is relative to: the largest
            momentum the joint motion carries, ``max_t |A_j q_dot|``, plus ``|h0|``.
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

    @property
    def mission_indices(self) -> np.ndarray:
        return self.robot.mission_indices

    @property
    def balance_indices(self) -> np.ndarray:
        return self.robot.balance_indices

    @property
    def quaternion(self) -> np.ndarray:
        """Base attitude (T, 4), (x, y, z, w)."""
        return self.q_pin[:, 3:7]

    @property
    def base_position(self) -> np.ndarray:
        """Base origin in the world (T, 3) [m]."""
        return self.q_pin[:, :3]

    @property
    def omega(self) -> np.ndarray:
        """Base angular velocity (T, 3), base frame [rad/s]."""
        return self.v[:, 3:6]

    @property
    def rpy(self) -> np.ndarray:
        """Base roll, pitch, yaw (T, 3) [rad] (``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
        return rpy_from_quaternion(self.quaternion)

    @property
    def angle(self) -> np.ndarray:
        """Base rotation from the initial attitude, ``|log(R_0^T R)|`` (T,) [rad]."""
        q = self.quaternion
        return rotation_angle(quaternion_multiply(quaternion_conjugate(q[:1]), q))

    @property
    def tracking_error(self) -> np.ndarray:
        """Planned minus simulated joint positions (T, n) [rad]."""
        return self.q_des - self.q

    @property
    def max_tracking_error(self) -> float:
        """Largest joint tracking error over the motion [rad]."""
        return float(np.abs(self.tracking_error).max())

    @property
    def total_wrench(self) -> np.ndarray:
        """Sum of the arms' wrenches on the base (T, 6) [N, N m]; equals the base's Newton-Euler
        wrench ``I_b a_b + v_b x* I_b v_b``."""
        return sum(self.arm_wrenches.values())

    @property
    def momentum_error(self) -> np.ndarray:
        """``h(t) - h0`` (T, 6) [N s, N m s]."""
        return self.momentum - self.h0

    @property
    def momentum_residual(self) -> np.ndarray:
        """Relative momentum residual (T,): the larger of ``|p - p0| / scale_p`` and
        ``|L - L0| / scale_L`` (see ``momentum_scale``)."""
        err = self.momentum_error
        lin = np.linalg.norm(err[:, :3], axis=1) / self.momentum_scale[0]
        ang = np.linalg.norm(err[:, 3:], axis=1) / self.momentum_scale[1]
        return np.maximum(lin, ang)

    def as_balance_result(self, method: str = "simulation") -> BalanceResult:
        """The simulated motion as a :class:`BalanceResult`, to compare field by field with the
        plan it tracked. ``momentum_residual`` there is the absolute angular momentum error
        [N m s]; ``sigma_min`` is recomputed along the simulated path."""
        robot = self.robot
        maps = NumericMaps(robot)
        sigma = np.array([maps.coupling_measures(qk).sigma_min for qk in self.q])
        info = dict(self.info)
        info.update(
            max_tracking_error_rad=self.max_tracking_error,
            max_relative_momentum_residual=float(self.momentum_residual.max()),
        )
        return BalanceResult.from_arm_vectors(
            robot,
            method,
            self.t.copy(),
            self.q,
            self.q_dot,
            self.q_ddot,
            self.quaternion.copy(),
            self.omega.copy(),
            np.linalg.norm(self.momentum_error[:, 3:], axis=1),
            sigma,
            info,
        )


# --------------------------------------------------------------------------------- dynamics
class _Dynamics:
    """``(q, v, planned joint state) -> (a, tau)`` with one reused Pinocchio data."""

    def __init__(self, robot: FloatingRobot, kp, kd, controller: str, clip_torque: bool):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.idx_v = robot.pin_v_indices
        jids = [robot.model.getJointId(j) for j in robot.joint_names]
        self.idx_q = np.array([robot.model.joints[j].idx_q for j in jids])
        self.revolute_only = all(robot.model.joints[j].nq == 1 for j in jids)
        self.kp, self.kd = kp, kd
        self.computed_torque = controller == "computed-torque"
        self.effort = robot.limits.effort if clip_torque else None
        self.tau_full = np.zeros(robot.model.nv)
        self.acc = np.zeros(robot.model.nv)

    def joint_positions(self, q):
        return q[self.idx_q] if self.revolute_only else self.robot.arm_q(q)

    def position_error(self, qd, q):
        e = qd - self.joint_positions(q)
        if not self.revolute_only:  # continuous joints: shortest way round
            e = (e + np.pi) % (2 * np.pi) - np.pi
        return e

    def __call__(self, q, v, qd, vd, ad):
        tau = self.kp * self.position_error(qd, q) + self.kd * (vd - v[self.idx_v])
        if self.computed_torque:
            tau = tau + self.feedforward(q, v, ad)
        if self.effort is not None:
            tau = np.clip(tau, -self.effort, self.effort)
        self.tau_full[self.idx_v] = tau
        return pin.aba(self.model, self.data, q, v, self.tau_full), tau

    def feedforward(self, q, v, ad):
        """Joint torques of the free-floating inverse dynamics for joint accelerations ``ad``."""
        M = pin.crba(self.model, self.data, q)
        self.acc[self.idx_v] = ad
        tau0 = pin.rnea(self.model, self.data, q, v, self.acc)
        # M_bb is the composite inertia of the whole system in the base frame
        a_b = -np.linalg.solve(self.data.Ycrb[1].matrix(), tau0[:6])
        return tau0[self.idx_v] + M[:6, self.idx_v].T @ a_b


def _initial_state(
    robot: FloatingRobot, plan: _ArmPlan, h0_world: np.ndarray, base: pin.SE3 | None
):
    q0, qd0, _ = (x[0] for x in plan.sample(np.zeros(1)))
    base = base or pin.SE3.Identity()
    R = base.rotation
    h0_base = np.r_[R.T @ h0_world[:3], R.T @ h0_world[3:]]
    twist = NumericMaps(robot).base_twist(q0, qd0, h0_base)
    return robot.pin_q(q0, base), robot.pin_v(qd0, twist)


def _rk4(dyn: _Dynamics, plan: _ArmPlan, x0, t_end: float, dt: float, stride: int):
    """Fixed-step RKMK4 (see the module docstring). Returns output arrays and step counts."""
    model = dyn.model
    n_steps = max(1, math.ceil(t_end / dt - 1e-9))
    h = t_end / n_steps
    # planned joint state at every stage time: index 2k is t_k, 2k+1 is t_k + h/2
    grid = np.arange(2 * n_steps + 1) * (h / 2)
    QD, VD, AD = plan.sample(grid)
    out_steps = np.unique(np.r_[np.arange(0, n_steps, stride), n_steps])
    is_out = np.zeros(n_steps + 1, dtype=bool)
    is_out[out_steps] = True
    T = out_steps.size
    Q, V, A, TAU = (np.empty((T, m)) for m in (model.nq, model.nv, model.nv, dyn.idx_v.size))
    q, v = x0
    integrate, ddiff, ARG1 = pin.integrate, pin.dDifference, pin.ArgumentPosition.ARG1
    h2, h6 = h / 2, h / 6
    j = 0
    for k in range(n_steps):
        i = 2 * k
        a1, tau1 = dyn(q, v, QD[i], VD[i], AD[i])
        if is_out[k]:
            Q[j], V[j], A[j], TAU[j] = q, v, a1, tau1
            j += 1
        v1 = v
        q2 = integrate(model, q, h2 * v1)
        v2 = v + h2 * a1
        a2, _ = dyn(q2, v2, QD[i + 1], VD[i + 1], AD[i + 1])
        u2 = ddiff(model, q, q2, ARG1) @ v2
        q3 = integrate(model, q, h2 * u2)
        v3 = v + h2 * a2
        a3, _ = dyn(q3, v3, QD[i + 1], VD[i + 1], AD[i + 1])
        u3 = ddiff(model, q, q3, ARG1) @ v3
        q4 = integrate(model, q, h * u3)
        v4 = v + h * a3
        a4, _ = dyn(q4, v4, QD[i + 2], VD[i + 2], AD[i + 2])
        u4 = ddiff(model, q, q4, ARG1) @ v4
        q = integrate(model, q, h6 * (v1 + 2.0 * (u2 + u3) + u4))
        v = v + h6 * (a1 + 2.0 * (a2 + a3) + a4)
    a_end, tau_end = dyn(q, v, QD[-1], VD[-1], AD[-1])
    Q[j], V[j], A[j], TAU[j] = q, v, a_end, tau_end
    return (
        out_steps * h,
        Q,
        V,
        A,
        TAU,
        {"steps": n_steps, "step_s": h, "rhs_evaluations": 4 * n_steps + 1},
    )


def _dopri5(
    dyn: _Dynamics, plan: _ArmPlan, x0, t_end: float, opts: SimulationOptions, output_dt: float
):
    """Adaptive RKMK Dormand-Prince 5(4) with steps that land on the output times."""
    model = dyn.model
    integrate, ddiff, ARG1 = pin.integrate, pin.dDifference, pin.ArgumentPosition.ARG1
    n_out = max(1, math.ceil(t_end / output_dt - 1e-9))
    t_out = np.linspace(0.0, t_end, n_out + 1)
    nv = model.nv
    Q, V, A, TAU = (np.empty((t_out.size, m)) for m in (model.nq, nv, nv, dyn.idx_v.size))

    def rhs(t, q, v):
        qd, vd, ad = (x[0] for x in plan.sample(np.array([t])))
        return dyn(q, v, qd, vd, ad)

    q, v = x0
    t, h = 0.0, min(opts.dt, opts.max_step)
    a, tau = rhs(t, q, v)
    Q[0], V[0], A[0], TAU[0] = q, v, a, tau
    KU, KV = np.empty((7, nv)), np.empty((7, nv))
    accepted = rejected = evaluations = 0
    for j in range(1, t_out.size):
        while t < t_out[j]:
            step = min(h, t_out[j] - t)
            last = step >= t_out[j] - t
            KU[0], KV[0] = v, a
            for s in range(1, 7):
                du = step * (_DP_A[s, :s] @ KU[:s])
                qs = integrate(model, q, du)
                vs = v + step * (_DP_A[s, :s] @ KV[:s])
                a_s, tau_s = rhs(t + _DP_C[s] * step, qs, vs)
                KU[s], KV[s] = ddiff(model, q, qs, ARG1) @ vs, a_s
            evaluations += 6
            # the 7th stage sits at the new state (first same as last)
            dv5 = step * (_DP_B5 @ KV)
            eu, ev = step * ((_DP_B5 - _DP_B4) @ KU), step * ((_DP_B5 - _DP_B4) @ KV)
            v_new = v + dv5
            scale_u = opts.atol + opts.rtol
            scale_v = opts.atol + opts.rtol * np.maximum(np.abs(v), np.abs(v_new))
            err = math.sqrt((np.sum((eu / scale_u) ** 2) + np.sum((ev / scale_v) ** 2)) / (2 * nv))
            if err <= 1.0:
                t = t_out[j] if last else t + step
                q, v = (
                    qs,
                    v_new,
                )  # qs is integrate(q, du5): stage 7 nodes equal the 5th-order weights
                a, tau = a_s, tau_s
                accepted += 1
            else:
                rejected += 1
            factor = STEP_SAFETY * err**-0.2 if err > 0 else STEP_GROWTH_MAX
            h_new = step * min(STEP_GROWTH_MAX, max(STEP_SHRINK_MIN, factor))
            if not last or err > 1.0:  # a step cut short to land on an output time says little
                h = min(h_new, opts.max_step)
            if h < MIN_STEP:
                raise InputError(
                    f"adaptive integration stalled at t = {t:.6g} s (step {h:.3g} s below "
                    f"{MIN_STEP} s); loosen 'rtol'/'atol' or check the gains"
                )
        Q[j], V[j], A[j], TAU[j] = q, v, a, tau
    return (
        t_out,
        Q,
        V,
        A,
        TAU,
        {"steps": accepted, "rejected_steps": rejected, "rhs_evaluations": evaluations + 1},
    )


# --------------------------------------------------------------------------------- entry points
def simulate(
    robot: FloatingRobot,
    mission,
    balance,
    options: SimulationOptions | None = None,
    *,
    duration: float | None = None,
    base: pin.SE3 | None = None,
) -> SimulationResult:
    """Simulate the free-floating robot tracking a mission and a balance trajectory.

    Args:
        robot: the floating robot.
        mission: the mission arm's planned motion: anything with ``sample(t) -> (q, q_dot,
            q_ddot)`` and ``duration`` (a :class:`~balance_opt.motion.trajectories.JointTrajectory`),
            a :class:`BalanceResult` (its mission part, interpolated), or a position (n_M,) [rad]
            to hold.
        balance: the balance arms' planned motion, same forms (n_B joints, balance arms
            stacked in order).
        options: see :class:`SimulationOptions`.
        duration: simulated time [s]; the longer of the two trajectories by default.
        base: initial base pose in the world (identity by default).

    Returns:
        The simulated motion, with outputs computed at ``options.output_dt``.

    Raises:
        TrajectoryError: a trajectory has the wrong number of joints, or there is nothing to
            simulate (zero duration).
        InputError: gains of the wrong size.
    """
    opts = options or SimulationOptions()
    started = time.perf_counter()
    plan = _ArmPlan(robot, mission, balance)
    t_end = float(plan.duration if duration is None else duration)
    if not t_end > 0:
        raise TrajectoryError(
            f"nothing to simulate: duration {t_end} s (give 'duration' or a moving trajectory)"
        )
    n = robot.n
    q0 = plan.sample(np.zeros(1))[0][0]
    kp_default, kd_default = default_gains(robot, q0, opts.bandwidth, opts.damping_ratio)
    kp = _per_joint(opts.kp, n, "kp")
    kd = _per_joint(opts.kd, n, "kd")
    kp = kp_default if kp is None else kp
    kd = kd_default if kd is None else kd
    dyn = _Dynamics(robot, kp, kd, opts.controller, opts.clip_torque)
    h0 = np.zeros(6) if opts.h0 is None else np.asarray(opts.h0, dtype=float)
    x0 = _initial_state(robot, plan, h0, base)

    if opts.integrator == "rk4":
        output_dt = opts.output_dt or opts.dt
        stride = max(1, round(output_dt / opts.dt))
        t, Q, V, A, TAU, stats = _rk4(dyn, plan, x0, t_end, opts.dt, stride)
    else:
        output_dt = opts.output_dt or 0.01
        t, Q, V, A, TAU, stats = _dopri5(dyn, plan, x0, t_end, opts, output_dt)
    integrated = time.perf_counter()

    result = _postprocess(robot, dyn, plan, t, Q, V, A, TAU, h0)
    done = time.perf_counter()
    result.info.update(
        integrator=opts.integrator,
        controller=opts.controller,
        duration_s=t_end,
        kp=kp.tolist(),
        kd=kd.tolist(),
        clip_torque=opts.clip_torque,
        wall_time_integration_s=integrated - started,
        wall_time_outputs_s=done - integrated,
        wall_time_s=done - started,
        **stats,
    )
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
        t_end,
        opts.integrator,
        stats["steps"],
        done - started,
        result.max_tracking_error,
        residual,
    )
    return result


def simulate_plan(
    robot: FloatingRobot, plan: BalanceResult, options: SimulationOptions | None = None, **kwargs
) -> SimulationResult:
    """Simulate a plan: its mission and balance motions (interpolated between its samples)
    tracked by the controller. Keyword arguments go to :func:`simulate`."""
    return simulate(
        robot,
        SampledTrajectory.from_result(plan, "mission"),
        SampledTrajectory.from_result(plan, "balance"),
        options,
        **kwargs,
    )


def _postprocess(robot, dyn: _Dynamics, plan: _ArmPlan, t, Q, V, A, TAU, h0) -> SimulationResult:
    """Joint states, momentum and arm wrenches at the output samples."""
    model, data = robot.model, dyn.data
    T = t.size
    q = np.empty((T, robot.n))
    momentum = np.empty((T, 6))
    joint_momentum = np.empty((T, 6))
    cols = robot.pin_v_indices
    for k in range(T):
        q[k] = dyn.joint_positions(Q[k])
        A_G = pin.computeCentroidalMap(model, data, Q[k])
        momentum[k] = A_G @ V[k]
        joint_momentum[k] = A_G[:, cols] @ V[k, cols]
    scale = tuple(
        max(
            float(np.linalg.norm(joint_momentum[:, s], axis=1).max() + np.linalg.norm(h0[s])),
            MOMENTUM_SCALE_FLOOR,
        )
        for s in (slice(0, 3), slice(3, 6))
    )
    q_des, q_dot_des, q_ddot_des = plan.sample(t)
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
