"""Running a task: the mission arm alone (Phase I, the reference), the analytic and/or optimal
balance plans, optionally each checked by forward dynamics, then every output written.

The CLI's ``plan``, ``simulate`` and ``compare`` commands and the Python API share this module::

    from balance_opt.io.task import load_task
    from balance_opt.app.pipeline import run_task

    run = run_task(load_task("examples/capture_task.yaml"), methods=("analytic", "optimal"),
                   simulate=True, output_dir="results/capture_task")
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
from typing import Any

from balance_opt.app.models import ModelCache
from balance_opt.errors import InputError, SolverError
from balance_opt.interrupts import handling_signals
from balance_opt.io.output_dir import OutputFolder
from balance_opt.io.task import Task, check_methods, check_optimal_supported
from balance_opt.result import BalanceResult

log = logging.getLogger(__name__)

METHODS = ("analytic", "optimal")
#: Name of the reference result: the mission arm alone, balance arm held (Phase I, Fig. 2).
REFERENCE = "mission-only"
METRICS_FILE = "metrics.json"
REPORT_FILE = "report.html"
FIGURES = {
    "attitude": (
        "attitude_plans",
        "Base attitude of each plan (kinematic), with the mission arm alone (dashed)",
    ),
    "simulated_attitude": (
        "attitude_simulated",
        "Base attitude in the forward-dynamics simulation of each plan",
    ),
    "torque": (
        "reaction_torque",
        "Torque the arms exert on the base in the simulation (paper Fig. 4)",
    ),
    "joints": (
        "balance_joints",
        "Balance joint positions, rates and accelerations with their limits (dotted)",
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


# =========================================================================================== methods
def plan_mission_only(task: Task) -> BalanceResult:
    """Phase I (paper Fig. 2): the base attitude with the mission arm moving and the balance arm
    held at its start, integrated from momentum conservation."""
    from balance_opt.analytic.phases import phase_one

    a = task.spec.analytic
    return phase_one(task.robot, task.mission, task.q_B0, h0=task.h0, integration=a.integration)


def plan_analytic(task: Task) -> BalanceResult:
    """Phase II: the analytic balance law (Eq. 31, 32) rolled out with the task's options.

    Raises:
        SolverError: the rollout failed; ``result`` holds the motion up to the failure.
    """
    from balance_opt.analytic.rollout import rollout

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
            instead of rolling out the law again.
        models: the planner models to reuse (with their compiled NLPs); without one, the
            model is built for this call only.

    Raises:
        SolverError: Ipopt did not solve the NLP; ``result`` is the last iterate, re-simulated.
    """
    from balance_opt.optimal.solve import build_balance_nlp

    check_optimal_supported(task)
    spec = task.spec.optimal
    options = task.planner_options(solver_options)
    model = (models if models is not None else ModelCache()).planner_model(
        task.robot, task.spec.robot.backend
    )
    nlp = build_balance_nlp(model, task.mission, task.q_B0, options, robot=task.robot)
    guess = (
        warm_start
        if (warm_start is not None and spec.initial_guess == "analytic")
        else spec.initial_guess
    )
    return nlp.solve(guess)


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


def simulate_result(task: Task, plan: BalanceResult):
    """Forward-dynamics simulation of a plan with the task's simulation options."""
    from balance_opt.dynamics.simulation import simulate_plan

    return simulate_plan(task.robot, plan, task.spec.simulation)


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

    Returns:
        The run; ``run.failures`` names the methods whose solver failed (their best iterate is
        in ``run.results`` and was written). ``run.files`` are the paths in ``output_dir``.

    Raises:
        InputError: an unknown method, or a method the task cannot use; an output folder that
            cannot be created, is in use by another run, or is not empty without ``force``
            (all checked before anything is computed).
        KeyboardInterrupt: Ctrl-C or SIGTERM (:class:`~balance_opt.interrupts.Interrupted`);
            nothing is written.
    """
    methods = _checked_methods(task, methods)
    if output_dir is None:
        with handling_signals():
            return _compute(task, methods, simulate, solver_options, models)
    folder = output_dir if isinstance(output_dir, OutputFolder) else OutputFolder(output_dir, force)
    with handling_signals(), folder:
        run = _compute(task, methods, simulate, solver_options, models)
        write_run(run, folder.staging)
        run.files = [folder.final(path) for path in run.files]
        run.report = None if run.report is None else folder.final(run.report)
    return run


def _compute(task: Task, methods, simulate: bool, solver_options, models) -> TaskRun:
    """The plans (the reference first) and, with ``simulate``, their simulations."""
    run = TaskRun(task)
    models = models if models is not None else ModelCache()
    for method in (REFERENCE, *methods):
        _plan_into(run, method, solver_options, models)
    if simulate:
        for name in list(run.results):
            _simulate_into(run, name)
    return run


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


# =========================================================================================== writing
def write_run(run: TaskRun, output_dir: Path) -> list[Path]:
    """Write the trajectories, ``metrics.json``, the figures and the report of ``run``."""
    from balance_opt.io.outputs import (
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
            files.append(write_trajectory_npz(output_dir / f"{name}.npz", res))
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
        run.report = write_report(
            output_dir / REPORT_FILE, run.metrics, figures, run.task.spec.description, extra
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
    """PNG figures of a run: the plans' attitude (and the mission arm alone), the balance
    joints against their limits and, when simulated, the simulated attitude and the reaction
    torques. Returns ``(caption, path)`` pairs."""
    from balance_opt.io.plots import attitude_figure, reaction_torque_figure
    from balance_opt.io.report_figures import joint_limits_figure

    def attitude(results, key, title):
        """Attitude of the plans, the reference dashed (alone when there is no plan)."""
        plans = {k: v for k, v in results.items() if k != REFERENCE}
        dashed = {REFERENCE: results[REFERENCE]} if plans and REFERENCE in results else None
        stem, caption = FIGURES[key]
        _, paths = attitude_figure(
            plans or results, output_dir / stem, dashed=dashed, title=title, formats=("png",)
        )
        figures.append((caption, paths[0]))
        return plans

    figures = []
    plans = attitude(run.results, "attitude", "Base attitude")
    if plans:
        stem, caption = FIGURES["joints"]
        path = joint_limits_figure(plans, run.task.robot, output_dir / f"{stem}.png")
        figures.append((caption, path))
    if run.simulations:
        sims = attitude(run.simulations, "simulated_attitude", "Base attitude, forward dynamics")
        if sims:
            stem, caption = FIGURES["torque"]
            _, paths = reaction_torque_figure(
                sims, output_dir / stem, title="Torque on the base", formats=("png",)
            )
            figures.append((caption, paths[0]))
    return figures


def paper_figures(
    output_dir: str | Path | OutputFolder,
    task: Task | None = None,
    solver_options: Mapping[str, Any] | None = None,
    force: bool = False,
) -> list[Path]:
    """The paper's study (Figs. 2-5, :func:`balance_opt.app.study.paper_study`) written to
    ``output_dir``, all-or-nothing as :func:`run_task` writes: by default Figs. 2-5 of the
    paper's law on ``paper_fig5`` and the law against the optimal plan on ``capture_task``,
    each in a subfolder; with ``task``, Figs. 2-5 of that task (its robot, mission, balance
    start and options), both methods, in a subfolder of its name.

    Raises:
        InputError: the output folder cannot be used (see :func:`run_task`), checked first.
        KeyboardInterrupt: Ctrl-C or SIGTERM; nothing is written.
    """
    from balance_opt.app.study import paper_study

    folder = output_dir if isinstance(output_dir, OutputFolder) else OutputFolder(output_dir, force)
    kwargs = {}
    if task is not None:
        from balance_opt.app.scenarios import Scenario

        kwargs = {
            "scenario": Scenario(
                task.robot, task.mission, task.q_B0, task.name, task.spec.analytic.law
            ),
            "law": task.spec.analytic.law,
            "planner": task.planner_options(solver_options),
            "simulation": task.spec.simulation,
        }
    elif solver_options:
        from balance_opt.optimal.options import PlannerOptions

        kwargs = {"planner": PlannerOptions(ipopt=dict(solver_options))}
    with handling_signals(), folder, _timed("paper study (Figs. 2-5)"):
        study = paper_study(folder.staging, **kwargs)
        files = [p for paths in study.figures.values() for p in paths]
        jsons = [folder.staging / name / "study.json" for name in study.parts]
        return [folder.final(p) for p in (*files, *jsons, folder.staging / "study.json")]
