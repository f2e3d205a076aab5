"""Where and when the tasks of a multi-start run (:mod:`balance_opt.optimal.starts`): this
process and a pool of worker processes take them from one :class:`Schedule`.

A start through the peak problem is two tasks: its first stage (``"first"``), then, unless it
was merged into an earlier start with the same first plan, its later stages (``"plan"``);
otherwise a start is one ``"plan"`` task. Start ``i``'s later stages may begin once its own
and every earlier start's first stage are done and it agrees with none of those: which start
owns a plan, and from which first plan the later stages start, is then the same whatever order
the tasks end in and however many processes run them (a run is reproducible from the seed).

This process has every problem built already; a worker has to start Python, load the compiled
planner and build its problems, seconds on a small machine. So this process does not wait for
the workers: it takes tasks itself, from the low start indices (the first starts' later stages
can begin at once), and the workers from the high ones, each worker one task at a time (a task
given to a worker cannot be taken back). A worker is given its next task as soon as it hands
back its last one (a callback in the pool's thread: Ipopt releases the GIL), even while this
process is inside Ipopt. When nothing is ready and the workers are still starting up (none has
handed back a task), this process runs their tasks too and keeps whichever result comes first
(the same: a task depends only on its input), so a multi-start never waits for a worker's
start-up (seconds on a loaded machine); the pool is then stopped, not waited for.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future

log = logging.getLogger(__name__)

FIRST, PLAN = "first", "plan"

#: Longest wait [s] of this process for a worker before it looks at the schedule again (a
#: worker's return wakes it at once; this is a safety net).
WAIT_S = 0.2


class Schedule:
    """The tasks of a multi-start and their results.

    Args:
        guesses: the starts' guesses.
        staged: the starts go through a first stage and are merged (the peak problem).
        same: ``same(a, b)``: the first stages' outcomes ``a`` and ``b`` reached one plan.
    """

    def __init__(self, guesses: list, staged: bool, same: Callable[[object, object], bool]):
        n = len(guesses)
        self.guesses, self.staged, self.same = guesses, staged, same
        self.firsts: list = [None] * n
        self.owner: list = [None] * n if staged else list(range(n))
        self.plans: dict = {}
        self._distinct: list[int] = []
        self._merged = 0  # the first stages merged so far: a prefix of the starts
        self._firsts = list(range(n)) if staged else []
        self._plans = [] if staged else list(range(n))

    def take(self, local: bool) -> tuple[str, int] | None:
        """The next task for this process (``local``: the lowest later stages, then the lowest
        first stage) or for a worker (the highest first stage, then the highest later stages);
        ``None``: none is ready."""
        end = 0 if local else -1
        if self._plans and (local or not self._firsts):
            return PLAN, self._plans.pop(end)
        if self._firsts:
            return FIRST, self._firsts.pop(end)
        return None

    def argument(self, task: tuple[str, int]):
        """What a task starts from: its guess, or its first stage's outcome."""
        kind, i = task
        return self.firsts[i] if kind == PLAN and self.staged else self.guesses[i]

    def done(self, task: tuple[str, int], value) -> None:
        """Record a task's result (the first one, if it ran twice); later stages that may now
        begin become ready."""
        kind, i = task
        if (kind == PLAN and i in self.plans) or (kind == FIRST and self.firsts[i] is not None):
            return  # a copy's (the task ran in two processes)
        if kind == PLAN:
            self.plans[i] = value
            return
        self.firsts[i] = value
        while self._merged < len(self.firsts) and self.firsts[self._merged] is not None:
            j, self._merged = self._merged, self._merged + 1
            first = self.firsts[j]
            self.owner[j] = next((k for k in self._distinct if self.same(self.firsts[k], first)), j)
            if self.owner[j] == j:
                self._distinct.append(j)
                self._plans.append(j)

    @property
    def finished(self) -> bool:
        return None not in self.owner and all(i in self.plans for i in set(self.owner))

    def outcomes(self) -> list:
        """Every start's result (a merged start's is that of the start it joined)."""
        return [self.plans[o] for o in self.owner]


class Lanes:
    """Runs a :class:`Schedule` in this process and ``workers`` worker processes (see the
    module docstring).

    Args:
        local: ``local(kind, argument)``: a task in this process.
        remote: ``(function, leading arguments)``: ``function(*leading, argument, kind)`` runs a
            task in a worker (picklable, by name).
        workers: worker processes (0: this process alone).
    """

    def __init__(self, local: Callable, remote: tuple[Callable, tuple], workers: int):
        self.local, self.remote, self.workers = local, remote, workers
        self.pool, self.error, self.closed = None, None, False
        self.in_workers: dict[tuple[str, int], float] = {}  # task: when it was given
        self.copied: set = set()
        self.warm = False  # a worker has handed back a task
        self.cond = threading.Condition()

    def run(self, schedule: Schedule) -> None:
        """Run every task of ``schedule``. Raises what a task raised (a worker's exception, a
        crashed worker's ``BrokenProcessPool``) or an interruption, the pool stopped."""
        self.schedule, self.t0 = schedule, time.perf_counter()
        if self.workers:
            from balance_opt.sweep.workers import new_pool

            self.pool = new_pool(self.workers, "spawn")
        failed = True
        try:
            self._run()
            failed = False
        finally:
            self._close(failed)

    def _run(self) -> None:
        with self.cond:
            self._feed()
        while True:
            with self.cond:
                if self.error is not None:
                    raise self.error
                if self.schedule.finished:
                    return
                task = self.schedule.take(local=True) or self._copy()
                if task is None:
                    self.cond.wait(WAIT_S)
                    continue
                argument = self.schedule.argument(task)
            begun = time.perf_counter()
            value = self.local(task[0], argument)
            self._log(task, "this process", begun)
            with self.cond:
                self.schedule.done(task, value)
                self._feed()

    def _copy(self) -> tuple[str, int] | None:
        """A task a worker still starting up has, to run here too while nothing else is ready
        (the one given first; the lock held): the same result whichever ends first. Not once
        a worker is up: it began its task before this process could, at the same speed."""
        waiting = [t for t in self.in_workers if t not in self.copied]
        if self.warm or not waiting:
            return None
        task = min(waiting, key=self.in_workers.get)
        self.copied.add(task)
        return task

    def _feed(self) -> None:
        """Give each idle worker a task (the lock held)."""
        while self.pool is not None and not self.closed and len(self.in_workers) < self.workers:
            task = self.schedule.take(local=False)
            if task is None:
                return
            function, leading = self.remote
            try:
                future = self.pool.submit(function, *leading, self.schedule.argument(task), task[0])
            except RuntimeError as exc:  # the pool broke (BrokenProcessPool: a worker died)
                self.error = self.error or exc
                return
            self.in_workers[task] = begun = time.perf_counter()
            future.add_done_callback(lambda f, task=task, b=begun: self._returned(task, f, b))

    def _log(self, task: tuple[str, int], lane: str, begun: float) -> None:
        now = time.perf_counter()
        log.debug(
            "start %d, %s: %s, %.2f-%.2f s", task[1], task[0], lane, begun - self.t0, now - self.t0
        )

    def _returned(self, task: tuple[str, int], future: Future, begun: float) -> None:
        """A worker's task ended (in the pool's thread)."""
        self._log(task, "a worker", begun)
        with self.cond:
            self.in_workers.pop(task, None)
            if not future.cancelled():
                if future.exception() is not None:
                    self.error = self.error or future.exception()
                elif not self.closed:
                    self.warm = True
                    self.schedule.done(task, future.result())
                    self._feed()
            self.cond.notify_all()

    def _close(self, failed: bool) -> None:
        with self.cond:
            self.closed = True
        if self.pool is None:
            return
        from balance_opt.sweep.workers import stop_pool

        with self.cond:
            busy = bool(self.in_workers)  # copies this process finished first: not waited for
        if failed or busy:
            stop_pool(self.pool)
        else:  # idle workers: they exit on their own (the pool's thread joins them), and the
            # plan need not wait for their interpreters to wind down (0.1-0.4 s)
            self.pool.shutdown(wait=False)


__all__ = ["FIRST", "PLAN", "Lanes", "Schedule"]
