"""Rows on the exact distance of the pairs the fitted shapes cannot hold (the *watched* pairs,
whose shapes overlap at the start while their bodies do not), linearised at the previous plan
as TrajOpt does, less a curvature term that keeps each row to where its linearisation holds:
at every collocation point

    d(q_0) + grad d(q_0) . (q - q_0) - 1/2 sum_j k_j (q_j - q_0j)^2 >= bound,

``d`` and its gradient from coal's witness points and normal and the frames' Jacobians
(numeric Pinocchio), ``k_j`` [m/rad^2] the least that keeps the row below the exact
distance at steps along joint ``j`` up to its limits (:func:`curvature`). The first solve's
rows are linearised with the balance arm at its start; the refinement linearises them again
at each plan whose continuous motion brings one of these pairs closer than it must keep, and
solves again (``docs/collision.md``)."""

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
    allowance,
    point_configurations,
    short,
)
from balance_opt.optimal.terms import Rows, SymbolicNLP, Term, block_rows

#: The steps [rad] along each joint (and the joint's limit) at which a row's curvature term is
#: fitted below the exact distance (:func:`curvature`): a kink of the distance lies anywhere
#: in the joint's range (Baxter's wrist 0.6 rad from the parallel ends of it and its forearm's
#: cover, its elbow 0.75 rad from another).
SECANT_STEPS = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0)


@dataclass(frozen=True)
class Linearisation:
    """The exact rows of a problem: per pair ``w`` and point ``k``, with ``r`` the rows
    ``w n_B .. (w + 1) n_B`` of the balance joints and ``x = q_B(k) - centre[r, k]``, the row
    ``distance[w, k] + gradient[r, k] . x - 1/2 sum_j bend[r, k]_j x_j^2 >= lower[w, k]``
    [m]: linearised at ``centre``, bent by ``bend`` [m/rad^2] (:func:`curvature`)."""

    distance: np.ndarray
    gradient: np.ndarray
    centre: np.ndarray
    bend: np.ndarray
    lower: np.ndarray


def distance_gradient(geometry: RobotGeometry, q, pair: int) -> tuple[float, np.ndarray]:
    """The exact distance [m] of checked pair ``pair`` (its index among the collision pairs)
    at the arm configuration ``q`` and its gradient over the arm joints [m/rad]: coal's normal
    ``n`` (from the first object to the second) times the difference of the witness points'
    velocities, ``n . (J_2(p_2) - J_1(p_1))``, each point's Jacobian that of its body's joint
    moved to it (``v_p = v + omega x (p - o)``)."""
    robot, model, data = geometry.robot, geometry.model, geometry.data
    # one forward kinematics for both: the Jacobians' placements place the objects too
    pin.computeJointJacobians(model, data, robot.pin_q(q))
    pin.updateGeometryPlacements(model, data, geometry.geometry_model, geometry.geometry_data)
    result = pin.computeDistance(geometry.geometry_model, geometry.geometry_data, int(pair))
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


def curvature(geometry: RobotGeometry, pair, q: np.ndarray, d: float, grad: np.ndarray, n_M: int):
    """``k`` [m/rad^2] of a pair's row at the arm configuration ``q`` over the balance joints:
    per joint that turns one of its objects and not the other, the least that keeps the row
    at or below the exact distance at ``q`` moved along that joint alone by each of
    :data:`SECANT_STEPS` either way and to its limit (half a turn at most), inside the limits.
    Without it a row linearised on one side of a kink of the distance (two cylinders' ends
    parallel, where the nearest rim point jumps across) holds on the other side too, where the
    distance falls again: Baxter's wrist went through such a kink and 37 mm into its forearm's
    cover."""
    robot = geometry.robot
    a, b = geometry.reach[pair.first], geometry.reach[pair.second]
    E, _ = robot.mimic_matrix
    alone = (np.abs(E).T @ ((a == 0.0) != (b == 0.0)))[n_M:] > 0
    # to the limits, half a turn at most (a continuous joint's are infinite)
    lower = np.maximum(robot.limits.lower[n_M:] - q[n_M:], -np.pi)
    upper = np.minimum(robot.limits.upper[n_M:] - q[n_M:], np.pi)
    out = np.zeros(alone.size)
    for j in np.flatnonzero(alone):
        for room in (lower[j], upper[j]):
            steps = [x for x in SECANT_STEPS if x < abs(room)] + [abs(room)]
            for step in (x * np.sign(room) for x in steps if x > 1e-3):
                moved = q.copy()
                moved[n_M + j] += step
                exact = geometry.distances(moved, [pair.index])[0]
                out[j] = max(out[j], 2.0 * (d + step * grad[j] - exact) / step**2)
    return out


def at_rest(problem) -> Linearisation:
    """The exact rows of ``problem`` (a :class:`~balance_opt.optimal.problem.BalanceProblem`
    with exact pairs) linearised with the balance arm held at its start, the mission moving:
    the first solve's. Linearised at a plan that passes through a body instead, a row pushes
    the arm out on the far side, where the start cannot reach (the first plan of two fat
    cylinders end to end did, and the re-solve was infeasible)."""
    q_M = problem.mission_samples[: problem.model.n_M].T
    points = np.hstack([q_M, np.tile(problem.q_B0, (q_M.shape[0], 1))])
    return linearise(problem, points)


def linearise(problem, points: np.ndarray, result=None) -> Linearisation:
    """The exact rows of ``problem`` linearised at the arm configurations ``points`` of its
    collocation points (n_points, n): those of the re-simulated plan ``result`` in a
    refinement round. Every point has a row, bounded by :func:`_held`, raised on each interval
    where the continuous motion of ``result`` came too close by its shortfall and as much more,
    up to :data:`PUSH` (as :func:`~balance_opt.optimal.collision.tighten` does); the raises of
    earlier rounds stay."""
    setup, n_M = problem.collision, problem.model.n_M
    pairs, before = setup.exact, problem.bounds.exact
    n_w, n_B, n_p = len(pairs), problem.model.n_B, points.shape[0]
    distance, lower = np.zeros((n_w, n_p)), np.zeros((n_w, n_p))
    gradient, bend = np.zeros((n_w * n_B, n_p)), np.zeros((n_w * n_B, n_p))
    centre = np.tile(points[:, n_M:].T, (n_w, 1))
    margin = problem.options.collision_margin
    start = setup.geometry.distances(points[0], [p.index for p in pairs])
    for w, pair in enumerate(pairs):
        rows = slice(w * n_B, (w + 1) * n_B)
        lower[w] = held = _held(start[w], margin)
        for k, qk in enumerate(points):
            d, grad = distance_gradient(setup.geometry, qk, pair.index)
            if before is not None and d < held:
                # inside the bound: linearised here the row would push the arm out on the far
                # side; the last row, from where the pair was apart, stays (raised below)
                distance[w, k], centre[rows, k] = before.distance[w, k], before.centre[rows, k]
                gradient[rows, k], bend[rows, k] = before.gradient[rows, k], before.bend[rows, k]
                continue
            distance[w, k], gradient[rows, k] = d, grad[n_M:]
            bend[rows, k] = curvature(setup.geometry, pair, qk, d, grad[n_M:], n_M)
        if before is not None:
            lower[w] = np.maximum(lower[w], before.lower[w])
        if result is not None:
            _raise_short(problem, result, pair, held, lower[w])
    # the arm starts at rest where it is: the first node's rows cannot move
    lower[:, 0] = np.minimum(lower[:, 0], start - COLLISION_SLACK)
    return Linearisation(distance, gradient, centre, bend, lower)


def _held(start: float, margin: float) -> float:
    """The bound [m] of a pair's exact rows starting ``start`` apart: the margin plus
    :data:`COLLISION_ALLOWANCE`, but not above half way from the margin to ``start`` (the arm
    starts at rest); for a pair that starts closer than the margin, ``start`` less half of
    :data:`COLLISION_SLACK`. Each stays above what the check holds the pair to by a share of
    the distance the motion may dip between the points: the rows are exact there, and a
    bound at the check's own threshold cost Baxter six rounds of micrometre dips."""
    if start < margin:
        return start - COLLISION_SLACK / 2
    return min(margin + COLLISION_ALLOWANCE, (start + margin) / 2)


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
    quadratic in the balance joints at every collocation point, their coefficients NLP
    parameters (``problem.bounds.exact``: linearised with the arm at rest, then at each plan
    the refinement finds too close)."""

    name = "exact collision"

    def __init__(self, key: str):
        self.key = key  # of the pairs (CollisionModels.exact)

    def values(self, problem):
        lin = problem.bounds.exact
        return {
            f"exact_{name}": getattr(lin, name)
            for name in ("distance", "gradient", "centre", "bend")
        }

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        pairs = nlp.model.collisions.exact[self.key]
        X, _ = nlp.variables.points()
        n_B = len(nlp.joints)
        par = nlp.parameters
        values = []
        for w in range(len(pairs)):
            rows = slice(w * n_B, (w + 1) * n_B)
            step = X[3 : 3 + n_B, :] - par.exact_centre[rows, :]
            values.append(
                par.exact_distance[w, :]
                + cs.sum1(par.exact_gradient[rows, :] * step)
                - 0.5 * cs.sum1(par.exact_bend[rows, :] * step**2)
            )
        labels = [f"{name} (exact, linearised)" for name in pairs]
        return block_rows(nlp, "collision clearance", labels, "m", cs.vertcat(*values))

    def row_bounds(self, problem, block):
        return problem.bounds.exact.lower.ravel(order="F"), np.full(block.size, np.inf)

    def tighten(self, problem, result):
        exact = {p.index for p in problem.collision.exact}
        pairs = [p for p in short(problem, result) if p.index in exact]
        if not pairs:
            return {}, []
        closest = f"closest {pairs[0].pair}, {pairs[0].distance:.4f} m"
        said = f"exact rows of {len(problem.collision.exact)} pairs linearised ({closest})"
        return {"exact": linearise(problem, point_configurations(problem, result), result)}, [said]
