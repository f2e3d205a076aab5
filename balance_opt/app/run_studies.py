"""What a run studies beside its plans: the robot's geometry (before and after a capture), the
clearance of every motion, the drift under model error, the closed loop."""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np

from balance_opt.app.models import ModelCache
from balance_opt.app.task_run import METHODS, TaskRun, timed
from balance_opt.errors import InputError

log = logging.getLogger(__name__)


def run_geometry(run: TaskRun, models: ModelCache | None = None):
    """The run's robot geometry (:class:`~balance_opt.geometry.robot_geometry.RobotGeometry`),
    built once and kept on ``run.geometry``: the optimal planner's when ``models`` holds its
    planner model (the pairs computed without an SRDF cost a thousand samples); ``False`` for
    a robot without geometry (a log line says so) or whose geometry does not load (a missing
    mesh: a warning)."""
    from balance_opt.geometry.robot_geometry import NoGeometryError, RobotGeometry

    if run.geometry is None:
        task, planner = run.task, run.task.spec.optimal.planner
        collisions = (
            None if models is None else models.collisions(task.robot, task.spec.robot.backend)
        )
        try:
            if collisions is not None:
                run.geometry = collisions.geometry(
                    planner.collision_ignore, planner.collision_srdf, task.robot
                )
            else:
                run.geometry = RobotGeometry(
                    task.robot, srdf=planner.collision_srdf, ignore=planner.collision_ignore
                )
        except NoGeometryError as exc:
            log.info("%s: no clearance check: %s", run.task.name, exc)
            run.geometry = False
        except InputError as exc:  # a mesh file missing: the plans still count
            log.warning("%s: no clearance check: %s", run.task.name, exc)
            run.geometry = False
        else:  # nobody reviews pairs computed without an SRDF: say which, once per run
            computed = run.geometry.computed
            if computed:
                log.info(
                    "%s: no SRDF: link pairs left out as computed (robot.srdf to choose): %s",
                    run.task.name,
                    ", ".join(f"{n} ({r})" for n, r in computed),
                )
    return run.geometry


def capture_geometry(run: TaskRun):
    """The geometry of the robot after the capture (the target a body of the mission end
    effector) and its pairs with the target, ``(geometry, pair indices)``, built once and kept
    on ``run.geometry_after``; ``None`` without a capture or without geometry."""
    from balance_opt.geometry.robot_geometry import RobotGeometry
    from balance_opt.model.capture import TARGET_LINK

    if run.task.target is None or run_geometry(run) is False:
        return None
    if run.geometry_after is None:
        try:
            geometry = RobotGeometry(
                run.task.robot_after_capture,
                disabled=run.geometry.disabled,  # the same pairs as before the capture
                ignore=run.task.spec.optimal.planner.collision_ignore,
            )
        except InputError as exc:  # a mesh not found from the URDF text: the rest still counts
            log.warning("%s: the target is not checked after the capture: %s", run.task.name, exc)
            run.geometry_after = False
            return None
        pairs = [p.index for p in geometry.pairs if TARGET_LINK in p.links]
        run.geometry_after = (geometry, pairs)
    return run.geometry_after or None


#: Samples of a motion at most in the clearance figure's curves.
CLEARANCE_CURVE_SAMPLES = 300


def clearance_into(run: TaskRun, motions: Mapping[str, tuple], into: dict) -> None:
    """The clearance of each motion ``(t, arm vectors)`` (a plan's, a simulation's) on the
    continuous motion (:func:`~balance_opt.geometry.clearance.clearance`) and its smallest
    distance over time for the figure, into ``into`` as ``{name: (report, t, distance)}``. From a
    capture on, the target is a body too (its pairs checked on the motion after it)."""
    from balance_opt.geometry.clearance import clearance

    if run_geometry(run) is False:
        return
    after = capture_geometry(run)
    for name, (t, q) in motions.items():
        report = clearance(run.geometry, t, q)
        step = max(1, len(t) // CLEARANCE_CURVE_SAMPLES)
        smallest = run.geometry.smallest_along(q[::step])
        if after is not None:
            geometry, pairs = after
            t_after, q_after = _from_capture(t, q, run.task.target.time)
            report = report.joined(clearance(geometry, t_after, q_after, pairs=pairs))
            late = t[::step] >= t_after[0]
            held = geometry.smallest_along(q[::step][late], pairs)
            smallest[late] = np.minimum(smallest[late], held)
        into[name] = (report, t[::step], smallest)


def _from_capture(t: np.ndarray, q: np.ndarray, t_c: float) -> tuple[np.ndarray, np.ndarray]:
    """The motion ``(t, q)`` from the capture time ``t_c`` on, starting at ``t_c`` (a sample
    within rounding of it, else one interpolated there: joint positions are continuous)."""
    k = int(np.searchsorted(t, t_c - 1e-9 * max(1.0, abs(t_c))))
    if abs(t[k] - t_c) <= 1e-9 * max(1.0, abs(t_c)):
        return t[k:], q[k:]
    start = np.array([np.interp(t_c, t, column) for column in q.T])
    return np.r_[t_c, t[k:]], np.vstack([start, q[k:]])


def model_error_into(run: TaskRun) -> None:
    """The drift of every plan replayed on perturbed models (not across a capture, where the
    robot changes mid-motion: the study is left out with a note)."""
    from balance_opt.motion.robustness import drift_under_model_error

    task = run.task
    if task.target is not None:
        log.info("%s: drift under model error not computed across a capture", task.name)
        return
    options = task.spec.robustness
    what = f"drift under {100 * options.perturbation:.0f} % model error ({options.samples} models)"
    with timed(f"{task.name}: {what}"):
        run.robustness = drift_under_model_error(task.robot, run.results, options, task.h0)


def closed_loop_into(run: TaskRun, executor) -> None:
    """Every plan that did not fail flown closed loop on perturbed models (not across a
    capture)."""
    from balance_opt.app.closed_loop import closed_loop_study

    task = run.task
    if task.target is not None:
        log.info("%s: no closed loop across a capture", task.name)
        return
    plans = {m: r for m, r in run.results.items() if m in METHODS and m not in run.failures}
    planner = task.spec.optimal.planner
    geometry = None
    if run_geometry(run) is not False:
        geometry = (planner.collision_srdf, planner.collision_ignore)
    opts = task.spec.closed_loop
    with timed(f"{task.name}: closed loop ({opts.samples} models, period {opts.period:g} s)"):
        run.closed_loop = closed_loop_study(task, plans, executor, geometry)
