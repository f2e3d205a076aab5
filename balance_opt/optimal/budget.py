"""How much memory and time the optimal planner's problem needs, estimated before it is built.

Everything the planner allocates for its NLP (CasADi's graphs of the outer problem, the mapped
kernels, Ipopt's KKT matrix and MUMPS's factors) grows linearly with the number of intervals
``N``, in proportion to the non-zeros of the KKT matrix (the constraint Jacobian, the upper
triangle of the Lagrangian's Hessian, and one diagonal entry per variable and per constraint).
Those are counted per interval from the problem's structure (no CasADi needed):

* variables: the state ``x`` (``3 + 2 n_B``, ``3 + 3 n_B`` with jerk control) and the control
  ``u`` (``n_B``) of each point, one point per interval (two with Hermite-Simpson's midpoints);
* constraints: ``n_x`` per collocation defect (two with Hermite-Simpson), ``n_B`` per interior
  Bernstein coefficient of each limited derivative, ``n_B`` torque rows and one attitude row per
  point when those are asked;
* Hessian: the kernels are nonlinear in ``k = 3 + 2 n_B`` entries of a point (attitude, balance
  positions and rates; the controls too with torque limits), dense among them, plus the control's
  diagonal: ``k (k + 1) / 2 + n_B`` per point;
* Jacobian: fitted on the planner's own counts (paper robot with 1 and 3 balance joints, Baxter
  with 7; both transcriptions, both controls, limits on and off; within 6 %):
  ``5.46 n_w + 3.60 n_g`` per Hermite-Simpson interval, ``4.94 n_w + 2.15 n_g`` per trapezoidal
  one, plus ``3 n_B`` per torque row.

Memory and time per non-zero were measured (peak resident memory with ``getrusage``, wall times)
on the paper robot (3 balance joints: 184, 231 and 298 MB at N = 100, 400, 800) and Baxter
(7: 209 and 323 MB at N = 100 and 400): 385-396 bytes per non-zero above a base of about 170 MB,
an NLP build of 9-18 us per non-zero, and 0.4-2.5 us per non-zero and Ipopt iteration (quiet to
loaded 2-core machine).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from balance_opt.optimal.collocation import Transcription

#: Bytes of memory per non-zero of the KKT matrix (measured: 385-396).
BYTES_PER_NONZERO = 400
#: Memory of the process before the NLP: Python, Pinocchio, CasADi, the kernels (170-182 MB).
BASE_BYTES = 200 * 2**20
#: Share of the machine's physical memory one optimal problem may take.
MEMORY_FRACTION = 0.5
#: Budget where the physical memory cannot be read [bytes].
FALLBACK_BUDGET = 4 * 2**30
#: Wall time of the NLP build per non-zero [s] (measured 9-18 us).
BUILD_SECONDS_PER_NONZERO = 15e-6
#: Wall time of one Ipopt iteration per non-zero [s] (measured 0.4-2.5 us).
ITERATION_SECONDS_PER_NONZERO = 1e-6
#: Jacobian non-zeros per variable and per constraint of an interval, by transcription (fitted).
JACOBIAN_FIT = {"hermite-simpson": (5.46, 3.60), "trapezoidal": (4.94, 2.15)}


@dataclass(frozen=True)
class ProblemSize:
    """The estimated size of one optimal problem.

    Attributes:
        intervals: ``N``.
        variables, constraints: lengths of the decision and constraint vectors.
        nonzeros: non-zeros of the KKT matrix (Jacobian, Hessian triangle, diagonal).
    """

    intervals: int
    variables: int
    constraints: int
    nonzeros: int

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
        """Estimated wall time of one Ipopt iteration [s]."""
        return ITERATION_SECONDS_PER_NONZERO * self.nonzeros


def _per_interval(n_B: int, options) -> tuple[float, float, float]:
    """(variables, constraints, KKT non-zeros) per interval of the problem of ``options``."""
    tr = Transcription(options.transcription)
    points = 2 if tr.has_midpoints else 1
    jerk = options.control == "jerk"
    n_x = 3 + (3 if jerk else 2) * n_B
    n_w = points * (n_x + n_B)
    levels = {
        "acceleration": options.acceleration_limits,
        "velocity": options.velocity_limits,
        "position": options.position_limits,
    }
    degree = tr.control_degree + (1 if jerk else 0)  # of the acceleration polynomial
    interior = sum(max(degree + i - 1, 0) for i, on in enumerate(levels.values()) if on)
    torque_rows = points * n_B if options.torque_limits else 0
    n_g = points * n_x  # Hermite-Simpson: a midpoint defect and a Simpson defect
    n_g += n_B * interior + torque_rows + (points if options.path_attitude_bound else 0)
    k = 3 + 2 * n_B + (n_B if options.torque_limits else 0)
    hessian = points * (k * (k + 1) / 2 + n_B)
    a, b = JACOBIAN_FIT[tr.name]
    jacobian = a * n_w + b * n_g + 3 * n_B * torque_rows
    return n_w, n_g, jacobian + hessian + n_w + n_g


def problem_size(n_B: int, options) -> ProblemSize:
    """The size of the optimal problem with ``n_B`` balance joints and the planner ``options``
    (a :class:`~balance_opt.optimal.options.PlannerOptions`)."""
    n_w, n_g, nonzeros = _per_interval(n_B, options)
    N = options.intervals
    return ProblemSize(N, round(n_w * N), round(n_g * N), round(nonzeros * N))


def memory_budget() -> float:
    """Memory one optimal problem may take: :data:`MEMORY_FRACTION` of the machine's physical
    memory (:data:`FALLBACK_BUDGET` where it cannot be read) [bytes]."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_BUDGET
    return MEMORY_FRACTION * total if total > 0 else FALLBACK_BUDGET


def largest_intervals(n_B: int, options, budget: float) -> int:
    """The largest ``N`` whose problem fits in ``budget`` bytes."""
    _, _, nonzeros = _per_interval(n_B, options)
    return max(0, math.floor((budget - BASE_BYTES) / (BYTES_PER_NONZERO * nonzeros)))
