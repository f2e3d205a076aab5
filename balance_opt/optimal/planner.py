"""The optimal balance planner: the paper's balance law (Eq. 31) posed as an optimal control
problem, transcribed by direct collocation and solved with Ipopt.

The balance arm's motion is chosen to keep the base still (integral of ``|omega_b|^2``), to
bring its attitude back at the end (``|log R_T|^2``: the motion is non-holonomic, so a closed
joint path can undo a rotation), and to stay smooth, while every balance joint respects its
position, velocity and acceleration limits (optionally torque limits) on the whole continuous
motion. The mission arm's motion is a hard input.

Pipeline, data first::

    options = PlannerOptions(intervals=100)                   # frozen settings
    nlp = build_balance_nlp(PlannerModel(robot), mission, q_B0, options)   # inspectable NLP
    result = nlp.solve()                                      # BalanceResult, re-simulated

or in one call :func:`plan_optimal`. The per-robot symbolic model (:class:`PlannerModel`) is
built once; the compiled NLP of one structure (intervals, transcription, control, which
constraints) is cached on it, and the mission, horizon, initial configuration, weights and
bounds are numeric inputs of that NLP (parameters and bounds), so building another problem of
the same structure costs milliseconds.

Decision variables (``Transcription`` in :mod:`balance_opt.optimal.collocation`, states in
:mod:`balance_opt.optimal.model`): states ``X`` at the nodes (n_x, N+1), controls ``U`` at the nodes
(n_u, N+1), and with Hermite-Simpson the same at the midpoints (``Xm``, ``Um``, (., N)). The
attitude is the rotation vector ``phi = log(R)`` at the initial attitude (exact terminal cost
and angle bounds, no norm constraint).

Assumptions: zero total momentum (the paper's case; a task with ``h0`` is refused upstream), the
base at its initial attitude and the balance arm at rest at ``q_B0`` at ``t = 0``.

Speed: the NLP's gradient, Jacobian and Hessian are assembled from per-point kernels with exact
derivatives (see :func:`_build_structure`), compiled to C once per robot when a compiler is
found; Ipopt (MUMPS) does the rest. ``benchmarks/bench_planner.py`` prints the times.

Every plan is re-simulated on a fine grid with numeric Pinocchio: the balance joints follow the
collocation polynomial (:class:`~balance_opt.optimal.collocation.CollocatedTrajectory`), the base
attitude is integrated from the rates momentum conservation forces, and the returned
:class:`~balance_opt.result.BalanceResult` holds that re-simulated motion: the plan's quality is
what the re-simulation says.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import casadi as cs
import numpy as np

from balance_opt.app.interrupts import raise_if_interrupted
from balance_opt.errors import InfeasibleLimitsError, InputError, SolverError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.rollout import replay
from balance_opt.motion.so3 import (
    quaternion_conjugate,
    quaternion_from_rotvec,
    quaternion_multiply,
    rotation_angle,
)
from balance_opt.optimal.collocation import (
    CollocatedTrajectory,
    Transcription,
    bernstein_value,
    joint_chain_coefficients,
)
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import (
    DEFAULT_IPOPT,
    GUESSES,
    SUCCESS_STATUSES,
    PlannerOptions,
)
from balance_opt.result import LIMIT_TOLERANCE, BalanceResult

log = logging.getLogger(__name__)

#: Parameters of the NLP before ``q_rest`` and the mission samples: ``h``, the terminal weight,
#: the running weights (4), ``1 / path bound^2``, ``1 / terminal bound^2``.
N_FIXED_PARAMETERS = 8


class PlannerSolverError(SolverError):
    """Ipopt did not solve the balance NLP.

    Attributes:
        status: Ipopt's return status.
        result: the last iterate, re-simulated, as a :class:`BalanceResult`.
        constraint: name of the most violated constraint.
        time: its time [s].
        violation: by how much it is violated (in its own unit).
    """

    def __init__(
        self, message: str, status: str, result, constraint: str, time: float, violation: float
    ):
        super().__init__(message, status, result)
        self.constraint = constraint
        self.time = time
        self.violation = violation


# ---------------------------------------------------------------------------------- structure
@dataclass(frozen=True)
class Block:
    """A block of variables or constraints: a matrix whose columns are time.

    Attributes:
        name: what the block holds (``"collocation (Simpson)"``, ``"torque"`` ...).
        rows: a label per row (``"balance_joint2 velocity"`` ...).
        units: a unit per row.
        taus: the time of each column in units of the interval length ``h`` (for a block
            of interval constraints, the interval's start).
        offset: index of its first entry in the stacked vector (column-major).
        per_interval: whether a column is a collocation interval rather than an instant.
    """

    name: str
    rows: tuple[str, ...]
    units: tuple[str, ...]
    taus: np.ndarray
    offset: int
    per_interval: bool = False

    @property
    def size(self) -> int:
        return len(self.rows) * len(self.taus)

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.rows), len(self.taus)

    def locate(self, index: int) -> tuple[str, str, float]:
        """``(row label, unit, tau)`` of a global index inside this block."""
        local = index - self.offset
        row, col = local % len(self.rows), local // len(self.rows)
        return self.rows[row], self.units[row], float(self.taus[col])


def _unit(label: str, control_unit: str = "rad/s^2") -> str:
    if label.startswith("attitude"):
        return "rad"
    for kind, unit in (
        ("position", "rad"),
        ("velocity", "rad/s"),
        ("acceleration", "rad/s^2"),
        ("jerk", "rad/s^3"),
        ("torque", "N m"),
    ):
        if label.endswith(kind):
            return unit
    return control_unit


@dataclass
class NLPStructure:
    """The compiled NLP of one structure, shared by every problem of that structure.

    Attributes:
        key: the structure (intervals, transcription, control, constraint switches, solver options).
        solver: the CasADi ``nlpsol`` (Ipopt).
        variables: blocks of the decision vector ``X``, ``Xm``, ``U``, ``Um`` by name.
        constraints: blocks of the constraint vector, in order.
        n_w, n_g, n_p: sizes of the decision, constraint and parameter vectors.
        build_time: wall time to build it [s].
    """

    key: tuple
    solver: cs.Function
    variables: dict[str, Block]
    constraints: list[Block]
    n_w: int
    n_g: int
    n_p: int
    bernstein_levels: dict[str, tuple[int, ...]]
    build_time: float

    def constraint_block(self, index: int) -> Block:
        offsets = [b.offset for b in self.constraints]
        return self.constraints[int(np.searchsorted(offsets, index, side="right")) - 1]

    def variable_block(self, index: int) -> Block:
        blocks = sorted(self.variables.values(), key=lambda b: b.offset)
        return blocks[int(np.searchsorted([b.offset for b in blocks], index, side="right")) - 1]


def _structure_key(robot: FloatingRobot, options: PlannerOptions) -> tuple:
    lim = robot.limits.subset(robot.balance_indices)
    finite = {
        "position": options.position_limits
        and bool(np.any(np.isfinite(lim.lower) | np.isfinite(lim.upper))),
        "velocity": options.velocity_limits and bool(np.any(np.isfinite(lim.velocity))),
        "acceleration": options.acceleration_limits and bool(np.any(np.isfinite(lim.acceleration))),
    }
    return (
        int(options.intervals),
        options.transcription,
        options.control,
        tuple(sorted(k for k, v in finite.items() if v)),
        bool(options.torque_limits and np.any(np.isfinite(lim.effort))),
        options.path_attitude_bound is not None,
        options.terminal_attitude_bound is not None,
        options.tolerance,
        int(options.max_iterations),
        tuple(sorted((k, repr(v)) for k, v in options.ipopt.items())),
    )


def _bernstein_levels(tr: Transcription, control: str) -> dict[str, tuple[int, ...]]:
    """Interior Bernstein coefficients bounded per derivative: ``1 .. degree - 1`` (the first is
    the node's value and the last the next node's, both bounded as variables)."""
    d_u = tr.control_degree
    if control == "acceleration":
        degrees = {"acceleration": d_u, "velocity": d_u + 1, "position": d_u + 2}
    else:
        degrees = {"acceleration": d_u + 1, "velocity": d_u + 2, "position": d_u + 3}
    return {kind: tuple(range(1, degree)) for kind, degree in degrees.items()}


def _point_variable_indices(variables: dict[str, Block], has_midpoints: bool) -> np.ndarray:
    """(n_z, n_points) indices into the decision vector of each point's ``z = [x; u]``, points in
    the order nodes, then midpoints."""

    def idx(name):
        b = variables[name]
        return b.offset + np.arange(b.size).reshape(b.shape, order="F")

    X, U = idx("X"), idx("U")
    if has_midpoints:
        X, U = np.hstack([X, idx("Xm")]), np.hstack([U, idx("Um")])
    return np.vstack([X, U])


def _scatter(
    sparsity: cs.Sparsity, n_points: int, rows_of_point, cols_of_point, shape, upper: bool = False
):
    """Sparsity and nonzero permutation that place the nonzeros of a mapped per-point sparse
    output (``n_points`` copies of ``sparsity`` side by side) into one global sparse matrix.

    Args:
        sparsity: pattern of one point's block.
        rows_of_point, cols_of_point: ``f(i) -> array``: the global row and column of each local
            row and column of point ``i``.
        shape: the global matrix's shape.
        upper: mirror every entry to the upper triangle (for a lower-triangular Hessian block).

    Returns:
        ``(global sparsity, permutation)`` with ``global_nz = mapped_nz[permutation]``.
    """
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
    return global_sp, mapping


def _build_structure(model: PlannerModel, key: tuple, options: PlannerOptions) -> NLPStructure:
    """Assemble the NLP of ``key``.

    The nonlinear work is in the point kernels (:class:`~balance_opt.optimal.model.PointKernels`),
    mapped over all collocation points. Everything else (collocation defects, quadrature,
    Bernstein limit constraints, attitude bounds, terminal cost) is an SX function of the
    decision vector ``w``, the kernels' outputs ``Y`` and the parameters ``p``, linear in ``Y``.
    The NLP's gradient, Jacobian and Hessian are assembled by the chain rule:
    ``dg/dw = G_w + G_Y dY/dw`` with ``dY/dw`` block diagonal (each variable belongs to one
    point), and ``H = d2(lam^T G)/dw2 + sum_i d2(mu_i^T y_i)/dz_i^2`` with
    ``mu = G_Y^T lam``, so no derivative is ever taken of an N-sized graph of kernel calls.
    """
    start = time.perf_counter()
    N, tr_name, control, limit_kinds, torque, path_bound, terminal_bound = key[:7]
    tr = Transcription(tr_name)
    kernels = model.kernels(control, torque)
    n_x, n_m, n_B, n_y = model.n_x(control), model.n_m, model.n_B, kernels.n_y
    n_pts = tr.n_points(N)
    taus = tr.point_taus(N)
    node_taus = np.arange(N + 1, dtype=float)
    mid_taus = node_taus[:-1] + 0.5
    interval_taus = node_taus[:-1]
    state_labels = tuple(model.state_labels(control))
    control_kind = "acceleration" if control == "acceleration" else "jerk"
    balance_names = [model.robot.joint_names[i] for i in model.robot.balance_indices]
    control_labels = tuple(f"{j} {control_kind}" for j in balance_names)

    # ---- decision variables
    variables: dict[str, Block] = {}
    offset = 0

    def add_var(name, rows, col_taus):
        nonlocal offset
        variables[name] = Block(name, rows, tuple(_unit(r) for r in rows), col_taus, offset)
        offset += len(rows) * len(col_taus)

    add_var("X", state_labels, node_taus)
    if tr.has_midpoints:
        add_var("Xm", state_labels, mid_taus)
    add_var("U", control_labels, node_taus)
    if tr.has_midpoints:
        add_var("Um", control_labels, mid_taus)
    n_w = offset
    n_p = N_FIXED_PARAMETERS + n_B + n_m * n_pts

    # ---- the outer problem: SX in (w, Y, p), linear in Y
    w = cs.SX.sym("w", n_w)
    Y = cs.SX.sym("Y", n_y, n_pts)
    p = cs.SX.sym("p", n_p)
    h, w_terminal, path_scale, terminal_scale = p[0], p[1], p[6], p[7]

    def var(name):
        b = variables.get(name)
        return None if b is None else cs.reshape(w[b.offset : b.offset + b.size], *b.shape)

    X, U, Xm, Um = var("X"), var("U"), var("Xm"), var("Um")
    F, L = Y[:n_x, :], Y[n_x, :]
    Fn, Fm = F[:, : N + 1], (F[:, N + 1 :] if tr.has_midpoints else None)
    cost = h * cs.mtimes(L, cs.DM(tr.quadrature_weights(N))) + w_terminal * cs.sumsqr(X[:3, N])

    constraints: list[Block] = []
    g_parts = []
    g_offset = 0

    def add_con(name, rows, units, col_taus, expr, per_interval=False):
        nonlocal g_offset
        constraints.append(
            Block(
                name,
                tuple(rows),
                tuple(units),
                np.asarray(col_taus, dtype=float),
                g_offset,
                per_interval,
            )
        )
        g_offset += len(rows) * len(col_taus)
        g_parts.append(cs.vec(expr))

    # collocation defects: the attitude by the transcription; the balance joints, a chain of
    # integrators, exactly: each node (and midpoint) is the value of the integrated control
    # polynomial, so the continuous plan passes through every node in every mode (with
    # control "acceleration" these are the transcription's own equations)
    starts = [X[3 : 3 + n_B, :-1], X[3 + n_B : 3 + 2 * n_B, :-1]]
    if control == "jerk":
        starts.append(X[3 + 2 * n_B : 3 + 3 * n_B, :-1])
    levels = joint_chain_coefficients(tr, starts, U, Um, h)
    joint_ends = cs.vertcat(*(bernstein_value(level, 1.0) for level in levels[:-1]))
    joint_mids = cs.vertcat(*(bernstein_value(level, 0.5) for level in levels[:-1]))
    for name, defect in tr.defects(X, Xm, Fn, Fm, h):
        exact = (Xm[3:, :] - joint_mids) if name == "Hermite midpoint" else (X[3:, 1:] - joint_ends)
        add_con(
            f"collocation ({name})",
            state_labels,
            [_unit(r) for r in state_labels],
            interval_taus,
            cs.vertcat(defect[:3, :], exact),
            per_interval=True,
        )

    # joint limits between the points: interior Bernstein coefficients (convex hull)
    bernstein = _bernstein_levels(tr, control)
    for level, kind in enumerate(("position", "velocity", "acceleration")):
        if kind not in limit_kinds or not bernstein[kind]:
            continue
        coeffs = [levels[level][i] for i in bernstein[kind]]
        rows = [f"{j} {kind} (control point {i})" for i in bernstein[kind] for j in balance_names]
        add_con(
            f"{kind} limit between points",
            rows,
            [_unit(kind)] * len(rows),
            interval_taus,
            cs.vertcat(*coeffs),
            per_interval=True,
        )

    Z_phi = cs.horzcat(X[:3, :], Xm[:3, :]) if tr.has_midpoints else X[:3, :]
    if torque:
        add_con(
            "torque limit",
            [f"{j} torque" for j in balance_names],
            ["N m"] * n_B,
            taus,
            Y[n_x + 1 :, :],
        )
    if path_bound:
        add_con(
            "path attitude bound",
            ["attitude |phi|^2 / bound^2"],
            ["(relative)"],
            taus,
            path_scale * cs.sum1(Z_phi**2),
        )
    if terminal_bound:
        add_con(
            "terminal attitude bound",
            ["attitude |phi_T|^2 / bound^2"],
            ["(relative)"],
            [float(N)],
            terminal_scale * cs.sumsqr(X[:3, N]),
        )
    g = cs.vertcat(*g_parts)
    n_g = int(g.numel())

    y = cs.vec(Y)
    lam_g = cs.SX.sym("lam_g", n_g)
    lam_f = cs.SX.sym("lam_f")
    lagrangian = lam_f * cost + cs.dot(lam_g, g)
    G_Y = cs.jacobian(g, y)
    f_Y = cs.jacobian(cost, y)
    if cs.depends_on(G_Y, cs.vertcat(w, y)) or cs.depends_on(f_Y, cs.vertcat(w, y)):
        raise AssertionError("the outer problem must be linear in the kernel outputs")
    outer = cs.Function("outer", [w, y, p], [cost, g])
    outer_grad = cs.Function(
        "outer_grad",
        [w, p],
        [cs.substitute(cost, y, cs.DM.zeros(y.shape)), cs.gradient(cost, w), f_Y.T],
    )
    outer_jac = cs.Function("outer_jac", [w, p], [cs.jacobian(g, w), G_Y])
    outer_hess = cs.Function(
        "outer_hess",
        [w, p, lam_f, lam_g],
        [cs.triu(cs.hessian(lagrangian, w)[0]), cs.gradient(lagrangian, y)],
    )

    # ---- the NLP in MX: kernels mapped over the points, derivatives assembled
    point_idx = _point_variable_indices(variables, tr.has_midpoints)
    point_flat = point_idx.ravel(order="F")
    if not np.array_equal(np.sort(point_flat), np.arange(n_w)):
        raise AssertionError("every decision variable must belong to exactly one point")
    wx, px = cs.MX.sym("w", n_w), cs.MX.sym("p", n_p)
    Zx = cs.reshape(wx[point_flat.tolist()], kernels.n_z, n_pts)
    Mx = cs.reshape(px[N_FIXED_PARAMETERS + n_B :], n_m, n_pts)
    data = (Mx, px[2:6], px[N_FIXED_PARAMETERS : N_FIXED_PARAMETERS + n_B])
    yx = cs.vec(kernels.value.map(n_pts)(Zx, *data))
    f_x, g_x = outer(wx, yx, px)

    # gradient of the objective: d(c_i^T y_i)/dz_i per point (reverse mode), scattered to w
    f0, f_w_x, f_Y_x = outer_grad(wx, px)
    cy, grad_z = kernels.gradient.map(n_pts)(Zx, *data, cs.reshape(f_Y_x, n_y, n_pts))
    scatter_w = np.empty(n_w, dtype=int)
    scatter_w[point_flat] = np.arange(n_w)
    grad_f = cs.Function(
        "nlp_grad_f",
        [wx, px],
        [f0 + cs.sum2(cy), f_w_x + cs.vec(grad_z)[scatter_w.tolist()]],
        ["x", "p"],
        ["f", "grad_f_x"],
    )

    # Jacobian of the constraints: G_w + G_Y dY/dw, dY/dw block diagonal
    Y_jac, dY = kernels.jacobian.map(n_pts)(Zx, *data)
    sp_dy, perm_dy = _scatter(
        kernels.jacobian_sparsity,
        n_pts,
        lambda i: n_y * i + np.arange(n_y),
        lambda i: point_idx[:, i],
        (n_y * n_pts, n_w),
    )
    dYdw = cs.sparsity_cast(dY.nz[perm_dy.tolist()], sp_dy)
    G_w_x, G_Y_x = outer_jac(wx, px)
    g_jac = outer(wx, cs.vec(Y_jac), px)[1]
    jac_g = cs.Function(
        "nlp_jac_g", [wx, px], [g_jac, G_w_x + cs.mtimes(G_Y_x, dYdw)], ["x", "p"], ["g", "jac_g_x"]
    )

    lf, lg = cs.MX.sym("lam_f"), cs.MX.sym("lam_g", n_g)
    H_outer, mu = outer_hess(wx, px, lf, lg)
    d2 = kernels.hessian.map(n_pts)(Zx, *data, cs.reshape(mu, n_y, n_pts))
    sp_h, perm_h = _scatter(
        kernels.hessian_sparsity,
        n_pts,
        lambda i: point_idx[:, i],
        lambda i: point_idx[:, i],
        (n_w, n_w),
        upper=True,
    )
    H_kernel = cs.sparsity_cast(d2.nz[perm_h.tolist()], sp_h)
    hess_lag = cs.Function(
        "nlp_hess_l",
        [wx, px, lf, lg],
        [H_outer + H_kernel],
        ["x", "p", "lam_f", "lam_g"],
        ["triu_hess_gamma_x_x"],
    )

    ipopt = dict(DEFAULT_IPOPT)
    ipopt.update({"tol": options.tolerance, "max_iter": int(options.max_iterations)})
    ipopt.update(options.ipopt)
    solver = cs.nlpsol(
        "balance_nlp",
        "ipopt",
        {"x": wx, "p": px, "f": f_x, "g": g_x},
        {
            "ipopt": ipopt,
            "print_time": False,
            "record_time": True,
            "calc_lam_p": False,
            "calc_lam_x": False,
            "grad_f": grad_f,
            "jac_g": jac_g,
            "hess_lag": hess_lag,
        },
    )
    build_time = time.perf_counter() - start
    log.debug(
        "balance NLP %s built in %.3f s: %d variables, %d constraints",
        key[:3],
        build_time,
        n_w,
        n_g,
    )
    return NLPStructure(key, solver, variables, constraints, n_w, n_g, n_p, bernstein, build_time)


# ---------------------------------------------------------------------------------- the NLP
@dataclass
class Solution:
    """A point of the NLP, unpacked: states and controls at nodes and midpoints."""

    X: np.ndarray
    U: np.ndarray
    Xm: np.ndarray | None
    Um: np.ndarray | None


class BalanceNLP:
    """One balance planning problem: a compiled NLP structure plus its numeric data.

    Built by :func:`build_balance_nlp`; inspect ``variables``, ``constraints``, ``lbx``/``ubx``,
    ``lbg``/``ubg``, ``parameters``, or name an index with :meth:`constraint_name`.
    """

    def __init__(
        self,
        model: PlannerModel,
        structure: NLPStructure,
        mission,
        q_B0: np.ndarray,
        options: PlannerOptions,
        horizon: float,
        setup_time: float,
        build_time: float = 0.0,
        robot: FloatingRobot | None = None,
    ):
        self.model = model
        self.robot = model.robot if robot is None else robot
        self.structure = structure
        self.mission = mission
        self.q_B0 = q_B0
        self.options = options
        self.horizon = horizon
        self.N = options.intervals
        self.h = horizon / self.N
        self.transcription = Transcription(options.transcription)
        self.control = options.control
        self.setup_time = setup_time
        self.build_time = build_time
        self.point_times = self.transcription.point_taus(self.N) * self.h
        q_M, q_dot_M, q_ddot_M = mission.sample(self.point_times)
        self.mission_samples = np.hstack([q_M, q_dot_M, q_ddot_M]).T  # (n_m, n_points)
        n_B = model.n_B
        self.q_rest = (
            q_B0 if options.rest_configuration is None else np.array(options.rest_configuration)
        )
        # attitude bounds enter as |phi|^2 / bound^2 <= 1: scaled, Ipopt's tolerance is relative
        scales = [
            1.0 / b**2 if b else 1.0
            for b in (options.path_attitude_bound, options.terminal_attitude_bound)
        ]
        self.parameters = np.r_[
            self.h,
            options.weights.terminal,
            options.weights.running(),
            scales,
            self.q_rest,
            self.mission_samples.ravel(order="F"),
        ]
        self.limits = self.robot.limits.subset(self.robot.balance_indices)
        self.balance_joints = tuple(self.robot.joint_names[i] for i in self.robot.balance_indices)
        self.lbx, self.ubx = self._variable_bounds()
        self.lbg, self.ubg = self._constraint_bounds()
        assert self.parameters.size == structure.n_p and n_B == len(self.balance_joints)

    # ------------------------------------------------------------------ inspection
    @property
    def variables(self) -> dict[str, Block]:
        return self.structure.variables

    @property
    def constraints(self) -> list[Block]:
        return self.structure.constraints

    def constraint_name(self, index: int) -> tuple[str, float, str]:
        """``(name, time [s], unit)`` of constraint ``index`` (for an interval's constraint, the
        interval's start)."""
        block = self.structure.constraint_block(index)
        row, unit, tau = block.locate(index)
        return f"{block.name}: {row}", tau * self.h, unit

    def describe_constraint(self, index: int) -> str:
        """Constraint ``index`` in words: what, which joint or quantity, when."""
        block = self.structure.constraint_block(index)
        name, t, _ = self.constraint_name(index)
        if block.per_interval:
            return f"{name} on the interval {t:.3f}-{t + self.h:.3f} s"
        return f"{name} at t = {t:.3f} s"

    def variable_name(self, index: int) -> tuple[str, float, str]:
        """``(name, time [s], unit)`` of decision variable ``index``."""
        block = self.structure.variable_block(index)
        row, unit, tau = block.locate(index)
        return f"{'midpoint' if block.name.endswith('m') else 'node'} {row}", tau * self.h, unit

    def unpack(self, w) -> Solution:
        """States and controls of a decision vector."""
        w = np.asarray(w, dtype=float).ravel()

        def get(name):
            b = self.variables.get(name)
            if b is None:
                return None
            return w[b.offset : b.offset + b.size].reshape(b.shape, order="F")

        return Solution(get("X"), get("U"), get("Xm"), get("Um"))

    def pack(self, sol: Solution) -> np.ndarray:
        """The decision vector of unpacked states and controls."""
        w = np.empty(self.structure.n_w)
        for name, arr in (("X", sol.X), ("U", sol.U), ("Xm", sol.Xm), ("Um", sol.Um)):
            b = self.variables.get(name)
            if b is not None:
                w[b.offset : b.offset + b.size] = np.asarray(arr, dtype=float).ravel(order="F")
        return w

    # ------------------------------------------------------------------ bounds
    def _state_bounds(self):
        n_B, lim, o = self.model.n_B, self.limits, self.options
        inf = np.full(n_B, np.inf)
        lo = [np.full(3, -np.inf)]
        hi = [np.full(3, np.inf)]
        lo.append(lim.lower if o.position_limits else -inf)
        hi.append(lim.upper if o.position_limits else inf)
        lo.append(-lim.velocity if o.velocity_limits else -inf)
        hi.append(lim.velocity if o.velocity_limits else inf)
        acc = lim.acceleration if o.acceleration_limits else inf
        if self.control == "jerk":
            lo.append(-acc)
            hi.append(acc)
            return np.concatenate(lo), np.concatenate(hi), -inf, inf
        return np.concatenate(lo), np.concatenate(hi), -acc, acc

    def _variable_bounds(self):
        n_B, N = self.model.n_B, self.N
        x_lo, x_hi, u_lo, u_hi = self._state_bounds()
        X_lo, X_hi = np.tile(x_lo[:, None], N + 1), np.tile(x_hi[:, None], N + 1)
        # initial state: attitude at the reference, balance arm at rest at q_B0
        x0 = np.r_[np.zeros(3), self.q_B0, np.zeros(self.model.n_x(self.control) - 3 - n_B)]
        X_lo[:, 0] = X_hi[:, 0] = x0
        if self.options.rest_at_end:
            X_lo[3 + n_B :, N] = X_hi[3 + n_B :, N] = 0.0
        if self.options.final_configuration is not None:
            X_lo[3 : 3 + n_B, N] = X_hi[3 : 3 + n_B, N] = self.options.final_configuration
        U_lo, U_hi = np.tile(u_lo[:, None], N + 1), np.tile(u_hi[:, None], N + 1)
        mid = (
            np.tile(x_lo[:, None], N),
            np.tile(x_hi[:, None], N),
            np.tile(u_lo[:, None], N),
            np.tile(u_hi[:, None], N),
        )
        lo = self.pack(Solution(X_lo, U_lo, mid[0], mid[2]))
        hi = self.pack(Solution(X_hi, U_hi, mid[1], mid[3]))
        return lo, hi

    def _constraint_bounds(self):
        lo, hi = np.zeros(self.structure.n_g), np.zeros(self.structure.n_g)
        lim = self.limits
        for b in self.constraints:
            sl = slice(b.offset, b.offset + b.size)
            if b.name.startswith("collocation"):
                continue
            if b.name.endswith("limit between points"):
                kind = b.name.split()[0]
                low, high = {
                    "position": (lim.lower, lim.upper),
                    "velocity": (-lim.velocity, lim.velocity),
                    "acceleration": (-lim.acceleration, lim.acceleration),
                }[kind]
                reps = len(b.rows) // low.size
                lo[sl] = np.tile(np.tile(low, reps)[:, None], len(b.taus)).ravel(order="F")
                hi[sl] = np.tile(np.tile(high, reps)[:, None], len(b.taus)).ravel(order="F")
            elif b.name == "torque limit":
                lo[sl] = np.tile(-lim.effort[:, None], len(b.taus)).ravel(order="F")
                hi[sl] = np.tile(lim.effort[:, None], len(b.taus)).ravel(order="F")
            elif b.name in ("path attitude bound", "terminal attitude bound"):
                lo[sl], hi[sl] = -np.inf, 1.0
        return lo, hi

    # ------------------------------------------------------------------ guesses
    def _attitude_along(self, sol: Solution) -> None:
        """Fill the attitude rows of ``sol`` by integrating the NLP's own dynamics along its
        joint motion (the transcription's quadrature of ``phi_dot``, from ``phi = 0``)."""
        dyn = self.model.dynamics_fun(self.control).map(self.transcription.n_points(self.N))
        Z = np.hstack([sol.X, sol.Xm]) if sol.Xm is not None else sol.X
        V = np.hstack([sol.U, sol.Um]) if sol.Um is not None else sol.U
        Z = Z.copy()
        Z[:3] = 0.0
        _, omega = dyn(Z, V, self.mission_samples)
        omega = np.array(omega)
        N, h = self.N, self.h
        w0, w1 = omega[:, :N], omega[:, 1 : N + 1]
        if self.transcription.has_midpoints:
            wm = omega[:, N + 1 :]
            step = h / 6.0 * (w0 + 4.0 * wm + w1)
        else:
            step = h / 2.0 * (w0 + w1)
        sol.X[:3] = np.hstack([np.zeros((3, 1)), np.cumsum(step, axis=1)])
        if sol.Xm is not None:
            sol.Xm[:3] = 0.5 * (sol.X[:3, :-1] + sol.X[:3, 1:]) + h / 8.0 * (w0 - w1)

    def _guess_from_samples(self, t, q_B, q_dot_B, q_ddot_B) -> Solution:
        """A decision vector from sampled balance motion: interpolated at the points, clipped
        to the limits, the initial state imposed and the attitude integrated along it."""
        pts = self.point_times
        lim = self.limits

        def at(values):
            values = np.atleast_2d(values)
            return np.array([np.interp(pts, t, values[:, j]) for j in range(values.shape[1])])

        q = np.clip(at(q_B).T, lim.lower, lim.upper).T
        qd = np.clip(at(q_dot_B).T, -lim.velocity, lim.velocity).T
        qdd = np.clip(at(q_ddot_B).T, -lim.acceleration, lim.acceleration).T
        if self.control == "jerk":
            states = np.vstack([q, qd, qdd])
            u = np.gradient(qdd[:, : self.N + 1], self.h, axis=1)
            u = (
                np.hstack([u, 0.5 * (u[:, :-1] + u[:, 1:])])
                if self.transcription.has_midpoints
                else u
            )
        else:
            states, u = np.vstack([q, qd]), qdd
        Z = np.vstack([np.zeros((3, pts.size)), states])
        N = self.N
        sol = Solution(
            Z[:, : N + 1].copy(),
            u[:, : N + 1].copy(),
            Z[:, N + 1 :].copy() if self.transcription.has_midpoints else None,
            u[:, N + 1 :].copy() if self.transcription.has_midpoints else None,
        )
        lbx = self.unpack(self.lbx)
        sol.X[3:, 0] = lbx.X[3:, 0]
        self._attitude_along(sol)
        return sol

    def rest_guess(self) -> Solution:
        """The balance arm held at ``q_B0``, the attitude it leaves (Phase I's)."""
        q_B = np.tile(self.q_B0, (2, 1))
        return self._guess_from_samples(
            np.array([0.0, self.horizon]), q_B, np.zeros_like(q_B), np.zeros_like(q_B)
        )

    def analytic_guess(self) -> Solution:
        """The analytic law's balance motion (Eq. 31, 32), clipped to the limits."""
        from balance_opt.analytic.law import analytic_plan

        t = np.linspace(0.0, self.horizon, max(4 * self.N + 1, 201))
        plan = analytic_plan(self.robot, self.mission, self.q_B0, t=t)
        return self._guess_from_samples(plan.t, plan.q_B, plan.q_dot_B, plan.q_ddot_B)

    def initial_guess(self, guess="analytic") -> np.ndarray:
        """The decision vector to start from: ``"analytic"``, ``"rest"``, a
        :class:`BalanceResult` (its balance motion, clipped) or a decision vector."""
        if isinstance(guess, BalanceResult):
            sol = self._guess_from_samples(guess.t, guess.q_B, guess.q_dot_B, guess.q_ddot_B)
        elif isinstance(guess, str):
            if guess not in GUESSES:
                raise InputError(
                    f"initial guess must be one of {', '.join(GUESSES)} or a BalanceResult, got {guess!r}"
                )
            if guess == "analytic":
                try:
                    sol = self.analytic_guess()
                except SolverError as exc:
                    log.info("analytic law failed (%s); starting from rest", exc)
                    sol = self.rest_guess()
            else:
                sol = self.rest_guess()
        else:
            w = np.asarray(guess, dtype=float).ravel()
            if w.size != self.structure.n_w:
                raise InputError(
                    f"initial guess vector has {w.size} entries, the NLP has {self.structure.n_w}"
                )
            return w
        return np.clip(self.pack(sol), self.lbx, self.ubx)

    # ------------------------------------------------------------------ solve
    def solve(self, initial_guess="analytic") -> BalanceResult:
        """Solve with Ipopt, re-simulate the plan, return it.

        Args:
            initial_guess: ``"analytic"`` (the analytic law clipped to the limits; the rest
                guess when the law is unavailable), ``"rest"``, a :class:`BalanceResult`, or a
                decision vector.

        Raises:
            PlannerSolverError: Ipopt stopped without a solution (infeasible, iteration limit,
                ...); its message names the status and the most violated constraint, its
                ``result`` is the last iterate, re-simulated.
        """
        t0 = time.perf_counter()
        w0 = self.initial_guess(initial_guess)
        t1 = time.perf_counter()
        out = self.structure.solver(
            x0=w0, p=self.parameters, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg
        )
        raise_if_interrupted()  # Ctrl-C inside Ipopt ends its solve as a "failure": go on
        t2 = time.perf_counter()
        stats = self.structure.solver.stats()
        w = np.array(out["x"]).ravel()
        g = np.array(out["g"]).ravel()
        status = str(stats.get("return_status", "unknown"))
        worst = self.largest_violation(w, g)
        sol = self.unpack(w)
        trajectory = self.trajectory(sol)
        result = resimulate(self, sol, trajectory)
        t3 = time.perf_counter()
        iters = stats.get("iterations", {})
        kernels = self.model.kernels(self.control, bool(self.structure.key[4]))
        result.info.update(
            {
                "status": status,
                "success": status in SUCCESS_STATUSES,
                "iterations": int(stats.get("iter_count", 0)),
                "objective": float(out["f"]),
                "max_constraint_violation": worst[2],
                "max_violation_at": {
                    "constraint": worst[0],
                    "time_s": worst[1],
                    "unit": worst[3],
                    "description": worst[4],
                },
                "wall_time_s": {
                    "build": self.build_time,
                    "setup": self.setup_time,
                    "guess": t1 - t0,
                    "solve": t2 - t1,
                    "resimulate": t3 - t2,
                },
                "kernels": {
                    "compiled": kernels.compiled,
                    "compile_time_s": kernels.compile_time,
                    "library": kernels.library,
                },
                "history": {
                    k: [float(v) for v in iters.get(k, [])] for k in ("obj", "inf_pr", "inf_du")
                },
                "intervals": self.N,
                "transcription": self.transcription.name,
                "control": self.control,
                "horizon_s": self.horizon,
                "options": self.options.as_dict(),
            }
        )
        result.info["nlp_solution"] = w.tolist()
        if status not in SUCCESS_STATUSES:
            name, t, amount, unit, where = worst
            raise PlannerSolverError(
                f"Ipopt stopped with status '{status}' after {result.info['iterations']} iterations; "
                f"largest constraint violation: {where}, by {amount:.3g} {unit}",
                status,
                result,
                name,
                t,
                amount,
            )
        if status != SUCCESS_STATUSES[0]:
            log.warning("Ipopt: %s", status)
        return result

    def largest_violation(self, w, g) -> tuple[str, float, float, str, str]:
        """``(name, time [s], amount, unit, description)`` of the most violated constraint or
        bound."""
        viol_g = np.maximum(np.maximum(self.lbg - g, g - self.ubg), 0.0)
        viol_x = np.maximum(np.maximum(self.lbx - w, w - self.ubx), 0.0)
        if viol_g.size and viol_g.max() >= (viol_x.max() if viol_x.size else 0.0):
            i = int(np.argmax(viol_g))
            name, t, unit = self.constraint_name(i)
            return name, t, float(viol_g[i]), unit, self.describe_constraint(i)
        i = int(np.argmax(viol_x))
        name, t, unit = self.variable_name(i)
        return f"bound on {name}", t, float(viol_x[i]), unit, f"bound on {name} at t = {t:.3f} s"

    def trajectory(self, sol: Solution) -> CollocatedTrajectory:
        """The balance joints' continuous motion of a solution."""
        n_B = self.model.n_B
        starts = [sol.X[3 : 3 + n_B, :-1], sol.X[3 + n_B : 3 + 2 * n_B, :-1]]
        if self.control == "jerk":
            starts.append(sol.X[3 + 2 * n_B : 3 + 3 * n_B, :-1])
        levels = joint_chain_coefficients(self.transcription, starts, sol.U, sol.Um, self.h)
        return CollocatedTrajectory(self.h, levels)


# ---------------------------------------------------------------------------------- build
def _check_problem(
    model: PlannerModel, robot: FloatingRobot, mission, q_B0, options: PlannerOptions
) -> tuple[np.ndarray, float]:
    if robot.joint_names != model.robot.joint_names:
        raise InputError(f"robot {robot.name} is not the robot of the planner model")
    if getattr(mission, "dof", None) != model.n_M:
        raise InputError(
            f"mission trajectory has {getattr(mission, 'dof', '?')} joints, "
            f"the mission arm of {robot.name} has {model.n_M}"
        )
    q_B0 = np.asarray(q_B0, dtype=float).ravel()
    names = [robot.joint_names[i] for i in robot.balance_indices]
    if q_B0.size != model.n_B:
        raise InputError(
            f"q_B0 has {q_B0.size} values, the balance joints are {model.n_B} ({', '.join(names)})"
        )
    horizon = float(mission.duration if options.horizon is None else options.horizon)
    if horizon < mission.duration:
        raise InputError(
            f"planner option 'horizon' ({horizon} s) is shorter than the mission ({mission.duration} s)"
        )
    lim = robot.limits.subset(robot.balance_indices)
    for what, values in (
        ("initial configuration q_B0", q_B0),
        ("final_configuration", options.final_configuration),
    ):
        if values is None:
            continue
        values = np.asarray(values, dtype=float)
        if values.size != model.n_B:
            raise InputError(
                f"planner option '{what}' has {values.size} values, the balance joints are {model.n_B}"
            )
        if not options.position_limits:
            continue
        for j, name in enumerate(names):
            if not lim.lower[j] - LIMIT_TOLERANCE <= values[j] <= lim.upper[j] + LIMIT_TOLERANCE:
                raise InfeasibleLimitsError(
                    f"balance joint '{name}': {what} is {values[j]:.6g} rad, outside its position limits "
                    f"[{lim.lower[j]:.6g}, {lim.upper[j]:.6g}] rad"
                )
    if options.rest_configuration is not None and len(options.rest_configuration) != model.n_B:
        raise InputError(
            f"planner option 'rest_configuration' has {len(options.rest_configuration)} values, "
            f"the balance joints are {model.n_B}"
        )
    return q_B0, horizon


def build_balance_nlp(
    planner_model: PlannerModel | FloatingRobot,
    mission_trajectory,
    q_B0,
    options: PlannerOptions | None = None,
    robot: FloatingRobot | None = None,
) -> BalanceNLP:
    """Build the balance NLP of a mission.

    The compiled structure is taken from ``planner_model.nlp_cache`` when a problem of the same
    structure was built before (same intervals, transcription, control, constraint switches and
    solver options); the mission, horizon, ``q_B0``, weights and bounds are numeric inputs.

    Args:
        planner_model: the robot's :class:`PlannerModel` (or the robot: a model is built, not kept).
        mission_trajectory: the mission arm's motion (``sample(t) -> q, q_dot, q_ddot``, ``duration``).
        q_B0: initial balance configuration [rad] (the balance arm starts at rest).
        options: planner settings (defaults: :class:`PlannerOptions`).
        robot: the robot whose joint limits bound the plan, of the model's kinematics (a task
            may change the limits; the model and its compiled NLPs stay valid); default: the
            model's robot.

    Raises:
        InputError: sizes or options that do not fit the robot.
        InfeasibleLimitsError: limits no plan can meet (``q_B0`` or the prescribed final
            configuration outside the position limits), naming the joint.
    """
    start = time.perf_counter()
    model = (
        planner_model if isinstance(planner_model, PlannerModel) else PlannerModel(planner_model)
    )
    options = options or PlannerOptions()
    robot = model.robot if robot is None else robot
    q_B0, horizon = _check_problem(model, robot, mission_trajectory, q_B0, options)
    key = _structure_key(robot, options)
    built_now = key not in model.nlp_cache
    if built_now:
        model.nlp_cache[key] = _build_structure(model, key, options)
    structure = model.nlp_cache[key]
    build_time = structure.build_time if built_now else 0.0
    return BalanceNLP(
        model,
        structure,
        mission_trajectory,
        q_B0,
        options,
        horizon,
        time.perf_counter() - start - build_time,
        build_time,
        robot,
    )


def plan_optimal(
    robot: FloatingRobot | PlannerModel,
    mission,
    q_B0,
    options: PlannerOptions | None = None,
    initial_guess="analytic",
) -> BalanceResult:
    """Plan the balance arm's motion for a mission: :func:`build_balance_nlp` then
    :meth:`BalanceNLP.solve`. Pass a :class:`PlannerModel` to reuse the symbolic model and the
    compiled NLPs across calls."""
    return build_balance_nlp(robot, mission, q_B0, options).solve(initial_guess)


# ---------------------------------------------------------------------------------- re-simulation
def _fine_grid(N: int, h: float, step: float) -> tuple[np.ndarray, int]:
    sub = max(1, math.ceil(h / step - 1e-9))
    return np.arange(N * sub + 1) * (h / sub), sub


def resimulate(nlp: BalanceNLP, sol: Solution, trajectory: CollocatedTrajectory) -> BalanceResult:
    """Re-simulate a plan on a fine grid: the balance joints follow the collocation polynomial,
    the attitude is integrated by :func:`balance_opt.motion.rollout.replay` (numeric Pinocchio, RK4 on
    the unit quaternion, one step per grid interval: below 1e-10 rad on the paper task at the
    default step); limit violations are those of the fine grid. ``info["resimulation"]``
    reports the collocation defects (NLP attitude at the nodes against the re-simulated one;
    joint polynomial at each interval's end against the next node), the momentum residual and
    the drift."""
    t, sub = _fine_grid(nlp.N, nlp.h, nlp.options.resample_step)
    result = replay(
        nlp.robot,
        nlp.mission,
        trajectory,
        t_eval=t,
        method="optimal",
        integration=IntegrationOptions(method="rk4", step=float(t[1] - t[0])),
    )
    quaternion = result.quaternion
    # collocation defects: NLP attitude at the nodes vs the re-simulated one
    q_nodes = quaternion[::sub]
    q_nlp = quaternion_from_rotvec(sol.X[:3].T)
    attitude_defect = rotation_angle(quaternion_multiply(quaternion_conjugate(q_nlp), q_nodes))
    n_B = nlp.model.n_B
    ends = trajectory.interval_ends()
    joint_defect = max(
        float(np.abs(ends[0] - sol.X[3 : 3 + n_B, 1:].T).max()),
        float(np.abs(ends[1] - sol.X[3 + n_B : 3 + 2 * n_B, 1:].T).max()),
    )
    result.info["resimulation"] = {
        "samples": int(t.size),
        "step_s": float(t[1] - t[0]),
        "attitude_defect_max_rad": float(attitude_defect.max()),
        "attitude_defect_final_rad": float(attitude_defect[-1]),
        "joint_defect_max": joint_defect,
        "max_momentum_residual": float(result.momentum_residual.max()),
        "max_drift_rad": result.max_drift,
        "final_drift_rad": result.final_drift,
        "nlp_final_drift_rad": float(np.linalg.norm(sol.X[:3, -1])),
        "limit_violations": [str(v) for v in result.violations],
    }
    return result
