"""One case of a task sweep, in a worker process: build its task, plan it (optionally simulate),
return the metrics of ``metrics.json``. Each worker keeps one ``ModelCache``
(:data:`WORKER_MODELS`): what cases vary enters the NLP as parameters, so no rebuild."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from balance_opt.app.models import ModelCache
from balance_opt.model.robot import urdf_warnings_shown

logger = logging.getLogger(__name__)

#: The planner models of this worker process (the process is the worker: one cache each).
WORKER_MODELS = ModelCache()


#: RK4 steps of the mission-only baseline over the mission: as accurate as the reference of
#: ``plan --method mission-only`` for a table, at a fraction of its cost.
BASELINE_STEPS = 200


def mission_only_baseline(task) -> dict:
    """The base drift of the case's mission with the balance arms held (a kinematic replay of
    :data:`BASELINE_STEPS` RK4 steps): ``max_drift_rad``, ``final_drift_rad``,
    ``max_base_rate_rad_s``."""
    from balance_opt.motion.options import IntegrationOptions
    from balance_opt.motion.replay import phase_one

    step = task.mission.duration / BASELINE_STEPS
    steps = IntegrationOptions(method="rk4", output_step=step)
    result = phase_one(task.robot, task.mission, task.q_B0, h0=task.h0, integration=steps)
    summary = result.summary()
    return {
        key: summary[key] for key in ("max_drift_rad", "final_drift_rad", "max_base_rate_rad_s")
    }


def run_task_case(case: dict, models: ModelCache | None = None) -> dict:
    """The case function of task sweeps: ``{"status", "metrics", "error", "info", "timing"}``,
    status ``ok`` or ``solver_failed`` (with the metrics computed before the failure); other
    errors are raised, and recorded by the engine."""
    models = WORKER_MODELS if models is None else models
    with urdf_warnings_shown():  # by the sweep's load of its task
        return _run_task_case(case, models)


def _run_task_case(case: dict, models: ModelCache) -> dict:
    from balance_opt.app.pipeline import plan, simulate
    from balance_opt.errors import SolverError
    from balance_opt.report.outputs import method_metrics
    from balance_opt.sweep.engine import STATUS_OK, STATUS_SOLVER_FAILED, error_record
    from balance_opt.tasks.task import task_from_dict

    start = time.perf_counter()
    task = task_from_dict(case["task"], Path(case["base_dir"]), source=f"case {case['index']}")
    loaded = time.perf_counter()
    try:
        result = plan(task, case["method"], case.get("solver_options"), models=models)
        status, error = STATUS_OK, None
    except SolverError as exc:
        if exc.result is None:
            raise
        result, status, error = exc.result, STATUS_SOLVER_FAILED, error_record(exc)
    planned = time.perf_counter()
    baseline = mission_only_baseline(task)
    replayed = time.perf_counter()
    simulation = simulate(task, result) if case.get("simulate") else None
    metrics = method_metrics(result, task.robot, simulation, task.h0)
    done = time.perf_counter()
    timing = {
        "load_s": loaded - start,
        "plan_s": planned - loaded,
        "baseline_s": replayed - planned,
        "metrics_s": done - replayed,
    }
    details = result.details()  # a capture's: both phases' solver work
    wall = details.get("wall_time_s")
    if isinstance(wall, dict):  # the optimal planner's own split: build, setup, guess, solve, ...
        timing.update({f"planner_{k}_s": float(v) for k, v in wall.items()})
    if "total_solve_time_s" in details:  # every Ipopt solve (``planner_solve_s``: the last)
        timing["planner_ipopt_s"] = float(details["total_solve_time_s"])
    return {
        "status": status,
        "error": error,
        "metrics": metrics,
        "info": {"mission_only": baseline},
        "timing": timing,
    }
