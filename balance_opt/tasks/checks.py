"""The checks of a task file that need its robot, its mission or another value: per-joint list
lengths, the mission within its limits, the time grids, the problem's size, the capture, a free
mission timing. Each raises a :class:`TaskFileError` located at the key to change."""

from __future__ import annotations

import logging

import numpy as np

from balance_opt.config.typed_config import suggest, walk_settings
from balance_opt.config.yaml_lines import TaskFileError, YamlDocument, format_path
from balance_opt.errors import InfeasibleLimitsError, InputError, TrajectoryError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import LIMIT_TOLERANCE, find_limit_violations
from balance_opt.motion.trajectories import JointTrajectory
from balance_opt.tasks.task_spec import (
    CartesianMission,
    CsvMission,
    PtpMission,
    TaskSpec,
    ViaMission,
)

log = logging.getLogger(__name__)


#: Samples per second used to check a mission trajectory against its limits [1/s].
LIMIT_CHECK_RATE = 200.0


#: Fewest samples used to check a mission trajectory against its limits.
LIMIT_CHECK_MIN_SAMPLES = 501


#: Most samples in one time grid of a plan (its outputs, its re-simulation, its simulation's
#: outputs): a sample of the paper robot's plan is about 60 numbers in memory and 1 kB of CSV,
#: so 1e6 samples are about 0.5 GB of arrays and 1 GB of files, for each method.
MAX_SAMPLES = 1_000_000


#: Fewest fixed integration steps (simulation ``rk4``, analytic ``rk4``) over the mission: a step
#: longer than 1/100 of the motion does not resolve it.
MIN_STEPS_PER_MISSION = 100


#: Ipopt iterations of a typical optimal plan, all its solves, by objective (the peak objective
#: has three stages), and the estimated planning time above which loading warns [s].
#: ``time``: a bisection of about six peak plans.
TYPICAL_ITERATIONS = {"integral": 50, "peak": 300, "time": 1800}


LONG_PLAN_SECONDS = 600.0


class TaskLimitsError(TaskFileError, InfeasibleLimitsError):
    """Limits that no plan can meet, located in the task file."""


class TaskTrajectoryError(TaskFileError, TrajectoryError):
    """A mission trajectory that cannot be built, located in the task file."""


def check_timing(spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot) -> None:
    """A free mission timing: no capture, every mission joint with a velocity and an
    acceleration limit; ``optimal.objective: time`` only with it, a path attitude bound and
    no initial momentum."""
    planner = spec.optimal.planner
    if planner.objective == "time" and (
        spec.mission.timing != "free" or planner.path_attitude_bound is None
    ):
        raise doc.error(
            ("optimal", "objective"),
            "objective time (the shortest mission within a drift bound) needs mission.timing: "
            "free and optimal.constraints.path_attitude_bound",
        )
    if planner.objective == "time" and any(v != 0.0 for v in spec.initial.momentum):
        raise doc.error(
            ("initial", "momentum"),
            "optimal.objective: time needs a zero initial momentum: with momentum the base "
            "drifts while the arms wait, so a longer mission is not always a stiller one",
        )
    if spec.mission.timing != "free":
        return
    if spec.capture is not None:
        raise doc.error(
            ("mission", "timing"),
            "a free timing is not available with a capture (the capture time is fixed); "
            "use timing: given",
        )
    lim = robot.limits.subset(robot.mission_indices)
    for kind in ("velocity", "acceleration"):
        for joint, value in zip(robot.mission.joints, getattr(lim, kind)):
            if not np.isfinite(value):
                raise doc.error(
                    ("mission", "timing"),
                    f"a free timing needs {'an' if kind == 'acceleration' else 'a'} {kind} limit "
                    f"of every mission joint; {joint} has none (set limits.{joint}.{kind})",
                )


# ------------------------------------------------------------ checks that need the robot, the mission
def check_lengths(spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot) -> None:
    """Every list declared with one value per joint of a kind (``per=``) has that many values;
    a list of such lists (via points) is checked item by item."""
    joints = {  # what a ``per=`` declaration counts: balance arms stacked, all arm joints
        "mission joint": list(robot.mission.joints),
        "balance joint": [robot.joint_names[i] for i in robot.balance_indices],
        "arm joint": list(robot.joint_names),
    }
    for path, value, meta in walk_settings(spec):
        kind = meta.get("per")
        if kind is None or not isinstance(value, tuple):
            continue  # not per joint, not given, or one value for every joint (kp: 5)
        nested = bool(value) and isinstance(value[0], tuple)
        items = [((*path, i), v) for i, v in enumerate(value)] if nested else [(path, value)]
        names = joints[kind]
        for where, values in items:
            if len(values) != len(names):
                raise doc.error(
                    where,
                    f"expected {len(names)} values (one per {kind}: {', '.join(names)}), "
                    f"got {len(values)}",
                )


def _limit_source(spec: TaskSpec, joint: str, key: str) -> str:
    over = spec.limits.get(joint)
    return (
        f"limits.{joint}.{key}" if over is not None and getattr(over, key) is not None else "URDF"
    )


def _set_positions(m, col: int) -> list[tuple[tuple, float]]:
    """``(key, value)`` of every position the task sets for mission joint ``col``."""
    if isinstance(m, PtpMission):
        return [(("mission", "start", col), m.start[col]), (("mission", "goal", col), m.goal[col])]
    if isinstance(m, ViaMission):
        return [(("mission", "points", k, col), p[col]) for k, p in enumerate(m.points)]
    return [(("mission", "start", col), m.start[col])]  # cartesian: the goal is solved for


def _mission_key(spec: TaskSpec, kind: str, col: int, lim: tuple[float, float]) -> tuple:
    """Where the task sets what makes mission joint ``col`` leave its ``kind`` limit: a start,
    goal or via point outside the position limits, else the duration (or the times, the file)."""
    m = spec.mission
    if isinstance(m, CsvMission):
        return ("mission", "file")
    if kind == "position":
        for key, value in _set_positions(m, col):
            if not lim[0] - LIMIT_TOLERANCE <= value <= lim[1] + LIMIT_TOLERANCE:
                return key
        if isinstance(m, CartesianMission):
            return ("mission", "position")
    if isinstance(m, ViaMission):
        return ("mission", "points" if kind == "position" else "times")
    return ("mission", "duration")


def check_limits(
    spec: TaskSpec,
    doc: YamlDocument,
    robot: FloatingRobot,
    mission: JointTrajectory,
    q_B0: np.ndarray,
) -> None:
    """Limits no plan can meet (a balance start or a prescribed final configuration outside the
    position limits, a mission that leaves its own limits; TaskLimitsError naming the limit's
    source) and a horizon shorter than the mission."""
    lim = robot.limits
    for k, i in enumerate(robot.balance_indices):
        j, q = robot.joint_names[i], q_B0[k]
        if not lim.lower[i] - LIMIT_TOLERANCE <= q <= lim.upper[i] + LIMIT_TOLERANCE:
            key = "lower" if q < lim.lower[i] else "upper"
            raise doc.error(
                ("initial", "balance", k) if spec.initial.balance else ("initial",),
                f"balance joint '{j}' starts at {q:g} rad, outside its position limits "
                f"[{lim.lower[i]:g}, {lim.upper[i]:g}] rad ({key} limit from "
                f"{_limit_source(spec, j, key)}); no plan can meet them",
                TaskLimitsError,
            )
    duration = float(mission.duration)
    t = np.linspace(
        0.0,
        duration,
        min(MAX_SAMPLES, max(LIMIT_CHECK_MIN_SAMPLES, int(duration * LIMIT_CHECK_RATE))),
    )
    q, qd, qdd = mission.sample(t)
    idx = robot.mission_indices
    violations = find_limit_violations(t, robot.mission.joints, q, qd, qdd, lim.subset(idx))
    if violations:
        v = violations[0]
        col = robot.mission.joints.index(v.joint)
        key = {"position": "lower", "velocity": "velocity", "acceleration": "acceleration"}[v.kind]
        if v.kind == "position":
            key = "upper" if q[:, col].max() > lim.upper[idx[col]] else "lower"
        bounds = (lim.lower[idx[col]], lim.upper[idx[col]])
        raise doc.error(
            _mission_key(spec, v.kind, col, bounds),
            f"the mission trajectory leaves the limits of the mission arm, which "
            f"follows it as given: {v} (limit from "
            f"{_limit_source(spec, v.joint, key)}); no plan can meet them",
            TaskLimitsError,
        )
    planner = spec.optimal.planner
    if planner.horizon is not None and planner.horizon < duration:
        raise doc.error(
            ("optimal", "horizon"),
            f"the horizon ({planner.horizon:g} s) is shorter than the mission ({duration:g} s)",
        )
    final = planner.final_configuration
    if final is not None and planner.position_limits:
        lim = robot.limits.subset(robot.balance_indices)
        for k, value in enumerate(final):
            if not lim.lower[k] - LIMIT_TOLERANCE <= value <= lim.upper[k] + LIMIT_TOLERANCE:
                j = robot.joint_names[robot.balance_indices[k]]
                raise doc.error(
                    ("optimal", "constraints", "final_configuration", k),
                    f"balance joint '{j}' must end at {value:g} rad, outside its position limits "
                    f"[{lim.lower[k]:g}, {lim.upper[k]:g}] rad; no plan can meet them",
                    TaskLimitsError,
                )


def _given(doc: YamlDocument, path: tuple) -> bool:
    """Whether the file sets the key at ``path``."""
    node = doc.data
    for part in path:
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def duration_key(spec: TaskSpec) -> tuple:
    """The key of the task that sets the mission's duration."""
    m = spec.mission
    if isinstance(m, ViaMission):
        return ("mission", "times", len(m.times) - 1)
    if isinstance(m, CsvMission):
        return ("mission", "file")
    return ("mission", "duration")


def check_time_grids(spec: TaskSpec, doc: YamlDocument, duration: float) -> None:
    """No time grid of a plan longer than :data:`MAX_SAMPLES` samples (located at the step when
    the file sets it, else at the duration), and no fixed integration step longer than
    1/:data:`MIN_STEPS_PER_MISSION` of the mission."""
    planner, sim, integration = spec.optimal.planner, spec.simulation, spec.analytic.integration
    plan_span = max(duration, planner.horizon or 0.0)
    plan_key = ("optimal", "horizon") if plan_span > duration else duration_key(spec)
    sim_out = ("simulation", "output_dt") if sim.output_dt is not None else ("simulation", "dt")
    grids = [  # what, step key, step [s]; over the mission (the first), else the plan
        ("the analytic plan's outputs", ("analytic", "output_step"), integration.output_step),
        (
            "the re-simulation of the optimal plan",
            ("optimal", "resample_step"),
            planner.resample_step,
        ),
        ("the simulation's outputs", sim_out, sim.output_dt or sim.dt),
    ]
    for k, (what, step_key, step) in enumerate(grids):
        span, span_key = (duration, duration_key(spec)) if k == 0 else (plan_span, plan_key)
        samples = span / step
        if samples <= MAX_SAMPLES:
            continue
        count = f"{samples:.3g}" if np.isfinite(samples) else "over 1e308"
        if _given(doc, step_key):
            raise doc.error(
                step_key,
                f"{step:g} s over {span:g} s ({what}) is {count} samples; a plan may "
                f"hold at most {MAX_SAMPLES:g}: over {span:g} s the step must be at least "
                f"{span / MAX_SAMPLES:.3g} s",
            )
        raise doc.error(
            span_key,
            f"{span:g} s sampled every {step:g} s ({format_path(step_key)}: {what}) is {count} "
            f"samples; a plan may hold at most {MAX_SAMPLES:g}: at that step the longest is "
            f"{step * MAX_SAMPLES:.3g} s",
        )
    steps = []  # the fixed-step integrations: integrator, step key, step [s]
    if sim.integrator == "rk4":
        steps.append(("the simulation's rk4", ("simulation", "dt"), sim.dt))
    if integration.method == "rk4":
        key = "step" if integration.step is not None else "output_step"
        steps.append(("the analytic rk4", ("analytic", key), getattr(integration, key)))
    for what, key, step in steps:
        longest = duration / MIN_STEPS_PER_MISSION
        if step > longest:
            raise doc.error(
                key,
                f"{what} step of {step:g} s does not resolve the {duration:g} s mission: it "
                f"must be at most 1/{MIN_STEPS_PER_MISSION} of it, {longest:.3g} s",
            )


def _duration_words(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def check_problem_size(spec: TaskSpec, doc: YamlDocument, robot: FloatingRobot) -> None:
    """The optimal planner's problem fits in the memory budget, by an estimate made before
    anything is built (else an error at ``optimal.intervals`` with the largest ``N`` that fits)."""
    from balance_opt.optimal.budget import largest_intervals, memory_budget, problem_size

    planner = spec.optimal.planner
    limits = robot.limits.subset(robot.balance_indices)
    size = problem_size(planner, limits)
    budget = memory_budget()
    iterations = TYPICAL_ITERATIONS[planner.objective] * planner.starts
    expected = size.build_seconds + iterations * size.iteration_seconds
    if size.memory_bytes <= budget:
        if expected > LONG_PLAN_SECONDS:
            log.warning(
                "%s: the optimal plan with %d intervals may take about %s (build %s, then "
                "%s per Ipopt iteration)",
                doc.source,
                planner.intervals,
                _duration_words(expected),
                _duration_words(size.build_seconds),
                _duration_words(size.iteration_seconds),
            )
        return
    matrices = (
        "Ipopt's KKT matrix"
        if size.problems == 1
        else f"the KKT matrices of the {size.problems} NLPs the plan builds"
    )
    raise doc.error(
        ("optimal", "intervals"),
        f"{planner.intervals} intervals would need about {size.memory_bytes / 2**30:.1f} GiB of "
        f"memory ({len(limits.lower)} balance joints: {size.variables:.3g} variables, "
        f"{size.nonzeros:.3g} non-zeros in {matrices}), about "
        f"{_duration_words(size.build_seconds)} to build and "
        f"{_duration_words(size.iteration_seconds)} per Ipopt iteration; a plan "
        f"may use {budget / 2**30:.1f} GiB (half of this machine's memory): at most "
        f"{largest_intervals(planner, limits, budget)} intervals fit",
    )


def check_capture(spec: TaskSpec, doc: YamlDocument, duration: float):
    """The capture section as a :class:`~balance_opt.model.capture.Target` (``None`` without
    one): the capture time strictly inside the mission, a physical inertia."""
    from balance_opt.model.capture import Target

    c = spec.capture
    if c is None:
        return None
    if not c.time < duration:
        raise doc.error(
            ("capture", "time"),
            f"must be before the end of the mission ({duration:g} s), got {c.time:g} s",
        )
    try:
        return Target(
            c.time, c.mass, np.array(c.inertia), c.com, c.linear_velocity, c.angular_velocity
        )
    except InputError as exc:
        raise doc.error(("capture", "inertia"), str(exc)) from None


def robot_key(robot_spec) -> str:
    """The key that names the task's URDF: ``urdf``, ``shipped`` or ``example``."""
    return next(k for k in ("urdf", "shipped", "example") if getattr(robot_spec, k) is not None)


def check_keep_out(spec: TaskSpec, doc: YamlDocument, robot, mission, q_B0) -> None:
    """The keep-out zones (names once, frames of the robot, arms of the task, sizes) given to
    the robot, and none that the mission arm's trajectory enters: the planner cannot move it.
    """
    from balance_opt.geometry.keep_out import zone_problems

    arms = [a.name for a in robot.arms]
    frames = [f.name for f in robot.model.frames if f.name != "universe"]
    for i, zone in enumerate(spec.keep_out):
        earlier = [z.name for z in spec.keep_out[:i]]
        if zone.name in earlier:
            raise doc.error(
                ("keep_out", i, "name"),
                f"zone {zone.name} is named twice (also keep_out[{earlier.index(zone.name)}])",
            )
        if zone.frame not in frames:
            raise doc.error(
                ("keep_out", i, "frame"),
                f"{robot.name} has no frame {zone.frame}" + suggest(zone.frame, frames),
            )
        for k, arm in enumerate(zone.arms or ()):
            if arm not in arms:
                raise doc.error(
                    ("keep_out", i, "arms", k), f"no arm {arm}; the arms are {', '.join(arms)}"
                )
        for path, problem in zone_problems(zone):
            raise doc.error(("keep_out", i, *path), problem)
    if not spec.keep_out:
        return
    from balance_opt.geometry.clearance import clearance
    from balance_opt.geometry.robot_geometry import RobotGeometry
    from balance_opt.model.meshes import MeshNotFoundError

    robot.keep_out = spec.keep_out
    try:
        geometry = RobotGeometry(robot, disabled={})  # the zones' pairs alone are wanted
    except MeshNotFoundError as exc:  # the zones are checked against the robot's bodies
        key = "packages" if spec.robot.packages else robot_key(spec.robot)
        raise doc.error(("robot", key), f"{exc} (the keep-out zones need the robot's bodies)")
    tree = robot.model.subtrees
    balance = set().union(
        *(tree[robot.model.getJointId(robot.joint_names[i])] for i in robot.balance_indices)
    )
    pairs = [  # the zones' pairs the balance arm does not move
        p.index
        for p in geometry.pairs
        if {p.first, p.second} & geometry.zones.keys()
        and not {geometry.body(p.first), geometry.body(p.second)} & balance
    ]
    t = np.linspace(0.0, float(mission.duration), 401)
    q = np.hstack([mission.sample(t)[0], np.tile(q_B0, (t.size, 1))])
    hit = clearance(geometry, t, q, pairs=pairs, watch=0.0).first_penetration
    if hit is not None:
        pair = next(p for p in geometry.pairs if p.name == hit.pair)
        zone, link = (
            (pair.second, pair.first)
            if pair.second in geometry.zones
            else (pair.first, pair.second)
        )
        i = spec.keep_out.index(geometry.zones[zone])
        raise doc.error(
            ("keep_out", i),
            f"zone {spec.keep_out[i].name}: the mission arm's trajectory enters it: "
            f"{geometry.link(link)} from "
            f"t = {hit.time:.3f} s, {hit.depth:.4f} m deep at most; the planner cannot move the "
            "mission arm: move the zone or the mission, or bind the zone to the balance arms "
            "only (arms: [balance])",
        )
