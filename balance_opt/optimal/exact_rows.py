"""Rows on the exact distance of the pairs the fitted shapes cannot hold (the *watched* pairs,
whose shapes overlap at the start while their bodies do not), linearised at the previous plan
as TrajOpt does: at every collocation point ``d(q_prev) + grad d(q_prev) . (q - q_prev) >=
bound``, ``d`` and its gradient from coal's witness points and normal and the frames'
Jacobians (numeric Pinocchio). The first solve's rows are linearised with the balance arm at
its start; the refinement linearises them again at each plan whose continuous motion brings
one of these pairs closer than it must keep, and solves again (``docs/collision.md``)."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as cs
import numpy as np
import pinocchio as pin

from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.optimal.collision import (
    COLLISION_ALLOWANCE,
    COLLISION_SLACK,
    PUSH,
    WATCH,
    allowance,
    short,
)
from balance_opt.optimal.terms import Rows, SymbolicNLP, Term, block_rows

#: A point gets its row once the pair comes within its threshold plus this [m] there (in a
#: linearised plan; it keeps it in the later rounds): farther, the linearisation only
#: restricts a motion that does not need it.
ACTIVATE = WATCH


@dataclass(frozen=True)
class Linearisation:
    """The exact rows of a problem linearised at a plan: per pair ``w`` and point ``k`` the
    row ``constant[w, k] + gradient[w n_B : (w + 1) n_B, k] . q_B(k) >= lower[w, k]`` [m]
    (``lower`` ``-inf`` where a point has no row yet)."""

    constant: np.ndarray
    gradient: np.ndarray
    lower: np.ndarray


def distance_gradient(geometry: RobotGeometry, q, pair: int) -> tuple[float, np.ndarray]:
    """The exact distance [m] of checked pair ``pair`` (its index among the collision pairs)
    at the arm configuration ``q`` and its gradient over the arm joints [m/rad]: coal's normal
    ``n`` (from the first object to the second) times the difference of the witness points'
    velocities, ``n . (J_2(p_2) - J_1(p_1))``, each point's Jacobian that of its body's joint
    moved to it (``v_p = v + omega x (p - o)``)."""
    robot, model, data = geometry.robot, geometry.model, geometry.data
    qp = robot.pin_q(q)
    geometry.place(q)
    result = pin.computeDistance(geometry.geometry_model, geometry.geometry_data, int(pair))
    pin.computeJointJacobians(model, data, qp)
    objects = geometry.geometry_model.geometryObjects
    cp = geometry.geometry_model.collisionPairs[int(pair)]
    normal = np.asarray(result.normal, dtype=float)
    rate = np.zeros(model.nv)  # d distance / d Pinocchio velocity
    for index, point, sign in (
        (cp.first, result.getNearestPoint1(), -1.0),
        (cp.second, result.getNearestPoint2(), 1.0),
    ):
        joint = int(objects[index].parentJoint)
        J = pin.getJointJacobian(model, data, joint, pin.LOCAL_WORLD_ALIGNED)
        arm = np.asarray(point, dtype=float) - data.oMi[joint].translation
        linear = J[:3] - pin.skew(arm) @ J[3:]
        rate += sign * normal @ linear
    return float(result.min_distance), rate @ robot.velocity_map[:, 6:]


def at_rest(problem) -> Linearisation:
    """The exact rows of ``problem`` (a :class:`~balance_opt.optimal.problem.BalanceProblem`
    with exact pairs) linearised with the balance arm held at its start, the mission moving:
    the first solve's. Linearised at a plan that passes through a body instead, a row pushes
    the arm out on the far side, where the start cannot reach (the first plan of two fat
    cylinders end to end did, and the re-solve was infeasible): from a motion that keeps the
    pairs apart, each round's rows hold at the plan they are linearised at."""
    q_M = problem.mission_samples[: problem.model.n_M].T
    points = np.hstack([q_M, np.tile(problem.q_B0, (q_M.shape[0], 1))])
    return linearise(problem, points)


def linearise(problem, points: np.ndarray, result=None) -> Linearisation:
    """The exact rows of ``problem`` linearised at the arm configurations ``points`` of its
    collocation points (n_points, n): those of the re-simulated plan ``result`` in a
    refinement round. A point has a row where the pair comes within its threshold plus
    :data:`ACTIVATE` there or had one before, bounded at the margin plus
    :data:`COLLISION_ALLOWANCE`, or at its start distance less :data:`COLLISION_SLACK` if
    smaller (the arm starts at rest), raised on each interval where the continuous motion
    of ``result`` came too close by its shortfall and as much more, up to :data:`PUSH` (as
    :func:`~balance_opt.optimal.collision.tighten` does)."""
    setup, n_M = problem.collision, problem.model.n_M
    pairs, before = setup.exact, problem.bounds.exact
    n_w, n_B, n_p = len(pairs), problem.model.n_B, points.shape[0]
    constant, gradient = np.zeros((n_w, n_p)), np.zeros((n_w * n_B, n_p))
    lower = np.full((n_w, n_p), -np.inf)
    margin = problem.options.collision_margin
    start = setup.geometry.distances(points[0], [p.index for p in pairs])
    for w, pair in enumerate(pairs):
        threshold = setup.threshold[pair.index]
        # as the collision rows start (CollisionSetup.start_bounds): the arm starts at rest
        held = min(margin + COLLISION_ALLOWANCE, start[w] - COLLISION_SLACK)
        for k, qk in enumerate(points):
            d, grad = distance_gradient(setup.geometry, qk, pair.index)
            g = grad[n_M:]
            constant[w, k] = d - g @ qk[n_M:]
            gradient[w * n_B : (w + 1) * n_B, k] = g
            if d < threshold + ACTIVATE or (before is not None and before.lower[w, k] > -np.inf):
                lower[w, k] = held
        if before is not None:  # the raises of earlier rounds stay
            lower[w] = np.maximum(lower[w], before.lower[w])
        if result is not None:
            _raise_short(problem, result, pair, held, lower[w])
    # the arm starts at rest where it is: the first node's rows cannot move
    lower[:, 0] = np.minimum(lower[:, 0], start - COLLISION_SLACK)
    return Linearisation(constant, gradient, lower)


def _raise_short(problem, result, pair, held: float, lower: np.ndarray) -> None:
    """Raise ``lower`` (the pair's row bounds, in place) on each interval where the continuous
    motion of ``result`` comes closer than the check holds the pair to."""
    setup, N, margin = problem.collision, problem.N, problem.options.collision_margin
    threshold = setup.threshold[pair.index]
    kept = threshold - allowance(threshold, margin)
    d = setup.geometry.distances_along(np.hstack([result.q_M, result.q_B]), pair.index)
    close = d < kept
    intervals = np.minimum((result.t[close] / problem.h).astype(int), N - 1)
    shortfall = np.full(N, -np.inf)
    np.maximum.at(shortfall, intervals, kept - d[close])
    mids = problem.transcription.has_midpoints
    for k in np.unique(intervals):
        columns = [k, k + 1] + ([N + 1 + k] if mids else [])
        s = shortfall[k]
        lower[columns] = np.maximum(lower[columns], held) + s + min(PUSH, s)


class ExactRows(Term):
    """The exact-distance rows of the watched pairs (:mod:`balance_opt.optimal.exact_rows`):
    linear in the balance joints at every collocation point, their coefficients NLP
    parameters (``problem.bounds.exact``: linearised with the arm at rest, then at each plan
    the refinement finds too close)."""

    name = "exact collision"

    def __init__(self, key: str):
        self.key = key  # of the pairs (CollisionModels.exact)

    def values(self, problem):
        lin = problem.bounds.exact
        if lin is None:
            n_w, n_B, n_p = (
                len(problem.collision.exact),
                problem.model.n_B,
                problem.point_times.size,
            )
            return {
                "exact_constant": np.zeros((n_w, n_p)),
                "exact_gradient": np.zeros((n_w * n_B, n_p)),
            }
        return {"exact_constant": lin.constant, "exact_gradient": lin.gradient}

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        pairs = nlp.model.collisions.exact[self.key]
        X, _ = nlp.variables.points()
        n_B = len(nlp.joints)
        q_B = X[3 : 3 + n_B, :]
        par = nlp.parameters
        values = cs.vertcat(
            *[
                par.exact_constant[w, :]
                + cs.sum1(par.exact_gradient[w * n_B : (w + 1) * n_B, :] * q_B)
                for w in range(len(pairs))
            ]
        )
        labels = [f"{name} (exact, linearised)" for name in pairs]
        return block_rows(nlp, "collision clearance", labels, "m", values)

    def row_bounds(self, problem, block):
        return problem.bounds.exact.lower.ravel(order="F"), np.full(block.size, np.inf)

    def tighten(self, problem, result):
        exact = {p.index for p in problem.collision.exact}
        pairs = [p for p in short(problem, result) if p.index in exact]
        if not pairs:
            return {}, []
        closest = f"closest {pairs[0].pair}, {pairs[0].distance:.4f} m"
        said = f"exact rows of {len(problem.collision.exact)} pairs linearised ({closest})"
        q = np.hstack([result.q_M, result.q_B])
        points = np.stack([np.interp(problem.point_times, result.t, c) for c in q.T], axis=1)
        return {"exact": linearise(problem, points, result)}, [said]
