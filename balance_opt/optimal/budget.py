"""How much memory and time the optimal planner's problem needs, estimated before it is built
from its terms' sizes (:meth:`~balance_opt.optimal.terms.Term.size`), nothing compiled."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

from balance_opt.optimal.collocation import Transcription

#: Bytes of memory per non-zero of the KKT matrix.
BYTES_PER_NONZERO = 400
#: Memory of the process before the NLP: Python, Pinocchio, CasADi, the kernels.
BASE_BYTES = 200 * 2**20
#: Share of the machine's physical memory one optimal problem may take.
MEMORY_FRACTION = 0.5
#: Budget where the physical memory cannot be read [bytes].
FALLBACK_BUDGET = 4 * 2**30
#: Wall time of the NLP build per non-zero [s].
BUILD_SECONDS_PER_NONZERO = 15e-6
#: Wall time of one Ipopt iteration per non-zero [s].
ITERATION_SECONDS_PER_NONZERO = 1e-6


@dataclass(frozen=True)
class ProblemSize:
    """The estimated size of one optimal problem."""

    variables: int
    nonzeros: int
    problems: int = 1

    @property
    def memory_bytes(self) -> float:
        """Estimated peak memory of a process that builds and solves it [bytes]."""
        return BASE_BYTES + BYTES_PER_NONZERO * self.nonzeros

    @property
    def build_seconds(self) -> float:
        """Estimated wall time of the NLP's build [s]."""
        return BUILD_SECONDS_PER_NONZERO * self.nonzeros

    @property
    def iteration_seconds(self) -> float:
        """Estimated wall time of one Ipopt iteration [s] (of the NLPs' average size)."""
        return ITERATION_SECONDS_PER_NONZERO * self.nonzeros / self.problems


def _per_interval(options, limits) -> tuple[int, int, float]:
    """(variables, constraints, KKT non-zeros) per interval of the problem of ``options`` with
    the balance joints' ``limits``: the sum of its terms' sizes
    (:meth:`~balance_opt.optimal.terms.Term.size`)."""
    # imported here: the terms are built of CasADi, which loading a task file needs nowhere else
    from balance_opt.optimal.nlp import terms_of
    from balance_opt.optimal.problem import StructureKey
    from balance_opt.optimal.terms import Size

    transcription, n_B = Transcription(options.transcription), len(limits.lower)
    terms = terms_of(StructureKey.of(limits, options))
    size = sum((term.size(n_B, transcription) for term in terms), Size())
    return round(size.variables), round(size.rows), size.nonzeros


#: What makes a problem an inner stage's, for its size: no joint-limit rows between the points.
_INNER = {"position_limits": False, "velocity_limits": False, "acceleration_limits": False}


def _built(options) -> list:
    """The options of every NLP a plan with ``options`` builds, each with its own intervals:
    the plan's, the free peak problem's of a path bound (the plan's own when it is a peak
    problem without a terminal bound: a peak problem's path bound adds no rows), the peak
    problem's on the coarser grids of its epigraph stage (:meth:`~.options.Stage.grids`) and the
    coarse stages of the options' ``stages`` on the coarsest's grid (the
    smooth stage has the integral's size: no epigraph)."""
    free = {"path_attitude_bound": None, "terminal_attitude_bound": None}
    bounded, peak = options.path_attitude_bound is not None, options.objective == "peak"
    built = [options]
    if bounded and (not peak or options.terminal_attitude_bound is not None):
        built.append(replace(options, objective="peak", **free))
    if peak or bounded:
        grids = options.stages[-1].grids(options.intervals, options.transcription)
        built += [replace(options, objective="peak", intervals=n, **free) for n in grids[:-1]]
        built += [
            replace(
                options,
                objective="integral",
                intervals=stage.intervals(grids[0], options.transcription),
                **free,
                **({} if stage.between_points else _INNER),
            )
            for stage in options.stages
            if stage.coarse
        ]
    return built


def _nonzeros_per_interval(options, limits) -> float:
    """KKT non-zeros per interval of ``options`` of every NLP a plan with ``options`` builds
    (an inner stage's on its coarser grid count in proportion)."""
    N = options.intervals
    return sum(_per_interval(o, limits)[2] * o.intervals / N for o in _built(options))


def problem_size(options, limits) -> ProblemSize:
    """The size of the optimal problem of the planner ``options`` (a
    :class:`~balance_opt.optimal.options.PlannerOptions`) whose balance joints have the
    ``limits`` (a :class:`~balance_opt.model.robot.JointLimits`, one entry per balance joint):
    its variables and the non-zeros of every NLP its plan builds."""
    N = options.intervals
    nonzeros = round(_nonzeros_per_interval(options, limits) * N)
    return ProblemSize(_per_interval(options, limits)[0] * N, nonzeros, len(_built(options)))


def memory_budget() -> float:
    """Memory one optimal problem may take: :data:`MEMORY_FRACTION` of the machine's physical
    memory (:data:`FALLBACK_BUDGET` where it cannot be read) [bytes]."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_BUDGET
    return MEMORY_FRACTION * total if total > 0 else FALLBACK_BUDGET


def largest_intervals(options, limits, budget: float) -> int:
    """The largest ``N`` whose problem fits in ``budget`` bytes."""
    nonzeros = _nonzeros_per_interval(options, limits)
    N = max(0, math.floor((budget - BASE_BYTES) / (BYTES_PER_NONZERO * nonzeros)))
    # the inner stages' grid is rounded up to whole intervals: the size per interval at
    # ``options.intervals`` can be a little below the one at N
    while N > 0 and problem_size(replace(options, intervals=N), limits).memory_bytes > budget:
        N -= 1
    # and a fine peak plan's coarser grids (Stage.grids) weigh less per interval on some grids
    # than on others: the one at ``options.intervals`` can be above the one at N
    while N >= 2 and problem_size(replace(options, intervals=N + 1), limits).memory_bytes <= budget:
        N += 1
    return N
