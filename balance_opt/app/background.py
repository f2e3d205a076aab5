"""A second process for the work of a run that does not wait for the optimal plan, or that can
go on while this process writes the other files (``plan``, ``simulate`` and ``compare`` with a
CPU to spare, :func:`worker_pays`):

* the forward-dynamics simulations of the plans made before the optimal one (the mission arm
  alone, the analytic plan), run while the optimal plan is solved;
* the figures, drawn while this process writes the trajectories, the animation and the joint
  torques of the report (Matplotlib is imported and its fonts loaded in the worker while the
  optimal plan is solved, and never in this process).

Ipopt releases Python's GIL, but the simulations and the figures are Python code that would
take it from this process's own Python work, so the worker is a process, started with
``spawn`` (nothing of CasADi or Pinocchio copied into it) as soon as the run starts, so that
its start-up overlaps the first plans. It gets its inputs pickled and runs
the same functions on them as this process would, so its numbers and files are the same. Its
log records come back with its results and are logged here, in the run's order. The worker
ignores Ctrl-C and dies with this process (:mod:`balance_opt.sweep.workers`); an interruption or
an error ends it at once, before the staging folder it writes figures into is removed. A worker
that died is not an error: its job is done here instead.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # typing.Self is Python 3.11+; annotations are not evaluated at run time
    from typing_extensions import Self

    from balance_opt.io.task import Task

log = logging.getLogger(__name__)


#: Environment variable: ``1`` always use the worker, ``0`` never; unset (or anything else):
#: when it pays, see :func:`worker_pays`.
WORKER_ENV = "BALANCE_OPT_WORKER"


def usable_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def worker_pays() -> bool:
    """Whether a worker process would shorten the run: two usable CPUs or more, and a load
    average over the last minute below their number. On a machine already busy the worker
    only takes CPU time from the main process (measured on 2 CPUs, ``compare`` on the capture
    task: 27 % faster at load 1.3-1.8, 4 % slower at load 3). :data:`WORKER_ENV` overrides."""
    setting = os.environ.get(WORKER_ENV, "").strip()
    if setting in ("0", "1"):
        return setting == "1"
    cpus = usable_cpus()
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # not available (Windows): assume idle
        load = 0.0
    return cpus >= 2 and load < cpus


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


def _warm_up_figures() -> None:
    """Import Matplotlib and load its fonts by drawing a small figure (to memory)."""
    import io

    from balance_opt.io import style

    with style.styled():
        fig = style.figure()
        fig.add_subplot().plot([0, 1], [0, 1], label="x")
        fig.legend()
        fig.savefig(io.BytesIO(), format="png", dpi=style.SCREEN_DPI)


def _call(function: Callable, args: tuple, level: int):
    """``(result, log records, seconds)`` of ``function(*args)``, in the worker."""
    handler = _Records(level)
    root = logging.getLogger()
    root.addHandler(handler)
    logging.getLogger("balance_opt").setLevel(level)
    started = time.perf_counter()
    try:
        result = function(*args)
    finally:
        root.removeHandler(handler)
    return result, handler.records, time.perf_counter() - started


def _simulate(simulate: Callable, task: Task, plan) -> tuple[Any, bool]:
    """``(simulation, robot taken out)``: the parent puts its own robot back (not pickled)."""
    sim = simulate(task, plan)
    own_robot = sim.robot is task.robot
    if own_robot:
        sim.robot = None
    return sim, own_robot


class RunWorker:
    """The worker process of one run; use as a context manager.

    Args:
        task: the task of the run.
        figure_dir: where the run's figures go, ``None`` if it draws none (else Matplotlib is
            prepared in the worker).
    """

    def __init__(self, task: Task, figure_dir: Path | None):
        from balance_opt.sweep.workers import new_pool

        self.task, self.figure_dir = task, figure_dir
        self.draws_figures = figure_dir is not None
        self._pool = new_pool(1, "spawn")
        self._jobs: dict[str, tuple[Future, Callable, tuple]] = {}
        self._pool.submit(_start)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        from balance_opt.sweep.workers import stop_pool

        if exc_type is None and not self._jobs:
            self._pool.shutdown(wait=True)
        else:  # an error or an interruption (or results never asked for): end it now
            stop_pool(self._pool)
        return False

    def __contains__(self, job: str) -> bool:
        return job in self._jobs

    def _submit(self, job: str, function: Callable, *args) -> None:
        level = logging.getLogger("balance_opt").getEffectiveLevel()
        try:
            future = self._pool.submit(_call, function, args, level)
        except BrokenProcessPool:  # died already: the job is done here when asked for
            future = None
        self._jobs[job] = (future, function, args)

    def _result(self, job: str) -> tuple[Any, float]:
        """``(result, seconds)`` of ``job``, waiting for it; done here if the worker died.

        Raises:
            Whatever the job raised in the worker.
        """
        future, function, args = self._jobs.pop(job)
        try:
            if future is None:
                raise BrokenProcessPool("it ended before this job was handed to it")
            result, records, seconds = future.result()
        except BrokenProcessPool as exc:
            log.warning("the worker process died (%s): %s done here", exc, job)
            started = time.perf_counter()
            return function(*args), time.perf_counter() - started
        for record in records:
            logging.getLogger(record.name).handle(record)
        return result, seconds

    # ------------------------------------------------------------------ simulations
    def submit_simulation(self, name: str, simulate: Callable, plan) -> None:
        """Start ``simulate(task, plan)`` (a module-level function: the worker gets it by
        name) of ``run.results[name]``."""
        self._submit(f"simulation of {name}", _simulate, simulate, self.task, plan)

    def has_simulation(self, name: str) -> bool:
        return f"simulation of {name}" in self._jobs

    def simulation(self, name: str) -> tuple[Any, float]:
        """``(simulation, seconds)`` of ``name``."""
        (sim, own_robot), seconds = self._result(f"simulation of {name}")
        if own_robot:
            sim.robot = self.task.robot
        return sim, seconds

    # ------------------------------------------------------------------ figures
    def warm_up_figures(self) -> None:
        """Prepare Matplotlib in the worker (queued after the simulations), if the run draws."""
        if self.draws_figures:
            with contextlib.suppress(BrokenProcessPool):
                self._pool.submit(_warm_up_figures)

    def submit_figures(self, part: str, draw: Callable, *args) -> None:
        """Start ``draw(*args)`` (module-level), the figures ``part``, in the worker."""
        self._submit(f"figures: {part}", draw, *args)

    def has_figures(self, part: str) -> bool:
        return f"figures: {part}" in self._jobs

    def figures(self, part: str) -> tuple[Any, float]:
        """``(what draw returned, seconds)`` of the figures ``part``."""
        return self._result(f"figures: {part}")


__all__ = ["WORKER_ENV", "RunWorker", "usable_cpus", "worker_pays"]
