"""An NLP whose nonlinear work is in per-point kernels: functions of one point's variables ``z``
(and its data) and their exact derivatives, mapped over the points; the outer problem (the cost
and the rows of ``g`` in the variables ``w`` and the kernels' outputs ``Y``) is linear in ``Y``,
so Ipopt's derivatives are the outer problem's plus the kernels' scattered to ``w``. Nothing here
knows what the points are (the optimal planner's collocation points).

The kernels are any object with ``value``, ``jacobian``, ``gradient``, ``hessian`` (and
``cost``: the outputs in the cost, or ``None`` when all are) as :func:`kernel_functions`
makes them, and the sizes ``n_y`` (outputs), ``n_z`` (a point's variables) and ``n_cost``
(the outputs in the cost, first)."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np

from balance_opt import progress
from balance_opt.solvers.ipopt_options import one_thread_for_ipopt


def function(name: str, inputs: dict, outputs: dict) -> cs.Function:
    """A CasADi function of named inputs and outputs, common subexpressions shared."""
    return cs.Function(
        name, [*inputs.values()], [*outputs.values()], [*inputs], [*outputs], {"cse": True}
    )


def kernel_functions(name: str, suffix: str, inputs: dict, y, y_cost) -> list[cs.Function]:
    """A point kernel's functions (SX) of its ``inputs`` (``z`` first, then its data): value,
    Jacobian in ``z``, gradient of the outputs in the cost ``y_cost`` (the first rows of ``y``)
    weighted, Hessian of the outputs weighted, and with outputs out of the cost the value of
    those in it (Ipopt evaluates the cost alone at every trial point of its line search)."""
    z = inputs["z"]
    mu = cs.SX.sym("mu", y.numel())
    c = cs.SX.sym("c", y_cost.numel())
    hess, _ = cs.hessian(cs.dot(mu, y), z)
    cy = cs.dot(c, y_cost)
    cost = function(f"{name}_cost_{suffix}", inputs, {"y": y_cost})
    return [
        function(f"{name}_{suffix}", inputs, {"y": y}),
        function(f"{name}_jac_{suffix}", inputs, {"y": y, "dy_dz": cs.jacobian(y, z)}),
        function(
            f"{name}_grad_{suffix}", {**inputs, "c": c}, {"cy": cy, "grad": cs.gradient(cy, z)}
        ),
        function(f"{name}_hess_{suffix}", {**inputs, "mu": mu}, {"d2": cs.tril(hess)}),
        *([cost] if y_cost.numel() < y.numel() else []),
    ]


@dataclass
class Outer:
    """The outer problem's functions (SX)."""

    cost: cs.Function  # (w, y, p) -> f
    constraints: cs.Function  # (w, y, p) -> g
    gradient: cs.Function  # (w, p) -> (f at y = 0, f_w, f_Y^T)
    jacobian: cs.Function  # (w, p) -> (G_w, G_Y)
    hessian: cs.Function  # (w, p, lam_f, lam_g) -> (triu d2L/dw2, dL/dy = mu)


def outer_functions(w, y, p, cost, g) -> Outer:
    """The outer problem's value and derivatives, checked linear in the kernel outputs ``y``."""
    lam_g = cs.SX.sym("lam_g", g.numel())
    lam_f = cs.SX.sym("lam_f")
    lagrangian = lam_f * cost + cs.dot(lam_g, g)
    G_Y = cs.jacobian(g, y)
    f_Y = cs.jacobian(cost, y)
    if cs.depends_on(G_Y, cs.vertcat(w, y)) or cs.depends_on(f_Y, cs.vertcat(w, y)):
        raise AssertionError("the outer problem must be linear in the kernel outputs")
    return Outer(
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


def _derivatives(kernels, outer: Outer, w, p, Z, data, point_idx, n_g) -> dict:
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


def kernel_solver(
    name: str, kernels, outer: Outer, point_idx: np.ndarray, n_w: int, n_p: int, data, ipopt: dict
) -> cs.Function:
    """The NLP in MX (the kernels mapped over the points, the outer problem on top) with its
    assembled derivatives, handed to Ipopt: ``point_idx`` (n_z, n_points) are the indices in
    ``w`` (of ``n_w`` variables) of each point's ``z``, ``data(p)`` the kernels' data inputs
    from the ``n_p`` parameters (MX)."""
    point_flat = point_idx.ravel(order="F")
    if not np.array_equal(np.sort(point_flat), np.arange(point_flat.size)):
        raise AssertionError("the points' variables must come first, each in one point")
    w, p = cs.MX.sym("w", n_w), cs.MX.sym("p", n_p)
    Z = cs.reshape(w[point_flat.tolist()], kernels.n_z, point_idx.shape[1])
    data = data(p)
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
        name,
        {"x": w, "p": p, "f": f, "g": g},
        {
            "ipopt": ipopt,
            "print_time": False,
            "record_time": True,
            "calc_lam_p": False,
            "calc_lam_x": False,
            **_derivatives(kernels, outer, w, p, Z, data, point_idx, g.numel()),
        },
    )
    one_thread_for_ipopt()  # the plugin, and its OpenBLAS, are loaded now
    return solver
