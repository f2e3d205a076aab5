"""Running a task: the mission arm alone (Phase I, the reference), the analytic and/or optimal
balance plans, optionally each checked by forward dynamics, then every output written.

The CLI's ``plan``, ``simulate`` and ``compare`` commands and the Python API share this module
(its public names are also the package's: ``balance_opt.run_task``, ...)::

    import balance_opt as bo

    task = bo.load_task("examples/capture_task.yaml")
    analytic = bo.plan_analytic(task)
    run = bo.run_task(task, plans={"analytic": analytic}, simulate=True,
                      output_dir="results/capture_task")   # plans only the optimal method
    run.results["optimal"].max_drift

A solver failure does not stop the run: the failing method's best iterate is kept, written and
marked in ``metrics.json`` and the report, and :attr:`TaskRun.failures` names it (the CLI then
exits with code 1).

Outputs are all-or-nothing (:class:`~balance_opt.io.output_dir.OutputFolder`): the output folder
is checked and locked before anything is computed, the files are written into a staging folder
beside it, and that folder takes the place of the old one only when every file is written. An
error or an interruption (Ctrl-C, SIGTERM: :mod:`balance_opt.interrupts`) leaves the old
folder as it was.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from balance_opt.app.models import ModelCache
from balance_opt.errors import InputError, SolverError
from balance_opt.interrupts import handling_signals
from balance_opt.io.output_dir import OutputFolder
from balance_opt.io.task import Task, check_methods, check_optimal_supported
from balance_opt.result import BalanceResult

if TYPE_CHECKING:
    from balance_opt.app.background import BackgroundSimulations
    from balance_opt.dynamics.simulation import SimulationResult

log = logging.getLogger(__name__)

METHODS = ("analytic", "optimal")
#: Name of the reference result: the mission arm alone, balance arm held (Phase I, Fig. 2).
REFERENCE = "mission-only"
METRICS_FILE = "metrics.json"
REPORT_FILE = "report.html"
#: Figures of a run: key -> (file name without suffix, caption). The figures carry no title;
#: the report prints these captions under them.
FIGURES = {
    "attitude": (
        "attitude_plans",
        "Base attitude of each plan (momentum model), with the mission arm alone for reference",
    ),
    "simulated_attitude": (
        "attitude_simulated",
        "Base attitude in the forward-dynamics simulation of each plan and of the mission arm alone",
    ),
    "torque": (
        "reaction_torque",
        (
            "Torque the arms exert on the base in the forward-dynamics simulation of each plan "
            "(paper Fig. 4): sum of the arms, mission arm and balance arm; each plan on its own "
            "scale"
        ),
    ),
    "joints": (
        "balance_joints",
        "Balance joint positions, rates and accelerations of each plan with their limits (dotted)",
    ),
}


@dataclass
class TaskRun:
    """Everything a run computed and wrote.

    Attributes:
        task: the task.
        results: ``{"mission-only" | "analytic" | "optimal": BalanceResult}``; a failed method's
            entry is its best iterate.
        simulations: ``{method: SimulationResult}`` when simulated.
        failures: ``{method: message}`` for the methods whose solver failed.
        metrics: the content of ``metrics.json``.
        files: every file written.
        report: the HTML report, if written.
    """

    task: Task
    results: dict[str, BalanceResult] = field(default_factory=dict)
    simulations: dict[str, Any] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    report: Path | None = None

    @property
    def ok(self) -> bool:
        """No solver failed."""
        return not self.failures

    def __repr__(self) -> str:
        lines = [f"TaskRun(task={self.task.name!r}, ok={self.ok})"]
        for name, res in self.results.items():
            failed = " (failed)" if name in self.failures else ""
            lines.append(
                f"  {name:13} max drift {res.max_drift:.4g} rad, final {res.final_drift:.4g} rad, "
                f"{len(res.violations)} limit violation(s){failed}"
            )
        if self.simulations:
            lines.append(f"  simulated     {', '.join(self.simulations)}")
        for name, message in self.failures.items():
            if name not in self.results:
                lines.append(f"  {name}: failed: {message[:80]}")
        if self.files:
            where = self.files[0].parent
            report = f", report {self.report}" if self.report is not None else ""
            lines.append(f"  files         {len(self.files)} in {where}{report}")
        return "\n".join(lines)


# =========================================================================================== methods
def plan_mission_only(task: Task) -> BalanceResult:
    """Phase I (paper Fig. 2): the base attitude with the mission arm moving and the balance arm
    held at its start, integrated from momentum conservation: the reference of every plan.

    Args:
        task: a loaded task (:func:`balance_opt.io.task.load_task`).

    Returns:
        A result with ``method="mission-only"``; for a task with a capture, both phases
        joined at the capture (:func:`balance_opt.app.capture.plan_captured`), as every method.
    """
    from balance_opt.analytic.phases import phase_one

    if task.target is not None:
        return _captured(task, REFERENCE)

    a = task.spec.analytic
    return phase_one(task.robot, task.mission, task.q_B0, h0=task.h0, integration=a.integration)


def plan_analytic(task: Task) -> BalanceResult:
    """Phase II: the analytic balance law (Eq. 31, 32) rolled out with the task's options.

    Args:
        task: a loaded task.

    Returns:
        A result with ``method="analytic"``.

    Raises:
        SolverError: the rollout failed; ``result`` holds the motion up to the failure.
    """
    from balance_opt.analytic.rollout import rollout

    if task.target is not None:
        return _captured(task, "analytic")

    a = task.spec.analytic
    return rollout(task.robot, task.mission, task.q_B0, a.law, integration=a.integration)


def plan_optimal(
    task: Task,
    solver_options: Mapping[str, Any] | None = None,
    warm_start: BalanceResult | None = None,
    models: ModelCache | None = None,
) -> BalanceResult:
    """The optimal planner with the task's options.

    Args:
        task: the task.
        solver_options: Ipopt options overriding ``optimal.ipopt`` (``--solver-option``).
        warm_start: an analytic result to start from (with ``optimal.initial_guess: analytic``),
            instead of rolling out the law again (not used for a task with a capture, whose
            phases start from their own guesses).
        models: the planner models to reuse (with their compiled NLPs); without one, the
            model is built for this call only.

    Returns:
        A result with ``method="optimal"``, re-simulated on a fine grid; ``info`` holds the
        solver's status, iterations, objective and wall times.

    Raises:
        InputError: the task asks for something the optimal planner cannot do.
        SolverError: Ipopt did not solve the NLP; ``result`` is the last iterate, re-simulated.
    """
    from balance_opt.optimal.solve import build_balance_nlp

    if task.target is not None:
        return _captured(task, "optimal", solver_options, models)
    check_optimal_supported(task)
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
    return nlp.solve(guess)


def _captured(task: Task, method: str, solver_options=None, models=None) -> BalanceResult:
    """The plan of a task with a capture: two phases joined at the capture (issue 16)."""
    from balance_opt.app.capture import plan_captured

    return plan_captured(task, method, solver_options, models)


def plan(
    task: Task,
    method: str,
    solver_options: Mapping[str, Any] | None = None,
    warm_start: BalanceResult | None = None,
    models: ModelCache | None = None,
) -> BalanceResult:
    """The plan of ``method``: the one dispatch of ``balance-opt plan`` and of the sweep cases.

    Args:
        task: the task.
        method: ``"mission-only"`` (the reference), ``"analytic"`` or ``"optimal"``.
        solver_options, warm_start, models: for the optimal method (see :func:`plan_optimal`).

    Raises:
        InputError: an unknown method.
        SolverError: the method failed; its ``result`` holds what was computed.
    """
    if method == REFERENCE:
        return plan_mission_only(task)
    if method == "analytic":
        return plan_analytic(task)
    if method == "optimal":
        return plan_optimal(task, solver_options, warm_start, models)
    raise InputError(f"unknown method '{method}'; expected {' or '.join(METHODS)}")


def simulate(task: Task, plan: BalanceResult) -> SimulationResult:
    """Forward-dynamics simulation of a plan with the task's simulation options
    (``simulation:``): joint controllers track the plan, the base floats.

    Args:
        task: the task the plan was made for.
        plan: any plan of that task (analytic, optimal, mission arm alone).

    Returns:
        The simulated motion, its joint torques and the arms' wrenches on the base.
    """
    from balance_opt.dynamics.simulation import simulate_plan

    if task.target is not None:  # through the capture's impulse (issue 16)
        from balance_opt.app.capture import robot_after
        from balance_opt.dynamics.capture_impulse import simulate_with_capture

        return simulate_with_capture(
            task.robot, robot_after(task), task.target, plan, task.spec.simulation
        )
    return simulate_plan(task.robot, plan, task.spec.simulation)


#: The name :func:`simulate` had first (the sweep's runner uses it).
simulate_result = simulate


# =========================================================================================== run
@contextlib.contextmanager
def _timed(what: str):
    """Log ``what ...``, then ``what: done in X s`` when the block ends without error."""
    log.info("%s ...", what)
    start = time.perf_counter()
    yield
    log.info("%s: done in %.2f s", what, time.perf_counter() - start)


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
    background: bool = False,
) -> TaskRun:
    """Plan a task with each method, optionally simulate each plan, and write the outputs.

    Args:
        task: a loaded task (:func:`balance_opt.io.task.load_task`).
        methods: among ``"analytic"`` and ``"optimal"``; the mission arm alone is always
            computed as the reference.
        simulate: check each plan in a forward-dynamics simulation (and the reference too).
        output_dir: where to write, all-or-nothing (see the module docstring): a folder, or an
            :class:`~balance_opt.io.output_dir.OutputFolder` (possibly opened already);
            ``None`` writes nothing.
        solver_options: Ipopt options overriding the task's ``optimal.ipopt``.
        models: planner models to reuse across runs; by default this run keeps its own.
        force: replace an output folder that exists and is not empty (once the new one is
            complete); without it such a folder is refused before anything is computed.
        plans: results already computed for this task, ``{"mission-only" | "analytic" |
            "optimal": BalanceResult}``: used as they are instead of planning again (a given
            analytic plan is also the optimal planner's warm start). A given plan whose solver
            failed (``info["success"]`` false) is recorded in ``failures``.
        simulations: simulations already computed, ``{name: SimulationResult}`` (with
            ``simulate``), likewise reused.
        background: with ``simulate`` and two CPUs or more, simulate the plans made before
            the optimal one in a worker process while it is solved (same results, less wall
            time; :mod:`balance_opt.app.background`). The CLI sets it.

    Returns:
        The run; ``run.failures`` names the methods whose solver failed (their best iterate is
        in ``run.results`` and was written). ``run.files`` are the paths in ``output_dir``.

    Raises:
        InputError: an unknown method, or a method the task cannot use; a given plan of
            another method, of other joints or of another duration than the task's; an output
            folder that cannot be created, is in use by another run, or is not empty without
            ``force`` (all checked before anything is computed).
        KeyboardInterrupt: Ctrl-C or SIGTERM (:class:`~balance_opt.interrupts.Interrupted`);
            nothing is written.
    """
    methods = _checked_methods(task, methods)
    given = _checked_plans(task, methods, plans or {})
    given_sims = dict(simulations or {})
    if output_dir is None:
        with handling_signals():
            return _compute(
                task, methods, simulate, solver_options, models, given, given_sims, background
            )
    folder = output_dir if isinstance(output_dir, OutputFolder) else OutputFolder(output_dir, force)
    with handling_signals(), folder:
        run = _compute(
            task, methods, simulate, solver_options, models, given, given_sims, background
        )
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
    background: bool = False,
) -> TaskRun:
    """The plans (the reference first) and, with ``simulate``, their simulations; the ones
    given are taken as they are."""
    run = TaskRun(task)
    models = models if models is not None else ModelCache()
    with _background(task, methods, simulate, given, given_sims, background) as worker:
        for method in (REFERENCE, *methods):
            if method in given:
                log.info("%s: %s plan given, not planned again", task.name, method)
                run.results[method] = given[method]
                if given[method].info.get("success", True) is False:
                    run.failures[method] = f"given plan: solver status {given[method].status}"
            else:
                _plan_into(run, method, solver_options, models)
            # the worker simulates a plan while the next one is planned
            if (
                worker is not None
                and method in run.results
                and method not in ("optimal", *given_sims)
            ):
                worker.submit(method, run.results[method])
        if simulate:
            for name in list(run.results):
                if name in given_sims:
                    run.simulations[name] = given_sims[name]
                elif worker is None or name not in worker:
                    _simulate_into(run, name)
            for name in list(run.results):  # the worker's, in the run's order
                if worker is not None and name in worker:
                    _simulate_into(run, name, worker)
            run.simulations = {k: run.simulations[k] for k in run.results if k in run.simulations}
    return run


def _background(task: Task, methods, simulate: bool, given, given_sims, background: bool):
    """The worker process that simulates the plans made before the optimal one while that one
    is solved (:mod:`balance_opt.app.background`), or a null context: only with
    ``background``, two CPUs or more, and an optimal plan to solve after a plan to simulate."""
    from balance_opt.app.background import BackgroundSimulations, usable_cpus

    worthwhile = (
        background
        and simulate
        and "optimal" in methods
        and "optimal" not in given
        and REFERENCE not in given_sims
        and usable_cpus() >= 2
    )
    return BackgroundSimulations(task, simulate_result) if worthwhile else contextlib.nullcontext()


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
    """The methods without repeats, checked before anything is computed."""
    methods = tuple(dict.fromkeys(methods))
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(
            f"methods must be among {', '.join(METHODS)}, got {', '.join(methods) or 'none'}"
        )
    check_methods(task, methods)
    return methods


def _plan_into(run: TaskRun, method: str, solver_options, models: ModelCache) -> None:
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
                task, method, solver_options, run.results.get("analytic"), models
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
            "%s: max drift %.4g rad, final drift %.4g rad, %d limit violations",
            method,
            res.max_drift,
            res.final_drift,
            len(res.violations),
        )


def _simulate_into(run: TaskRun, name: str, worker: BackgroundSimulations | None = None) -> None:
    """Simulate ``run.results[name]`` (or take the worker's simulation of it); a diverging
    simulation is a failure, not a result."""
    from balance_opt.dynamics.simulation import divergence

    task = run.task
    if worker is None:
        with _timed(f"{task.name}: forward-dynamics simulation of {name}"):
            sim = simulate_result(task, run.results[name])
    else:
        sim, seconds = worker.result(name, run.results[name])
        log.info(
            "%s: forward-dynamics simulation of %s: done in %.2f s (worker process)",
            task.name,
            name,
            seconds,
        )
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


# =========================================================================================== writing
def write_run(run: TaskRun, output_dir: Path) -> list[Path]:
    """Write the trajectories, ``metrics.json``, the figures and the report of ``run``."""
    from balance_opt.io.outputs import (
        plan_joint_torques,
        run_metrics,
        write_metrics,
        write_trajectory_csv,
        write_trajectory_npz,
    )

    out = run.task.spec.outputs
    output_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for name, res in run.results.items():
        if out.csv:
            files.append(write_trajectory_csv(output_dir / f"{name}.csv", res))
        if out.npz:
            npz = output_dir / f"{name}.npz"
            files.append(write_trajectory_npz(npz, res, run.task.robot, run.task.h0))
    run.metrics = run_metrics(run.task, run.results, run.simulations, run.failures)
    files.append(write_metrics(output_dir / METRICS_FILE, run.metrics))
    figures = []
    if out.plots or out.report:
        with _timed("figures"):
            figures = write_figures(run, output_dir)
        if out.plots:
            files.extend(path for _, path in figures)
    if out.report:
        from balance_opt.io.report import write_report

        extra = _animation_section(run) if out.animation else ""
        torques = {
            name: (res.t, plan_joint_torques(res, run.task.robot, run.task.h0))
            for name, res in run.results.items()
        }
        about = run.task.spec.description
        run.report = write_report(
            output_dir / REPORT_FILE, run.metrics, figures, about, extra, torques
        )
        files.append(run.report)
        if not out.plots:
            for _, path in figures:
                path.unlink()
    run.files = files
    return files


def _animation_section(run: TaskRun) -> str:
    """The report's 3D animation of every plan (see :mod:`balance_opt.io.animation`)."""
    from balance_opt.io.animation import animation_html
    from balance_opt.io.plots import plan_colour, plan_label

    names = list(run.results)
    colours = {name: plan_colour(name, i) for i, name in enumerate(names)}
    labels = {name: plan_label(name) for name in names}
    with _timed("animation"):
        body = animation_html(run.task.robot, run.results, run.task.h0, colours, labels)
    return (
        '<h2>Animation</h2><p class="meta">The robot as a stick figure (base axes: red x, green y, '
        "blue z), base pose from the plan; drag to turn the view.</p>" + body
    )


def write_figures(run: TaskRun, output_dir: Path) -> list[tuple[str, Path]]:
    """PNG figures of a run at one resolution (:data:`~balance_opt.io.style.SCREEN_DPI`, the
    report's): the plans' attitude with the mission arm alone, the balance joints against their
    limits and, when simulated, the simulated attitude and the torques on the base. PNG only:
    the report embeds them, and ``paper-figures`` writes the PDFs for print. Returns
    ``(caption, path)`` pairs."""
    from balance_opt.io.plots import attitude_figure, reaction_torque_figure
    from balance_opt.io.report_figures import joint_limits_figure
    from balance_opt.io.style import SCREEN_DPI, SIM

    def draw(key, function, curves):
        stem, caption = FIGURES[key]
        _, paths = function(curves, output_dir / stem, formats=("png",), dpi=SCREEN_DPI)
        figures.append((caption, paths[0]))

    figures = []
    plans = {k: v for k, v in run.results.items() if k != REFERENCE}
    draw("attitude", attitude_figure, {**plans, **_only(run.results, REFERENCE)})
    if plans:
        stem, caption = FIGURES["joints"]
        path = joint_limits_figure(plans, run.task.robot, output_dir / f"{stem}.png", SCREEN_DPI)
        figures.append((caption, path))
    if run.simulations:
        sims = {f"{k}{SIM}": v for k, v in run.simulations.items() if k != REFERENCE}
        reference = {f"{k}{SIM}": v for k, v in _only(run.simulations, REFERENCE).items()}
        draw("simulated_attitude", attitude_figure, {**sims, **reference})
        if sims:
            balanced = {k: v for k, v in run.simulations.items() if k != REFERENCE}
            draw("torque", reaction_torque_figure, balanced)
    if run.task.target is not None:  # issue 16
        from balance_opt.io.capture_figures import CAPTION, capture_figure

        curves = {**plans, **{f"{k}{SIM}": v for k, v in run.simulations.items() if k in plans}}
        path = capture_figure(curves, run.task.target.time, output_dir / "capture.png")
        figures.append((CAPTION, path))
    return figures


def _only(results: Mapping[str, Any], name: str) -> dict[str, Any]:
    return {name: results[name]} if name in results else {}
