"""What one case of a task sweep does, in a worker process: build its task, plan it with its
method (optionally simulate the plan), and return the metrics of ``metrics.json`` as plain data.

Each worker keeps one :class:`~balance_opt.app.models.ModelCache` (:data:`WORKER_MODELS`) for its
life. What cases vary enters the NLP as parameters and bounds, so a new case of a known
structure costs no build."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from balance_opt.app.models import ModelCache

logger = logging.getLogger(__name__)

#: The planner models of this worker process (the process is the worker: one cache each).
WORKER_MODELS = ModelCache()


#: RK4 steps of the mission-only baseline over the mission: as accurate as the reference of
#: ``plan --method mission-only`` for a table, at a fraction of its cost.
BASELINE_STEPS = 200


def mission_only_baseline(task) -> dict:
    """The base drift the case's mission causes with the balance arms held at their start: a
    kinematic replay (momentum conservation, RK4 on :data:`BASELINE_STEPS` steps), the
    reference every plan of the case is compared with. Plain data: ``max_drift_rad``,
    ``final_drift_rad``, ``max_base_rate_rad_s``."""
    from balance_opt.analytic.phases import phase_one
    from balance_opt.motion.options import IntegrationOptions

    step = task.mission.duration / BASELINE_STEPS
    steps = IntegrationOptions(method="rk4", output_step=step)
    result = phase_one(task.robot, task.mission, task.q_B0, h0=task.h0, integration=steps)
    summary = result.summary()
    return {
        key: summary[key] for key in ("max_drift_rad", "final_drift_rad", "max_base_rate_rad_s")
    }


def run_task_case(case: dict, models: ModelCache | None = None) -> dict:
    """The case function of task sweeps (see :func:`balance_opt.sweep.engine.execute_case`).

    Returns:
        ``{"status", "metrics", "error", "info", "timing"}``: status ``ok``, or
        ``solver_failed`` with the metrics of what the method computed before it failed;
        ``info["mission_only"]`` is :func:`mission_only_baseline`. Other errors are raised, and
        recorded by the engine.
    """
    from balance_opt.app.pipeline import plan, simulate_result
    from balance_opt.errors import SolverError
    from balance_opt.report.outputs import method_metrics
    from balance_opt.sweep.engine import STATUS_OK, STATUS_SOLVER_FAILED, error_record
    from balance_opt.tasks.task import task_from_dict

    models = WORKER_MODELS if models is None else models
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
    simulation = simulate_result(task, result) if case.get("simulate") else None
    metrics = method_metrics(result, task.robot, simulation)
    done = time.perf_counter()
    timing = {
        "load_s": loaded - start,
        "plan_s": planned - loaded,
        "baseline_s": replayed - planned,
        "metrics_s": done - replayed,
    }
    wall = result.info.get("wall_time_s")
    if isinstance(wall, dict):  # the optimal planner's own split: build, setup, guess, solve, ...
        timing.update({f"planner_{k}_s": float(v) for k, v in wall.items()})
    if "total_solve_time_s" in result.info:  # every Ipopt solve (``planner_solve_s``: the last)
        timing["planner_ipopt_s"] = float(result.info["total_solve_time_s"])
    return {
        "status": status,
        "error": error,
        "metrics": metrics,
        "info": {"mission_only": baseline},
        "timing": timing,
    }
