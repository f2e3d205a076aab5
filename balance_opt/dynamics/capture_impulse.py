"""Forward dynamics through a capture (``docs/physics.md``, "Capture"): the robot simulated up
to the capture, an instantaneous inelastic impulse (joints held: only the base twist jumps, to
the one that conserves the total momentum of robot and target), then the robot with the target.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from balance_opt.dynamics.options import SimulationOptions
from balance_opt.dynamics.simulation import SimulationResult, simulate
from balance_opt.model.capture import CaptureState, Target, capture_state
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.trajectories import MissionWindow, SampledTrajectory


def impulse(
    robot: FloatingRobot, after: FloatingRobot, target: Target, q_pin, v, h_before
) -> tuple[np.ndarray, np.ndarray, CaptureState]:
    """The Pinocchio state ``(q, v)`` of the robot with the target just after the capture, from
    the robot's state ``(q_pin, v)`` and momentum ``h_before`` (world) just before."""
    q_arm, q_dot = robot.arm_q(q_pin), robot.arm_v(v)
    quaternion = np.asarray(q_pin[3:7], dtype=float)
    state = capture_state(robot, after, target, q_arm, q_dot, quaternion, h_before)
    base = pin.XYZQUATToSE3(np.asarray(q_pin[:7], dtype=float))
    return after.pin_q(q_arm, base), after.pin_v(q_dot, state.twist_after), state


def simulate_with_capture(
    robot: FloatingRobot,
    after: FloatingRobot,
    target: Target,
    plan: BalanceResult,
    options: SimulationOptions | None = None,
) -> SimulationResult:
    """Simulate a plan through the capture of ``target``: one result whose ``h0`` is per sample
    (T, 6); ``info["capture"]`` holds the impulse, ``info["after_capture"]`` phase two's info."""
    opts = options or SimulationOptions()
    mission = SampledTrajectory.from_result(plan, "mission")
    balance = SampledTrajectory.from_result(plan, "balance")
    t_c = float(target.time)
    attitude = (plan.t, plan.quaternion)  # for the feedforward torques under momentum
    first = simulate(robot, mission, balance, opts, duration=t_c, attitude=attitude)
    q_pin, v, state = impulse(
        robot, after, target, first.q_pin[-1], first.v[-1], first.momentum[-1]
    )
    second = simulate(
        after,
        MissionWindow(mission, t_c, mission.duration),
        MissionWindow(balance, t_c, balance.duration),
        dataclasses.replace(opts, h0=tuple(state.h_after.tolist())),
        initial_state=(q_pin, v),
        start=t_c,
        attitude=(plan.t - t_c, plan.quaternion),
    )
    return _joined(first, second, t_c, state)


def _joined(
    first: SimulationResult, second: SimulationResult, t_c: float, state: CaptureState
) -> SimulationResult:
    keep = slice(1, None)
    names = ["q", "q_dot", "q_ddot", "q_des", "q_dot_des", "q_ddot_des", "tau"]
    names += ["q_pin", "v", "a", "momentum"]
    arrays = {
        name: np.concatenate([getattr(first, name), getattr(second, name)[keep]]) for name in names
    }
    n1, n2 = first.t.size, second.t.size - 1
    h0 = np.vstack([np.broadcast_to(first.h0, (n1, 6)), np.broadcast_to(second.h0, (n2, 6))])
    info = dict(first.info)
    info["after_capture"] = dict(second.info)
    info["capture"] = state.as_dict(t_c)
    return dataclasses.replace(
        first,
        t=np.concatenate([first.t, second.t[keep] + t_c]),
        **arrays,
        h0=h0,
        momentum_scale=tuple(
            max(a, b) for a, b in zip(first.momentum_scale, second.momentum_scale)
        ),
        arm_wrenches={
            k: np.concatenate([w, second.arm_wrenches[k][keep]])
            for k, w in first.arm_wrenches.items()
        },
        info=info,
    )
