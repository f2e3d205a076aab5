"""A run's files: trajectories (CSV, NPZ), ``metrics.json``, the figures (their names,
captions and order), the 3D scene and the HTML report."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.app.run_studies import run_geometry
from balance_opt.app.task_run import GIVEN_TIMING, REFERENCE, TaskRun, timed
from balance_opt.errors import InputError
from balance_opt.report import plots
from balance_opt.report.style import SCREEN_DPI, SIM, method_label, save

log = logging.getLogger(__name__)


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
        with timed("figures"):
            figures = write_figures(run, output_dir)
    if out.plots:
        files.extend(path for _, path in figures)
    if out.report:
        from balance_opt.report.report import render_report

        extra, scene = _report_sections(run, output_dir)
        torque_curves = {name: (res.t, torques[name]) for name, res in run.results.items()}
        about = run.task.spec.description
        run.report = output_dir / REPORT_FILE
        page = render_report(run.metrics, figures, about, extra, torque_curves)
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
        "<code>balance-opt view</code> opens it).</p>"
        f'<iframe src="{SCENE_FILE}" title="3D scene" style="width:100%;height:600px;'
        'border:1px solid #ddd"></iframe>'
    ), scene


def write_run_scene(run: TaskRun, path: Path) -> Path:
    """The 3D scene of every plan of ``run`` (:mod:`balance_opt.report.scene`) written to
    ``path``."""
    from balance_opt.report.scene import build_scene, write_scene

    task = run.task
    labels = {
        name: method_label(name) + (" (FAILED)" if name in run.failures else "")
        for name in run.results
    }
    geometry = run_geometry(run)  # the run's own when it checked clearance
    with timed("3D scene"):
        scene = build_scene(
            task.robot, run.results, task.h0, task.target, labels, geometry=geometry or None,
            margin=task.spec.optimal.planner.collision_margin,
        )  # fmt: skip
        return write_scene(path, scene, task.name)


def write_figures(run: TaskRun, output_dir: Path) -> list[tuple[str, Path]]:
    """The PNG figures of a run at the report's resolution (PNG only: the report embeds them,
    and ``paper-figures`` writes the PDFs for print), as ``(caption, path)`` pairs in the
    report's order."""
    figures = []

    def draw(key, function, *args, note="", **kwargs):
        stem, caption = FIGURES[key]
        [path] = save(function(*args, **kwargs), output_dir / stem, ("png",), SCREEN_DPI)
        figures.append((caption + note, path))

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
    timing = free.details().get("timing") if free is not None else None  # a plan read back too
    if timing is not None:
        both = {k: v for k, v in plans.items() if k in ("optimal", GIVEN_TIMING)}
        draw("timing", plots.timing_figure, timing, both)
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
