"""Running a task: the mission arm alone (the reference), the analytic and/or optimal balance
plans, optionally each checked by forward dynamics, then every output written: trajectories (CSV,
NPZ), ``metrics.json``, the figures, the 3D scene and the HTML report, into a folder (the staging
folder of an all-or-nothing run).

A solver failure does not stop the run: the failing method's best iterate is kept, written and
marked, and :attr:`TaskRun.failures` names it (the CLI then exits with code 1)."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from balance_opt.app.capture import plan_task
from balance_opt.app.models import ModelCache
from balance_opt.app.run_files import write_run
from balance_opt.app.run_studies import (
    clearance_into,
    closed_loop_into,
    model_error_into,
    run_geometry,
)
from balance_opt.app.task_run import GIVEN_TIMING, METHODS, REFERENCE, TaskRun, timed
from balance_opt.errors import DivergenceError, InputError, SolverError
from balance_opt.interrupts import handling_signals
from balance_opt.motion.result import BalanceResult
from balance_opt.report.output_dir import OutputFolder
from balance_opt.tasks.task import Task, check_methods

if TYPE_CHECKING:
    from balance_opt.dynamics.simulation import SimulationResult

log = logging.getLogger(__name__)


def checked_task(task: Task | str | Path) -> Task:
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
        "task: expected a Task (balance_opt.load_task) or a task file path, "
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
    return plan_task(checked_task(task), REFERENCE)


def plan_analytic(task: Task | str | Path) -> BalanceResult:
    """Phase II: the analytic balance law (Eq. 31, 32) rolled out with the task's options.

    Raises:
        SolverError: the rollout failed; ``result`` holds the motion up to the failure.
    """
    return plan_task(checked_task(task), "analytic")


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
    task = checked_task(task)
    if warm_start is not None:
        _checked_plan(warm_start)
    check_methods(task, ("optimal",))
    warm = warm_start is not None and task.spec.optimal.initial_guess == "analytic"
    return plan_task(
        task, "optimal", solver_options, models, executor, warm_start if warm else None
    )


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
    if method == GIVEN_TIMING:
        result = plan_optimal(given_timing(task), solver_options, warm_start, models, executor)
        return dataclasses.replace(result, method=GIVEN_TIMING)
    raise InputError(f"unknown method '{method}'; expected {' or '.join(METHODS)}")


def given_timing(task: Task) -> Task:
    """The task at its mission's given timing (a time objective becomes the peak, its bound
    left out): :data:`GIVEN_TIMING`'s."""
    spec, planner = task.spec, task.spec.optimal.planner
    changes = {"timing": "given"}
    if planner.objective == "time":
        changes.update(objective="peak", path_attitude_bound=None)
    optimal = dataclasses.replace(spec.optimal, planner=dataclasses.replace(planner, **changes))
    mission = dataclasses.replace(spec.mission, timing="given")
    return dataclasses.replace(
        task, spec=dataclasses.replace(spec, mission=mission, optimal=optimal)
    )


def simulate(task: Task, plan: BalanceResult) -> SimulationResult:
    """Forward-dynamics simulation of a plan of ``task`` with its simulation options: joint
    controllers track the plan, the base floats. Returns the simulated motion, its joint torques
    and the arms' wrenches on the base.
    """
    from balance_opt.dynamics.simulation import simulate_plan

    task, plan = checked_task(task), _checked_plan(plan)
    if task.target is not None:  # through the capture's impulse (issue 16)
        from balance_opt.dynamics.capture_impulse import simulate_with_capture

        return simulate_with_capture(
            task.robot, task.robot_after_capture, task.target, plan, task.spec.simulation
        )
    return simulate_plan(task.robot, plan, task.spec.simulation)


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
    closed_loop: bool = False,
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
        closed_loop: fly every plan closed loop on perturbed models (``closed_loop:``), its
            Monte Carlo on ``executor``.

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
    given_sims = simulations or {}
    if robustness is None:
        robustness = task.spec.robustness.runs_in("plan")
    folder = output_dir
    if output_dir is not None and not isinstance(output_dir, OutputFolder):
        folder = OutputFolder(output_dir, force)
    with handling_signals(), contextlib.nullcontext() if folder is None else folder:
        # the plans (the reference first), their drift under model error and their
        # simulations, in this process and in this order; the ones given are taken as they are
        run = TaskRun(task)
        models = models if models is not None else ModelCache()
        _plans_into(run, methods, given, solver_options, models, executor)
        run_geometry(run, models)  # the planner's, if it planned
        if robustness:
            model_error_into(run)
        motions = {n: (r.t, np.hstack([r.q_M, r.q_B])) for n, r in run.results.items()}
        clearance_into(run, motions, run.clearance)
        if simulate:
            for name in list(run.results):
                if name in given_sims:
                    run.simulations[name] = given_sims[name]
                else:
                    _simulate_into(run, name)
            sims = {name: (sim.t, sim.q) for name, sim in run.simulations.items()}
            clearance_into(run, sims, run.simulated_clearance)
        if closed_loop:
            closed_loop_into(run, executor)
        if folder is not None:
            write_run(run, folder.staging)
            run.files = [folder.final(path) for path in run.files]
            run.report = None if run.report is None else folder.final(run.report)
    return run


def _plans_into(
    run: TaskRun,
    methods: tuple[str, ...],
    given: Mapping[str, BalanceResult],
    solver_options,
    models: ModelCache,
    executor,
) -> None:
    """The reference and every method's plan into ``run.results``, in that order: those in
    ``given`` taken as they are, the others planned (:func:`_plan_into`)."""
    for method in (REFERENCE, *methods):
        if method in given:
            log.info("%s: %s plan given, not planned again", run.task.name, method)
            run.results[method] = given[method]
            if given[method].details().get("success", True) is False:
                run.failures[method] = f"given plan: solver status {given[method].status}"
        else:
            _plan_into(run, method, solver_options, models, executor)


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
    known = METHODS + ((GIVEN_TIMING,) if task.spec.mission.timing == "free" else ())
    unknown = [m for m in methods if m not in known]
    if unknown or not given:
        raise InputError(
            f"methods must be among {', '.join((REFERENCE, *known))}, "
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
    elif method in ("optimal", GIVEN_TIMING):
        spec = task.spec.optimal.planner
        what = f"optimal plan (N = {spec.intervals}, {spec.transcription}, Ipopt)"
    else:
        what = f"{method} plan"
    with timed(f"{task.name}: {what}"):
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
    with timed(f"{task.name}: forward-dynamics simulation of {name}"):
        try:
            sim = simulate(task, run.results[name])
            diverged = divergence(sim)
        except DivergenceError as error:  # stopped where its state left every sane bound
            sim, diverged = None, f"stopped at t = {error.t:.4g} s: {error.reason}"
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
