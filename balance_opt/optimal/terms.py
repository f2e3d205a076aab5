"""The term protocol of the balance NLP: every nonlinear piece of the planner, a constraint or a
part of the objective, is one :class:`Term` that owns everything about it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from balance_opt.errors import SolverError
from balance_opt.motion.result import LIMIT_TOLERANCE, BalanceResult
from balance_opt.optimal.collocation import Transcription
from balance_opt.optimal.layout import Block, Solution

if TYPE_CHECKING:
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.problem import BalanceProblem


#: Where the re-simulated plan's torque exceeds its effort limit (beyond
#: :data:`~balance_opt.motion.result.EFFORT_TOLERANCE`), the refinement bounds it this much below the
#: limit (relative) on that interval: the torque rows hold at the collocation points only, and a
#: bound at the limit itself leaves the torque between them just over it again (+0.08 % at the
#: samples was reported as a success before).
TORQUE_MARGIN = 1e-3
#: Points per collocation interval, both ends included, at which the refinement and the check
#: evaluate the torques (:meth:`TorqueLimit.torques`): the torque of a plan bent around a body
#: peaks inside an interval, and a coarse grid there misses a peak by more than the tolerance.
TORQUE_POINTS = 65


class PlannerSolverError(SolverError):
    """Ipopt did not solve the balance NLP, or its plan is no plan (a term's :meth:`~Term.accept`)."""

    def __init__(
        self, message: str, status: str, result, constraint: str, time: float, violation: float
    ):
        super().__init__(message, status, result)
        self.constraint = constraint
        self.time = time
        self.violation = violation


@dataclass(frozen=True)
class Violation:
    """The worst breach of a constraint by a motion."""

    constraint: str
    time: float
    amount: float
    unit: str

    def __str__(self) -> str:
        return f"{self.constraint} at t = {self.time:.3f} s, by {self.amount:.4g} {self.unit}"


@dataclass(frozen=True)
class SymbolicNLP:
    """What the rows and the cost are made of, in the build (CasADi SX): the structure's key,
    the variables and parameters unpacked, the balance joints' Bernstein levels and the point
    kernels' outputs by name (:attr:`Term.outputs`), each (size, n_points)."""

    key: Any
    transcription: Transcription
    joints: tuple[str, ...]
    state_labels: tuple[str, ...]
    variables: Solution
    levels: list[list]
    outputs: dict
    parameters: Any
    model: Any = None
    mission_path: Any = None
    mission_joints: tuple[str, ...] = ()


@dataclass(frozen=True)
class Point:
    """The symbols of one collocation point a term's :class:`Output` is made of: the state
    ``x``, the control ``u``, the data ``m`` (``[q_M; q_dot_M; q_ddot_M; h0]``, a free timing's
    mission rows from the variables), the arm configuration ``q`` (``[q_M; q_B]`` through the
    mimic map), the dynamics ``x_dot`` and the base rate ``omega``, the kernel's inputs by name."""

    model: Any
    control: str
    momentum: bool
    x: Any
    u: Any
    m: Any
    q: Any
    x_dot: Any
    omega: Any
    inputs: dict


@dataclass(frozen=True)
class Output:
    """Rows of the point kernels' outputs ``y`` that a term needs (``make(point)``, ``size``
    rows, :class:`Point`), keyed by ``tag`` (in the kernels' key and file names). ``inputs``:
    the kernel inputs it reads besides the point's ``z`` and ``m``, ``(name, rows)``, fed from
    the NLP's parameters of that name. An output out of the cost (``in_cost`` false, e.g. the
    collision rows) is left out of the kernel Ipopt evaluates for the cost alone, at every trial
    point of its line search: such outputs come last. An output ``with_dynamics`` is made in one
    function with the dynamics (the running cost: it shares ``omega``)."""

    name: str
    size: int
    tag: str
    make: Callable = field(compare=False, repr=False)
    in_cost: bool = True
    inputs: tuple[tuple[str, int], ...] = ()
    with_dynamics: bool = False


#: Rows a term adds to ``g``: a block (not yet stacked) and its values, (rows, columns), symbolic.
Rows = tuple[Block, Any]


def block_rows(nlp: SymbolicNLP, name, labels, unit, values, taus=None, per_interval=False):
    """One block of rows ``values`` named ``name``, a row per label, all in ``unit``, at ``taus``
    (default: every collocation point), or on the intervals that start there."""
    taus = nlp.transcription.point_taus(nlp.key.intervals) if taus is None else taus
    return [(Block(name, tuple(labels), (unit,) * len(labels), taus, per_interval), values)]


def worst(problem, excess, t: np.ndarray, what: str, unit: str) -> Violation | None:
    """The largest entry of ``excess`` (T, n) above :data:`LIMIT_TOLERANCE`, as a violation of
    ``what`` (formatted with the balance joint of its column) at ``t[row]``, or ``None``."""
    excess = np.asarray(excess, dtype=float)
    if excess.size == 0 or not excess.max() > LIMIT_TOLERANCE:
        return None
    row, col = np.unravel_index(int(np.argmax(excess)), excess.shape)
    what = what.format(problem.balance_joints[col])
    return Violation(what, float(t[row]), float(excess[row, col]), unit)


def rounds_tried(result: BalanceResult) -> str:
    """``"after n refinement rounds"`` of a refined plan (for the message of a failure)."""
    refinement = (getattr(result, "solver", None) and result.solver.refinement) or {}
    n = refinement.get("rounds", 0)
    said = f"after {n} refinement round{'' if n == 1 else 's'}"
    if "failed" in refinement:
        said += f" (the next re-solve failed: {refinement['failed']})"
    return said


@dataclass(frozen=True)
class Size:
    """A term's share of its NLP per collocation interval (the problem-size estimate,
    :mod:`balance_opt.optimal.budget`): decision variables, rows of ``g`` and non-zeros of the
    KKT matrix (its Jacobian's and Hessian's entries, one per variable and per row besides)."""

    variables: float = 0.0
    rows: float = 0.0
    nonzeros: float = 0.0

    def __add__(self, other: Size) -> Size:
        return Size(
            self.variables + other.variables,
            self.rows + other.rows,
            self.nonzeros + other.nonzeros,
        )


def points_per_interval(transcription: Transcription) -> int:
    """Collocation points per interval: a node, and the midpoint if the transcription has one."""
    return 2 if transcription.has_midpoints else 1


class Term:
    """One nonlinear piece of the balance NLP, a constraint or a part of the objective. A term
    declares

    * :meth:`outputs`: what it needs the point kernels to compute at every collocation point
      (:class:`~balance_opt.optimal.model.Output`; they key the kernels);
    * :meth:`values`: its numbers in the parameter vector ``p`` (weights, scales, a bound the
      refinement lowers), by name, packed from the problem for every solve (their layout is
      read from the first problem's: a scalar, a column, or a matrix of columns);
    * :meth:`variables`: decision variables of its own (the peak's epigraph variable);
    * :meth:`cost`: its part of the objective (symbolic), if any;
    * :meth:`rows` and :meth:`row_bounds`: its rows of ``g`` (``(block, values)`` pairs, the
      block named for the failure messages) and their bounds (stacked column by column);
    * :meth:`bound_variables`: the bounds it puts on the variables (in place);
    * :meth:`check`: its worst violation by the re-simulated (continuous) motion, beyond
      :data:`~balance_opt.motion.result.LIMIT_TOLERANCE`;
    * :meth:`tighten`: the refinement's changes of
      :class:`~balance_opt.optimal.problem.Bounds` after a check, and what they tighten, in
      words;
    * :meth:`accept`: the refined plan's acceptance (it raises :class:`PlannerSolverError` if
      the plan is no plan);
    * :meth:`size`: its share of the NLP per interval, for the problem-size estimate made before
      anything is built (what is not per interval, e.g. the terminal rows, is left out).
    """

    name = "term"

    def outputs(self, model: PlannerModel) -> tuple[Output, ...]:
        return ()

    def values(self, problem: BalanceProblem) -> dict[str, Any]:
        return {}

    def variables(self) -> tuple[Block, ...]:
        return ()

    def cost(self, nlp: SymbolicNLP) -> Any:
        return None

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        return []

    def row_bounds(self, problem: BalanceProblem, block: Block) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError(f"{self.name} adds no rows")

    def bound_variables(self, problem: BalanceProblem, lower: Solution, upper: Solution) -> None:
        pass

    def check(self, problem: BalanceProblem, result: BalanceResult) -> Violation | None:
        return None

    def tighten(self, problem: BalanceProblem, result: BalanceResult) -> tuple[dict, list[str]]:
        return {}, []

    def accept(self, problem: BalanceProblem, result: BalanceResult) -> None:
        pass

    def size(self, n_B: int, transcription: Transcription) -> Size:
        """Its :class:`Size` per interval with ``n_B`` balance joints."""
        return Size()
