"""What one case of a task sweep does, in a worker process: build its task, plan it with its
method (optionally simulate the plan), and return the metrics of ``metrics.json`` as plain data.

Each worker process keeps, for the life of the process, one
:class:`~balance_opt.optimal.model.PlannerModel` per robot (URDF, arms, locked joints): the symbolic
model is built once, and so is each compiled NLP structure (intervals, transcription, control,
constraint switches, solver options; :func:`~balance_opt.optimal.solve.build_balance_nlp` caches them
on the model). What the cases vary (mission, horizon, initial configuration, weights, limits)
enters the NLP as parameters and bounds: a new case of a known structure costs no build.

The joint limits belong to the robot object, and a case that varies them builds its own robot;
it then shares the cached model's symbolic functions and compiled NLPs through a shallow copy
of the model whose ``robot`` is the case's (the NLP reads the limits from ``model.robot`` as
numeric bounds only).
"""

from __future__ import annotations

import copy
import logging
import time
from pathlib import Path
from typing import Any

from balance_opt.sweep.spec import canonical_json

logger = logging.getLogger(__name__)

#: Planner models kept per worker process, keyed by the robot's kinematic description.
_MODELS: dict[str, Any] = {}
#: Task sections that define the robot's kinematics and inertia (not its limits).
ROBOT_SECTIONS = ("robot", "arms")


def robot_key(task_data: dict, base_dir: str) -> str:
    """Cache key of a task's robot: its URDF, arms, locked joints and end-effector frames."""
    return canonical_json(
        {"base_dir": str(base_dir), **{k: task_data.get(k) for k in ROBOT_SECTIONS}}
    )


def planner_model_for(task, key: str):
    """The worker's planner model of the task's robot (built on first use), bound to
    ``task.robot`` (see the module docstring)."""
    from balance_opt.optimal.model import PlannerModel

    model = _MODELS.get(key)
    if model is None:
        start = time.perf_counter()
        model = _MODELS[key] = PlannerModel(task.robot)
        logger.debug(
            "planner model of %s built in %.3f s", task.robot.name, time.perf_counter() - start
        )
    if model.robot is task.robot:
        return model
    view = copy.copy(model)  # shares maps, compiled functions and the NLP cache
    view.robot = task.robot
    return view


def plan_case(task, method: str, solver_options: dict | None = None):
    """Plan ``task`` with ``method`` as ``balance-opt plan`` does (:mod:`balance_opt.app.pipeline`),
    with the worker's cached planner model for the optimal method.

    Returns:
        The :class:`~balance_opt.result.BalanceResult`.

    Raises:
        SolverError: the method failed; its ``result`` holds what was computed.
        InputError: options the task's robot cannot take.
    """
    if method == "analytic":
        from balance_opt.app.pipeline import plan_analytic

        return plan_analytic(task)
    if method == "optimal":
        # pipeline.plan_optimal, with this worker's model cache (the pipeline keeps one model
        # per robot object, and every case builds its own robot)
        from balance_opt.io.task import check_optimal_supported
        from balance_opt.optimal.solve import build_balance_nlp

        check_optimal_supported(task)
        spec = task.spec.optimal
        model = planner_model_for(task, robot_key(task.document.data, str(task.base_dir)))
        nlp = build_balance_nlp(
            model, task.mission, task.q_B0, spec.planner_options(solver_options)
        )
        return nlp.solve(spec.initial_guess)
    raise ValueError(f"unknown method '{method}'; expected analytic or optimal")


def _metrics(result, task, simulate: bool) -> dict:
    from balance_opt.io.outputs import method_metrics

    simulation = None
    if simulate:
        from balance_opt.app.pipeline import simulate_result

        simulation = simulate_result(task, result)
    return method_metrics(result, task.robot, simulation)


def run_task_case(case: dict) -> dict:
    """The case function of task sweeps (see :func:`balance_opt.sweep.engine.execute_case`).

    Args:
        case: plain data with ``task`` (the task's content, with the case's parameters),
            ``base_dir`` (relative paths of the task), ``method``, ``simulate``,
            ``solver_options`` and ``index``.

    Returns:
        ``{"status", "metrics", "error", "timing"}``: status ``ok``, or ``solver_failed`` with the
        metrics of what the method computed before it failed and the error (type, message).
        Other errors are raised, and recorded by the engine.
    """
    from balance_opt.errors import SolverError
    from balance_opt.io.task import task_from_dict
    from balance_opt.sweep.engine import STATUS_OK, STATUS_SOLVER_FAILED, error_record

    start = time.perf_counter()
    task = task_from_dict(case["task"], Path(case["base_dir"]), source=f"case {case['index']}")
    loaded = time.perf_counter()
    try:
        result = plan_case(task, case["method"], case.get("solver_options"))
        status, error = STATUS_OK, None
    except SolverError as exc:
        if exc.result is None:
            raise
        result, status, error = exc.result, STATUS_SOLVER_FAILED, error_record(exc)
    planned = time.perf_counter()
    metrics = _metrics(result, task, bool(case.get("simulate")))
    done = time.perf_counter()
    timing = {"load_s": loaded - start, "plan_s": planned - loaded, "metrics_s": done - planned}
    wall = result.info.get("wall_time_s")
    if isinstance(wall, dict):  # the optimal planner's own split: build, setup, guess, solve, ...
        timing.update({f"planner_{k}_s": float(v) for k, v in wall.items()})
    return {"status": status, "error": error, "metrics": metrics, "timing": timing}
