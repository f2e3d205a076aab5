"""Interrupts (Ctrl-C, SIGTERM) that stop a run wherever they arrive, inside Ipopt included.

Python turns SIGINT into :class:`KeyboardInterrupt` at the next bytecode, and SIGTERM ends the
process at once by default (leaving a staging folder behind and a sweep's workers running).
Within :func:`handling_signals` both raise :class:`Interrupted`, a ``KeyboardInterrupt``, and
the signal is also recorded.

The record is what makes Ctrl-C work inside Ipopt: between iterations CasADi runs the Python
signal handler, but it catches the exception the handler raises, and Ipopt then stops with the
status ``NonIpopt_Exception_Thrown`` as if it had failed. Code that calls into such a library
calls :func:`raise_if_interrupted` right after it (the optimal planner does, after Ipopt), so
that the interruption goes on instead of a half-converged iterate being taken for a result.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

#: The signals turned into :class:`Interrupted`.
SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Python's own handlers, replaced within :func:`handling_signals` (a handler of the caller's
#: own, or SIG_IGN, is left as it is).
_DEFAULTS = (signal.default_int_handler, signal.SIG_DFL)
_received: list[int] = []


class Interrupted(KeyboardInterrupt):
    """The run was interrupted by a signal.

    Attributes:
        signum: the signal (``signal.SIGINT`` or ``signal.SIGTERM``).
    """

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _handler(signum: int, frame) -> None:
    _received.append(signum)
    raise Interrupted(signum)


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` if a signal was received within the current
    :func:`handling_signals` block (even if the exception its handler raised was caught by a
    library on the way)."""
    if _received:
        raise Interrupted(_received[0])


@contextlib.contextmanager
def handling_signals() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise :class:`Interrupted` and are recorded.

    The handlers are installed only from the main thread (the only one Python runs them in)
    and only over Python's defaults; the previous ones are restored at the end. Nested blocks
    share the outermost one; the record is cleared when it starts and when it ends.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    outermost = _handler not in previous.values()
    replaced = {s: h for s, h in previous.items() if any(h is d for d in _DEFAULTS)}
    if outermost:
        _received.clear()
    for signum in replaced:
        signal.signal(signum, _handler)
    try:
        yield
    finally:
        for signum, handler in replaced.items():
            signal.signal(signum, handler)
        if outermost:
            _received.clear()
