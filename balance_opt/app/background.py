"""Forward-dynamics simulations of finished plans in one worker process, while this process
plans on (``compare``: the mission arm alone and the analytic plan are simulated during the
optimal solve, on the second core).

CasADi holds Python's GIL while Ipopt runs, so a thread would gain nothing: the worker is a
process, started with ``spawn`` (nothing of CasADi or Pinocchio copied into it) as soon as the
run starts, so that its start-up overlaps the first plans. It gets the task and the plan
pickled and returns the :class:`~balance_opt.dynamics.simulation.SimulationResult`: the same
code on the same inputs, so the same numbers as in this process. Its log records come back
with the result and are logged here, in the run's order. The worker ignores Ctrl-C and dies
with this process (:mod:`balance_opt.sweep.workers`); an interruption or an error ends it at
once. A worker that died is not an error: the simulation is run here instead.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING, Self

if TYPE_CHECKING:
    from balance_opt.dynamics.simulation import SimulationResult
    from balance_opt.io.task import Task
    from balance_opt.result import BalanceResult

log = logging.getLogger(__name__)

#: ``(task, plan) -> simulation``.
Simulate = Callable[["Task", "BalanceResult"], "SimulationResult"]


def usable_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


class _Records(logging.Handler):
    """Keeps the worker's log records, message formatted, to be logged by the parent."""

    def __init__(self, level: int):
        super().__init__(level)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        record.msg, record.args, record.exc_info = record.getMessage(), None, None
        self.records.append(record)


def _start() -> None:
    """The worker's first job: the imports a simulation needs, while the parent plans."""
    import balance_opt.dynamics.simulation  # noqa: F401


def _simulate(simulate: Simulate, task: Task, plan: BalanceResult, level: int):
    """``(simulation, robot replaced, log records, seconds)`` of one plan, in the worker."""
    handler = _Records(level)
    root = logging.getLogger()
    root.addHandler(handler)
    logging.getLogger("balance_opt").setLevel(level)
    started = time.perf_counter()
    try:
        sim = simulate(task, plan)
    finally:
        root.removeHandler(handler)
    seconds = time.perf_counter() - started
    own_robot = sim.robot is task.robot  # the parent puts back its own (not pickled twice)
    if own_robot:
        sim.robot = None
    return sim, own_robot, handler.records, seconds


class BackgroundSimulations:
    """Simulations in one worker process; use as a context manager.

    Args:
        task: the task whose plans are simulated.
        simulate: ``(task, plan) -> simulation``, a module-level function (the worker gets it
            by name).
    """

    def __init__(self, task: Task, simulate: Simulate):
        from balance_opt.sweep.workers import new_pool

        self.task, self.simulate = task, simulate
        self._pool = new_pool(1, "spawn")
        self._futures: dict[str, Future] = {}
        self._pool.submit(_start)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        from balance_opt.sweep.workers import stop_pool

        if exc_type is None and not self._futures:
            self._pool.shutdown(wait=True)
        else:  # an error or an interruption (or results never asked for): end it now
            stop_pool(self._pool)
        return False

    def __contains__(self, name: str) -> bool:
        return name in self._futures

    def submit(self, name: str, plan: BalanceResult) -> None:
        """Start simulating ``plan`` (``run.results[name]``) in the worker."""
        level = logging.getLogger("balance_opt").getEffectiveLevel()
        self._futures[name] = self._pool.submit(_simulate, self.simulate, self.task, plan, level)
        log.debug("%s: simulation of %s handed to the worker process", self.task.name, name)

    def result(self, name: str, plan: BalanceResult) -> tuple[SimulationResult, float]:
        """``(simulation, seconds)`` of ``name``, waiting for the worker; the worker's log
        records are logged here. Run here if the worker died.

        Raises:
            Whatever ``simulate`` raised in the worker.
        """
        future = self._futures.pop(name)
        try:
            sim, own_robot, records, seconds = future.result()
        except BrokenProcessPool as exc:
            log.warning("the worker process died (%s): simulating %s here", exc, name)
            started = time.perf_counter()
            return self.simulate(self.task, plan), time.perf_counter() - started
        for record in records:
            logging.getLogger(record.name).handle(record)
        if own_robot:
            sim.robot = self.task.robot
        return sim, seconds


__all__ = ["BackgroundSimulations", "usable_cpus"]
