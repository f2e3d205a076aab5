"""Collision avoidance in the optimal planner: which pairs a problem keeps apart, and how."""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import casadi as cs
import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError
from balance_opt.geometry.clearance import ClearanceReport, PairClearance, clearance
from balance_opt.geometry.robot_geometry import NoGeometryError, Pair, RobotGeometry
from balance_opt.geometry.shapes import ClearanceRows, clearance_rows, moved_by

log = logging.getLogger(__name__)

#: How far below its value at ``t = 0`` a collision row that starts inside the margin is
#: bounded [m] (a bound equal to the fixed initial value would leave no interior).
COLLISION_SLACK = 1e-3
#: The collision rows hold the margin plus this at the collocation points [m]: the motion
#: between two points bends toward a body by about this much, and every
#: dip below the margin costs a refinement round (a full re-solve).
COLLISION_ALLOWANCE = 2e-3
#: Distance [m] by which the re-simulated motion may come closer than the margin without a
#: refinement round.
TOLERANCE = 1e-6
#: The refinement raises a row's bound by the pair's shortfall and this much more [m].
PUSH = 2e-3
#: The check certifies the pairs' distances down to the margin plus this [m] (farther pairs are
#: only known to stay beyond it).
WATCH = 0.05

#: A pair whose fitted shapes start closer than the margin plus this [m] gets a row of its own
#: (a shared row's soft minimum lies up to log(n) / BETA below its pairs).
ALONE_GAP = 0.01


class InitialCollisionError(InputError):
    """Checked pairs in contact at a plan's initial configuration: no plan can keep them
    apart, and every plan's clearance check would report them."""

    def __init__(self, geometry: RobotGeometry, q0: np.ndarray, contacts: list[Pair]):
        d = geometry.distances(q0, [p.index for p in contacts])
        self.pairs = [p.name for p in contacts]
        pairs = ", ".join(f"{p.name} ({max(-x, 0.0):.4f} m deep)" for p, x in zip(contacts, d))
        super().__init__(
            f"{geometry.robot.name}: the initial configuration is in collision: {pairs}; "
            "move it, or leave the pairs out (robot.srdf, optimal.collision.ignore) if the "
            "geometry overlaps there by design"
        )


@dataclass
class CollisionSetup:
    """The collision avoidance of one problem."""

    geometry: RobotGeometry
    rows: ClearanceRows
    pairs: list[Pair]
    initial_rows: np.ndarray
    owner: dict[int, int | None]
    threshold: dict[int, float]


class CollisionModels:
    """A robot's collision geometry and rows, built once per planner model: its geometry per
    set of ignored pairs, the setup of each problem's start, each rows key's rows with their
    numeric function (the point kernels read them by key)."""

    def __init__(self, robot):
        self.robot = robot
        self.geometries: dict = {}
        self.setups: dict = {}
        #: rows key -> (rows, ``clearance_rows(q_model)``)
        self.rows: dict = {}

    def geometry(self, ignore=(), srdf: str | None = None) -> RobotGeometry:
        key = (tuple(sorted(tuple(sorted(p)) for p in ignore)), srdf)
        if key not in self.geometries:
            self.geometries[key] = RobotGeometry(self.robot, srdf=srdf, ignore=key[0])
        return self.geometries[key]

    def function(self, rows: ClearanceRows, placements: cs.Function) -> cs.Function:
        if rows.key not in self.rows:
            q = cs.SX.sym("q_model", placements.size1_in(0))
            f = cs.Function("clearance_rows", [q], [rows.expressions(placements, q)], {"cse": True})
            self.rows[rows.key] = (rows, f)
        return self.rows[rows.key][1]

    def labels(self, key: str) -> tuple[str, ...]:
        """The labels of the rows of a key (none for ``""``)."""
        return self.rows[key][0].labels if key else ()


def _moving_rows(geometry: RobotGeometry, rows: ClearanceRows, placements) -> ClearanceRows:
    """``rows`` without the rows the balance joints cannot change (a link turning about its
    own axis of symmetry, its pairs with bodies the mission moves): constant rows in the NLP."""
    robot = geometry.robot
    q = cs.SX.sym("q", robot.n)
    E, e = robot.mimic_matrix
    values = rows.expressions(placements, cs.DM(E) @ q + cs.DM(e))
    balance = q[robot.mission.dof :]
    keep = [k for k in range(values.numel()) if cs.depends_on(values[k], balance)]
    return dataclasses.replace(rows, rows=tuple(rows.rows[k] for k in keep))


def _out_of_reach(geometry: RobotGeometry, pairs, moved: set[int], beyond: float) -> set[int]:
    """The pairs (indices) of a body the balance joints move and an object fixed to the base
    that can never come within ``beyond`` [m] of each other: the balance arm's first joint
    turns about a fixed point, its bodies stay within their reach of it
    (:attr:`RobotGeometry.reach`), and the object's bounding sphere is farther (Talos's legs
    from its arm). Their rows would only cost: they are left out of the NLP."""
    model, geom = geometry.model, geometry.geometry_model
    root = int(min(o.parentJoint for o in geom.geometryObjects))
    column = {j: c for c, j in enumerate(geometry.moving_joints)}
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    gdata = pin.GeometryData(geom)
    pin.updateGeometryPlacements(model, data, geom, gdata)
    out = set()
    for p in pairs:
        a, b = p.first, p.second
        if geometry.body(a) not in moved:
            a, b = b, a
        if geometry.body(b) != root:
            continue
        j = geometry.body(a)  # the first joint of its chain the balance joints move
        while int(model.parents[j]) in moved:
            j = int(model.parents[j])
        kind = model.joints[j].shortname()
        if int(model.parents[j]) != root or kind.startswith(("JointModelP", "JointModelPrism")):
            continue
        box = geom.geometryObjects[b].geometry.aabb_local
        lo, hi = np.asarray(box.min_), np.asarray(box.max_)
        centre = gdata.oMg[b].act(0.5 * (lo + hi))
        gap = np.linalg.norm(centre - data.oMi[j].translation) - 0.5 * np.linalg.norm(hi - lo)
        if gap - geometry.reach[a, column[j]] > beyond:
            out.add(p.index)
    return out


def collision_setup(model, options, q0: np.ndarray) -> CollisionSetup | None:
    """The collision avoidance of a problem of ``model`` (a
    :class:`~balance_opt.optimal.model.PlannerModel`) starting at the arm configuration ``q0``;
    ``None`` when ``options.collision_avoidance`` is off or no pair involves the balance arm."""
    if not options.collision_avoidance:
        return None
    # the stages and refinements of one plan are variants of one problem: built once
    key = (
        options.collision_ignore,
        options.collision_srdf,
        options.collision_margin,
        np.asarray(q0, float).tobytes(),
    )
    setups = model.collisions.setups
    if key not in setups:  # the shapes placed by the planner's own kinematics
        setups[key] = _setup(model.collisions, options, q0, model.maps.joint_placements_fun())
    return setups[key]


def _setup(models: CollisionModels, options, q0: np.ndarray, placements) -> CollisionSetup | None:
    try:
        geometry = models.geometry(options.collision_ignore, options.collision_srdf)
    except NoGeometryError as exc:  # nothing to keep apart
        log.info("no collision avoidance: %s", exc)
        return None
    robot = geometry.robot
    moved = moved_by(geometry, [robot.joint_names[i] for i in robot.balance_indices])
    contacts = geometry.contacts(q0)
    if contacts:  # not disabled (SRDF, reference pose, nearly always): the task's own fault
        raise InitialCollisionError(geometry, q0, contacts)
    pairs = [p for p in geometry.pairs if {geometry.body(p.first), geometry.body(p.second)} & moved]
    out_of_reach = _out_of_reach(geometry, pairs, moved, options.collision_margin + WATCH)
    pairs = [p for p in pairs if p.index not in out_of_reach]
    if not pairs:
        return None
    rows = clearance_rows(geometry, pairs, moved)
    # pairs whose shapes start closer than the margin get rows of their own, bounded below
    # their start: in a shared row they would lower the bound of every pair of their body
    E, e = robot.mimic_matrix
    shape_pairs, distances = rows.pair_distances(placements)
    start = np.array(distances(E @ q0 + e)).ravel()
    alone = {p for p, d in zip(shape_pairs, start) if d < options.collision_margin + ALONE_GAP}
    # shapes that overlap where the bodies do not: a row there sits inside a shape, where the
    # distance is least smooth; the check alone holds these pairs (a penetration fails the plan)
    overlap = {p for p, d in zip(shape_pairs, start) if d < 0.0}
    rows = clearance_rows(geometry, pairs, moved, alone, skip=overlap)
    rows = _moving_rows(geometry, rows, placements)
    if not rows.rows:
        return None
    shape_of = {i: k for k, s in enumerate(rows.shapes) for i in s.objects}
    unrowed = [p for p in pairs if (shape_of[p.first], shape_of[p.second]) in overlap]
    unrowed += [p for p in pairs if (shape_of[p.second], shape_of[p.first]) in overlap]
    pairs = [p for p in pairs if rows.row_of(p) is not None or p in unrowed]
    f = models.function(rows, placements)
    initial = np.array(f(E @ q0 + e)).ravel()
    owner = {p.index: rows.row_of(p) for p in pairs}
    exact = geometry.distances(q0)
    threshold = {p.index: min(options.collision_margin, exact[p.index]) for p in pairs}
    return CollisionSetup(geometry, rows, pairs, initial, owner, threshold)


def report(problem, result) -> ClearanceReport:
    """The clearance of a re-simulated plan of ``problem`` over the pairs the balance joints
    move (computed once per result: the check, the refinement and the acceptance share it)."""
    last = problem.last_clearance
    if last is not None and last[0] is result:
        return last[1]
    setup = problem.collision
    out = clearance(
        setup.geometry,
        result.t,
        np.hstack([result.q_M, result.q_B]),
        pairs=[p.index for p in setup.pairs],
        watch=problem.options.collision_margin + WATCH,
    )
    problem.last_clearance = (result, out)
    return out


def short(problem, result, rowed: bool = False) -> list[PairClearance]:
    """The pairs closer than their threshold (the margin, or their distance at the start if
    smaller: the arm starts at rest there) beyond :data:`TOLERANCE`, closest first; with
    ``rowed`` only those with a row (the ones the refinement can push)."""
    setup = problem.collision
    return [
        p
        for p in report(problem, result).below(problem.options.collision_margin)
        if p.distance < setup.threshold[p.index] - TOLERANCE
        and not (rowed and setup.owner[p.index] is None)
    ]


def tighten(problem, result) -> tuple[dict, list[str]]:
    """The collision rows' bounds (a change of :class:`~balance_opt.optimal.problem.Bounds`)
    raised for the pairs closer than the margin by their shortfall plus :data:`PUSH` on every
    interval where they are (and on the one of their minimum), and what it raised, in words."""
    pairs = short(problem, result, rowed=True)
    if not pairs:
        return {}, []
    closest = f"closest {pairs[0].pair}, {pairs[0].distance:.4f} m"
    said = [f"collision rows of {len(pairs)} pairs ({closest})"]
    margin, setup, N = problem.options.collision_margin, problem.collision, problem.N
    mids = problem.transcription.has_midpoints
    bound = np.array(problem.bounds.collision)
    q = np.hstack([result.q_M, result.q_B])
    for pair in pairs:
        row = setup.owner[pair.index]
        d = setup.geometry.distances_along(q, pair.index)
        times = np.append(result.t[d < margin], pair.time)
        for k in np.unique(np.minimum((times / problem.h).astype(int), N - 1)):
            columns = [k, k + 1] + ([N + 1 + k] if mids else [])
            bound[row, columns] += margin - pair.distance + PUSH
    # the arm starts at rest where it is: the first node's rows cannot move
    bound[:, 0] = np.minimum(bound[:, 0], setup.initial_rows - COLLISION_SLACK)
    return {"collision": bound}, said
