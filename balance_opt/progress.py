"""Progress of long work on stderr: stage notices and a live line of Ipopt's iterations.

Silent until :func:`configure` turns it on (the CLI does, unless ``-q``), so notebooks and sweep
workers see nothing. On a terminal the line updates in place; elsewhere each stage and each
solve's summary is one line.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

#: Shortest time between two updates of the live line on a terminal [s].
REFRESH_S = 0.1
_CLEAR = "\r\x1b[K"


class _Progress:
    """Where progress goes and the live line's state (one per process)."""

    def __init__(self) -> None:
        self.enabled = False
        self.stream: IO[str] | None = None
        self.live = False  # a live line is on screen (terminal only)
        self.last_write = 0.0
        self.lock = threading.Lock()
        self.solve: dict[str, Any] | None = None

    @property
    def tty(self) -> bool:
        stream = self.stream
        try:
            return bool(stream is not None and stream.isatty())
        except (AttributeError, ValueError):  # closed or not a file
            return False

    def write(self, text: str, live: bool) -> None:
        """Show ``text``: as the live line (terminal, ``live``) or as a line of its own."""
        stream = self.stream
        if not self.enabled or stream is None:
            return
        with self.lock:
            try:
                if self.tty:
                    stream.write(_CLEAR + text + ("" if live else "\n"))
                    self.live = live
                else:
                    stream.write(text + "\n")
                stream.flush()
            except (OSError, ValueError):  # stderr closed: progress is not worth failing for
                self.enabled = False
            self.last_write = time.monotonic()

    def clear(self) -> None:
        """Remove the live line, so that the next message starts on a clean line."""
        if self.live and self.stream is not None:
            with self.lock, contextlib.suppress(OSError, ValueError):
                self.stream.write(_CLEAR)
                self.stream.flush()
            self.live = False


_STATE = _Progress()


def configure(enabled: bool, stream: IO[str] | None = None) -> None:
    """Turn progress on (to ``stream``, default stderr) or off."""
    _STATE.clear()
    _STATE.enabled = enabled
    _STATE.stream = (stream or sys.stderr) if enabled else None


def status(message: str) -> None:
    """A stage notice: the live line on a terminal, a line of its own elsewhere; logged at
    debug level in any case."""
    logging.getLogger("balance_opt.progress").debug("%s", message)
    _STATE.write(message, live=True)


def clear() -> None:
    """Remove the live line (before a log message is written to the same stream)."""
    _STATE.clear()


class LogHandler(logging.StreamHandler):
    """A stream handler that first removes the live progress line, so that log messages and the
    live line never share a line."""

    def emit(self, record: logging.LogRecord) -> None:
        _STATE.clear()
        super().emit(record)


# =========================================================================================== Ipopt
def _line(solve: dict[str, Any], final: bool = False) -> str:
    # Ipopt numbers its iterations from 0 (the starting point), and calls back for each
    done = solve["calls"] - 1
    what = f"{done} iterations" if final else f"iteration {done}"
    return (
        f"{solve['label']}: {what}, objective {solve['objective']:.6g}, "
        f"constraint violation {solve['violation']:.2e}"
    )


def iteration(objective: float, g: np.ndarray | None) -> None:
    """One Ipopt iteration of the solve in progress (see :func:`solving`): the objective and
    the constraint values, whose violation of their bounds is shown."""
    solve = _STATE.solve
    if solve is None:
        return
    solve["calls"] += 1
    solve["objective"] = float(objective)
    if g is not None and g.size:
        lbg, ubg = solve["lbg"], solve["ubg"]
        solve["violation"] = float(np.max(np.maximum(np.maximum(lbg - g, g - ubg), 0.0)))
    if _STATE.tty and time.monotonic() - _STATE.last_write >= REFRESH_S:
        _STATE.write(_line(solve), live=True)


@contextlib.contextmanager
def solving(lbg: Any, ubg: Any, label: str = "Ipopt") -> Iterator[None]:
    """Around one Ipopt call with constraint bounds ``lbg``, ``ubg``: its iterations feed the
    live line, and one summary line (iterations, objective, violation, wall time) ends it."""
    if not _STATE.enabled:
        yield
        return
    lbg, ubg = np.asarray(lbg, float).ravel(), np.asarray(ubg, float).ravel()
    solve = {"label": label, "calls": 0, "objective": np.nan, "violation": np.nan}
    solve.update(lbg=lbg, ubg=ubg, start=time.perf_counter())
    _STATE.solve = solve
    try:
        yield
    finally:
        _STATE.solve = None
        if solve["calls"]:
            elapsed = time.perf_counter() - solve["start"]
            _STATE.write(f"{_line(solve, final=True)} in {elapsed:.1f} s", live=False)
        else:
            _STATE.clear()


def nlpsol(name: str, problem: dict[str, Any], options: dict[str, Any]) -> Any:
    """``casadi.nlpsol(name, "ipopt", problem, options)`` with the progress line: an
    ``iteration_callback`` feeding :func:`iteration`, whose errors are ignored rather than ending
    the solve. The solver holds the callback (CasADi keeps no Python reference to it)."""
    import casadi as cs

    n_x, n_g = problem["x"].numel(), problem["g"].numel()

    class _IterationCallback(cs.Callback):
        def __init__(self) -> None:
            cs.Callback.__init__(self)
            self.construct(f"progress_{n_x}_{n_g}", {})

        def get_n_in(self) -> int:
            return cs.nlpsol_n_out()

        def get_sparsity_in(self, i: int) -> Any:
            name = cs.nlpsol_out(i)
            if name == "f":
                return cs.Sparsity.scalar()
            if name in ("x", "lam_x"):
                return cs.Sparsity.dense(n_x)
            if name in ("g", "lam_g"):
                return cs.Sparsity.dense(n_g)
            return cs.Sparsity(0, 0)

        def has_eval_buffer(self) -> bool:
            return True  # numpy views of CasADi's own buffers: no copy of x or g

        def eval_buffer(self, arg: list[Any], res: list[Any]) -> int:
            # An interrupt raised in here (Ctrl-C, SIGTERM) stops Ipopt at this iteration
            # (CasADi's own handling; the run then raises it: balance_opt.interrupts); any
            # other error is ignored (iteration_callback_ignore_errors): progress never
            # ends a solve.
            if res and res[0] is not None:
                np.frombuffer(res[0], dtype=float)[:] = 0.0  # non-zero would stop Ipopt
            if _STATE.solve is not None and arg[1] is not None:
                g = np.frombuffer(arg[2], dtype=float) if arg[2] is not None else None
                iteration(float(np.frombuffer(arg[1], dtype=float)[0]), g)
            return 0

    callback = _IterationCallback()
    options = {**options, "iteration_callback": callback, "iteration_callback_ignore_errors": True}
    solver = cs.nlpsol(name, "ipopt", problem, options)
    solver.progress_callback = callback
    return solver
