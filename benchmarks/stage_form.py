"""The planner's NLP rewritten stage by stage, in the form fatrop's structure needs
(``structure_detection: manual``), for :mod:`bench_solvers`.

fatrop solves ``min sum_k l_k(x_k, u_k)`` subject to ``x_{k+1} = F_k(x_k, u_k)`` and path
constraints of ``(x_k, u_k)`` only, with the variables ordered ``x_0, u_0, x_1, u_1, ..., x_N``
and the constraints ``gap_0, path_0, gap_1, path_1, ..., path_N``. The planner's
Hermite-Simpson NLP is not of that form: the Simpson defect of interval ``k`` is implicit in
the node ``k+1`` (its kernel ``f(x_{k+1})``), and the global epigraph variable ``S`` enters every
point. :func:`stage_form` rewrites it without changing its solution set:

* stage ``k``'s state is node ``k``'s variables (states and control) and a copy ``S_k`` of ``S``;
* stage ``k``'s control is midpoint ``k``'s variables and a copy of node ``k+1``'s, so that
  every row of interval ``k`` (defects, Bernstein rows, ...) is a function of stage ``k`` alone;
* the gap rows say that node ``k+1`` is its copy and ``S_{k+1} = S_k``.

The rows are the planner's own (its SX expression with the parameters substituted), only
reordered and re-expressed in the copies; the cost is unchanged (each point's own variables,
``S_0`` for ``S``). A row that couples points farther apart than a node and the next one is an
error (none does). The copies cost one more kernel evaluation per interval.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as cs
import numpy as np


@dataclass
class StageForm:
    """One NLP in stage form.

    Attributes:
        nlp: ``{"x", "f", "g"}`` for ``casadi.nlpsol`` (the parameters are numbers in it).
        structure: fatrop's ``N``, ``nx``, ``nu``, ``ng`` options.
        bounds: ``lbx``, ``ubx``, ``lbg``, ``ubg`` (the copies are free).
        to_stages, from_stages: the planner's decision vector to the stage form's and back.
    """

    nlp: dict
    structure: dict
    bounds: dict
    to_stages: Callable[[np.ndarray], np.ndarray]
    from_stages: Callable[[np.ndarray], np.ndarray]


def _indices(problem):
    """Per node and midpoint, the planner's variable indices; and that of ``S`` (or None)."""
    layout = problem.structure.variables
    ix = layout.unpack(np.arange(problem.structure.variables.size, dtype=float))
    X, Xm, U, Um = (np.asarray(a).astype(int) for a in (ix.X, ix.Xm, ix.U, ix.Um))
    nodes = [np.r_[X[:, k], U[:, k]] for k in range(X.shape[1])]
    mids = [np.r_[Xm[:, k], Um[:, k]] for k in range(Xm.shape[1])]
    S = None if ix.S is None else int(np.asarray(ix.S).ravel()[0])
    return nodes, mids, S


def _rows_by_stage(g, w, nodes, mids) -> list[list[int]]:
    """The rows of each stage: a row belongs to the first node it touches (a midpoint counts as
    its interval's start)."""
    point = np.full(w.numel(), -1)
    for k, idx in enumerate(nodes):
        point[idx] = 2 * k
    for k, idx in enumerate(mids):
        point[idx] = 2 * k + 1
    colind, row = cs.jacobian(g, w).sparsity().get_ccs()
    touched = [[] for _ in range(g.numel())]
    for j in range(w.numel()):
        if point[j] >= 0:
            for r in row[colind[j] : colind[j + 1]]:
                touched[r].append(point[j])
    stages = [[] for _ in nodes]
    for r, points in enumerate(touched):
        if not points:
            raise ValueError(f"row {r} touches no collocation point")
        k = min(points) // 2
        if max(points) > 2 * k + 2:
            raise ValueError(f"row {r} couples points {min(points)} and {max(points)}")
        stages[k].append(r)
    return stages


def stage_form(problem, captured: dict) -> StageForm:
    """The stage form of a :class:`~balance_opt.optimal.solve.BalanceNLP` whose ``nlpsol`` input
    ``captured`` (``x``, ``p``, ``f``, ``g``) was recorded when it was built."""
    nodes, mids, S = _indices(problem)
    N, n_node = len(mids), len(nodes[0])
    n_state, n_control = n_node + (S is not None), n_node + len(mids[0])
    fg = cs.Function("fg", [captured["x"], captured["p"]], [captured["f"], captured["g"]])
    w = cs.SX.sym("w", problem.structure.variables.size)
    f, g = fg.expand()(w, cs.DM(problem.parameters))
    x = [cs.SX.sym(f"x{k}", n_state) for k in range(N + 1)]
    u = [cs.SX.sym(f"u{k}", n_control) for k in range(N)]  # [copy of node k+1; midpoint k]

    def stage_symbols(k: int, next_node_copy: bool, with_S: bool = True):
        old, new = [w[int(i)] for i in nodes[k]], [x[k][i] for i in range(n_node)]
        if S is not None and with_S:
            old.append(w[S])
            new.append(x[k][n_node])
        if k < N:
            old += [w[int(i)] for i in mids[k]]
            new += [u[k][n_node + i] for i in range(len(mids[k]))]
            if next_node_copy:
                old += [w[int(i)] for i in nodes[k + 1]]
                new += [u[k][i] for i in range(n_node)]
        return old, new

    lbg, ubg = np.asarray(problem.lbg, float), np.asarray(problem.ubg, float)
    parts, bounds_g, ng = [], [], []
    for k, rows in enumerate(_rows_by_stage(g, w, nodes, mids)):
        if k < N:
            copy = [u[k][i] for i in range(n_node)] + ([x[k][n_node]] if S is not None else [])
            parts.append(x[k + 1] - cs.vertcat(*copy))
            bounds_g.append(np.zeros((2, n_state)))
        old, new = stage_symbols(k, next_node_copy=True)
        rows_k = cs.vertcat(*[g[r] for r in rows])
        parts.append(cs.substitute(rows_k, cs.vertcat(*old), cs.vertcat(*new)))
        bounds_g.append(np.vstack([lbg[rows], ubg[rows]]))
        ng.append(len(rows))
    old, new = [], []
    for k in range(N + 1):  # the cost: every point's own variables, S as S_0
        o, n = stage_symbols(k, next_node_copy=False, with_S=k == 0)
        old, new = old + o, new + n
    cost = cs.substitute(f, cs.vertcat(*old), cs.vertcat(*new))
    z = cs.vertcat(*[v for k in range(N + 1) for v in ([x[k], u[k]] if k < N else [x[k]])])

    def to_stages(v: np.ndarray, copies: float | None = None) -> np.ndarray:
        out = []
        for k in range(N + 1):
            out.append(v[nodes[k]])
            if S is not None:
                out.append(v[[S]])
            if k < N:
                out.append(v[nodes[k + 1]] if copies is None else np.full(n_node, copies))
                out.append(v[mids[k]])
        return np.concatenate(out).astype(float)

    def from_stages(zv: np.ndarray) -> np.ndarray:
        v, pos = np.empty(problem.structure.variables.size), 0
        for k in range(N + 1):
            v[nodes[k]] = zv[pos : pos + n_node]
            pos += n_node
            if S is not None:
                v[S] = zv[pos] if k == 0 else v[S]
                pos += 1
            if k < N:
                v[mids[k]] = zv[pos + n_node : pos + n_control]
                pos += n_control
        return v

    gb = np.hstack(bounds_g)
    return StageForm(
        nlp={"x": z, "f": cost, "g": cs.vertcat(*parts)},
        structure={"N": N, "nx": [n_state] * (N + 1), "nu": [n_control] * N + [0], "ng": ng},
        bounds={
            "lbx": to_stages(np.asarray(problem.lbx), copies=-np.inf),
            "ubx": to_stages(np.asarray(problem.ubx), copies=np.inf),
            "lbg": gb[0],
            "ubg": gb[1],
        },
        to_stages=to_stages,
        from_stages=from_stages,
    )
