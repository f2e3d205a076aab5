"""Worker processes of the local pool that never outlive the sweep that started them.

* Each worker asks the kernel to kill it when its parent dies (Linux ``prctl(PR_SET_PDEATHSIG,
  SIGKILL)``; elsewhere a thread that watches the parent's process id), so ``kill -9`` of a
  sweep leaves no worker computing on, holding memory and the sweep's stdout open (a
  ``balance-opt sweep ... | tee log`` then sees the end of its input). Once the workers are
  gone, multiprocessing's resource tracker sees its pipe closed and ends too.
* Workers ignore SIGINT: Ctrl-C in a terminal reaches the whole process group, and it is the
  parent that handles it, by :func:`stop_pool`: the cases not started are cancelled and the
  workers are ended at once (SIGTERM, then SIGKILL), instead of finishing their cases first.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor

logger = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h)
#: Seconds between two looks at the parent where the kernel cannot signal its death.
PARENT_POLL_S = 0.5
#: Seconds the workers get to end on SIGTERM before they are killed.
STOP_GRACE_S = 2.0


def _die_with_parent() -> bool:
    """Ask the kernel for SIGKILL when the parent dies (Linux); False where unavailable."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return False
    return prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def init_worker(parent_pid: int | None) -> None:
    """Initializer of each pool worker (see the module docstring).

    Args:
        parent_pid: the process id of the worker's parent, taken before the worker started (a
            parent that died before the worker could ask to die with it is noticed here);
            ``None`` when it is not known in advance (a forkserver's child).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent_pid = os.getppid() if parent_pid is None else parent_pid
    if not _die_with_parent():
        threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True).start()
    if os.getppid() != parent_pid:
        os._exit(1)


def new_pool(jobs: int, start_method: str) -> ProcessPoolExecutor:
    """A process pool of ``jobs`` workers that end with this process (``start_method``
    ``"spawn"``, or ``"forkserver"``: its workers end with the fork server, which ends with
    this process)."""
    return ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=multiprocessing.get_context(start_method),
        initializer=init_worker,
        initargs=(os.getpid() if start_method == "spawn" else None,),
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


__all__ = ["init_worker", "new_pool", "stop_pool"]
