"""``balance-opt paper-figures``: the paper's study (:mod:`balance_opt.app.study`) written to an
output folder all-or-nothing, as :func:`balance_opt.app.pipeline.run_task` writes its outputs."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from balance_opt.app.run_files import _timed
from balance_opt.interrupts import handling_signals
from balance_opt.report.output_dir import OutputFolder
from balance_opt.tasks.task import Task


def paper_figures(
    output_dir: str | Path | OutputFolder,
    task: Task | None = None,
    solver_options: Mapping[str, Any] | None = None,
    force: bool = False,
    backend: str | None = None,
) -> list[Path]:
    """The paper's study (Figs. 2-5, :func:`balance_opt.app.study.paper_study`) written to
    ``output_dir``, all-or-nothing as :func:`run_task` writes: by default Figs. 2-5 of the
    paper's law on ``paper_fig5`` and the law against the optimal plan on ``capture_task``,
    each in a subfolder; with ``task``, Figs. 2-5 of that task (its robot, mission, balance
    start and options), both methods, in a subfolder of its name. ``backend`` (the optimal
    planner's symbolic backend) defaults to the task's ``robot.backend``, else ``"auto"``.

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
        if backend is None:
            backend = task.spec.robot.backend if task is not None else "auto"
        study = paper_study(folder.staging, backend=backend, **kwargs)
        files = [p for paths in study.figures.values() for p in paths]
        jsons = [folder.staging / name / "study.json" for name in study.parts]
        return [folder.final(p) for p in (*files, *jsons, folder.staging / "study.json")]
