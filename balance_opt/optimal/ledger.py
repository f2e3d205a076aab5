"""The Ipopt work behind one plan: the iterations and wall time of every solve, whichever stage,
bound or refinement round made it, including the solves that failed.

:func:`~balance_opt.optimal.refine.solve_with_bounds` opens a ledger around one plan; every
Ipopt call of :class:`~balance_opt.optimal.solve.BalanceNLP` records into the open ledger (none
is open outside a plan: then nothing is recorded), and the plan, or the result a failure
carries, is stamped with the totals (``info["total_iterations"]``,
``info["total_solve_time_s"]``), which ``metrics.json`` reports as ``solver.iterations`` and
``solver.solve_time_s``. Counting at the call, rather than adding up the stages' reports
afterwards, leaves no path uncounted (a failed stage and its fallback, a refinement round that
fails).
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator

_OPEN: contextvars.ContextVar[list[tuple[int, float]] | None] = contextvars.ContextVar(
    "balance_opt_ipopt_ledger", default=None
)


@contextlib.contextmanager
def ledger() -> Iterator[list[tuple[int, float]]]:
    """Record the Ipopt solves made inside the block: a list of ``(iterations, wall time [s])``."""
    entries: list[tuple[int, float]] = []
    token = _OPEN.set(entries)
    try:
        yield entries
    finally:
        _OPEN.reset(token)


def record(iterations: int, seconds: float) -> None:
    """One Ipopt solve (or one done elsewhere that the plan builds on, e.g. a multi-start's
    first stage); nothing when no ledger is open."""
    entries = _OPEN.get()
    if entries is not None:
        entries.append((int(iterations), float(seconds)))


def stamp(info: dict, entries: list[tuple[int, float]]) -> None:
    """Write the totals of ``entries`` into a result's ``info``."""
    info["total_iterations"] = sum(i for i, _ in entries)
    info["total_solve_time_s"] = sum(s for _, s in entries)
