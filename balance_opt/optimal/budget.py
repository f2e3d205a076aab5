"""How much memory and time the optimal planner's problem needs, estimated before it is built.

Everything the planner allocates for its NLP (CasADi's graphs of the outer problem, the mapped
kernels, Ipopt's KKT matrix and MUMPS's factors) grows linearly with the number of intervals
``N``, in proportion to the non-zeros of the KKT matrix (the constraint Jacobian, the upper
triangle of the Lagrangian's Hessian, and one diagonal entry per variable and per constraint).
Those are counted per interval from the problem's structure (no CasADi needed):

* variables: the state ``x`` (``3 + 2 n_B``, ``3 + 3 n_B`` with jerk control) and the control
  ``u`` (``n_B``) of each point, one point per interval (two with Hermite-Simpson's midpoints);
* constraints: ``n_x`` per collocation defect (two with Hermite-Simpson), ``n_B`` per interior
  Bernstein coefficient of each limited derivative (limited: asked for, and finite for some
  balance joint), ``n_B`` torque rows per point with torque limits, and one attitude row per
  point with the peak objective (its epigraph) or a path attitude bound;
* Hessian: the kernels are nonlinear in ``k = 3 + 2 n_B`` entries of a point (attitude, balance
  positions and rates), dense among them, plus the control's diagonal: ``k (k + 1) / 2 + n_B``
  per point, and ``n_B^2`` more with torque limits;
* Jacobian: fitted on the planner's own counts (paper robot with 1 and 3 balance joints, Baxter
  with 7; both transcriptions, both controls, limits on and off; within 6 %):
  ``5.46 n_w + 3.60 n_g`` per Hermite-Simpson interval, ``4.94 n_w + 2.15 n_g`` per trapezoidal
  one (``n_g`` the defects and limit rows), plus ``3 n_B`` per torque row and 3 per attitude
  row (4 for the epigraph's, which also holds the peak variable).

Collision avoidance's rows (one per point for each body the balance arm moves, at most, of a
few non-zeros each; :mod:`balance_opt.optimal.collision`) are not counted: finding them needs
the robot's geometry, and they are few next to the defects.

A plan may build more than one NLP, all kept until it ends (:mod:`balance_opt.optimal.refine`):
the peak objective is solved in stages (the integral objective's plan and the smooth peak on a
coarser grid, :func:`~balance_opt.optimal.options.inner_intervals`, without the
rows between the points; then the epigraph), and a path attitude bound is approached through
the peak problem without it; the estimate adds them up, each on its own grid. (A failed
epigraph stage builds one more, the smooth peak on the plan's grid, as large as the integral
problem: it is not counted.)

Memory and time per non-zero were measured (peak resident memory with ``getrusage``, wall times)
on the paper robot (3 balance joints, integral objective: 184, 231 and 298 MB at N = 100, 400,
800; peak objective, two NLPs: 200 and 298 MB at N = 100 and 400) and Baxter (7, integral: 209
and 323 MB at N = 100 and 400): 355-406 bytes per non-zero above a base of about 170 MB, an NLP
build of 9-18 us per non-zero, and 0.4-2.5 us per non-zero and Ipopt iteration (quiet to loaded
2-core machine).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

import numpy as np

from balance_opt.optimal.collocation import Transcription
from balance_opt.optimal.options import inner_intervals

#: Bytes of memory per non-zero of the KKT matrix (measured: 355-406).
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
        nonzeros: non-zeros of the KKT matrices (Jacobian, Hessian triangle, diagonal) of
            every NLP the plan builds.
        problems: how many NLPs the plan builds.
    """

    intervals: int
    variables: int
    constraints: int
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


def _limited(options, limits) -> dict[str, bool]:
    """Which limit constraints the planner adds: asked for, and finite for some balance joint."""
    return {
        "acceleration": options.acceleration_limits
        and bool(np.isfinite(limits.acceleration).any()),
        "velocity": options.velocity_limits and bool(np.isfinite(limits.velocity).any()),
        "position": options.position_limits
        and bool((np.isfinite(limits.lower) | np.isfinite(limits.upper)).any()),
        "torque": options.torque_limits and bool(np.isfinite(limits.effort).any()),
    }


def _per_interval(options, limits) -> tuple[int, int, float]:
    """(variables, constraints, KKT non-zeros) per interval of the problem of ``options`` with
    the balance joints' ``limits``."""
    tr = Transcription(options.transcription)
    n_B = len(limits.lower)
    points = 2 if tr.has_midpoints else 1
    jerk = options.control == "jerk"
    n_x = 3 + (3 if jerk else 2) * n_B
    n_w = points * (n_x + n_B)
    limited = _limited(options, limits)
    degree = tr.control_degree + (1 if jerk else 0)  # of the acceleration polynomial
    interior = sum(
        max(degree + i - 1, 0)
        for i, kind in enumerate(("acceleration", "velocity", "position"))
        if limited[kind]
    )
    # Hermite-Simpson has a midpoint defect and a Simpson defect, trapezoidal one
    n_g_fit = points * n_x + n_B * interior
    torque_rows = points * n_B if limited["torque"] else 0
    peak = options.objective == "peak"
    path_rows = points if peak or options.path_attitude_bound is not None else 0
    a, b = JACOBIAN_FIT[tr.name]
    # a torque row depends on a point's positions, rates and controls; an attitude row on phi
    # (and the epigraph's on the peak variable too)
    jacobian = a * n_w + b * n_g_fit + 3 * n_B * torque_rows + (4 if peak else 3) * path_rows
    k = 3 + 2 * n_B
    hessian = points * (k * (k + 1) / 2 + n_B + (n_B**2 if limited["torque"] else 0))
    n_g = n_g_fit + torque_rows + path_rows
    return n_w, n_g, jacobian + hessian + n_w + n_g


#: What makes a problem an inner stage's, for its size: no joint-limit rows between the points.
_INNER = {"position_limits": False, "velocity_limits": False, "acceleration_limits": False}


def _built(options) -> list:
    """The options of every NLP a plan with ``options`` builds, each with its own intervals
    (see the module docstring)."""
    free = {"path_attitude_bound": None, "terminal_attitude_bound": None}
    built = [options]
    if options.path_attitude_bound is not None:
        built.append(dataclasses.replace(options, objective="peak", **free))
    staged = options.objective == "peak" or options.path_attitude_bound is not None
    inner = {**_INNER, "intervals": inner_intervals(options.intervals, options.transcription)}
    if staged:  # the first stage
        built.append(dataclasses.replace(options, objective="integral", **free, **inner))
    # a peak problem's path bound adds no rows: such a problem is the free one
    shapes = {
        (
            o.objective,
            o.objective != "peak" and o.path_attitude_bound is not None,
            o.terminal_attitude_bound is not None,
        ): o
        for o in reversed(built)
    }
    out = list(shapes.values())
    # the smooth stage: the peak problem without the epigraph (the integral's size), inner
    if staged:
        out.append(dataclasses.replace(options, objective="integral", **free, **inner))
    return out


def _nonzeros_per_interval(options, limits) -> float:
    """KKT non-zeros per interval of ``options`` of every NLP a plan with ``options`` builds
    (an inner stage's on its coarser grid count in proportion)."""
    N = options.intervals
    return sum(_per_interval(o, limits)[2] * o.intervals / N for o in _built(options))


def problem_size(options, limits) -> ProblemSize:
    """The size of the optimal problem of the planner ``options`` (a
    :class:`~balance_opt.optimal.options.PlannerOptions`) whose balance joints have the
    ``limits`` (a :class:`~balance_opt.model.robot.JointLimits`, one entry per balance joint):
    its variables and constraints, and the non-zeros of every NLP its plan builds."""
    n_w, n_g, _ = _per_interval(options, limits)
    N = options.intervals
    nonzeros = round(_nonzeros_per_interval(options, limits) * N)
    return ProblemSize(N, n_w * N, n_g * N, nonzeros, len(_built(options)))


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
    return max(0, math.floor((budget - BASE_BYTES) / (BYTES_PER_NONZERO * nonzeros)))
