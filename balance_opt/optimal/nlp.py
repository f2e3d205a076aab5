"""Building the compiled balance NLP of one structure. Its nonlinear work is in the point
kernels (:class:`~balance_opt.optimal.model.PointKernels`: the outputs ``y`` of one collocation
point and their derivatives), mapped over the points; the outer problem (the cost and the rows of
``g`` in the variables ``w`` and the kernels' outputs ``Y``) is linear in ``Y``, so Ipopt's
derivatives are the outer problem's plus the kernels' scattered to ``w``."""

from __future__ import annotations

import ctypes
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import casadi as cs
import numpy as np

from balance_opt import progress
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
from balance_opt.optimal.late_drift import LateDrift
from balance_opt.optimal.layout import BlockStack, parameter_layout, variable_layout
from balance_opt.optimal.model import PlannerModel, PointKernels, kernel_key
from balance_opt.optimal.objectives import OBJECTIVES, RunningCost, TerminalCost
from balance_opt.optimal.options import DEFAULT_IPOPT, PlannerOptions
from balance_opt.optimal.problem import StructureKey
from balance_opt.optimal.terms import SymbolicNLP, Term
from balance_opt.optimal.timing import MISSION_LEVELS, MissionTiming

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


@dataclass
class _Outer:
    """The outer problem's functions (SX)."""

    cost: cs.Function  # (w, y, p) -> f
    constraints: cs.Function  # (w, y, p) -> g
    gradient: cs.Function  # (w, p) -> (f at y = 0, f_w, f_Y^T)
    jacobian: cs.Function  # (w, p) -> (G_w, G_Y)
    hessian: cs.Function  # (w, p, lam_f, lam_g) -> (triu d2L/dw2, dL/dy = mu)


def build_structure(model: PlannerModel, key: StructureKey, problem, path=None) -> NLPStructure:
    """Build and compile the NLP of a structure, the parameters laid out as ``problem``'s (a
    :class:`~balance_opt.optimal.problem.BalanceProblem`; with a free mission timing, of its
    :class:`~balance_opt.optimal.timing.MissionPath` ``path``)."""
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
    solver = _ipopt_solver(kernels, inputs, variables, parameters, outer, rows.size, ipopt)
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
) -> tuple[_Outer, BlockStack, tuple[Term, ...]]:
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
    return _outer_functions(w, cs.vec(Y), p, cost, g), rows, tuple(row_terms)


def mission_labels(model: PlannerModel) -> list[str]:
    """Rows of a free timing's mission joints at a point (kernel inputs after ``x``, ``u``)."""
    joints = model.robot.mission.joints
    return [f"{j} {kind}" for kind in MISSION_LEVELS for j in joints]


def _outer_functions(w, y, p, cost, g) -> _Outer:
    """The outer problem's value and derivatives, checked linear in the kernel outputs ``y``."""
    lam_g = cs.SX.sym("lam_g", g.numel())
    lam_f = cs.SX.sym("lam_f")
    lagrangian = lam_f * cost + cs.dot(lam_g, g)
    G_Y = cs.jacobian(g, y)
    f_Y = cs.jacobian(cost, y)
    if cs.depends_on(G_Y, cs.vertcat(w, y)) or cs.depends_on(f_Y, cs.vertcat(w, y)):
        raise AssertionError("the outer problem must be linear in the kernel outputs")
    return _Outer(
        # apart: Ipopt evaluates the cost alone at every trial point of its line search
        cs.Function("outer_cost", [w, y, p], [cost]),
        cs.Function("outer_g", [w, y, p], [g]),
        cs.Function(
            "outer_grad",
            [w, p],
            [cs.substitute(cost, y, cs.DM.zeros(y.shape)), cs.gradient(cost, w), f_Y.T],
        ),
        cs.Function("outer_jac", [w, p], [cs.jacobian(g, w), G_Y]),
        cs.Function(
            "outer_hess",
            [w, p, lam_f, lam_g],
            [cs.triu(cs.hessian(lagrangian, w)[0]), cs.gradient(lagrangian, y)],
        ),
    )


def _scattered(
    values: cs.MX,
    sparsity: cs.Sparsity,
    n_points: int,
    rows_of_point,
    cols_of_point,
    shape,
    upper: bool = False,
) -> cs.MX:
    """The nonzeros of a mapped per-point sparse output (``n_points`` copies of ``sparsity``
    side by side) placed into one global sparse matrix."""
    local_rows, local_cols = (np.asarray(v) for v in sparsity.get_triplet())
    nnz = local_rows.size
    rows = np.concatenate([rows_of_point(i)[local_rows] for i in range(n_points)])
    cols = np.concatenate([cols_of_point(i)[local_cols] for i in range(n_points)])
    if upper:
        rows, cols = np.minimum(rows, cols), np.maximum(rows, cols)
    global_sp, mapping = cs.Sparsity.triplet(
        int(shape[0]), int(shape[1]), rows.tolist(), cols.tolist(), False
    )
    mapping = np.asarray(mapping)
    if mapping.size != nnz * n_points or np.unique(mapping).size != mapping.size:
        raise AssertionError("overlapping per-point blocks")  # every variable belongs to one point
    return cs.sparsity_cast(values.nz[mapping.tolist()], global_sp)


def _derivatives(kernels: PointKernels, outer: _Outer, w, p, Z, data, point_idx, n_g) -> dict:
    """Ipopt's ``grad_f``, ``jac_g`` and ``hess_lag``: the outer problem's, plus the kernels'
    mapped over the points and scattered to ``w`` (``dY/dw`` is block diagonal, and so is the
    kernels' part of the Hessian, weighted by ``mu``)."""
    n_y, n_points, n_w, n_pt = kernels.n_y, point_idx.shape[1], w.numel(), point_idx.size
    f0, f_w, f_Y = outer.gradient(w, p)
    seeds = cs.reshape(f_Y, n_y, n_points)[: kernels.n_cost, :]  # none on outputs out of it
    cy, grad_z = kernels.gradient.map(n_points)(Z, *data, seeds)
    scatter_w = np.empty(n_pt, dtype=int)
    scatter_w[point_idx.ravel(order="F")] = np.arange(n_pt)
    grad_points = cs.vertcat(cs.vec(grad_z)[scatter_w.tolist()], cs.MX.zeros(n_w - n_pt))
    Y, dY = kernels.jacobian.map(n_points)(Z, *data)
    dYdw = _scattered(
        dY,
        kernels.jacobian.sparsity_out(1),
        n_points,
        lambda i: n_y * i + np.arange(n_y),
        lambda i: point_idx[:, i],
        (n_y * n_points, n_w),
    )
    G_w, G_Y = outer.jacobian(w, p)
    g = outer.constraints(w, cs.vec(Y), p)
    lf, lg = cs.MX.sym("lam_f"), cs.MX.sym("lam_g", n_g)
    H_outer, mu = outer.hessian(w, p, lf, lg)
    d2 = kernels.hessian.map(n_points)(Z, *data, cs.reshape(mu, kernels.n_y, n_points))
    H_kernel = _scattered(
        d2,
        kernels.hessian.sparsity_out(0),
        n_points,
        lambda i: point_idx[:, i],
        lambda i: point_idx[:, i],
        (n_w, n_w),
        upper=True,
    )
    return {
        "grad_f": cs.Function(
            "nlp_grad_f",
            [w, p],
            [f0 + cs.sum2(cy), f_w + grad_points],
            ["x", "p"],
            ["f", "grad_f_x"],
        ),
        "jac_g": cs.Function(
            "nlp_jac_g", [w, p], [g, G_w + cs.mtimes(G_Y, dYdw)], ["x", "p"], ["g", "jac_g_x"]
        ),
        "hess_lag": cs.Function(
            "nlp_hess_l",
            [w, p, lf, lg],
            [H_outer + H_kernel],
            ["x", "p", "lam_f", "lam_g"],
            ["triu_hess_gamma_x_x"],
        ),
    }


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
    outer: _Outer,
    n_g: int,
    ipopt: dict,
) -> cs.Function:
    """The NLP in MX (the kernels mapped over the points, the outer problem on top) with its
    assembled derivatives, handed to Ipopt."""
    point_idx = _point_indices(variables)
    point_flat = point_idx.ravel(order="F")
    if not np.array_equal(np.sort(point_flat), np.arange(point_flat.size)):
        raise AssertionError("the points' variables must come first, each in one point")
    w, p = cs.MX.sym("w", variables.size), cs.MX.sym("p", parameters.size)
    Z = cs.reshape(w[point_flat.tolist()], kernels.n_z, point_idx.shape[1])
    par = parameters.unpack(p, SimpleNamespace)
    data = (par.mission, *(getattr(par, name) for name in inputs))
    n_points = point_idx.shape[1]
    Y = kernels.value.map(n_points)(Z, *data)
    g = outer.constraints(w, cs.vec(Y), p)
    if kernels.cost is not None:  # the cost from the kernel without the outputs out of it
        Y = cs.vertcat(
            kernels.cost.map(n_points)(Z, *data),
            cs.MX.zeros(kernels.n_y - kernels.n_cost, n_points),
        )
    f = outer.cost(w, cs.vec(Y), p)
    # with the live progress line (balance_opt.progress); returns at once when it is off
    solver = progress.nlpsol(
        "balance_nlp",
        {"x": w, "p": p, "f": f, "g": g},
        {
            "ipopt": ipopt,
            "print_time": False,
            "record_time": True,
            "calc_lam_p": False,
            "calc_lam_x": False,
            **_derivatives(kernels, outer, w, p, Z, data, point_idx, n_g),
        },
    )
    one_thread_for_ipopt()  # the plugin, and its OpenBLAS, are loaded now
    return solver


#: The environment variables OpenBLAS reads its number of threads from: one set overrides
#: the choice.
THREADS_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def casadi_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS that CasADi's Ipopt plugin loaded, or ``None`` when none is loaded (before
    the first ``nlpsol``, or another build of CasADi). The wheel holds several copies of the
    file under different names: opening one by its path could load a second, unused instance,
    so it is looked up by name among the loaded libraries only (``RTLD_NOLOAD``)."""
    if not hasattr(os, "RTLD_NOLOAD"):
        return None  # no way to find the loaded one without loading another
    mode = os.RTLD_NOLOAD | os.RTLD_LAZY
    for path in sorted(Path(cs.__file__).parent.glob("libcasadi-tp-openblas*")):
        try:
            lib = ctypes.CDLL(path.name, mode=mode)
            lib.openblas_get_num_threads  # noqa: B018 (raises AttributeError without it)
        except (OSError, AttributeError):
            continue
        return lib
    return None


def one_thread_for_ipopt() -> None:
    """Set CasADi's OpenBLAS to one thread for Ipopt's linear algebra (each time an NLP is
    built: cheap), unless one of :data:`THREADS_VARIABLES` is set."""
    if any(os.environ.get(name) for name in THREADS_VARIABLES):
        return
    lib = casadi_openblas()
    if lib is None:
        log.debug("CasADi's Ipopt loaded no OpenBLAS of its own: its threads are left alone")
        return
    lib.openblas_set_num_threads(ctypes.c_int(1))
