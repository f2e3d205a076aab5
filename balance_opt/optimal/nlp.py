"""Building the compiled balance NLP of one structure: its terms, their point kernels
(:class:`~balance_opt.optimal.model.PointKernels`: the outputs ``y`` of one collocation point
and their derivatives), their parts of the cost and their rows of ``g``, linear in the kernels'
outputs, handed to Ipopt as an NLP of per-point kernels (:mod:`balance_opt.solvers.kernel_nlp`)."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from types import SimpleNamespace

import casadi as cs
import numpy as np

from balance_opt.optimal.collision import Collision
from balance_opt.optimal.collocation import Transcription, joint_chain_coefficients
from balance_opt.optimal.constraints import (
    DERIVATIVES,
    Collocation,
    EndConditions,
    InitialState,
    JerkLimit,
    JointLimit,
    PathAttitudeBound,
    TerminalAttitudeBound,
    TorqueLimit,
)
from balance_opt.optimal.exact_rows import ExactRows
from balance_opt.optimal.late_drift import LateDrift
from balance_opt.optimal.layout import BlockStack, parameter_layout, variable_layout
from balance_opt.optimal.model import PlannerModel, PointKernels, kernel_key
from balance_opt.optimal.objectives import OBJECTIVES, RunningCost, TerminalCost
from balance_opt.optimal.options import DEFAULT_IPOPT, PlannerOptions
from balance_opt.optimal.problem import StructureKey
from balance_opt.optimal.terms import SymbolicNLP, Term
from balance_opt.optimal.timing import MISSION_LEVELS, MissionTiming
from balance_opt.solvers.kernel_nlp import Outer, kernel_solver, outer_functions

log = logging.getLogger(__name__)


def terms_of(key: StructureKey) -> tuple[Term, ...]:
    """The terms of a structure, in the order of their kernel outputs, of their parts of the
    cost, of their rows in ``g`` and of their variable bounds (later terms override earlier
    ones: the fixed initial and end values win over the limits)."""
    transcription = Transcription(key.transcription)
    objective = OBJECTIVES[key.objective]
    terms: list[Term] = [
        Collocation(key.control),
        RunningCost(objective.regularised),
        TerminalCost("peak_terminal" if objective.regularised else "terminal"),
    ]
    terms += [
        JointLimit(kind, transcription, key.control, key.between_points)
        for kind in DERIVATIVES
        if kind in key.joint_limits
    ]
    if "jerk" in key.joint_limits:
        terms.append(JerkLimit(transcription, key.control))
    if key.torque_limits:
        terms.append(TorqueLimit(key.control, key.momentum))
    terms += objective.terms(key.control)
    if key.late_drift and key.objective == "peak":  # the epigraph stage's
        terms.append(LateDrift())
    if key.path_attitude_bound:
        terms.append(PathAttitudeBound())
    if key.terminal_attitude_bound:
        terms.append(TerminalAttitudeBound())
    if key.collision:
        terms.append(Collision(key.collision))
    if key.exact:
        terms.append(ExactRows(key.exact))
    if key.timing:
        terms.append(MissionTiming(transcription))
    return (*terms, InitialState(), EndConditions())


def point_kernels(
    model: PlannerModel,
    control: str = "acceleration",
    extra: tuple[Term, ...] = (),
    momentum: bool = False,
    timing: bool = False,
) -> PointKernels:
    """The point kernels of every structure's outputs (the dynamics, the running cost) and of
    the ``extra`` terms'."""
    terms = (Collocation(control), RunningCost(regularised=False), *extra)
    outputs = tuple(o for term in terms for o in term.outputs(model))
    return model.kernels(control, outputs, momentum, timing)


@dataclass
class NLPStructure:
    """The compiled NLP of one structure, shared by every problem of that structure."""

    key: StructureKey
    solver: cs.Function
    variables: BlockStack
    parameters: BlockStack
    rows: BlockStack
    row_terms: tuple[Term, ...]
    terms: tuple[Term, ...]
    kernels: PointKernels
    build_time: float

    @property
    def kernel_key(self) -> tuple:
        return kernel_key(*self.kernels.variant)


def build_structure(model: PlannerModel, key: StructureKey, problem, path=None) -> NLPStructure:
    """Build and compile the NLP of a structure, the parameters laid out as ``problem``'s (a
    :class:`~balance_opt.optimal.problem.BalanceProblem`; with a free mission timing, of its
    :class:`~balance_opt.motion.retiming.MissionPath` ``path``)."""
    start = time.perf_counter()
    terms = terms_of(key)
    outputs = tuple(o for term in terms for o in term.outputs(model))
    kernels = model.kernels(key.control, outputs, key.momentum, bool(key.timing))
    tr = Transcription(key.transcription)
    N = key.intervals
    joints = [model.robot.joint_names[i] for i in model.robot.balance_indices]
    variables = variable_layout(
        tr,
        N,
        model.state_labels(key.control),
        [f"{j} {key.control}" for j in joints],
        mission_labels=mission_labels(model) if key.timing else (),
        extra=tuple(block for term in terms for block in term.variables()),
    )
    parameters = parameter_layout({k: v for term in terms for k, v in term.values(problem).items()})
    outer, rows, row_terms = _outer_problem(model, key, kernels, variables, parameters, terms, path)
    ipopt = ipopt_options_for(key.objective, problem.options, key.intervals)
    inputs = tuple(dict(i for o in outputs for i in o.inputs))
    solver = _ipopt_solver(kernels, inputs, variables, parameters, outer, ipopt)
    build_time = time.perf_counter() - start
    log.debug(
        "%s built in %.3f s: %d variables, %d rows", key, build_time, variables.size, rows.size
    )
    return NLPStructure(
        key, solver, variables, parameters, rows, row_terms, terms, kernels, build_time
    )


def _outer_problem(
    model: PlannerModel,
    key: StructureKey,
    kernels: PointKernels,
    variables: BlockStack,
    parameters: BlockStack,
    terms: tuple[Term, ...],
    path=None,
) -> tuple[Outer, BlockStack, tuple[Term, ...]]:
    """The outer problem in SX: the terms' parts of the cost summed, and their rows stacked
    into ``g``."""
    tr, N = Transcription(key.transcription), key.intervals
    w = cs.SX.sym("w", variables.size)
    Y = cs.SX.sym("Y", kernels.n_y, tr.n_points(N))
    p = cs.SX.sym("p", parameters.size)
    v = variables.unpack(w)
    par = parameters.unpack(p, SimpleNamespace)
    starts = [v.X[r, :-1] for r in model.joint_rows(key.control)]
    symbols = SymbolicNLP(
        key=key,
        transcription=tr,
        joints=tuple(model.robot.joint_names[i] for i in model.robot.balance_indices),
        state_labels=tuple(model.state_labels(key.control)),
        variables=v,
        levels=joint_chain_coefficients(tr, starts, v.U, v.Um, par.h),
        outputs=kernels.rows(Y),
        parameters=par,
        model=model,
        mission_path=path,
        mission_joints=tuple(model.robot.mission.joints),
    )
    cost = None
    for term in terms:
        part = term.cost(symbols)
        if part is not None:
            cost = part if cost is None else cost + part
    if kernels.n_cost < kernels.n_y and cs.depends_on(cost, cs.vec(Y[kernels.n_cost :, :])):
        raise AssertionError("the cost must not depend on the outputs out of the cost")
    rows, row_terms, parts = BlockStack(), [], []
    for term in terms:
        for block, values in term.rows(symbols):
            rows.add(block)
            row_terms.append(term)
            parts.append(cs.vec(values))
    g = cs.vertcat(*parts)
    return outer_functions(w, cs.vec(Y), p, cost, g), rows, tuple(row_terms)


def mission_labels(model: PlannerModel) -> list[str]:
    """Rows of a free timing's mission joints at a point (kernel inputs after ``x``, ``u``)."""
    joints = model.robot.mission.joints
    return [f"{j} {kind}" for kind in MISSION_LEVELS for j in joints]


def ipopt_options_for(
    objective: str, options: PlannerOptions, intervals: int | None = None
) -> dict:
    """Ipopt's options for a structure of ``objective`` (``"peak"``, ``"smooth"``,
    ``"integral"``) on ``intervals`` (default: the options' own): the defaults, the tolerance
    and iteration limit, the stage's own options (:meth:`Stage.ipopt_at`), then the user's
    ``optimal.ipopt``."""
    ipopt = dict(DEFAULT_IPOPT)
    ipopt.update({"tol": options.tolerance, "max_iter": int(options.max_iterations)})
    n = options.intervals if intervals is None else intervals
    ipopt.update(next((s.ipopt_at(n) for s in options.stages if s.name == objective), {}))
    ipopt.update(options.ipopt)
    return ipopt


def _point_indices(variables: BlockStack) -> np.ndarray:
    """(n_z, n_points) indices into ``w`` of each point's ``z = [x; u]``, points in the order
    nodes, then midpoints."""

    def indices(name):
        b = variables.by_name[name]
        return b.offset + np.arange(b.size).reshape(b.shape, order="F")

    names = ["X", "U"] + (["M"] if "M" in variables.by_name else [])
    if "Xm" in variables.by_name:
        return np.vstack([np.hstack([indices(n), indices(n + "m")]) for n in names])
    return np.vstack([indices(n) for n in names])


def _ipopt_solver(
    kernels: PointKernels,
    inputs: tuple[str, ...],
    variables: BlockStack,
    parameters: BlockStack,
    outer: Outer,
    ipopt: dict,
) -> cs.Function:
    """The NLP handed to Ipopt (:func:`~balance_opt.solvers.kernel_nlp.kernel_solver`): the
    kernels at the points of :func:`_point_indices`, fed the mission data and the terms'
    kernel ``inputs`` from the parameters."""

    def data(p):
        par = parameters.unpack(p, SimpleNamespace)
        return (par.mission, *(getattr(par, name) for name in inputs))

    point_idx = _point_indices(variables)
    return kernel_solver(
        "balance_nlp", kernels, outer, point_idx, variables.size, parameters.size, data, ipopt
    )
