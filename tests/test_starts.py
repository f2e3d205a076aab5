"""The multi-start's schedule and its lanes (:mod:`balance_opt.optimal.start_schedule`): which
start owns a plan does not depend on the order tasks end in nor on where they run; a worker's
error and an interruption (Ctrl-C on the command line too) end the pool at once; a worker still
starting up is not waited for; and the planner's multi-start gives the same starts with one
process and with a worker.
"""

from __future__ import annotations

import os
import time

import numpy as np
import psutil
import pytest

from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.optimal.start_schedule import FIRST, PLAN, Lanes, Schedule

#: Each start's first plan in the fake problem: starts with one value reach one plan.
FIRST_PLANS = [3, 1, 3, 2, 1, 3, 2, 4]


def _same(a, b) -> bool:
    return a == b


def _first(i: int) -> int:
    return FIRST_PLANS[i]


def _plan(first: int) -> tuple:
    return ("plan from", first)


def _drive(order_seed: int | None) -> tuple[list, list]:
    """Run the fake multi-start, the ready tasks done in a random order (``None``: in order);
    check that no later stage is taken before every earlier first stage is done."""
    rng = np.random.default_rng(order_seed)
    schedule = Schedule(list(range(len(FIRST_PLANS))), True, _same)
    taken: list = []
    while not schedule.finished:
        while (task := schedule.take(local=bool(rng.integers(2)))) is not None:
            taken.append(task)
        assert taken, "nothing ready but not finished"
        task = taken.pop(0 if order_seed is None else int(rng.integers(len(taken))))
        kind, i = task
        if kind == PLAN:
            assert all(f is not None for f in schedule.firsts[: i + 1])
        argument = schedule.argument(task)
        schedule.done(task, _first(argument) if kind == FIRST else _plan(argument))
    return schedule.owner, schedule.outcomes()


def test_owners_and_plans_do_not_depend_on_the_order_tasks_end_in():
    owner, outcomes = _drive(None)
    assert owner == [0, 1, 0, 3, 1, 0, 3, 7]
    assert outcomes == [_plan(FIRST_PLANS[o]) for o in owner]
    for seed in range(20):
        assert _drive(seed) == (owner, outcomes)


def test_this_process_takes_the_first_starts_and_a_worker_the_last():
    schedule = Schedule(list(range(4)), True, _same)
    assert schedule.take(local=False) == (FIRST, 3)
    assert schedule.take(local=True) == (FIRST, 0)
    schedule.done((FIRST, 0), 5)
    # start 0's later stages may begin at once: they come before the next first stage
    assert schedule.take(local=True) == (PLAN, 0)
    assert schedule.take(local=True) == (FIRST, 1)
    schedule.done((FIRST, 3), 5)  # not merged before starts 1 and 2 are known
    assert schedule.owner == [0, None, None, None]
    schedule.done((FIRST, 1), 6)
    assert schedule.owner == [0, 1, None, None] and schedule.take(local=False) == (FIRST, 2)


def test_without_stages_every_start_is_one_task():
    schedule = Schedule(["a", "b", "c"], False, _same)
    assert schedule.take(local=False) == (PLAN, 2)
    assert [schedule.take(local=True) for _ in range(3)] == [(PLAN, 0), (PLAN, 1), None]
    for i, g in enumerate("abc"):
        schedule.done((PLAN, i), g.upper())
    assert schedule.finished and schedule.outcomes() == ["A", "B", "C"]


def test_first_plans_are_one_within_the_state_and_control_tolerances():
    from balance_opt.optimal.layout import Solution
    from balance_opt.optimal.refine import IntegralStart
    from balance_opt.optimal.starts import SAME_CONTROL, SAME_PLAN, _same_first_plan

    def first(dx=0.0, du=0.0, status="Solve_Succeeded"):
        X, U = np.zeros((9, 5)), np.ones((3, 5))
        X[4, 2] += dx
        U[1, 3] += du
        return IntegralStart({"status": status}, Solution(X, U))

    assert _same_first_plan(first(), first(0.9 * SAME_PLAN, -0.9 * SAME_CONTROL))
    assert not _same_first_plan(first(), first(1.1 * SAME_PLAN))
    assert not _same_first_plan(first(), first(du=-1.1 * SAME_CONTROL))
    # a first stage that failed joins no other
    assert not _same_first_plan(first(), first(status="Maximum_Iterations_Exceeded"))


# ------------------------------------------------------------------------------ lanes
def fake_task(tag: str, argument, kind: str):
    """A task of the fake multi-start in a worker: its value, and the process it ran in."""
    if tag == "fail" and kind == FIRST:
        raise ValueError(f"worker failed on {argument}")
    if tag == "sleep":
        time.sleep(600)
    time.sleep(0.05)
    value = _first(argument) if kind == FIRST else _plan(argument)
    return value, os.getpid()


def _lanes(tag: str, local=None) -> tuple[Lanes, Schedule, dict]:
    """Lanes of this process and one worker on the fake multi-start; the returned dict is
    filled with the process each task ran in."""
    where: dict = {}

    def here(kind, argument):
        time.sleep(0.2)  # slower than the worker once it is up
        return fake_task("", argument, kind)

    schedule = Schedule(list(range(len(FIRST_PLANS))), True, _same)
    done = schedule.done

    def record(task, value_and_pid):
        value, where[task] = value_and_pid
        done(task, value)

    schedule.done = record
    return Lanes(local or here, (fake_task, (tag,)), 1), schedule, where


def _children() -> list:
    """This process's children, but multiprocessing's resource tracker (started once, it ends
    with this process)."""
    out = []
    for p in psutil.Process().children(recursive=True):
        try:
            if "resource_tracker" not in " ".join(p.cmdline()):
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


@pytest.mark.slow
def test_lanes_run_tasks_in_this_process_and_a_worker_with_the_same_outcome():
    lanes, schedule, where = _lanes("")
    lanes.run(schedule)
    assert (schedule.owner, schedule.outcomes()) == _drive(None)
    assert os.getpid() in where.values() and set(where.values()) - {os.getpid()}
    assert psutil.wait_procs(_children(), timeout=5)[1] == []


@pytest.mark.slow
def test_a_worker_slower_than_this_process_is_not_waited_for():
    lanes, schedule, where = _lanes("sleep")  # the worker never ends its task
    start = time.monotonic()
    lanes.run(schedule)
    assert time.monotonic() - start < 10
    assert (schedule.owner, schedule.outcomes()) == _drive(None)
    assert set(where.values()) == {os.getpid()}  # its task (start 7) was done here too
    assert psutil.wait_procs(_children(), timeout=5)[1] == []


@pytest.mark.slow
def test_a_worker_error_is_raised_and_ends_the_pool():
    lanes, schedule, _ = _lanes("fail")
    with pytest.raises(ValueError, match="worker failed on 7"):
        lanes.run(schedule)
    assert psutil.wait_procs(_children(), timeout=5)[1] == []


@pytest.mark.slow
def test_an_interrupt_ends_a_busy_worker_at_once():
    def interrupted(kind, argument):
        time.sleep(1.0)  # the worker has started its (endless) task
        raise KeyboardInterrupt

    lanes, schedule, _ = _lanes("sleep", interrupted)
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        lanes.run(schedule)
    assert time.monotonic() - start < 5
    assert psutil.wait_procs(_children(), timeout=5)[1] == []


# ------------------------------------------------------------------------------ the planner
@pytest.mark.slow
def test_multi_start_is_the_same_with_one_process_and_with_a_worker(capture):
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.starts import multi_start

    model = PlannerModel(capture.robot)
    options = PlannerOptions(intervals=20, starts=3, seed=3)
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options)
    alone = multi_start(nlp, "analytic", jobs=1)
    shared = multi_start(nlp, "analytic", jobs=2)
    assert (alone.info["starts"]["workers"], shared.info["starts"]["workers"]) == (1, 2)
    # the same plans; to the last bit when both processes run the same compiled kernels (not
    # while this one runs them on CasADi's VM as a fresh cache compiles them): 1e-7
    for a, b in zip(alone.info["starts"]["runs"], shared.info["starts"]["runs"]):
        assert a.get("same_as") == b.get("same_as") and a["status"] == b["status"]
        assert a["objective"] == pytest.approx(b["objective"], rel=1e-7)
    assert shared.max_drift == pytest.approx(alone.max_drift, rel=1e-7)


@pytest.mark.slow
def test_ctrl_c_on_a_multi_start_exits_130_without_orphans(tmp_path):
    """Ctrl-C (SIGINT to the whole process group) while this process and a worker are inside
    Ipopt: exit 130 within seconds, the worker and the pool's helpers gone."""
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
        for line in proc.stdout:  # the workers' Ipopt logs come here too
            if IPOPT_ITERATION.match(line):
                iterations += 1
            descendants = psutil.Process(proc.pid).children(recursive=True)
            if iterations >= 20 and len(descendants) >= 2:  # a worker and the resource tracker
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
