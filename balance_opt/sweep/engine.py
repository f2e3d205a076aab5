"""Run the cases of a sweep: in this process, on a local process pool, or on a Dask cluster.

Cases, results and the runner (a ``"module:function"`` string) are plain data; workers are
processes, never threads (MUMPS is not thread-safe). Each finished case is written atomically to
``<out>/cases/<case_id>.json`` for ``resume``. Pool workers never outlive the sweep: each dies
with its parent (``prctl(PR_SET_PDEATHSIG)``, else a watcher thread), and they ignore SIGINT,
which the parent handles by ending them at once (:func:`stop_pool`).
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import json
import logging
import math
import multiprocessing
import multiprocessing.connection
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from balance_opt.report.output_dir import replaced_atomically

logger = logging.getLogger(__name__)

#: Case statuses. ``ok``: ran to the end; ``solver_failed``: the planner raised a solver error
#: (its best iterate's metrics are still recorded); ``error``: any other exception.
STATUS_OK, STATUS_SOLVER_FAILED, STATUS_ERROR = "ok", "solver_failed", "error"
#: Folder of the per-case result files, inside the sweep's output folder.
CASES_DIR = "cases"
#: Thread pools of numeric libraries inside each worker process: one thread, since the
#: parallelism is across processes (two workers on two cores must not start four threads each).
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: Lines of a failing case's traceback kept in its result file.
TRACEBACK_LINES = 12
#: Seconds between two looks at the parent where the kernel cannot signal its death.
PARENT_POLL_S = 0.5
#: Seconds the workers get to end on SIGTERM before they are killed.
STOP_GRACE_S = 2.0
_PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h)

# One case at a time per process, even on a multi-threaded Dask worker (MUMPS is not thread-safe).
_CASE_LOCK = threading.Lock()


def resolve_runner(spec: str) -> Callable[[dict], dict]:
    """The function named by ``"package.module:function"``."""
    module_name, sep, name = spec.partition(":")
    if not sep or not module_name or not name:
        raise ValueError(f"runner must be 'module:function', got '{spec}'")
    return getattr(importlib.import_module(module_name), name)


def error_record(exc: BaseException) -> dict[str, Any]:
    """Plain-data description of an exception: type, message and the end of its traceback."""
    lines = traceback.format_exception(type(exc), exc, exc.__traceback__)
    tail = "".join(lines).rstrip().splitlines()[-TRACEBACK_LINES:]
    return {"type": type(exc).__name__, "message": str(exc), "traceback": "\n".join(tail)}


def execute_case(runner: str, case: dict) -> dict:
    """Run one case in this process; its result record (plain data). An exception becomes
    status ``error`` (``solver_failed`` for a ``SolverError``); ``timing`` gets the wall and CPU
    times [s] and the process id."""
    from balance_opt.errors import SolverError

    runner_timing: dict[str, Any] = {}
    with _CASE_LOCK:
        start, cpu_start = time.perf_counter(), time.process_time()
        try:
            out = resolve_runner(runner)(case)
            status = out.get("status", STATUS_OK)
            record = _record(case, status, out.get("error"), out.get("metrics", {}))
            record["info"], runner_timing = out.get("info", {}), out.get("timing", {})
        except SolverError as exc:
            record = _record(case, STATUS_SOLVER_FAILED, error_record(exc))
        except Exception as exc:  # noqa: BLE001 - a failing case is recorded, the sweep goes on
            record = _record(case, STATUS_ERROR, error_record(exc))
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    timing = {"case_s": elapsed, "cpu_s": cpu, "pid": os.getpid(), **runner_timing}
    return {**record, "timing": timing}


def _record(case: dict, status: str, error: dict | None, metrics: dict | None = None) -> dict:
    """A result record of ``case`` without its timing."""
    record = {key: case[key] for key in ("index", "case_id", "method", "parameters")}
    return {**record, "status": status, "error": error, "metrics": metrics or {}, "info": {}}


def _crash_record(case: dict, exc: BaseException) -> dict:
    """The record of a case whose worker process died running it."""
    message = f"the worker process running this case died: {exc}"
    error = {"type": "WorkerCrashed", "message": message, "traceback": ""}
    return {**_record(case, STATUS_ERROR, error), "timing": {"case_s": math.nan, "pid": None}}


def result_path(out_dir: str | Path, case_id: str) -> Path:
    return Path(out_dir) / CASES_DIR / f"{case_id}.json"


def write_json_atomic(path: str | Path, data: Any) -> None:
    """Write ``data`` as JSON atomically (the old content or the whole new one, never a part)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with replaced_atomically(path) as tmp:
        tmp.write_text(json.dumps(data, indent=1, allow_nan=True) + "\n")


def read_result(out_dir: str | Path, case_id: str) -> dict | None:
    """The recorded result of a case, or None if there is no whole record of it."""
    path = result_path(out_dir, case_id)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("case_id") != case_id or "status" not in data:
        logger.warning("ignoring %s: not a result record of case %s", path, case_id)
        return None
    return data


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


class _Stopped(BaseException):
    """SIGTERM in a pool worker running a case (the sweep is stopped)."""


def _stop_case(signum, frame) -> None:
    raise _Stopped


def execute_in_worker(runner: str, case: dict) -> dict:
    """:func:`execute_case` in a pool worker, where SIGTERM unwinds the case (the compilers it
    started, in sessions of their own, end with it) before the worker exits."""
    previous = signal.signal(signal.SIGTERM, _stop_case)
    try:
        return execute_case(runner, case)
    except _Stopped:
        os._exit(128 + signal.SIGTERM)
    finally:
        signal.signal(signal.SIGTERM, previous)


def init_worker(parent_pid: int) -> None:
    """Initializer of each pool worker: SIGKILL when the parent dies (Linux's ``prctl``, else a
    watcher thread); ``parent_pid`` is taken before the worker started, so a parent that died
    before the worker could ask to die with it is noticed."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        prctl = None
    if prctl is None or prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
        threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()
    if os.getppid() != parent_pid:
        os._exit(1)


def new_pool(jobs: int) -> ProcessPoolExecutor:
    """A process pool of ``jobs`` workers that end with this process."""
    return ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=init_worker,
        initargs=(os.getpid(),),
    )


def stop_pool(pool: ProcessPoolExecutor, grace_s: float = STOP_GRACE_S) -> None:
    """Cancel the cases not started and end the workers now, running cases included."""
    # The executor has no public way to end running workers before Python 3.14.
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    running = {p.sentinel: p for p in processes}
    deadline = time.monotonic() + grace_s
    while running and (left := deadline - time.monotonic()) > 0:
        for sentinel in multiprocessing.connection.wait(list(running), timeout=left):
            running.pop(sentinel)
    for process in running.values():
        logger.debug("worker %s did not end on SIGTERM: killed", process.pid)
        with contextlib.suppress(Exception):
            process.kill()


class InProcessEngine(contextlib.nullcontext):
    """Runs the cases one after the other in this process (``--jobs 0``)."""

    workers = 1

    def imap_unordered(self, runner: str, cases: Sequence[dict]) -> Iterator[dict]:
        for case in cases:
            yield execute_case(runner, case)

    def describe(self) -> str:
        return "in-process"


@contextlib.contextmanager
def _single_threaded_children():
    """Worker processes started inside the block get ``SINGLE_THREAD_ENV`` (user's values kept)."""
    added = {k: v for k, v in SINGLE_THREAD_ENV.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


class _ExecutorEngine:
    """Runs the cases on a ``concurrent.futures`` executor (``self._executor``): the local pool,
    or Dask's through ``Client.get_executor``. A case whose worker died is recorded as
    ``WorkerCrashed``; ``timeout``: longest wait for all the cases [s], None for no limit."""

    timeout: float | None = None
    execute = staticmethod(execute_case)

    def map(self, function: Callable, *iterables) -> Iterator:
        """``function`` over ``iterables`` in the workers, in order (the planner's starts)."""
        return self._executor.map(function, *iterables)

    def imap_unordered(self, runner: str, cases: Sequence[dict]) -> Iterator[dict]:
        futures = {self._executor.submit(self.execute, runner, case): case for case in cases}
        suspects: list[dict] = []
        try:
            for fut in as_completed(futures, timeout=self.timeout):
                # dropped once done: Dask releases a result nobody holds, and does not compute
                # it again when the worker that keeps it dies
                case = futures.pop(fut)
                try:
                    yield fut.result()
                except BrokenProcessPool:
                    suspects.append(case)
                except Exception as exc:  # noqa: BLE001 - Dask's KilledWorker, a cancelled case
                    yield _crash_record(case, exc)
        finally:
            for fut in futures:
                fut.cancel()
        if suspects:
            # A pool worker died and took the pool with it: every case not finished raised. Run
            # them again one at a time, each in a fresh process, so the culprit is known.
            logger.warning(
                "a worker process died; running %d unfinished case(s) one at a time", len(suspects)
            )
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = new_pool(self.workers)
            for case in sorted(suspects, key=lambda c: c["index"]):
                alone = new_pool(1)
                try:
                    record = alone.submit(self.execute, runner, case).result()
                except BrokenProcessPool as exc:
                    record = _crash_record(case, exc)
                except BaseException:
                    stop_pool(alone)
                    raise
                alone.shutdown(wait=True)
                yield record


class LocalPoolEngine(_ExecutorEngine):
    """A pool of ``jobs`` worker processes started with ``spawn`` (CasADi and Pinocchio state
    must not be forked). When a worker dies the unfinished cases run again one at a time, each in
    a fresh process; a case whose process dies again is recorded as ``WorkerCrashed``."""

    execute = staticmethod(execute_in_worker)

    def __init__(self, jobs: int):
        if jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {jobs}")
        self.workers = jobs

    def __enter__(self):
        self._env = _single_threaded_children()
        self._env.__enter__()
        self._executor = new_pool(self.workers)
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self._executor.shutdown(wait=True)
        else:  # an interruption: drop the cases not started, end the running ones now
            stop_pool(self._executor)
        self._executor = None
        return self._env.__exit__(exc_type, exc, tb)

    def describe(self) -> str:
        return f"local process pool, {self.workers} worker(s) (spawn)"


@dataclass
class DaskEngine(_ExecutorEngine):
    """Dask distributed: a running scheduler (``address``; workers need balance-opt installed,
    one thread each), or a local cluster of ``workers`` processes on ``host``, started here and
    stopped on exit. A case whose worker dies is computed again elsewhere, until it has killed
    every worker that ran it (``KilledWorker``)."""

    address: str | None = None
    workers: int = 2
    host: str = "127.0.0.1"
    timeout: float | None = None
    _cluster: Any = field(default=None, repr=False)
    _client: Any = field(default=None, repr=False)

    def __enter__(self):
        from dask.distributed import Client, LocalCluster

        if self.address is None:
            with _single_threaded_children():
                self._cluster = LocalCluster(
                    n_workers=self.workers,
                    threads_per_worker=1,
                    processes=True,
                    host=self.host,
                    dashboard_address=None,
                )
            self._client = Client(self._cluster)
        else:
            self._client = Client(self.address)
            self.workers = max(1, len(self._client.scheduler_info().get("workers", {})))
        self._executor = self._client.get_executor(pure=False)
        logger.info("Dask scheduler %s, %d worker(s)", self._client.scheduler.address, self.workers)
        return self

    def __exit__(self, exc_type, exc, tb):
        for resource in (self._client, self._cluster):  # the client first
            if resource is not None:
                resource.close()
        self._client = self._cluster = self._executor = None
        return False

    def describe(self) -> str:
        where = self.address or f"local cluster on {self.host}"
        return f"Dask ({where}), {self.workers} worker(s)"


def make_engine(jobs: int = 1, scheduler: str | None = None):
    """The engine of ``jobs`` and ``scheduler`` (as in :func:`balance_opt.sweep.run.run_sweep`)."""
    if scheduler is None:
        return InProcessEngine() if jobs == 0 else LocalPoolEngine(jobs)
    if scheduler == "local":
        return DaskEngine(None, workers=max(1, jobs))
    return DaskEngine(scheduler)


@dataclass
class SweepRun:
    """What :func:`run_cases` did: every result in case-index order (skipped ones included), the
    ids run now and skipped (``resume``), the wall time [s] and the number of workers."""

    results: list[dict]
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    workers: int = 1

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.results if r["status"] != STATUS_OK]


def run_cases(
    cases: Sequence[Mapping],
    runner: str,
    out_dir: str | Path,
    engine,
    resume: bool = False,
    retry_failed: bool = False,
    on_result: Callable[[dict, int, int], None] | None = None,
) -> SweepRun:
    """Run every case, write each result as it comes, and return them all in index order (those
    run now and those found on disk). ``resume`` skips cases with a result file (failed ones too
    unless ``retry_failed``); ``on_result(record, done, to_run)`` is called after each write
    and may raise to stop the sweep."""
    cases = [dict(case) for case in cases]
    ids = [case["case_id"] for case in cases]
    if len(set(ids)) != len(ids):
        raise ValueError("case ids are not unique")
    found: dict[str, dict] = {}
    if resume:
        for case in cases:
            record = read_result(out_dir, case["case_id"])
            if record is not None and (record["status"] == STATUS_OK or not retry_failed):
                found[case["case_id"]] = record
    todo = [case for case in cases if case["case_id"] not in found]
    if found:
        logger.info("resume: %d case(s) already done, %d to run", len(found), len(todo))
    (Path(out_dir) / CASES_DIR).mkdir(parents=True, exist_ok=True)
    run = SweepRun(
        results=[],
        skipped=[c["case_id"] for c in cases if c["case_id"] in found],
        workers=engine.workers,
    )
    start = time.perf_counter()
    if todo:
        logger.info("running %d case(s) on %s", len(todo), engine.describe())
        with engine:
            run.workers = engine.workers
            for record in engine.imap_unordered(runner, todo):
                write_json_atomic(result_path(out_dir, record["case_id"]), record)
                found[record["case_id"]] = record
                run.ran.append(record["case_id"])
                if record["status"] != STATUS_OK:
                    logger.warning(
                        "case %d (%s) %s: %s",
                        record["index"],
                        record["case_id"],
                        record["status"],
                        (record.get("error") or {}).get("message"),
                    )
                if on_result is not None:
                    on_result(record, len(run.ran), len(todo))
    run.elapsed_s = time.perf_counter() - start
    run.results = sorted(found.values(), key=lambda r: r["index"])
    return run
