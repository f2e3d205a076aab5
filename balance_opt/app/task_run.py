"""What a run of a task holds (:class:`TaskRun`), the names of its methods, and the timed log
lines of its steps."""

from __future__ import annotations

import contextlib
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from balance_opt.motion.result import BalanceResult
from balance_opt.tasks.task import Task

log = logging.getLogger(__name__)


METHODS = ("analytic", "optimal")


#: With a free mission timing (``mission.timing: free``), the optimal plan at the given timing,
#: which ``compare`` puts beside the free one.
GIVEN_TIMING = "optimal-given"


#: Name of the reference result: the mission arm alone, balance arm held (Phase I, Fig. 2).
REFERENCE = "mission-only"


@dataclass
class TaskRun:
    """Everything a run (:func:`balance_opt.app.pipeline.run_task`) computed and wrote.

    Attributes:
        task: the task.
        results: ``{"mission-only" | "analytic" | "optimal": BalanceResult}``; a failed method's
            entry is its best iterate.
        simulations: ``{method: SimulationResult}`` when simulated.
        failures: ``{method: message}`` for the methods whose solver failed.
        metrics: the content of ``metrics.json``.
        files: every file written.
        report: the HTML report, if written.
        robustness: the plans' drift under model error
            (:class:`~balance_opt.motion.robustness.RobustnessResult`), if studied.
        clearance: per plan ``(ClearanceReport, t, smallest distance)``
            (:mod:`balance_opt.geometry.clearance`); ``simulated_clearance`` the same of the
            simulations; empty for a robot without geometry.
        geometry: the robot's :class:`~balance_opt.geometry.robot_geometry.RobotGeometry`
            (``False``: it has none; ``None``: not built yet).
        geometry_after: with a capture, the geometry after it and the target's pairs
            (:func:`capture_geometry`; ``False``: it did not load).
        closed_loop: the plans flown closed loop on perturbed robots
            (:class:`~balance_opt.app.closed_loop.ClosedLoopStudy`), if studied.
    """

    task: Task
    results: dict[str, BalanceResult] = field(default_factory=dict)
    simulations: dict[str, Any] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    report: Path | None = None
    robustness: Any = None
    clearance: dict[str, Any] = field(default_factory=dict)
    simulated_clearance: dict[str, Any] = field(default_factory=dict)
    geometry: Any = None
    geometry_after: Any = None
    closed_loop: Any = None

    @property
    def ok(self) -> bool:
        """No solver failed."""
        return not self.failures

    def __repr__(self) -> str:
        lines = [f"TaskRun(task={self.task.name!r}, ok={self.ok})"]
        for name, res in self.results.items():
            failed = " (failed)" if name in self.failures else ""
            lines.append(
                f"  {name:13} max drift {res.max_drift:.4g} rad, final {res.final_drift:.4g} rad, "
                f"{len(res.violations)} limit violation(s){failed}"
            )
        if self.simulations:
            lines.append(f"  simulated     {', '.join(self.simulations)}")
        for name, message in self.failures.items():
            if name not in self.results:
                lines.append(f"  {name}: failed: {message[:80]}")
        if self.files:
            where = self.files[0].parent
            report = f", report {self.report}" if self.report is not None else ""
            lines.append(f"  files         {len(self.files)} in {where}{report}")
        return "\n".join(lines)


@contextlib.contextmanager
def timed(what: str):
    """Log ``what ...``, then ``what: done in X s`` when the block ends without error."""
    log.info("%s ...", what)
    start = time.perf_counter()
    yield
    log.info("%s: done in %.2f s", what, time.perf_counter() - start)
