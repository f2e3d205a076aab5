"""Planning a task with a capture (``capture:``) as two phases joined at the capture time.

At ``t_c`` the target is attached to the mission end effector (:mod:`balance_opt.model.capture`):
joint positions and rates run on, the base twist jumps and the momentum gains the target's.
Each phase is planned in the frame of its own initial base attitude and turned back into the
world frame, so every planner (the law's feedback included) holds the attitude its phase
started from. The optimal first phase ends in the second's balance start condition so the
balance rates are continuous through the capture; end conditions apply to the second phase."""

from __future__ import annotations

import dataclasses

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.model.capture import CaptureState, capture_state
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import (
    BULKY_INFO_KEYS,
    BalanceResult,
    find_limit_violations,
    rate_steps,
)
from balance_opt.motion.so3 import matrix_from_quaternion, quaternion_multiply
from balance_opt.motion.trajectories import MissionWindow
from balance_opt.report.outputs import SAMPLED_ARRAYS


def _state_at_end(r: BalanceResult):
    """Arm positions, rates (arm vectors: the mission joints, then the balance joints) and the
    attitude at a result's last sample."""
    return np.r_[r.q_M[-1], r.q_B[-1]], np.r_[r.q_dot_M[-1], r.q_dot_B[-1]], r.quaternion[-1]


def _in_world(result: BalanceResult, quat_c: np.ndarray, t_c: float) -> BalanceResult:
    """A second-phase result (attitudes from the identity, clock from 0) in world time and
    attitude."""
    quat = quaternion_multiply(np.broadcast_to(quat_c, result.quaternion.shape), result.quaternion)
    return dataclasses.replace(result, t=result.t + t_c, quaternion=quat)


def join_phases(task, before: BalanceResult, after: BalanceResult, state: CaptureState):
    """One result of the two phases: the samples of both (the second's first sample, at the
    capture, left out: the first's last is the state just before), the limit violations of the
    whole motion, the first phase's details with the second's under ``after_capture`` (without
    its bulky arrays), the iterations of both, and the capture's numbers under ``capture``."""
    arrays = {
        name: np.concatenate([getattr(before, name), getattr(after, name)[1:]])
        for name in SAMPLED_ARRAYS
    }
    robot = task.robot
    q, q_dot, q_ddot = (
        np.hstack([arrays[f"q{s}_M"], arrays[f"q{s}_B"]]) for s in ("", "_dot", "_ddot")
    )
    info, second = before.details(), after.details()
    info["after_capture"] = {k: v for k, v in second.items() if k not in BULKY_INFO_KEYS}
    success = [r.get("success") for r in (info, second)]
    if any(s is not None for s in success):
        info["success"] = all(s is not False for s in success)
        if success[0] and not success[1]:
            info["status"] = second.get("status")
    # the solver's work of both phases (report.outputs.solver_metrics reports the totals)
    for key in ("iterations", "total_iterations", "total_solve_time_s"):
        if key in info and key in second:
            info[key] = info[key] + second[key]
    info["capture"] = state.as_dict(task.target.time)
    # the rates the second phase starts from: a jump there is counted (the law's does jump)
    steps = rate_steps(
        float(before.t[-1]),
        float(after.t[1] - after.t[0]),
        robot.joint_names,
        np.r_[before.q_dot_M[-1], before.q_dot_B[-1]],
        np.r_[after.q_dot_M[0], after.q_dot_B[0]],
        robot.limits,
    )
    return dataclasses.replace(
        before,
        **arrays,
        violations=find_limit_violations(
            arrays["t"], robot.joint_names, q, q_dot, q_ddot, robot.limits
        )
        + steps,
        info=info,
    )


def plan_part(
    task, method: str, robot: FloatingRobot, mission, q_B0, h0, options, guess, models, executor
) -> BalanceResult:
    """The plan of ``method`` of a whole task or of one phase of a capture: its own robot,
    mission, balance start and momentum ``h0`` (the law's feedback holds it)."""
    a = task.spec.analytic
    if method == "mission-only":
        from balance_opt.motion.replay import phase_one

        return phase_one(robot, mission, q_B0, h0=h0, integration=a.integration)
    if method == "analytic":
        from balance_opt.analytic.rollout import rollout

        law = dataclasses.replace(a.law, h0=tuple(float(v) for v in h0))
        return rollout(robot, mission, q_B0, law, integration=a.integration)
    from balance_opt.app.models import ModelCache
    from balance_opt.optimal.collision import InitialCollisionError, check_start
    from balance_opt.optimal.solve import build_balance_nlp
    from balance_opt.tasks.task import start_error

    model = (models if models is not None else ModelCache()).planner_model(
        robot, task.spec.robot.backend
    )
    try:  # before the planner's kinematics are built
        q0 = np.r_[mission.sample(np.zeros(1))[0].ravel(), q_B0]
        check_start(model.collisions, options, q0, robot)
    except InitialCollisionError as exc:
        if robot is not task.robot:  # the start after a capture: no key of the task sets it
            raise
        raise start_error(task, str(exc), exc.balance) from exc
    nlp = build_balance_nlp(model, mission, q_B0, options, robot=robot, h0=h0)
    return nlp.solve(guess, executor)


def _phase_options(task, options, index: int):
    """The optimal planner's options of phase ``index``: its share of the intervals (in
    proportion to the phases' durations, at least 2 each), the end conditions of the module
    docstring."""
    n = options.intervals
    first = min(max(2, round(n * task.target.time / task.duration)), max(2, n - 2))
    if index == 1:
        return dataclasses.replace(options, intervals=max(2, n - first), horizon=None)
    return dataclasses.replace(
        options,
        intervals=first,
        end=options.start,
        rest_at_end=False,
        horizon=None,
        final_configuration=None,
        terminal_attitude_bound=None,
    )


def plan_task(
    task, method: str, solver_options=None, models=None, executor=None, guess=None
) -> BalanceResult:
    """The plan of ``method`` (``"mission-only"``, ``"analytic"``, ``"optimal"``) of a task; with
    a capture, that method in each phase (each in its own start frame, see the module
    docstring), joined. ``guess``: the optimal planner's initial guess (default: the task's
    ``optimal.initial_guess``; a given one covers the whole mission: not for a capture).

    Raises:
        SolverError: the method failed; with a capture its ``result`` joins what was planned.
    """
    options = task.planner_options(solver_options) if method == "optimal" else None
    initial_guess = task.spec.optimal.initial_guess
    if task.target is None:
        return plan_part(
            task, method, task.robot, task.mission, task.q_B0, task.h0, options,
            initial_guess if guess is None else guess, models, executor,
        )  # fmt: skip

    def phase(index: int, robot, mission, q_B0, h0) -> BalanceResult:
        phase_options = None if options is None else _phase_options(task, options, index)
        return plan_part(
            task, method, robot, mission, q_B0, h0, phase_options, initial_guess, models, executor
        )

    t_c, q_B0 = task.target.time, np.asarray(task.q_B0, dtype=float)
    before = phase(0, task.robot, MissionWindow(task.mission, 0.0, t_c), q_B0, task.h0)
    q_c, qd_c, quat_c = _state_at_end(before)
    after_robot = task.robot_after_capture
    state = capture_state(task.robot, after_robot, task.target, q_c, qd_c, quat_c, task.h0)
    R_c, h = matrix_from_quaternion(quat_c), state.h_after
    h_c = np.r_[R_c.T @ h[:3], R_c.T @ h[3:]]  # in the axes of the base attitude at t_c
    window = MissionWindow(task.mission, t_c, task.duration)
    try:
        after = phase(1, after_robot, window, before.q_B[-1].copy(), h_c)
    except SolverError as exc:
        if exc.result is None:
            raise
        joined = join_phases(task, before, _in_world(exc.result, quat_c, t_c), state)
        raise SolverError(str(exc), exc.status, joined) from exc
    return join_phases(task, before, _in_world(after, quat_c, t_c), state)
