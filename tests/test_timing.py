"""Co-planned mission timing (``mission.timing: free``, ``optimal.objective: time``): the path,
the re-timed mission against an independent replay of its exported joints, the mission joints'
limits between the samples, the task file's keys, and given-timing problems left alone."""

from __future__ import annotations

import json
import re
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from balance_opt.config.yaml_lines import TaskFileError
from balance_opt.errors import InputError
from balance_opt.motion.retiming import MissionPath, shortest_duration
from balance_opt.motion.trajectories import PointToPoint, SampledTrajectory, ViaPoints
from balance_opt.optimal.nlp import point_kernels
from balance_opt.optimal.refine import PlanReport
from balance_opt.tasks.task import load_task

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
CAPTURE = (EXAMPLES / "capture_task.yaml").read_text()
DURATION_LINE = "  duration: 10.0                   # [s]\n"


def _task(tmp_path, text: str, name: str = "task.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _free(text: str = CAPTURE, extra: str = "") -> str:
    assert DURATION_LINE in text
    return text.replace(DURATION_LINE, DURATION_LINE + "  timing: free\n") + extra


def _line_of(text: str, fragment: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if fragment in line)


# ------------------------------------------------------------------------------ the path


def test_curved_path_passes_through_the_given_trajectory_with_its_derivatives():
    via = ViaPoints([0.0, 3.0, 7.0], [[0.0, 0.3, -0.6], [0.8, 0.1, -1.0], [1.2, 0.9, -1.6]])
    path = MissionPath(via)
    assert not path.linear
    sigma = np.linspace(0.0, 1.0, 317)
    q, d1, d2 = path.evaluate(sigma)
    g, gd, gdd = via.sample(sigma * via.duration)
    T0 = via.duration
    # quintic Hermite pieces on 40 knots: the given motion to within 1e-5 rad, its derivatives
    # (in sigma: times T0, T0^2) to within 1e-3 of their size
    assert np.abs(q - g).max() < 1e-5
    assert np.abs(d1 - gd * T0).max() < 1e-3 * np.abs(gd * T0).max()
    assert np.abs(d2 - gdd * T0**2).max() < 1e-2 * np.abs(gdd * T0**2).max()
    # the symbolic path (the NLP's rows) is the numeric one
    s = cs.SX.sym("s")
    f = cs.Function("path", [s], list(path.symbolic(s)))
    for value in (0.0, 0.013, 0.5, 0.77, 1.0):
        got = [np.array(v).ravel() for v in f(value)]
        want = [v[0] for v in path.evaluate([value])]
        for a, b in zip(got, want):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_straight_path_of_a_point_to_point_mission_and_its_given_progress():
    ptp = PointToPoint([0.0, 0.3, -0.6], [1.2, 0.9, -1.6], 10.0)
    path = MissionPath(ptp)
    assert path.linear
    t = np.linspace(0.0, 10.0, 101)
    q = ptp.sample(t)[0]
    sigma = path.given_progress(t)
    np.testing.assert_allclose(path.evaluate(sigma)[0], q, atol=1e-14)
    np.testing.assert_allclose(path.given_time(sigma), t, atol=1e-3)
    # rate 1 rad/s and acceleration 2 rad/s^2 on a 1.2 rad move: coast at 1/1.2 of the path per
    # second after 0.5 s of acceleration, 1.7 s in all
    assert shortest_duration(path, (1.0 / 1.2, 2.0 / 1.2)) == pytest.approx(1.7)


# ------------------------------------------------------------------------ the task file


@pytest.mark.parametrize(
    "text, fragment, message",
    [
        (
            CAPTURE.replace(DURATION_LINE, DURATION_LINE + "  timing: fast\n"),
            "timing: fast",
            "mission.timing: expected one of 'given', 'free'",
        ),
        (
            _free(CAPTURE.replace("  mission_joint2: {acceleration: 2.0}\n", "")),
            "timing: free",
            "mission.timing: a free timing needs an acceleration limit of every mission joint; "
            "mission_joint2 has none (set limits.mission_joint2.acceleration)",
        ),
        (
            CAPTURE + "optimal:\n  objective: time\n",
            "objective: time",
            "optimal.objective: objective time (the shortest mission within a drift bound) "
            "needs mission.timing: free and optimal.constraints.path_attitude_bound",
        ),
        (
            _free(extra="optimal:\n  objective: time\n"),
            "objective: time",
            "optimal.objective: objective time (the shortest mission within a drift bound) "
            "needs mission.timing: free and optimal.constraints.path_attitude_bound",
        ),
        (
            _free(
                CAPTURE.replace("momentum: [0, 0, 0, 0, 0, 0]", "momentum: [0, 0, 0, 0, 0, 0.2]"),
                "optimal:\n  objective: time\n  constraints: {path_attitude_bound: 0.03}\n",
            ),
            "momentum: [0, 0, 0, 0, 0, 0.2]",
            "initial.momentum: optimal.objective: time needs a zero initial momentum: with "
            "momentum the base drifts while the arms wait, so a longer mission is not always a "
            "stiller one",
        ),
    ],
    ids=[
        "unknown timing",
        "no acceleration limit",
        "time without free",
        "time without bound",
        "time with momentum",
    ],
)
def test_bad_timing_keys_name_file_line_and_key(tmp_path, text, fragment, message):
    path = _task(tmp_path, text)
    with pytest.raises(TaskFileError) as info:
        load_task(path)
    assert str(info.value).startswith(f"{path}:{_line_of(text, fragment)}: {message}")


def _plan(max_drift, final_drift=0.0, rounds=6):
    """A stand-in for a refined, re-simulated plan: its drift (peak at t = 2 s of a 4 s
    motion) and its refinement rounds."""
    from types import SimpleNamespace

    t = np.linspace(0.0, 4.0, 5)
    angle = np.array([0.0, 0.5, 1.0, 0.5, 0.0]) * max_drift
    angle[-1] = final_drift
    solver = PlanReport((), refinement={"rounds": rounds})
    return SimpleNamespace(
        t=t, angle=angle, max_drift=max_drift, final_drift=final_drift, solver=solver, info={}
    )


@pytest.mark.parametrize(
    "kind, drifts, message",
    [
        (
            "PathAttitudeBound",
            (0.0125, 0.001),
            "no plan keeps the path_attitude_bound: the base turns 0.0125 rad at t = 2.000 s, "
            "0.0025 rad (+25.000%) over its 0.01 rad, after 6 refinement rounds",
        ),
        (
            "PeakEpigraph",
            (0.0125, 0.001),
            "no plan keeps the path_attitude_bound: the base turns 0.0125 rad at t = 2.000 s, "
            "0.0025 rad (+25.000%) over its 0.01 rad, after 6 refinement rounds",
        ),
        (
            "TerminalAttitudeBound",
            (0.009, 0.003),
            "no plan keeps the terminal_attitude_bound: the base ends 0.003 rad from its "
            "initial attitude, 0.001 rad (+50.000%) over its 0.002 rad, after 6 refinement "
            "rounds",
        ),
    ],
)
def test_a_plan_over_its_attitude_bound_after_the_rounds_fails(kind, drifts, message):
    """A plan whose re-simulated drift still breaks an attitude bound after the refinement is
    no plan (it was returned as a success before, the rounds only logged)."""
    from types import SimpleNamespace

    from balance_opt.optimal import constraints, objectives
    from balance_opt.optimal.terms import PlannerSolverError

    options = SimpleNamespace(path_attitude_bound=0.01, terminal_attitude_bound=0.002)
    problem = SimpleNamespace(options=options)
    bound = getattr(constraints, kind, None) or getattr(objectives, kind)
    bound = bound()
    with pytest.raises(PlannerSolverError, match=re.escape(message)) as info:
        bound.accept(problem, _plan(*drifts))
    assert info.value.status == "Attitude_Bound"
    # within the planner's tolerance (1e-3 of the bound) both bounds hold
    bound.accept(problem, _plan(0.01 * (1 + 0.9e-3), 0.002 * (1 + 0.9e-3)))


def test_shortest_duration_probes_judge_the_resimulated_drift():
    """A probe whose plan comes back (no solver error) with its re-simulated peak over the
    bound is not feasible: with a peak of 0.08 rad s / T and a bound of 0.01 rad, the shortest
    duration is 8 s (every probe counted as feasible before: 0.08 s)."""
    from types import SimpleNamespace

    from balance_opt.optimal.solve import TIME_RESOLUTION, fastest

    mission = PointToPoint([0.0, 0.3, -0.6], [1.2, 0.9, -1.6], 10.0)
    options = SimpleNamespace(path_attitude_bound=0.01, terminal_attitude_bound=None)

    class Probe:
        def __init__(self, horizon):
            self.horizon = horizon

        def solve(self, guess, executor):
            return _plan(0.08 / self.horizon)

    nlp = SimpleNamespace(
        options=options,
        free_timing=True,
        h0=np.zeros(6),
        mission=mission,
        mission_path=MissionPath(mission),
        path_rate_limits=(np.inf, np.inf),
        variant=lambda objective, horizon: Probe(horizon),
    )
    found = fastest(nlp, None).solver.minimum_time
    assert 8.0 <= found["duration_s"] <= 8.0 + TIME_RESOLUTION
    assert all(p["feasible"] == (p["duration_s"] >= 8.0) for p in found["probes"])
    nlp.h0 = np.r_[0.0, 0.0, 0.0, 0.0, 0.0, 0.2]
    with pytest.raises(InputError, match=re.escape("objective time needs a zero initial momentum")):
        fastest(nlp, None)


def test_free_timing_with_a_capture_is_refused(tmp_path):
    text = (EXAMPLES / "capture_tumbling_target.yaml").read_text()
    text = re.sub(r"(\n  duration: [^\n]*\n)", r"\1  timing: free\n", text, count=1)
    limits = "".join(f"  mission_joint{i}: {{acceleration: 2.0}}\n" for i in (1, 2, 3))
    first = "  balance_joint1: {acceleration"
    text = text.replace(first, limits + first, 1)
    path = _task(tmp_path, text)
    message = (
        f"{path}:{_line_of(text, 'timing: free')}: mission.timing: a free timing is not "
        "available with a capture (the capture time is fixed); use timing: given"
    )
    with pytest.raises(TaskFileError, match=re.escape(message)):
        load_task(path)


def test_given_timing_problem_has_no_timing_variables_rows_or_kernel_inputs(tmp_path, model):
    """``timing: given`` builds the NLP it built before the option existed: the same structure
    key, variables, rows and point kernels (the capture task's CSVs, compared with ``cmp``
    before and after the change, are identical)."""
    from balance_opt.optimal.solve import build_balance_nlp

    given = load_task(_task(tmp_path, CAPTURE))
    free = load_task(_task(tmp_path, _free(), "free.yaml"))
    options = [
        t.planner_options().__class__(
            **{**t.planner_options().as_dict(), "intervals": 6, "collision_avoidance": False}
        )
        for t in (given, free)
    ]
    assert options[0].timing == "given" and options[1].timing == "free"
    nlps = [
        build_balance_nlp(model, t.mission, t.q_B0, o, robot=t.robot)
        for t, o in zip((given, free), options)
    ]
    g, f = (n.structure for n in nlps)
    assert g.key.timing == "" and f.key.timing.startswith("linear:")
    assert [b.name for b in g.variables.blocks] == ["X", "Xm", "U", "Um", "S"]
    assert {"M", "Mm", "P", "Pm", "A", "Am"} <= set(f.variables.by_name)
    assert not any("mission" in b.name for b in g.rows.blocks)
    assert g.rows.size < f.rows.size
    kernels = point_kernels(model)
    assert kernels.n_z == model.n_x("acceleration") + model.n_u
    assert point_kernels(model, timing=True).n_z == kernels.n_z + 3 * model.n_M
    # the given problem's mission data are the given mission's samples
    q, qd, qdd = given.mission.sample(nlps[0].point_times)
    np.testing.assert_array_equal(nlps[0].mission_samples[:9], np.hstack([q, qd, qdd]).T)


# ----------------------------------------------------------------------- a free-timing plan


@pytest.fixture(scope="module")
def free_plan(tmp_path_factory):
    """A free-timing plan of the capture task on a coarse grid, without collision avoidance,
    its outputs written."""
    from balance_opt.app.pipeline import run_task

    folder = tmp_path_factory.mktemp("free")
    options = "  intervals: 20\n  collision: {avoid: false}\n  weights: {jerk: 0}\n"
    text = _free(extra="optimal:\n" + options)
    text += "outputs: {plots: false, report: false, animation: false}\n"
    task = load_task(_task(folder, text))
    run = run_task(task, methods=("optimal",), output_dir=folder / "out", robustness=False)
    return task, run.results["optimal"], folder / "out"


@pytest.mark.slow
def test_free_timing_replayed_from_its_exported_joints(free_plan):
    """The attitude of the exported plan, replayed from its exported joints of both arms with
    numeric Pinocchio (DOP853, not the planner's RK4 re-simulation), is the plan's; the plan is
    far stiller than the given timing's (0.0211 rad without avoidance)."""
    from balance_opt.motion.replay import replay
    from balance_opt.report.outputs import read_npz_result

    task, result, out = free_plan
    saved = read_npz_result(out / "optimal.npz")
    mission = SampledTrajectory(saved.t, saved.q_M, saved.q_dot_M, saved.q_ddot_M)
    balance = SampledTrajectory(saved.t, saved.q_B, saved.q_dot_B, saved.q_ddot_B)
    again = replay(task.robot, mission, balance, t_eval=saved.t)
    assert np.abs(again.angle - saved.angle).max() < 2e-6
    assert again.max_drift < 0.012 and again.final_drift < 0.0025
    # the mission's joints in the CSV are the re-timed ones (not the quintic profile)
    csv = np.genfromtxt(out / "optimal.csv", delimiter=",", names=True)
    np.testing.assert_allclose(csv["mission_joint1"], saved.q_M[:, 0], atol=1e-12)
    given = task.mission.sample(saved.t)[0]
    assert np.abs(saved.q_M - given).max() > 0.05


@pytest.mark.slow
def test_free_timing_follows_the_path_within_the_mission_limits_between_samples(free_plan):
    task, result, out = free_plan
    metrics = json.loads((out / "metrics.json").read_text())["methods"]["optimal"]
    timing = metrics["timing"]
    assert timing["timing"] == "free" and timing["duration_s"] == pytest.approx(10.0)
    s = np.array(timing["progress_s"])
    # never backwards (to the solver's tolerance: the mission pauses while the balance arm works)
    assert np.diff(s).min() > -1e-6 and s[0] == pytest.approx(0, abs=1e-9)
    assert s[-1] == pytest.approx(10.0, abs=1e-3)
    assert np.abs(s - np.array(timing["progress_t"])).max() > 0.5  # really re-timed
    # the re-timed mission on a grid 50 times finer than the exported samples
    mission = _retimed(task, result)
    t = np.linspace(0.0, mission.duration, 50001)
    q, qd, qdd = mission.sample(t)
    lim = task.robot.limits.subset(task.robot.mission_indices)
    assert np.all(np.abs(qd) <= lim.velocity * (1 + 1e-6))
    assert np.all(np.abs(qdd) <= lim.acceleration * (1 + 1e-6))
    assert np.abs(qd).max() > 0.2  # the limits are approached, not vacuous
    # on the straight segment from start to goal, at rest at both ends
    q0, qf = task.mission.start, task.mission.end
    d = (qf - q0) / np.linalg.norm(qf - q0)
    off = (q - q0) - np.outer((q - q0) @ d, d)
    assert np.abs(off).max() < 1e-12
    np.testing.assert_allclose(q[-1], qf, atol=1e-9)
    assert np.abs(qd[[0, -1]]).max() < 1e-9 and np.abs(qdd[[0, -1]]).max() < 1e-9
    assert not result.violations


def _retimed(task, result):
    """The plan's re-timed mission, from its solution (the path chain's polynomials)."""
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.problem import BalanceProblem
    from balance_opt.optimal.timing import retimed

    model = PlannerModel(task.robot, compile=False)
    problem = BalanceProblem(model, task.mission, task.q_B0, task.planner_options(), task.robot)
    return retimed(problem, result.solver.solution)


@pytest.mark.slow
def test_shortest_mission_within_a_drift_bound(tmp_path):
    """``objective: time``: the duration found keeps the bound (re-simulated), the last
    shorter one probed did not, and both are within the search's resolution."""
    from balance_opt.app.pipeline import plan_optimal
    from balance_opt.optimal.solve import TIME_RESOLUTION

    extra = (
        "optimal:\n  objective: time\n  intervals: 12\n  collision: {avoid: false}\n"
        "  constraints: {path_attitude_bound: 0.03}\n"
    )
    task = load_task(_task(tmp_path, _free(extra=extra)))
    result = plan_optimal(task)
    found = result.solver.minimum_time
    T = found["duration_s"]
    assert result.t[-1] == pytest.approx(T) and T < 10.0
    assert result.max_drift <= 0.03 * (1 + 1e-3)
    lo, hi = found["bracket_s"]
    assert hi == T and hi - lo <= TIME_RESOLUTION
    probed = {p["duration_s"]: p["feasible"] for p in found["probes"]}
    assert probed[hi] and probed.get(lo) is False
    # the mission ends at its goal, at the plan's end
    np.testing.assert_allclose(result.q_M[-1], task.mission.end, atol=1e-8)


@pytest.mark.slow
def test_free_timing_of_a_curved_path(tmp_path):
    """A via-point mission re-timed: the mission joints stay on the given path (to its
    interpolation by quintic pieces), end at its last point, within their limits."""
    from balance_opt.app.pipeline import plan_optimal

    via = (
        "  type: via\n  timing: free\n  times: [0, 4, 10]\n"
        "  points: [[0.0, 0.3, -0.6], [0.7, 0.4, -1.2], [1.2, 0.9, -1.6]]\n"
    )
    text = re.sub(r"  type: ptp\n.*?\n\n", via + "\n", CAPTURE, flags=re.DOTALL)
    text += "optimal:\n  intervals: 12\n  collision: {avoid: false}\n"
    task = load_task(_task(tmp_path, text))
    result = plan_optimal(task)
    path = MissionPath(task.mission)
    sigma = result.solver.solution.P[0]
    assert np.all(np.diff(sigma) > -1e-7)
    # every sample of the re-timed mission is a point of the given path
    dense = task.mission.sample(np.linspace(0.0, 10.0, 20001))[0]
    gap = np.min(np.linalg.norm(result.q_M[:, None, :] - dense[None, :, :], axis=2), axis=1)
    assert gap.max() < 1e-3
    np.testing.assert_allclose(result.q_M[-1], task.mission.end, atol=1e-6)
    assert not result.violations, result.violations
    assert path.linear is False
    # the chain rule through the quintic pieces: the re-timed mission's rates and accelerations
    # against central differences of its positions every 0.1 ms, within their own error
    mission = _retimed(task, result)
    t = np.linspace(0.0, mission.duration, int(round(mission.duration / 1e-4)) + 1)
    q, qd, qdd = mission.sample(t)
    jerk = np.abs(np.diff(qdd, axis=0)).max(axis=0) / 1e-4 * 1.05
    rate, acceleration = _central_differences(t, q)
    assert np.all(np.abs(rate - qd[1:-1]) <= jerk * 1e-8 / 6 + 1e-12)
    assert np.all(np.abs(acceleration - qdd[1:-1]) <= jerk * 1e-4 / 3 + 1e-7)


# --------------------------------------------- the mission limits between the points (curved path)


class _Motion:
    """A mission of two joints on [0, 1] s: a revolute one whose rate peaks at 1.05 rad/s
    (t = 0.5 s), a prismatic one whose acceleration peaks at 10.3 m/s^2 (t = 0.25, 0.75 s)."""

    c = 10.3 / (4 * np.pi**2)

    def sample(self, t):
        t = np.asarray(t, dtype=float)
        w = 2 * np.pi
        q = np.stack([1.05 / np.pi * (1 - np.cos(np.pi * t)), self.c * np.sin(w * t)], axis=1)
        qd = np.stack([1.05 * np.sin(np.pi * t), self.c * w * np.cos(w * t)], axis=1)
        qdd = np.stack([1.05 * np.pi * np.cos(np.pi * t), -self.c * w**2 * np.sin(w * t)], axis=1)
        return q, qd, qdd


def _limited(velocity=1.0, acceleration=10.0, lower=-0.3, upper=0.3, factor=None):
    """A stand-in free-timing problem of 10 intervals of 0.1 s (with midpoints) following
    :class:`_Motion`, and its plan after 6 refinement rounds."""
    from types import SimpleNamespace

    from balance_opt.motion.retiming import MissionData

    limits = MissionData(
        np.array([-1.0, lower]),
        np.array([1.0, upper]),
        np.array([velocity, 2.0]),
        np.array([10.0, acceleration]),
    )
    robot = SimpleNamespace(
        mission=SimpleNamespace(joints=("j1", "j2")),
        joint_units=("rad", "m", "rad"),
        mission_indices=np.array([0, 1]),
    )
    problem = SimpleNamespace(
        mission_limits=limits,
        robot=robot,
        N=10,
        h=0.1,
        model=SimpleNamespace(n_M=2),
        point_times=np.zeros(21),
        transcription=SimpleNamespace(has_midpoints=True),
        bounds=SimpleNamespace(mission_factor=factor),
        path_rate_limits=(np.inf, np.inf),
        mission_motion=lambda solution: _Motion(),
    )
    t = np.linspace(0.0, 1.0, 11)
    q, qd, qdd = _Motion().sample(t)
    solver = SimpleNamespace(solution=object(), refinement={"rounds": 6})
    result = SimpleNamespace(t=t, q_M=q, q_dot_M=qd, q_ddot_M=qdd, solver=solver)
    return problem, result


def test_mission_limits_between_points_ranked_relative_to_the_limits_and_refused():
    """The worst breach is the largest relative to its limit (5 % of 1 rad/s, not 3 % of
    10 m/s^2, though 0.05 < 0.3), in the joint's unit; a plan still breaking it after the
    refinement fails, naming the joint, the amount, the time and the rounds."""
    from balance_opt.optimal.terms import PlannerSolverError
    from balance_opt.optimal.timing import MissionTiming

    kind = MissionTiming.__new__(MissionTiming)
    problem, result = _limited()
    worst = kind.check(problem, result)
    assert (worst.constraint, worst.unit) == ("velocity limit of j1", "rad/s")
    assert worst.time == pytest.approx(0.5) and worst.amount == pytest.approx(0.05)
    message = (
        "no free timing keeps the mission joints' limits: j1 exceeds its velocity limit 1 "
        "rad/s by 0.05 rad/s (+5.000%) at t = 0.500 s, after 6 refinement rounds"
    )
    with pytest.raises(PlannerSolverError, match=re.escape(message)):
        kind.accept(problem, result)
    # the prismatic joint's acceleration in m/s^2 once the revolute one is within its limit
    problem, result = _limited(velocity=1.1)
    worst = kind.check(problem, result)
    assert (worst.constraint, worst.unit) == ("acceleration limit of j2", "m/s^2")
    assert worst.time == pytest.approx(0.25) and worst.amount == pytest.approx(0.3)
    # a position beyond the range (the quintic pieces can overshoot): relative to its width
    problem, result = _limited(velocity=1.1, acceleration=10.4, lower=-0.25, upper=0.25)
    worst = kind.check(problem, result)
    assert (worst.constraint, worst.unit) == ("position limit of j2", "m")
    assert worst.amount == pytest.approx(_Motion.c - 0.25)
    message = (
        "no free timing keeps the mission joints' limits: j2 leaves its range [-0.25, 0.25] m "
        "by 0.0109 m (the path's, whatever its timing) at t = 0.250 s, after 6 refinement rounds"
    )
    with pytest.raises(PlannerSolverError, match=re.escape(message)):
        kind.accept(problem, result)
    # within the limits: nothing to report, nothing to refuse
    problem, result = _limited(velocity=1.1, acceleration=10.4)
    assert kind.check(problem, result) is None
    kind.accept(problem, result)


def test_mission_limits_tightened_on_the_intervals_that_break_them():
    """The refinement lowers the mission joints' rate and acceleration bounds at the points of
    the intervals where the continuous motion breaks a limit (by (1 - 1e-3) / (1 + excess)),
    and the next problem's variable bounds are the lowered ones."""
    from types import SimpleNamespace

    from balance_opt.optimal.timing import MissionTiming

    kind = MissionTiming.__new__(MissionTiming)
    problem, result = _limited()
    changes, words = kind.tighten(problem, result)
    factor = changes["mission_factor"]
    assert words == ["mission joint bounds on 4 intervals (worst +5.000%)"]
    assert factor.shape == (4, 21)
    # j1's rate breaks on intervals 4 and 5 (t in 0.40-0.60 s), j2's acceleration on 2 and 7
    lowered = {0: [4, 5, 6, 15, 16], 3: [2, 3, 13, 7, 8, 18]}
    expected = np.ones_like(factor)
    expected[0, lowered[0]] = (1 - 1e-3) / 1.05
    expected[3, lowered[3]] = (1 - 1e-3) / 1.03
    np.testing.assert_allclose(factor, expected, rtol=2e-4)
    assert np.all(factor[expected == 1.0] == 1.0)
    # the lowered bounds on the mission data M (nodes) and Mm (midpoints)
    problem, _ = _limited(factor=factor)
    N = problem.N

    def blank(columns):
        return np.zeros((6, columns))

    lower = SimpleNamespace(
        P=np.zeros((2, N + 1)),
        Pm=np.zeros((2, N)),
        A=np.zeros((1, N + 1)),
        Am=np.zeros((1, N)),
        M=blank(N + 1),
        Mm=blank(N),
    )
    upper = SimpleNamespace(**{k: v.copy() for k, v in vars(lower).items()})
    kind.bound_variables(problem, lower, upper)
    np.testing.assert_allclose(upper.M[2], factor[0, : N + 1])  # j1's rate
    np.testing.assert_allclose(lower.Mm[5], -10.0 * factor[3, N + 1 :])  # j2's acceleration
    np.testing.assert_array_equal(upper.M[:2], [[1.0] * (N + 1), [0.3] * (N + 1)])
    # a motion within the limits tightens nothing
    problem, result = _limited(velocity=1.1, acceleration=10.4)
    assert kind.tighten(problem, result) == ({}, [])


# ----------------------------------- the exported mission against its own finite differences


def _central_differences(t, q):
    """Rates and accelerations of positions ``q`` (T, n) on the uniform grid ``t`` by central
    differences, at the interior samples: owes nothing to the path's chain rule."""
    dt = t[1] - t[0]
    np.testing.assert_allclose(np.diff(t), dt, rtol=1e-9)
    return (q[2:] - q[:-2]) / (2 * dt), (q[2:] - 2 * q[1:-1] + q[:-2]) / dt**2


@pytest.mark.slow
def test_exported_mission_rates_are_the_derivatives_of_its_positions(free_plan):
    """The exported mission rates and accelerations (NPZ and CSV) against central differences
    of the exported positions, and of the re-timed mission sampled every 0.1 ms, within the
    differences' own error; the mission joints' limits checked on those differences (not on
    the planner's own rates)."""
    from balance_opt.report.outputs import read_npz_result

    task, result, out = free_plan
    lim = task.robot.limits.subset(task.robot.mission_indices)
    # the re-timed mission sampled every 0.1 ms: its third derivative's bound ``jerk`` (it
    # steps at the nodes), which bounds the differences' error: dt^2 / 6 jerk for the rates,
    # dt / 3 jerk for the accelerations
    mission = _retimed(task, result)
    fine = np.linspace(0.0, mission.duration, int(round(mission.duration / 1e-4)) + 1)
    q, qd, qdd = mission.sample(fine)
    dt = fine[1] - fine[0]
    jerk = np.abs(np.diff(qdd, axis=0)).max(axis=0) / dt * 1.05
    rate, acceleration = _central_differences(fine, q)
    assert np.all(np.abs(rate - qd[1:-1]) <= jerk * dt**2 / 6 + 1e-12)
    assert np.all(np.abs(acceleration - qdd[1:-1]) <= jerk * dt / 3 + 1e-7)
    assert np.all(np.abs(rate) <= lim.velocity * (1 + 1e-6))
    assert np.all(np.abs(acceleration) <= lim.acceleration + jerk * dt / 3 + 1e-7)
    # the exported positions (NPZ and CSV) at 100 Hz against the exported rates
    saved = read_npz_result(out / "optimal.npz")
    csv = np.genfromtxt(out / "optimal.csv", delimiter=",", names=True)
    q = np.stack([csv[name] for name in task.robot.mission.joints], axis=1)
    np.testing.assert_allclose(q, saved.q_M, atol=1e-12)
    rate, acceleration = _central_differences(saved.t, q)
    dt = saved.t[1] - saved.t[0]
    assert np.all(np.abs(rate - saved.q_dot_M[1:-1]) <= jerk * dt**2 / 6 + 1e-9)
    assert np.all(np.abs(acceleration - saved.q_ddot_M[1:-1]) <= jerk * dt / 3 + 1e-7)
    assert np.all(np.abs(rate) <= lim.velocity * (1 + 1e-6) + jerk * dt**2 / 6)
    assert np.all(np.abs(acceleration) <= lim.acceleration + jerk * dt / 3)
    # the given (quintic) timing's rates fail the same comparison: it discriminates
    given = task.mission.sample(saved.t)[1]
    assert np.abs(rate - given[1:-1]).max() > 100 * (jerk * dt**2 / 6).max()
