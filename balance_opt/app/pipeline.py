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
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from balance_opt.app.capture import plan_task
from balance_opt.app.models import ModelCache
from balance_opt.errors import InputError, SolverError
from balance_opt.interrupts import handling_signals
from balance_opt.motion.result import BalanceResult
from balance_opt.report import plots
from balance_opt.report.output_dir import OutputFolder
from balance_opt.report.style import SCREEN_DPI, SIM, method_label
from balance_opt.tasks.task import Task, check_methods

if TYPE_CHECKING:
    from balance_opt.dynamics.simulation import SimulationResult

log = logging.getLogger(__name__)

METHODS = ("analytic", "optimal")
#: With a free mission timing (``mission.timing: free``), the optimal plan at the given timing,
#: which ``compare`` puts beside the free one.
GIVEN_TIMING = "optimal-given"
#: Name of the reference result: the mission arm alone, balance arm held (Phase I, Fig. 2).
REFERENCE = "mission-only"
METRICS_FILE = "metrics.json"
REPORT_FILE = "report.html"
#: The 3D scene of the plans beside the report (issue 28), which the report shows in a frame.
SCENE_FILE = "scene.html"
#: Figures of a run: key -> (file name without suffix, caption). The figures carry no title;
#: the report prints these captions under them.
FIGURES = {
    "clearance": (
        "clearance",
        "Smallest distance between any two bodies of the robot that may touch (adjacent links "
        "and pairs the robot's SRDF disables left out), exact geometry, against time; below zero "
        "the bodies penetrate; dotted: the optimal planner's collision margin",
    ),
    "model_error": (
        "attitude_model_error",
        "Base rotation of each plan as planned (lines) and its 95th percentile when the plan's "
        "joint motion is replayed on robots whose masses, centres of mass and inertias are "
        "perturbed (shaded up to the dotted edge)",
    ),
    "closed_loop": (
        "attitude_closed_loop",
        "Base rotation of each plan as planned (line), and its 95th percentile over perturbed "
        "true robots in forward dynamics: flown open loop (dotted) and closed loop, re-planned "
        "from the measured state every period (dashed, shaded)",
    ),
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
    "timing": (
        "mission_timing",
        "Free mission timing: the path progress s(t) of the optimal plan (the time at which the "
        "given trajectory passes where the re-timed mission is), the given timing dotted (s = t); "
        "below, the drift of the optimal plans at the free and at the given timing (the analytic "
        "law follows the given timing: it has no say over the mission)",
    ),
    "capture": (
        "capture",
        "Base angular velocity |omega_b| and attitude drift through the capture (dotted line); "
        "the drift after the capture is measured from the attitude at the capture (thin lines)",
    ),
}


@dataclass
class TaskRun:
    """Everything a run (:func:`balance_opt.app.pipeline.run_task`) computed and wrote.

    Attributes:
        task: the task.
        results: ``{"mission-only" | "analytic" | "optimal": BalanceResult}``; a failed method's
            entry is its best iterate.
        simulations: ``{method: SimulationResult}`` when simulated.
        failures: ``{method: message}`` for the methods whose solver failed.
        metrics: the content of ``metrics.json``.
        files: every file written.
        report: the HTML report, if written.
        robustness: the plans' drift under model error
            (:class:`~balance_opt.motion.robustness.RobustnessResult`), if studied.
        clearance: per plan ``(ClearanceReport, t, smallest distance)``
            (:mod:`balance_opt.geometry.clearance`); ``simulated_clearance`` the same of the
            simulations; empty for a robot without geometry.
        geometry: the robot's :class:`~balance_opt.geometry.robot_geometry.RobotGeometry`
            (``False``: it has none; ``None``: not built yet).
        geometry_after: with a capture, the geometry after it and the target's pairs
            (:func:`capture_geometry`; ``False``: it did not load).
        closed_loop: the plans flown closed loop on perturbed robots
            (:class:`~balance_opt.app.closed_loop.ClosedLoopStudy`), if studied.
    """

    task: Task
    results: dict[str, BalanceResult] = field(default_factory=dict)
    simulations: dict[str, Any] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    report: Path | None = None
    robustness: Any = None
    clearance: dict[str, Any] = field(default_factory=dict)
    simulated_clearance: dict[str, Any] = field(default_factory=dict)
    geometry: Any = None
    geometry_after: Any = None
    closed_loop: Any = None

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


@contextlib.contextmanager
def _timed(what: str):
    """Log ``what ...``, then ``what: done in X s`` when the block ends without error."""
    log.info("%s ...", what)
    start = time.perf_counter()
    yield
    log.info("%s: done in %.2f s", what, time.perf_counter() - start)


def write_run(run: TaskRun, output_dir: Path) -> list[Path]:
    """Write the trajectories, ``metrics.json``, the figures and the report of ``run``."""
    from balance_opt.dynamics.inverse_dynamics import plan_joint_torques
    from balance_opt.report.outputs import (
        run_metrics,
        write_metrics,
        write_trajectory_csv,
        write_trajectory_npz,
    )

    out, files = run.task.spec.outputs, []
    output_dir.mkdir(parents=True, exist_ok=True)
    torques = {  # the NPZ files, the metrics and the report each use them
        name: plan_joint_torques(res, run.task.robot, run.task.h0)
        for name, res in run.results.items()
    }
    for name, res in run.results.items():
        if out.csv:
            files.append(write_trajectory_csv(output_dir / f"{name}.csv", res))
        if out.npz:
            files.append(write_trajectory_npz(output_dir / f"{name}.npz", res, torques[name]))
    margin = run.task.spec.optimal.planner.collision_margin
    run.metrics = run_metrics(
        run.task,
        run.results,
        run.simulations,
        run.failures,
        torques,
        run.robustness,
        {name: c[0] for name, c in run.clearance.items()},
        {name: c[0] for name, c in run.simulated_clearance.items()},
        # what the clearance check held apart and the pairs close at the start
        run.geometry.summary(run.task.q0, margin) if run.geometry else None,
    )
    if run.closed_loop is not None:
        from balance_opt.app.closed_loop import write_worst

        for name in run.closed_loop.runs:
            run.metrics["methods"][name]["closed_loop"] = run.closed_loop.metrics(name)
        files += write_worst(run.closed_loop, run.task, output_dir)
    files.append(write_metrics(output_dir / METRICS_FILE, run.metrics))
    figures = []
    if out.plots or out.report:
        with _timed("figures"):
            figures = write_figures(run, output_dir)
    if out.plots:
        files.extend(path for _, path in figures)
    if out.report:
        from balance_opt.report.report import render_report

        extra, scene = _report_sections(run, output_dir)
        timed = {name: (res.t, torques[name]) for name, res in run.results.items()}
        about = run.task.spec.description
        run.report = output_dir / REPORT_FILE
        page = render_report(run.metrics, figures, about, extra, timed)
        run.report.write_text(page, encoding="utf-8")
        files += [run.report] + ([scene] if scene is not None else [])
        if not out.plots:
            for _, path in figures:
                path.unlink()
    run.files = files
    return files


def _report_sections(run: TaskRun, output_dir: Path) -> tuple[str, Path | None]:
    """The report's 3D section (the scene, written beside it) and the scene's file (None: not
    written)."""
    if not run.task.spec.outputs.animation:
        return "", None
    try:
        scene = write_run_scene(run, output_dir / SCENE_FILE)
    except InputError as exc:  # a mesh file missing: the rest of the run still counts
        log.warning("3D scene not written: %s", exc)
        return "", None
    return (
        '<h2 id="scene">3D scene</h2><p class="meta">The robot\'s own geometry moving through '
        f'each plan (<a href="{SCENE_FILE}">{SCENE_FILE}</a>, a page of its own; '
        "<code>balance-opt view</code> serves it).</p>"
        f'<iframe src="{SCENE_FILE}" title="3D scene" style="width:100%;height:600px;'
        'border:1px solid #ddd"></iframe>'
    ), scene


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


def write_run_scene(run: TaskRun, path: Path) -> Path:
    """The 3D scene of every plan of ``run`` (:mod:`balance_opt.report.scene`) written to
    ``path``."""
    from balance_opt.report.scene import write_scene

    labels = {
        name: method_label(name) + (" (FAILED)" if name in run.failures else "")
        for name in run.results
    }
    geometry = run_geometry(run)  # the run's own when it checked clearance
    with _timed("3D scene"):
        return write_scene(
            path, run.task.robot, run.results, run.task.h0, run.task.target, labels,
            run.task.name, geometry=geometry or None,
            margin=run.task.spec.optimal.planner.collision_margin,
        )  # fmt: skip


def write_figures(run: TaskRun, output_dir: Path) -> list[tuple[str, Path]]:
    """The PNG figures of a run at the report's resolution (PNG only: the report embeds them,
    and ``paper-figures`` writes the PDFs for print), as ``(caption, path)`` pairs in the
    report's order."""
    figures = []

    def draw(key, function, *args, note="", **kwargs):
        stem, caption = FIGURES[key]
        _, paths = function(*args, output_dir / stem, formats=("png",), dpi=SCREEN_DPI, **kwargs)
        figures.append((caption + note, paths[0]))

    plans = {k: v for k, v in run.results.items() if k != REFERENCE}
    draw("attitude", plots.attitude_figure, _reference_last(run.results))
    if run.clearance:
        planner = run.task.spec.optimal.planner
        margin = planner.collision_margin if planner.collision_avoidance else None
        curves = {name: (c[1], c[2]) for name, c in run.clearance.items()}
        draw("clearance", plots.clearance_figure, _reference_last(curves), margin)
    if run.robustness is not None:
        draw(
            "model_error",
            plots.model_error_figure,
            _reference_last(run.results),
            run.robustness.attitude_p95,
            perturbation=run.robustness.options.perturbation,
        )
    if run.closed_loop is not None and run.closed_loop.bands:
        draw(
            "closed_loop",
            plots.closed_loop_figure,
            run.results,
            run.robustness.attitude_p95 if run.robustness is not None else {},
            run.closed_loop.bands,
            perturbation=run.closed_loop.options.perturbation,
        )
    if plans:
        draw("joints", plots.joint_limits_figure, plans, run.task.robot)
    free = run.results.get("optimal")
    if free is not None and "timing" in free.info:
        both = {k: v for k, v in plans.items() if k in ("optimal", GIVEN_TIMING)}
        draw("timing", plots.timing_figure, free.info["timing"], both)
    if run.simulations:
        sims = {f"{k}{SIM}": v for k, v in _reference_last(run.simulations).items()}
        draw("simulated_attitude", plots.attitude_figure, sims)
        balanced = {k: v for k, v in run.simulations.items() if k != REFERENCE}
        if balanced:
            draw("torque", plots.reaction_torque_figure, balanced, note=_torque_scales(balanced))
    if run.task.target is not None:
        shown = plans or run.results  # a mission-only run: the mission arm's own motion
        curves = {**shown, **{f"{k}{SIM}": v for k, v in run.simulations.items() if k in shown}}
        draw("capture", plots.capture_figure, curves, run.task.target.time)
    return figures


def _torque_scales(simulations: Mapping[str, Any]) -> str:
    """The caption's words on the torque figure's scales: each plan's largest torque of an arm
    on the base, and how many times the smallest the largest is."""
    peaks = {
        name: max(float(np.abs(w[:, 3:]).max()) for w in sim.arm_wrenches.values())
        for name, sim in simulations.items()
    }
    text = ", ".join(f"{method_label(n)} up to {p:.3g} N m" for n, p in peaks.items())
    if len(peaks) > 1 and min(peaks.values()) > 0:
        ratio = max(peaks.values()) / min(peaks.values())
        text += f": the scales differ {ratio:.3g}x"
    return f" ({text})"


def _reference_last(results: Mapping[str, Any]) -> dict[str, Any]:
    """``results`` with the mission arm alone last (its curve drawn over the plans')."""
    first = {k: v for k, v in results.items() if k != REFERENCE}
    return {**first, **({REFERENCE: results[REFERENCE]} if REFERENCE in results else {})}


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
        for method in (REFERENCE, *methods):
            if method in given:
                log.info("%s: %s plan given, not planned again", task.name, method)
                run.results[method] = given[method]
                if given[method].info.get("success", True) is False:
                    run.failures[method] = f"given plan: solver status {given[method].status}"
            else:
                _plan_into(run, method, solver_options, models, executor)
        run_geometry(run, models)  # the planner's, if it planned
        if robustness:
            _model_error_into(run)
        motions = {n: (r.t, np.hstack([r.q_M, r.q_B])) for n, r in run.results.items()}
        _clearance_into(run, motions, run.clearance)
        if simulate:
            for name in list(run.results):
                if name in given_sims:
                    run.simulations[name] = given_sims[name]
                else:
                    _simulate_into(run, name)
            sims = {name: (sim.t, sim.q) for name, sim in run.simulations.items()}
            _clearance_into(run, sims, run.simulated_clearance)
        if closed_loop:
            _closed_loop_into(run, executor)
        if folder is not None:
            write_run(run, folder.staging)
            run.files = [folder.final(path) for path in run.files]
            run.report = None if run.report is None else folder.final(run.report)
    return run


#: Samples of a motion at most in the clearance figure's curves.
CLEARANCE_CURVE_SAMPLES = 300


def _clearance_into(run: TaskRun, motions: Mapping[str, tuple], into: dict) -> None:
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


def _model_error_into(run: TaskRun) -> None:
    """The drift of every plan replayed on perturbed models (not across a capture, where the
    robot changes mid-motion: the study is left out with a note)."""
    from balance_opt.motion.robustness import drift_under_model_error

    task = run.task
    if task.target is not None:
        log.info("%s: drift under model error not computed across a capture", task.name)
        return
    options = task.spec.robustness
    what = f"drift under {100 * options.perturbation:.0f} % model error ({options.samples} models)"
    with _timed(f"{task.name}: {what}"):
        run.robustness = drift_under_model_error(task.robot, run.results, options, task.h0)


def _closed_loop_into(run: TaskRun, executor) -> None:
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
    with _timed(f"{task.name}: closed loop ({opts.samples} models, period {opts.period:g} s)"):
        run.closed_loop = closed_loop_study(task, plans, executor, geometry)


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
        sim = simulate(task, run.results[name])
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
