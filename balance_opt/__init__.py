"""balance-opt: balance-arm motion planning for free-floating multi-arm space robots.

The stages, one subpackage each, are mapped in ``docs/architecture.md``. The notebook API is at
the top level::

    import balance_opt as bo

    task = bo.load_task("examples/capture_task.yaml")
    analytic = bo.plan_analytic(task)                   # a BalanceResult
    optimal = bo.plan_optimal(task, warm_start=analytic)
    run = bo.run_task(task, plans={"analytic": analytic, "optimal": optimal})

Importing the package loads the robot model (Pinocchio), not CasADi, pandas or matplotlib: the
names below are imported from their modules when first used (module ``__getattr__``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from balance_opt.errors import BalanceOptError, InputError, SolverError
from balance_opt.model.library import baxter_floating, paper_robot
from balance_opt.model.limits import JointLimits
from balance_opt.model.robot import Arm, FloatingRobot

__version__ = "0.1.0"

#: Public names imported on first use: ``name -> module``.
_LAZY = {
    "BalanceResult": "balance_opt.motion.result",
    "LimitViolation": "balance_opt.motion.result",
    "Task": "balance_opt.tasks.task",
    "load_task": "balance_opt.tasks.task",
    "task_from_dict": "balance_opt.tasks.task",
    "TaskRun": "balance_opt.app.task_run",
    "plan_mission_only": "balance_opt.app.pipeline",
    "plan_analytic": "balance_opt.app.pipeline",
    "plan_optimal": "balance_opt.app.pipeline",
    "simulate": "balance_opt.app.pipeline",
    "run_task": "balance_opt.app.pipeline",
    "SimulationResult": "balance_opt.dynamics.simulation",
    "plot_result": "balance_opt.report.plots",
}

if TYPE_CHECKING:  # for type checkers and editors; at run time __getattr__ imports them
    from balance_opt.app.pipeline import (
        plan_analytic,
        plan_mission_only,
        plan_optimal,
        run_task,
        simulate,
    )
    from balance_opt.app.task_run import TaskRun
    from balance_opt.dynamics.simulation import SimulationResult
    from balance_opt.motion.result import BalanceResult, LimitViolation
    from balance_opt.report.plots import plot_result
    from balance_opt.tasks.task import Task, load_task, task_from_dict


def __getattr__(name: str) -> Any:
    """Import a public name of :data:`_LAZY` from its module on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'balance_opt' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = sorted(
    [
        "Arm",
        "BalanceOptError",
        "FloatingRobot",
        "InputError",
        "JointLimits",
        "SolverError",
        "__version__",
        "baxter_floating",
        "paper_robot",
        *_LAZY,
    ]
)
