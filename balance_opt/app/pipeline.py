"""Running a task: the mission arm alone (the reference), the analytic and/or optimal balance
plans, optionally each checked by forward dynamics, then every output written.

A solver failure does not stop the run: the failing method's best iterate is kept, written and
marked, and :attr:`TaskRun.failures` names it (the CLI then exits with code 1)."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from balance_opt.app.models import ModelCache
from balance_opt.app.run_files import REFERENCE, TaskRun, _timed, run_geometry, write_run
from balance_opt.errors import InputError, SolverError
from balance_opt.interrupts import handling_signals
from balance_opt.report.output_dir import OutputFolder
from balance_opt.result import BalanceResult
from balance_opt.tasks.task import Task, check_methods

if TYPE_CHECKING:
    from balance_opt.dynamics.simulation import SimulationResult

log = logging.getLogger(__name__)

METHODS = ("analytic", "optimal")


def checked_task(task: Task | str | Path, what: str = "task") -> Task:
    """``task``, or the task loaded from the file it names (a path or a string).

    Raises:
        TypeError: neither a :class:`~balance_opt.tasks.task.Task` nor a path.
    """
    if isinstance(task, Task):
        return task
    if isinstance(task, (str, Path)):
        from balance_opt.tasks.task import load_task

        return load_task(task)
    raise TypeError(
        f"{what}: expected a Task (balance_opt.load_task) or a task file path, "
        f"got {type(task).__name__}"
    )


def _checked_plan(plan) -> BalanceResult:
    if not isinstance(plan, BalanceResult):
        raise TypeError(
            f"plan: expected a BalanceResult (balance_opt.plan_analytic, plan_optimal, ...), "
            f"got {type(plan).__name__}"
        )
    return plan


def plan_mission_only(task: Task | str | Path) -> BalanceResult:
    """Phase I (paper Fig. 2): the base attitude with the mission arm moving and the balance arm
    held at its start, integrated from momentum conservation: the reference of every plan
    (``method="mission-only"``).
    """
    from balance_opt.analytic.phases import phase_one

    task = checked_task(task)
    if task.target is not None:
        return _captured(task, REFERENCE)

    a = task.spec.analytic
    return phase_one(task.robot, task.mission, task.q_B0, h0=task.h0, integration=a.integration)


def plan_analytic(task: Task | str | Path) -> BalanceResult:
    """Phase II: the analytic balance law (Eq. 31, 32) rolled out with the task's options.

    Raises:
        SolverError: the rollout failed; ``result`` holds the motion up to the failure.
    """
    from balance_opt.analytic.rollout import rollout

    task = checked_task(task)
    if task.target is not None:
        return _captured(task, "analytic")

    a = task.spec.analytic
    return rollout(task.robot, task.mission, task.q_B0, a.law, integration=a.integration)


def plan_optimal(
    task: Task,
    solver_options: Mapping[str, Any] | None = None,
    warm_start: BalanceResult | None = None,
    models: ModelCache | None = None,
    executor: Any | None = None,
) -> BalanceResult:
    """The optimal planner with the task's options.

    Args:
        solver_options: Ipopt options overriding ``optimal.ipopt``.
        warm_start: an analytic result to start from (``optimal.initial_guess: analytic``),
            instead of rolling out the law again (not for a task with a capture).
        models: the planner models to reuse; without one, the model is built for this call only.
        executor: what runs the starts of ``optimal.starts > 1`` (anything with ``map``);
            ``None``: this process.

    Raises:
        InputError: the task asks for something the optimal planner cannot do.
        SolverError: Ipopt did not solve the NLP; ``result`` is the last iterate, re-simulated.
    """
    from balance_opt.optimal.solve import build_balance_nlp

    task = checked_task(task)
    if warm_start is not None:
        _checked_plan(warm_start)
    if task.target is not None:
        return _captured(task, "optimal", solver_options, models, executor)
    check_methods(task, ("optimal",))
    spec = task.spec.optimal
    options = task.planner_options(solver_options)
    model = (models if models is not None else ModelCache()).planner_model(
        task.robot, task.spec.robot.backend
    )
    nlp = build_balance_nlp(model, task.mission, task.q_B0, options, robot=task.robot, h0=task.h0)
    guess = (
        warm_start
        if (warm_start is not None and spec.initial_guess == "analytic")
        else spec.initial_guess
    )
    return nlp.solve(guess, executor)


def _captured(
    task: Task, method: str, solver_options=None, models=None, executor=None
) -> BalanceResult:
    """The plan of a task with a capture: two phases joined at the capture (issue 16)."""
    from balance_opt.app.capture import plan_captured

    return plan_captured(task, method, solver_options, models, executor)


def plan(
    task: Task,
    method: str,
    solver_options: Mapping[str, Any] | None = None,
    warm_start: BalanceResult | None = None,
    models: ModelCache | None = None,
    executor: Any | None = None,
) -> BalanceResult:
    """The plan of ``method`` (``"mission-only"``, ``"analytic"`` or ``"optimal"``): the one
    dispatch of ``balance-opt plan`` and of the sweep cases. The other arguments are those of
    :func:`plan_optimal`, for the optimal method.

    Raises:
        InputError: an unknown method.
        SolverError: the method failed; its ``result`` holds what was computed.
    """
    if method == REFERENCE:
        return plan_mission_only(task)
    if method == "analytic":
        return plan_analytic(task)
    if method == "optimal":
        return plan_optimal(task, solver_options, warm_start, models, executor)
    raise InputError(f"unknown method '{method}'; expected {' or '.join(METHODS)}")


def simulate(task: Task, plan: BalanceResult) -> SimulationResult:
    """Forward-dynamics simulation of a plan of ``task`` with its simulation options: joint
    controllers track the plan, the base floats. Returns the simulated motion, its joint torques
    and the arms' wrenches on the base.
    """
    from balance_opt.dynamics.simulation import simulate_plan

    task, plan = checked_task(task), _checked_plan(plan)
    if task.target is not None:  # through the capture's impulse (issue 16)
        from balance_opt.app.capture import robot_after
        from balance_opt.dynamics.capture_impulse import simulate_with_capture

        return simulate_with_capture(
            task.robot, robot_after(task), task.target, plan, task.spec.simulation
        )
    return simulate_plan(task.robot, plan, task.spec.simulation)


#: The name :func:`simulate` had first (the sweep's runner uses it).
simulate_result = simulate


def run_task(
    task: Task,
    methods: Sequence[str] = METHODS,
    simulate: bool = False,
    output_dir: str | Path | OutputFolder | None = None,
    solver_options: Mapping[str, Any] | None = None,
    models: ModelCache | None = None,
    force: bool = False,
    plans: Mapping[str, BalanceResult] | None = None,
    simulations: Mapping[str, SimulationResult] | None = None,
    executor: Any | None = None,
    robustness: bool | None = None,
) -> TaskRun:
    """Plan a task with each method, optionally simulate each plan, and write the outputs.

    Args:
        task: a loaded task.
        methods: among ``"analytic"`` and ``"optimal"``; the mission arm alone is always computed.
        simulate: check each plan (and the reference) in a forward-dynamics simulation.
        output_dir: a folder or an opened :class:`~balance_opt.report.output_dir.OutputFolder`,
            written all-or-nothing; ``None`` writes nothing.
        solver_options: Ipopt options overriding the task's ``optimal.ipopt``.
        models: planner models to reuse across runs.
        force: replace a non-empty output folder once the new one is complete.
        plans: ``{method: BalanceResult}`` already computed, used instead of planning again (a
            given analytic plan is also the optimal warm start).
        simulations: ``{name: SimulationResult}`` already computed, likewise reused.
        executor: runs the optimal planner's starts (see :func:`plan_optimal`); owned by the caller.
        robustness: replay every plan on perturbed models; ``None``: the task's
            ``robustness.enabled``.

    Returns:
        The run; ``run.failures`` names the methods whose solver failed (their best iterate is
        in ``run.results`` and was written).

    Raises:
        InputError: a bad method or given plan, or an unusable output folder (all checked before
            anything is computed).
        KeyboardInterrupt: Ctrl-C or SIGTERM; nothing is written.
    """
    task = checked_task(task)
    methods = _checked_methods(task, methods)
    given = _checked_plans(task, methods, plans or {})
    given_sims = dict(simulations or {})
    if robustness is None:
        robustness = task.spec.robustness.runs_in("plan")
    args = (task, methods, simulate, solver_options, models, given, given_sims, executor, robustness)
    if output_dir is None:
        with handling_signals():
            return _compute(*args)
    folder = output_dir if isinstance(output_dir, OutputFolder) else OutputFolder(output_dir, force)
    with handling_signals(), folder:
        run = _compute(*args)
        write_run(run, folder.staging)
        run.files = [folder.final(path) for path in run.files]
        run.report = None if run.report is None else folder.final(run.report)
    return run


def _compute(
    task: Task,
    methods,
    simulate: bool,
    solver_options,
    models,
    given: dict,
    given_sims: dict,
    executor: Any | None = None,
    robustness: bool = False,
) -> TaskRun:
    """The plans (the reference first), with ``robustness`` their drift under model error, and
    with ``simulate`` their simulations, in this process and in this order; the ones given are
    taken as they are."""
    run = TaskRun(task)
    models = models if models is not None else ModelCache()
    for method in (REFERENCE, *methods):
        if method in given:
            log.info("%s: %s plan given, not planned again", task.name, method)
            run.results[method] = given[method]
            if given[method].info.get("success", True) is False:
                run.failures[method] = f"given plan: solver status {given[method].status}"
        else:
            _plan_into(run, method, solver_options, models, executor)
    if robustness:
        _model_error_into(run)
    _clearance_into(
        run, {n: (r.t, np.hstack([r.q_M, r.q_B])) for n, r in run.results.items()}, run.clearance
    )
    if simulate:
        for name in list(run.results):
            if name in given_sims:
                run.simulations[name] = given_sims[name]
            else:
                _simulate_into(run, name)
        sims = {name: (sim.t, sim.q) for name, sim in run.simulations.items()}
        _clearance_into(run, sims, run.simulated_clearance)
    return run


#: Samples of a motion at most in the clearance figure's curves.
CLEARANCE_CURVE_SAMPLES = 300


def _clearance_into(run: TaskRun, motions: Mapping[str, tuple], into: dict) -> None:
    """The clearance of each motion ``(t, arm vectors)`` (a plan's, a simulation's) on the continuous
    motion (:func:`~balance_opt.geometry.clearance.clearance`) and its smallest distance over
    time for the figure, into ``into`` as ``{name: (report, t, distance)}``. A robot without
    geometry has none (a log line says so); across a capture the target is not a body of the
    check (the robot's own bodies are). A geometry that does not load (a missing mesh) leaves
    the check out with a warning."""
    from balance_opt.geometry.clearance import clearance

    if run_geometry(run) is False:
        return
    for name, (t, q) in motions.items():
        report = clearance(run.geometry, t, q)
        step = max(1, len(t) // CLEARANCE_CURVE_SAMPLES)
        into[name] = (report, t[::step], run.geometry.smallest_along(q[::step]))


def _model_error_into(run: TaskRun) -> None:
    """The drift of every plan replayed on perturbed models (not across a capture, where the
    robot changes mid-motion: the study is left out with a note)."""
    from balance_opt.motion.robustness import drift_under_model_error

    task = run.task
    if task.target is not None:
        log.info("%s: drift under model error not computed across a capture", task.name)
        return
    options = task.spec.robustness
    log.info(
        "%s: drift under %.0f %% model error (%d models) ...",
        task.name, 100 * options.perturbation, options.samples,
    )
    run.robustness = drift_under_model_error(task.robot, run.results, options, task.h0)
    log.info("%s: drift under model error: done in %.2f s", task.name, run.robustness.wall_time_s)


def _checked_plans(
    task: Task, methods: tuple[str, ...], plans: Mapping[str, BalanceResult]
) -> dict[str, BalanceResult]:
    """The plans given to :func:`run_task`, checked against the task and the methods."""
    robot = task.robot
    balance = tuple(j for arm in robot.balance_arms for j in arm.joints)
    for name, res in plans.items():
        where = f"run_task: plans[{name!r}]"
        if name not in (REFERENCE, *methods):
            raise InputError(
                f"{where}: not among the methods of this run ({', '.join((REFERENCE, *methods))})"
            )
        if not isinstance(res, BalanceResult):
            raise InputError(f"{where}: expected a BalanceResult, got {type(res).__name__}")
        if res.method != name:
            raise InputError(f"{where}: is a plan of method {res.method!r}")
        if res.mission_joints != robot.mission.joints or res.balance_joints != balance:
            raise InputError(f"{where}: its joints are not this task's arms ({task.name})")
        duration = float(res.t[-1] - res.t[0])
        if abs(duration - task.duration) > 1e-9 * max(1.0, task.duration):
            raise InputError(
                f"{where}: lasts {duration:g} s, the task's mission {task.duration:g} s"
            )
    return dict(plans)


def _checked_methods(task: Task, methods: Sequence[str]) -> tuple[str, ...]:
    """The methods without repeats, checked before anything is computed; the reference
    (``"mission-only"``) may be asked for alone: every run computes it."""
    given = tuple(dict.fromkeys(methods))
    methods = tuple(m for m in given if m != REFERENCE)
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not given:
        raise InputError(
            f"methods must be among {', '.join((REFERENCE, *METHODS))}, "
            f"got {', '.join(given) or 'none'}"
        )
    check_methods(task, methods)
    return methods


def _plan_into(
    run: TaskRun, method: str, solver_options, models: ModelCache, executor=None
) -> None:
    """Plan ``method`` into ``run.results``; a solver failure is recorded, its iterate kept."""
    task = run.task
    if method == REFERENCE:
        what = "mission arm alone (Phase I)"
    elif method == "optimal":
        spec = task.spec.optimal.planner
        what = f"optimal plan (N = {spec.intervals}, {spec.transcription}, Ipopt)"
    else:
        what = f"{method} plan"
    with _timed(f"{task.name}: {what}"):
        try:
            run.results[method] = plan(
                task, method, solver_options, run.results.get("analytic"), models, executor
            )
        except SolverError as exc:
            if method == REFERENCE:
                raise
            log.error("%s plan failed: %s", method, exc)
            run.failures[method] = str(exc)
            if exc.result is not None:
                run.results[method] = exc.result
    res = run.results.get(method)
    if res is not None and method != REFERENCE:
        log.info(
            "%s: max drift %.4g rad, final drift %.4g rad, %d position/velocity/acceleration "
            "limit violations",
            method,
            res.max_drift,
            res.final_drift,
            len(res.violations),
        )
        for warning in res.warnings():
            log.warning("%s plan: %s", method, warning)


def _simulate_into(run: TaskRun, name: str) -> None:
    """Simulate ``run.results[name]``; a diverging simulation is a failure, not a result."""
    from balance_opt.dynamics.simulation import divergence

    task = run.task
    with _timed(f"{task.name}: forward-dynamics simulation of {name}"):
        sim = simulate_result(task, run.results[name])
    diverged = divergence(sim)
    if diverged:
        message = (
            f"the forward-dynamics simulation of the {name} plan diverged ({diverged}); "
            f"try a smaller simulation.dt (now {task.spec.simulation.dt:g} s) or the "
            f"dopri5 integrator"
        )
        log.error("%s", message)
        run.failures[f"simulation of {name}"] = message
    else:
        run.simulations[name] = sim
