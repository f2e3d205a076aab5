"""Multi-start (:func:`balance_opt.optimal.refine.multi_start`): starts whose first plans agree are merged,
the plan kept is the best objective among the starts, the outcome is the same whether the
starts run in this process or in a process pool, and Ctrl-C ends a multi-start at once.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import time

import numpy as np
import psutil
import pytest

from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp


def test_first_plans_are_one_within_the_state_and_control_tolerances():
    from balance_opt.optimal.layout import Solution
    from balance_opt.optimal.refine import (
        SAME_CONTROL,
        SAME_PLAN,
        IntegralStart,
        SolveReport,
        same_first_plan,
    )

    def first(dx=0.0, du=0.0, status="Solve_Succeeded"):
        X, U = np.zeros((9, 5)), np.ones((3, 5))
        X[4, 2] += dx
        U[1, 3] += du
        sol = Solution(X, U)
        return IntegralStart(SolveReport("integral", 4, status, 10, 0.1, 1.0, sol), sol)

    assert same_first_plan(first(), first(0.9 * SAME_PLAN, -0.9 * SAME_CONTROL))
    assert not same_first_plan(first(), first(1.1 * SAME_PLAN))
    assert not same_first_plan(first(), first(du=-1.1 * SAME_CONTROL))
    # a first stage that failed joins no other
    assert not same_first_plan(first(), first(status="Maximum_Iterations_Exceeded"))


@pytest.mark.slow
@pytest.mark.parametrize("objective", ["integral", "peak"])
def test_multi_start_is_the_same_in_this_process_and_in_a_pool(capture, objective):
    """The starts mapped over a process pool give the starts, merges and plan of the starts
    solved here in turn; the plan kept is the best objective among the starts."""
    from balance_opt.optimal.model import PlannerModel

    model = PlannerModel(capture.robot)
    options = PlannerOptions(intervals=20, objective=objective, starts=3, seed=3)
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    alone = nlp.solve()
    spawn = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(2, mp_context=spawn) as pool:
        shared = nlp.solve(executor=pool)
    runs = alone.solver.starts["runs"]
    assert [r["guess"] for r in runs] == ["analytic", "rest", "random"]
    objectives = [r["objective"] for r in runs if "objective" in r]
    assert alone.solver.solves[-1].objective == min(objectives)
    # the same plans; to the last bit when both processes run the same compiled kernels (not
    # while this one runs them on CasADi's VM as a fresh cache compiles them): 1e-7
    for a, b in zip(runs, shared.solver.starts["runs"], strict=True):
        assert a.get("same_as") == b.get("same_as") and a["status"] == b["status"]
        assert a["objective"] == pytest.approx(b["objective"], rel=1e-7)
    assert shared.max_drift == pytest.approx(alone.max_drift, rel=1e-7)


@pytest.mark.slow
def test_ctrl_c_on_a_multi_start_exits_130_without_orphans(tmp_path):
    """Ctrl-C (SIGINT to the whole process group) while a multi-start is inside Ipopt: exit 130
    within seconds, no process of it left."""
    import signal
    import subprocess

    from test_interrupts import IPOPT_ITERATION, SLOW_IPOPT, START_TIMEOUT, _cli, _fast_task

    task = _fast_task(tmp_path, intervals=40)
    task.write_text(task.read_text().replace("{intervals: 40}", "{intervals: 40, starts: 4}"))
    args = ["plan", str(task), "-m", "optimal", "-o", str(tmp_path / "out"), "-v"]
    for option in SLOW_IPOPT:
        args += ["--solver-option", option]
    proc = subprocess.Popen(
        _cli(*args),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        bufsize=1,
        start_new_session=True,
    )
    descendants: list = []
    try:
        deadline = time.monotonic() + START_TIMEOUT
        iterations = 0
        for line in proc.stdout:
            if IPOPT_ITERATION.match(line):
                iterations += 1
            descendants = psutil.Process(proc.pid).children(recursive=True)
            if iterations >= 20:
                break
            assert time.monotonic() < deadline, "no multi-start under way"
        os.killpg(proc.pid, signal.SIGINT)
        start = time.monotonic()
        _, stderr = proc.communicate(timeout=30)
        assert time.monotonic() - start < 10
        assert proc.returncode == 130, stderr
        assert stderr.rstrip().splitlines()[-1] == "balance-opt: interrupted"
        assert psutil.wait_procs(descendants, timeout=10)[1] == []
        assert not (tmp_path / "out").exists()
    finally:
        for p in [proc, *descendants]:
            try:
                p.kill()
            except (psutil.NoSuchProcess, ProcessLookupError):
                pass


def test_the_sweep_engine_maps_over_its_worker_processes_in_order():
    """The local pool engine is the executor ``balance-opt plan`` hands the starts to: its
    ``map`` runs in its worker processes, not this one, and returns in the order given."""
    import operator

    from balance_opt.sweep.engine import LocalPoolEngine

    with LocalPoolEngine(2) as engine:
        squares = list(engine.map(pow, range(5), [2] * 5))
        pids = set(engine.map(operator.call, [os.getpid] * 4))
    assert squares == [0, 1, 4, 9, 16]
    assert pids and os.getpid() not in pids


@pytest.mark.slow
def test_run_task_hands_the_starts_to_the_executor_it_is_given():
    """``run_task(executor=...)`` maps the optimal planner's starts over that executor (the CLI
    passes the sweep engine's pool): a recording executor sees both phases of every start."""
    from pathlib import Path

    import yaml

    from balance_opt.app.pipeline import run_task
    from balance_opt.tasks.task import task_from_dict

    class Recording:
        def __init__(self):
            self.phases = []

        def map(self, function, *iterables):
            self.phases.append(function.phase)
            return map(function, *iterables)

    task_file = Path(__file__).parents[1] / "examples" / "capture_task.yaml"
    data = yaml.safe_load(task_file.read_text())
    data["optimal"] = {"intervals": 20, "starts": 2}
    task = task_from_dict(data, task_file.parent, source=task_file.name)
    executor = Recording()
    run = run_task(task, methods=("optimal",), executor=executor)
    assert executor.phases == ["first", "plan"]
    assert run.results["optimal"].solver.starts["solved"] >= 1
