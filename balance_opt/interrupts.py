"""Interrupts (Ctrl-C, SIGTERM, SIGHUP) that stop a run wherever they arrive, Ipopt included.

Within :func:`handling_signals` each raises :class:`Interrupted` (a ``KeyboardInterrupt``) and
is recorded. CasADi swallows the exception raised in Ipopt's callbacks (Ipopt then stops as if it
had failed), so code calling such a library calls :func:`raise_if_interrupted` right after.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

#: The signals turned into :class:`Interrupted`; SIGHUP too (a closed terminal), since the
#: compilers run in sessions of their own that the terminal's signals do not reach.
SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
#: Python's own handlers, replaced within :func:`handling_signals` (a handler of the caller's
#: own, or SIG_IGN, is left as it is).
_DEFAULTS = (signal.default_int_handler, signal.SIG_DFL)
_received: list[int] = []


class Interrupted(KeyboardInterrupt):
    """The run was interrupted by the signal ``signum`` (one of :data:`SIGNALS`)."""

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
    """Within the block, the :data:`SIGNALS` raise :class:`Interrupted` and are recorded.

    Installed only from the main thread and only over Python's defaults, restored at the end;
    nested blocks share the outermost one.
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
