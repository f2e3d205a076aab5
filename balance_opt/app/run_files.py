"""The files of a run (:func:`balance_opt.app.pipeline.run_task`): trajectories (CSV, NPZ),
``metrics.json``, the figures, the animation and the HTML report, written into a folder (the
staging folder of an all-or-nothing run), and the stage timing of the run's log.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from balance_opt.app.background import RunWorker
    from balance_opt.app.pipeline import TaskRun

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


@contextlib.contextmanager
def _timed(what: str):
    """Log ``what ...``, then ``what: done in X s`` when the block ends without error."""
    log.info("%s ...", what)
    start = time.perf_counter()
    yield
    log.info("%s: done in %.2f s", what, time.perf_counter() - start)


# =========================================================================================== writing
def write_run(run: TaskRun, output_dir: Path, worker: RunWorker | None = None) -> list[Path]:
    """Write the trajectories, ``metrics.json``, the figures and the report of ``run``; the
    ``worker`` draws the figures meanwhile."""
    from balance_opt.io.outputs import run_metrics, write_metrics

    out = run.task.spec.outputs
    output_dir.mkdir(parents=True, exist_ok=True)
    drawing = out.plots or out.report
    if drawing and worker is not None:  # the rest of them if it drew the plans' already
        part = "simulations" if worker.has_figures("plans") else "all"
        worker.submit_figures(part, write_figures, run, output_dir, part)
    files = _write_trajectories(run, output_dir)
    run.metrics = run_metrics(run.task, run.results, run.simulations, run.failures)
    files.append(write_metrics(output_dir / METRICS_FILE, run.metrics))
    if drawing and worker is None:
        with _timed("figures"):
            figures = write_figures(run, output_dir)
    report_parts = _report_parts(run, output_dir) if out.report else None
    if drawing and worker is not None:
        figures, seconds = [], 0.0
        for part in ("plans", "simulations", "all"):
            if worker.has_figures(part):
                drawn, took = worker.figures(part)
                figures, seconds = figures + drawn, seconds + took
        log.info("figures: done in %.2f s (worker process)", seconds)
    if out.plots:
        files.extend(path for _, path in figures)
    if out.report:
        from balance_opt.io.report import write_report

        about = run.task.spec.description
        extra, torques, scene = report_parts
        run.report = write_report(
            output_dir / REPORT_FILE, run.metrics, figures, about, extra, torques
        )
        files += [run.report] + ([scene] if scene is not None else [])
        if not out.plots:
            for _, path in figures:
                path.unlink()
    run.files = files
    return files


def _write_trajectories(run: TaskRun, output_dir: Path) -> list[Path]:
    """The CSV and NPZ files of every plan."""
    from balance_opt.io.outputs import write_trajectory_csv, write_trajectory_npz

    out, files = run.task.spec.outputs, []
    for name, res in run.results.items():
        if out.csv:
            files.append(write_trajectory_csv(output_dir / f"{name}.csv", res))
        if out.npz:
            npz = output_dir / f"{name}.npz"
            files.append(write_trajectory_npz(npz, res, run.task.robot, run.task.h0))
    return files


def _report_parts(run: TaskRun, output_dir: Path) -> tuple[str, dict, Path | None]:
    """The report's 3D sections (the scene written beside it, the stick-figure animation), the
    joint torques of every plan and the scene's file (None: not written)."""
    from balance_opt.errors import InputError
    from balance_opt.io.outputs import plan_joint_torques

    extra, scene = "", None
    if run.task.spec.outputs.animation:
        try:
            scene = write_run_scene(run, output_dir / SCENE_FILE)
        except InputError as exc:  # a mesh file missing: the rest of the run still counts
            log.warning("3D scene not written: %s", exc)
        extra = _animation_section(run, scene is not None)
    torques = {
        name: (res.t, plan_joint_torques(res, run.task.robot, run.task.h0))
        for name, res in run.results.items()
    }
    return extra, torques, scene


def _animation_section(run: TaskRun, scene: bool) -> str:
    """The report's 3D animation of every plan (see :mod:`balance_opt.io.animation`)."""
    from balance_opt.io.animation import animation_html
    from balance_opt.io.plots import plan_colour, plan_label

    names = list(run.results)
    colours = {name: plan_colour(name, i) for i, name in enumerate(names)}
    labels = {name: plan_label(name) for name in names}
    with _timed("animation"):
        body = animation_html(run.task.robot, run.results, run.task.h0, colours, labels)
    frame = (
        '<h2 id="scene">3D scene</h2><p class="meta">The robot\'s own geometry moving through '
        f'each plan (<a href="{SCENE_FILE}">{SCENE_FILE}</a>, a page of its own; '
        "<code>balance-opt view</code> serves it).</p>"
        f'<iframe src="{SCENE_FILE}" title="3D scene" style="width:100%;height:600px;'
        'border:1px solid #ddd"></iframe>'
    )
    return (frame if scene else "") + (
        '<h2>Animation</h2><p class="meta">The robot as a stick figure (base axes: red x, green y, '
        "blue z), base pose from the plan; drag to turn the view.</p>" + body
    )


def write_run_scene(run: TaskRun, path: Path) -> Path:
    """The 3D scene of every plan of ``run`` (:mod:`balance_opt.io.scene`) written to ``path``."""
    from balance_opt.io.plots import plan_label
    from balance_opt.io.scene import write_scene

    labels = {
        name: plan_label(name) + (" (FAILED)" if name in run.failures else "")
        for name in run.results
    }
    with _timed("3D scene"):
        return write_scene(
            path, run.task.robot, run.results, run.task.h0, run.task.target, labels, run.task.name
        )


def write_figures(run: TaskRun, output_dir: Path, part: str = "all") -> list[tuple[str, Path]]:
    """PNG figures of a run at one resolution (:data:`~balance_opt.io.style.SCREEN_DPI`, the
    report's): the plans' attitude with the mission arm alone, the balance joints against their
    limits and, when simulated, the simulated attitude and the torques on the base. PNG only:
    the report embeds them, and ``paper-figures`` writes the PDFs for print. ``part``
    ``"plans"`` draws the first two only, ``"simulations"`` the others (the run's worker draws
    the first while the plans are simulated). Returns ``(caption, path)`` pairs, in the
    report's order."""
    from balance_opt.io.plots import attitude_figure, reaction_torque_figure
    from balance_opt.io.report_figures import joint_limits_figure
    from balance_opt.io.style import SCREEN_DPI, SIM

    def draw(key, function, curves):
        stem, caption = FIGURES[key]
        _, paths = function(curves, output_dir / stem, formats=("png",), dpi=SCREEN_DPI)
        figures.append((caption, paths[0]))

    figures = []
    plans = {k: v for k, v in run.results.items() if k != REFERENCE}
    if part != "simulations":
        draw("attitude", attitude_figure, {**plans, **_only(run.results, REFERENCE)})
        if plans:
            stem, caption = FIGURES["joints"]
            path = joint_limits_figure(
                plans, run.task.robot, output_dir / f"{stem}.png", SCREEN_DPI
            )
            figures.append((caption, path))
        if part == "plans":
            return figures
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
