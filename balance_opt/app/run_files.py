"""The files of a run (:func:`balance_opt.app.pipeline.run_task`): trajectories (CSV, NPZ),
``metrics.json``, the figures, the 3D scene and the HTML report, written into a folder (the
staging folder of an all-or-nothing run), and the stage timing of the run's log.
"""

from __future__ import annotations

import contextlib
import logging
import time

import numpy as np
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from balance_opt.result import BalanceResult
    from balance_opt.tasks.task import Task

log = logging.getLogger("balance_opt.app.pipeline")  # the run's log: one logger

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
            (:func:`capture_geometry`).
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
    from balance_opt.report.outputs import run_metrics, write_metrics

    out = run.task.spec.outputs
    output_dir.mkdir(parents=True, exist_ok=True)
    torques = {  # the NPZ files, the metrics and the report each use them
        name: plan_joint_torques(res, run.task.robot, run.task.h0)
        for name, res in run.results.items()
    }
    files = _write_trajectories(run, output_dir, torques)
    run.metrics = run_metrics(
        run.task,
        run.results,
        run.simulations,
        run.failures,
        torques,
        run.robustness,
        {name: c[0] for name, c in run.clearance.items()},
        {name: c[0] for name, c in run.simulated_clearance.items()},
        _geometry_summary(run),
    )
    files.append(write_metrics(output_dir / METRICS_FILE, run.metrics))
    figures = []
    if out.plots or out.report:
        with _timed("figures"):
            figures = write_figures(run, output_dir)
    if out.plots:
        files.extend(path for _, path in figures)
    if out.report:
        from balance_opt.report.report import write_report

        extra, scene = _report_sections(run, output_dir)
        timed = {name: (res.t, torques[name]) for name, res in run.results.items()}
        about = run.task.spec.description
        run.report = write_report(
            output_dir / REPORT_FILE, run.metrics, figures, about, extra, timed
        )
        files += [run.report] + ([scene] if scene is not None else [])
        if not out.plots:
            for _, path in figures:
                path.unlink()
    run.files = files
    return files


def _geometry_summary(run: TaskRun) -> dict | None:
    """What the run's clearance check held apart and the pairs close at the start (``None``
    without geometry)."""
    if not run.geometry:
        return None
    margin = run.task.spec.optimal.planner.collision_margin
    return run.geometry.summary(run.task.q0, margin)


def _write_trajectories(run: TaskRun, output_dir: Path, torques: dict) -> list[Path]:
    """The CSV and NPZ files of every plan (the NPZ with the plan's joint ``torques``)."""
    from balance_opt.report.outputs import write_trajectory_csv, write_trajectory_npz

    out, files = run.task.spec.outputs, []
    for name, res in run.results.items():
        if out.csv:
            files.append(write_trajectory_csv(output_dir / f"{name}.csv", res))
        if out.npz:
            npz = output_dir / f"{name}.npz"
            files.append(write_trajectory_npz(npz, res, torques[name]))
    return files


def _report_sections(run: TaskRun, output_dir: Path) -> tuple[str, Path | None]:
    """The report's 3D section (the scene, written beside it) and the scene's file (None: not
    written)."""
    from balance_opt.errors import InputError

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


def run_geometry(run: TaskRun):
    """The run's robot geometry (:class:`~balance_opt.geometry.robot_geometry.RobotGeometry`),
    built once and kept on ``run.geometry``; ``False`` for a robot without geometry (a log line
    says so) or whose geometry does not load (a missing mesh: a warning)."""
    from balance_opt.errors import InputError
    from balance_opt.geometry.robot_geometry import NoGeometryError, RobotGeometry

    if run.geometry is None:
        planner = run.task.spec.optimal.planner
        try:
            run.geometry = RobotGeometry(
                run.task.robot, srdf=planner.collision_srdf, ignore=planner.collision_ignore
            )
        except NoGeometryError as exc:
            log.info("%s: no clearance check: %s", run.task.name, exc)
            run.geometry = False
        except InputError as exc:  # a mesh file missing: the plans still count
            log.warning("%s: no clearance check: %s", run.task.name, exc)
            run.geometry = False
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
        geometry = RobotGeometry(
            run.task.robot_after_capture,
            srdf=run.geometry.srdf or False,
            ignore=run.task.spec.optimal.planner.collision_ignore,
        )
        pairs = [p.index for p in geometry.pairs if TARGET_LINK in p.links]
        run.geometry_after = (geometry, pairs)
    return run.geometry_after


def write_run_scene(run: TaskRun, path: Path) -> Path:
    """The 3D scene of every plan of ``run`` (:mod:`balance_opt.report.scene`) written to
    ``path``."""
    from balance_opt.report.style import method_label
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
    """PNG figures of a run at one resolution (:data:`~balance_opt.report.style.SCREEN_DPI`, the
    report's): the plans' attitude with the mission arm alone, the balance joints against their
    limits and, when simulated, the simulated attitude and the torques on the base. PNG only:
    the report embeds them, and ``paper-figures`` writes the PDFs for print. Returns
    ``(caption, path)`` pairs, in the report's order."""
    from balance_opt.report.plots import attitude_figure, reaction_torque_figure
    from balance_opt.report.report_figures import joint_limits_figure
    from balance_opt.report.style import SCREEN_DPI, SIM

    def draw(key, function, curves):
        stem, caption = FIGURES[key]
        _, paths = function(curves, output_dir / stem, formats=("png",), dpi=SCREEN_DPI)
        figures.append((caption, paths[0]))

    figures = []
    plans = {k: v for k, v in run.results.items() if k != REFERENCE}
    draw("attitude", attitude_figure, {**plans, **_only(run.results, REFERENCE)})
    if run.clearance:
        from balance_opt.report.plots import clearance_figure

        planner = run.task.spec.optimal.planner
        margin = planner.collision_margin if planner.collision_avoidance else None
        curves = {name: (c[1], c[2]) for name, c in run.clearance.items()}
        curves = {**{k: v for k, v in curves.items() if k != REFERENCE}, **_only(curves, REFERENCE)}
        stem, caption = FIGURES["clearance"]
        _, paths = clearance_figure(
            curves, margin, output_dir / stem, formats=("png",), dpi=SCREEN_DPI
        )
        figures.append((caption, paths[0]))
    if run.robustness is not None:
        from balance_opt.report.plots import model_error_figure

        stem, caption = FIGURES["model_error"]
        _, paths = model_error_figure(
            {**plans, **_only(run.results, REFERENCE)},
            run.robustness.attitude_p95,
            output_dir / stem,
            perturbation=run.robustness.options.perturbation,
            formats=("png",),
            dpi=SCREEN_DPI,
        )
        figures.append((caption, paths[0]))
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
            figures[-1] = (figures[-1][0] + _torque_scales(balanced), figures[-1][1])
    if run.task.target is not None:  # issue 16
        from balance_opt.report.capture_figures import CAPTION, capture_figure

        curves = {**plans, **{f"{k}{SIM}": v for k, v in run.simulations.items() if k in plans}}
        path = capture_figure(curves, run.task.target.time, output_dir / "capture.png")
        figures.append((CAPTION, path))
    return figures


def _torque_scales(simulations: Mapping[str, Any]) -> str:
    """The caption's words on the torque figure's scales: each plan's largest torque of an arm
    on the base, and how many times the smallest the largest is."""
    from balance_opt.report.style import method_label

    peaks = {
        name: max(float(np.abs(w[:, 3:]).max()) for w in sim.arm_wrenches.values())
        for name, sim in simulations.items()
    }
    text = ", ".join(f"{method_label(n)} up to {p:.3g} N m" for n, p in peaks.items())
    if len(peaks) > 1 and min(peaks.values()) > 0:
        ratio = max(peaks.values()) / min(peaks.values())
        text += f": the scales differ {ratio:.3g}x"
    return f" ({text})"


def _only(results: Mapping[str, Any], name: str) -> dict[str, Any]:
    return {name: results[name]} if name in results else {}
