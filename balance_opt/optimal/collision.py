"""Collision avoidance in the optimal planner: which pairs a problem keeps apart, and how."""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter
from dataclasses import dataclass

import casadi as cs
import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError
from balance_opt.geometry.clearance import ClearanceReport, PairClearance, clearance
from balance_opt.geometry.robot_geometry import NoGeometryError, Pair, RobotGeometry
from balance_opt.geometry.shapes import ClearanceRows, clearance_rows, moved_by
from balance_opt.optimal.terms import (
    Output,
    PlannerSolverError,
    Rows,
    SymbolicNLP,
    Term,
    Violation,
    block_rows,
    rounds_tried,
)

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
#: The refinement raises a row's bound by the pair's shortfall and as much more, up to this
#: [m].
PUSH = 2e-3
#: The check certifies the pairs' distances down to the margin plus this [m] (farther pairs are
#: only known to stay beyond it).
WATCH = 0.05

#: A pair whose fitted shapes start closer than the margin plus this [m] gets a row of its own
#: (a shared row's soft minimum lies up to log(n) / BETA below its pairs).
ALONE_GAP = 0.01


class InitialCollisionError(InputError):
    """Checked pairs in contact at a plan's initial configuration: no plan can keep them
    apart, and every plan's clearance check would report them.

    Attributes:
        pairs: the pairs in contact, by name.
        balance: whether a body the balance joints move is among them (the balance start is at
            fault, not the mission's alone).
    """

    def __init__(self, geometry: RobotGeometry, q0: np.ndarray, contacts: list[Pair]):
        d = geometry.distances(q0, [p.index for p in contacts])
        self.pairs = [p.name for p in contacts]
        robot = geometry.robot
        moved = moved_by(geometry, [robot.joint_names[i] for i in robot.balance_indices])
        self.balance = any(
            {geometry.body(p.first), geometry.body(p.second)} & moved for p in contacts
        )
        pairs = ", ".join(f"{p.name} ({max(-x, 0.0):.4f} m deep)" for p, x in zip(contacts, d))
        super().__init__(
            f"{geometry.robot.name}: the initial configuration is in collision: {pairs}; "
            "move it, or leave the pairs out (robot.srdf, optimal.collision.ignore) if the "
            "geometry overlaps there by design"
        )


#: Why a checked pair has no row in the planner (:attr:`CollisionSetup.left_out`).
MISSION_ONLY = "moved by the mission alone (checked, the planner cannot change it)"
OUT_OF_REACH = "out of the balance arm's reach"
CONSTANT = "a distance the balance joints cannot change"


@dataclass
class CollisionSetup:
    """The collision avoidance of one problem.

    Attributes:
        pairs: the checked pairs the planner holds, each with a row (``owner``).
        watched: per row, whether it stays unbounded: the row of a pair whose fitted shapes
            overlap at the start while its bodies do not (a bound there would start inside a
            shape); its pairs are held by exact rows (``exact``).
        left_out: every other checked pair of the geometry, by name, and why it has no row.
        exact: the pairs of the watched rows, held by rows on their exact distance instead
            (:mod:`~balance_opt.optimal.exact_rows`).
    """

    geometry: RobotGeometry
    rows: ClearanceRows
    pairs: list[Pair]
    initial_rows: np.ndarray
    owner: dict[int, int]
    threshold: dict[int, float]
    watched: np.ndarray
    left_out: dict[str, str]
    exact: tuple[Pair, ...] = ()

    @property
    def exact_key(self) -> str:
        """The key of the exact rows' pairs (``""``: none), registered with the models."""
        if not self.exact:
            return ""
        return f"{self.rows.key}:" + ",".join(str(p.index) for p in self.exact)

    def start_bounds(self, margin: float) -> np.ndarray:
        """The rows' lower bounds before any refinement [m]: the margin plus
        :data:`COLLISION_ALLOWANCE`, below a row's start value by :data:`COLLISION_SLACK` at
        most, and none for a watched row."""
        start = np.minimum(margin + COLLISION_ALLOWANCE, self.initial_rows - COLLISION_SLACK)
        return np.where(self.watched, -np.inf, start)

    def account(self) -> dict:
        """What the planner does with each checked pair, as plain data: the pairs with a row
        (``constrained``), those of them held by exact rows instead (``watched``), and the
        pairs left out, counted by reason."""
        watched = set(np.flatnonzero(self.watched).tolist())
        return {
            "constrained": len(self.pairs),
            "watched": sorted(p.name for p in self.pairs if self.owner[p.index] in watched),
            "left_out": dict(Counter(self.left_out.values())),
        }


def _robot_key(robot) -> tuple:
    """What of a robot of the model's kinematics its geometry depends on: the limits (the
    samples of the pairs computed without an SRDF are drawn inside them), the mesh folders and
    the keep-out zones."""
    limits = robot.limits
    return (limits.lower.tobytes(), limits.upper.tobytes(), robot.packages, robot.keep_out)


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
        #: exact rows key (:attr:`CollisionSetup.exact_key`) -> the pairs' names
        self.exact: dict = {}

    def geometry(self, ignore=(), srdf: str | None = None, robot=None) -> RobotGeometry:
        """The geometry of ``robot`` (default: the model's; the model's kinematics, possibly
        other limits) with the pairs ``ignore`` and ``srdf`` left out, built once: the planner
        and a run's clearance check share it (``app.pipeline.run_geometry``)."""
        robot = self.robot if robot is None else robot
        ignore = tuple(sorted(tuple(sorted(p)) for p in ignore))
        key = (ignore, srdf, _robot_key(robot))
        if key not in self.geometries:
            self.geometries[key] = RobotGeometry(robot, srdf=srdf, ignore=ignore)
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


def collision_setup(model, options, q0: np.ndarray, robot=None) -> CollisionSetup | None:
    """The collision avoidance of a problem of ``model`` (a
    :class:`~balance_opt.optimal.model.PlannerModel`) for ``robot`` (default: the model's)
    starting at the arm configuration ``q0``; ``None`` when ``options.collision_avoidance`` is
    off or no pair involves the balance arm."""
    if not options.collision_avoidance:
        return None
    robot = model.robot if robot is None else robot
    # the stages and refinements of one plan are variants of one problem: built once
    key = (
        options.collision_ignore,
        options.collision_srdf,
        options.collision_margin,
        np.asarray(q0, float).tobytes(),
        _robot_key(robot),
    )
    setups = model.collisions.setups
    if key not in setups:  # the shapes placed by the planner's own kinematics
        placements = model.maps.joint_placements_fun()
        setups[key] = _setup(model.collisions, options, q0, placements, robot)
    return setups[key]


def restarted(
    setup: CollisionSetup | None, model, options, q0: np.ndarray
) -> CollisionSetup | None:
    """``setup``, the collision avoidance of the same problem from another start, with its rows'
    start values and its pairs' thresholds taken at ``q0``: a re-plan
    (:mod:`balance_opt.control.replan`) keeps the rows, and so the NLP structure, built before
    the motion (choosing them again from every measured start costs a quarter second, and a
    row set of its own a new structure); only the start's bounds move."""
    if setup is None:
        return None
    E, e = setup.geometry.robot.mimic_matrix
    f = model.collisions.function(setup.rows, model.maps.joint_placements_fun())
    indices = [p.index for p in setup.pairs]
    exact = dict(zip(indices, setup.geometry.distances(q0, indices)))
    threshold = {i: min(options.collision_margin, d) for i, d in exact.items()}
    return dataclasses.replace(
        setup, initial_rows=np.array(f(E @ q0 + e)).ravel(), threshold=threshold
    )


def check_start(
    models: CollisionModels, options, q0: np.ndarray, robot=None
) -> RobotGeometry | None:
    """The geometry a problem of ``options`` for ``robot`` (default: the model's) starting at
    the arm configuration ``q0`` keeps apart (``None``: no avoidance, or no geometry), checked
    before anything else is built.

    Raises:
        InitialCollisionError: checked pairs in contact at ``q0``.
    """
    if not options.collision_avoidance:
        return None
    try:
        geometry = models.geometry(options.collision_ignore, options.collision_srdf, robot)
    except NoGeometryError as exc:  # nothing to keep apart
        log.info("no collision avoidance: %s", exc)
        return None
    contacts = geometry.contacts(q0)
    if contacts:  # not disabled (SRDF, reference pose, nearly always): the task's own fault
        raise InitialCollisionError(geometry, q0, contacts)
    return geometry


def _setup(
    models: CollisionModels, options, q0: np.ndarray, placements, robot
) -> CollisionSetup | None:
    geometry = check_start(models, options, q0, robot)
    if geometry is None:
        return None
    robot = geometry.robot
    moved = moved_by(geometry, [robot.joint_names[i] for i in robot.balance_indices])
    left_out = {}
    pairs = []
    for p in geometry.pairs:
        if {geometry.body(p.first), geometry.body(p.second)} & moved:
            pairs.append(p)
        else:
            left_out[p.name] = MISSION_ONLY
    out_of_reach = _out_of_reach(geometry, pairs, moved, options.collision_margin + WATCH)
    left_out |= {p.name: OUT_OF_REACH for p in pairs if p.index in out_of_reach}
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
    # shapes that overlap where the bodies do not: a bound there would start inside a shape,
    # where the distance is least smooth (Ipopt got stuck on one); their rows start unbounded
    # and the refinement bounds them where the exact check finds the pair too close
    overlap = {p for p, d in zip(shape_pairs, start) if d < 0.0}
    rows = _moving_rows(geometry, clearance_rows(geometry, pairs, moved, alone), placements)
    if not rows.rows:
        return None
    left_out |= {p.name: CONSTANT for p in pairs if rows.row_of(p) is None}
    pairs = [p for p in pairs if rows.row_of(p) is not None]
    log.info(
        "%s: %d checked pairs held by %d collision rows; left out: %s",
        robot.name,
        len(pairs),
        len(rows.rows),
        ", ".join(f"{n} {r}" for r, n in Counter(left_out.values()).items()) or "none",
    )
    f = models.function(rows, placements)
    initial = np.array(f(E @ q0 + e)).ravel()
    watched = np.array([len(row) == 1 and row[0] in overlap for _, row in rows.rows], dtype=bool)
    owner = {p.index: rows.row_of(p) for p in pairs}
    exact = geometry.distances(q0)
    threshold = {p.index: min(options.collision_margin, exact[p.index]) for p in pairs}
    # the watched rows' pairs: their shapes cannot tell them apart, their exact distance can
    held = tuple(p for p in pairs if watched[owner[p.index]])
    setup = CollisionSetup(
        geometry, rows, pairs, initial, owner, threshold, watched, left_out, held
    )
    if held:
        models.exact[setup.exact_key] = tuple(p.name for p in held)
    return setup


def report(problem, result) -> ClearanceReport:
    """The clearance of a re-simulated plan of ``problem`` over the pairs the balance joints
    move (computed once per result and collision setup: the check, the refinement and the
    acceptance share it; kept with the result, which the solve made)."""
    setup = problem.collision
    last = getattr(result, "_clearance", None)
    if last is not None and last.setup is setup:
        return last.report
    out = clearance(
        setup.geometry,
        result.t,
        np.hstack([result.q_M, result.q_B]),
        pairs=[p.index for p in setup.pairs],
        watch=problem.options.collision_margin + WATCH,
    )
    result._clearance = _Checked(setup, out)
    return out


class _Checked:
    """A result's clearance report for one collision setup, kept with the result (which the
    solve made; the problem is left alone); not pickled with it: a plan sent to another
    process is checked again there."""

    def __init__(self, setup=None, report=None):
        self.setup, self.report = setup, report

    def __reduce__(self):
        return (_Checked, ())


def short(problem, result) -> list[PairClearance]:
    """The pairs closer than they must keep, closest first: the margin (less
    :data:`TOLERANCE`), or, for a pair that starts closer (the arm starts at rest there), its
    distance at the start less :data:`COLLISION_SLACK`, as its row is bounded. A watched pair
    too (its fitted shapes overlap at the start): its exact rows are linearised again
    (:mod:`~balance_opt.optimal.exact_rows`), and a plan that stays too close after the rounds
    fails."""
    setup, margin = problem.collision, problem.options.collision_margin
    return [
        p
        for p in report(problem, result).below(margin)
        if p.distance < setup.threshold[p.index] - allowance(setup.threshold[p.index], margin)
    ]


def allowance(threshold: float, margin: float) -> float:
    """How far below its threshold [m] a pair may come: :data:`COLLISION_SLACK` for a pair
    held to its distance at the start (below the margin), else :data:`TOLERANCE`."""
    return COLLISION_SLACK if threshold < margin else TOLERANCE


def point_configurations(problem, result) -> np.ndarray:
    """The arm configurations of a re-simulated plan at the collocation points (n_points, n)."""
    q = np.hstack([result.q_M, result.q_B])
    return np.stack([np.interp(problem.point_times, result.t, c) for c in q.T], axis=1)


def row_values(problem, result) -> np.ndarray:
    """The collision rows' values at the collocation points of a re-simulated plan (n_c,
    n_points) [m]."""
    setup = problem.collision
    points = point_configurations(problem, result)
    E, e = setup.geometry.robot.mimic_matrix
    f = problem.model.collisions.function(setup.rows, problem.model.maps.joint_placements_fun())
    return np.array(f.map(points.shape[0])((points @ E.T + e).T))


def tighten(problem, result) -> tuple[dict, list[str]]:
    """The collision rows' bounds (a change of :class:`~balance_opt.optimal.problem.Bounds`)
    raised for the pairs closer than their threshold (:func:`short`) on every interval where
    they are (and on the one of their minimum): to the row's bound or its value in this plan,
    whichever is larger, plus twice the interval's shortfall, or the shortfall and
    :data:`PUSH` if less (not the watched pairs: their exact rows are linearised again,
    :mod:`~balance_opt.optimal.exact_rows`); and what it raised, in words."""
    setup = problem.collision
    exact = {p.index for p in setup.exact}  # held by their exact rows (exact_rows.ExactRows)
    pairs = [p for p in short(problem, result) if p.index not in exact]
    if not pairs:
        return {}, []
    closest = f"closest {pairs[0].pair}, {pairs[0].distance:.4f} m"
    said = [f"collision rows of {len(pairs)} pairs ({closest})"]
    N = problem.N
    mids = problem.transcription.has_midpoints
    before = problem.bounds.collision
    bound = np.array(before)
    # from this plan's bound or value: pairs that share a row raise it once, by the most
    floor = np.maximum(before, row_values(problem, result))
    q = np.hstack([result.q_M, result.q_B])
    for pair in pairs:
        row = setup.owner[pair.index]
        target = setup.threshold[pair.index]
        d = setup.geometry.distances_along(q, pair.index)
        close = d < target - TOLERANCE
        times = np.append(result.t[close], pair.time)
        distances = np.append(d[close], pair.distance)
        # each interval by its own shortfall, and pushed beyond it by as much, up to PUSH: the
        # deepest shortfall, or a full PUSH, would push a pair that only grazes its threshold
        # (one held at its start distance, next to an arm that starts at rest) as far as where
        # it goes through, farther than the arm can move there
        intervals = np.minimum((times / problem.h).astype(int), N - 1)
        shortfall = np.full(N, -np.inf)
        np.maximum.at(shortfall, intervals, target - distances)
        for k in np.unique(intervals):
            columns = [k, k + 1] + ([N + 1 + k] if mids else [])
            raised = floor[row, columns] + shortfall[k] + min(PUSH, shortfall[k])
            bound[row, columns] = np.maximum(bound[row, columns], raised)
    # the arm starts at rest where it is: the first node's rows cannot move
    bound[:, 0] = np.minimum(bound[:, 0], setup.initial_rows - COLLISION_SLACK)
    return {"collision": bound}, said


class Collision(Term):
    """Collision avoidance (:mod:`balance_opt.optimal.collision`, which does the work): at
    every collocation point, one row per body the balance joints move, the soft minimum of
    its fitted shapes' distances to the others, at least ``collision.margin`` (its bounds:
    ``problem.bounds.collision``), and rows of their own for pairs that start close (watched,
    unbounded, where their shapes overlap: held by exact rows instead). The shapes contain the bodies; between the points
    the refinement raises a row's bound where the re-simulated motion comes closer than the
    margin (:meth:`tighten`), and a plan that still penetrates, or comes closer than the
    margin (a pair that starts closer: than its start, less the rows' slack), fails
    (:meth:`accept`)."""

    name = "collision"

    def __init__(self, key: str):
        self.key = key  # of the collision rows (:class:`CollisionModels`)

    def outputs(self, model):
        rows, f = model.collisions.rows[self.key]
        # out of the cost: Ipopt's line search needs none of them
        return (Output("clearance", len(rows.rows), f"_c{self.key}", lambda p: f(p.q), False),)

    def rows(self, nlp: SymbolicNLP) -> list[Rows]:
        labels = [f"{label} (soft minimum)" for label in nlp.model.collisions.labels(self.key)]
        clearance = nlp.outputs["clearance"]
        return block_rows(nlp, "collision clearance", labels, "m", clearance)

    def row_bounds(self, problem, block):
        return problem.bounds.collision.ravel(order="F"), np.full(block.size, np.inf)

    def check(self, problem, result):
        pairs = short(problem, result)
        if not pairs:
            return None
        closest = pairs[0]
        amount = problem.collision.threshold[closest.index] - closest.distance
        return Violation(f"collision margin of {closest.pair}", closest.time, amount, "m")

    def tighten(self, problem, result):
        return tighten(problem, result)

    def accept(self, problem, result):
        """A plan that still penetrates, or comes closer than the margin, after the
        refinement fails, naming the pair, the depth, the time and the rounds tried."""
        rounds = rounds_tried(result)
        pen = report(problem, result).first_penetration
        if pen is not None:
            raise PlannerSolverError(
                f"no collision-free plan found: {pen.pair} penetrate by {pen.depth:.4g} m at "
                f"t = {pen.time:.3f} s, {rounds}",
                "Collision",
                result,
                f"collision of {pen.pair}",
                pen.time,
                pen.depth,
            )
        pairs = short(problem, result)
        if pairs:
            threshold = problem.collision.threshold
            p = max(pairs, key=lambda p: threshold[p.index] - p.distance)  # the farthest in
            threshold = threshold[p.index]
            raise PlannerSolverError(
                f"no plan keeps the collision margin: {p.pair} come within {p.distance:.4g} m "
                f"at t = {p.time:.3f} s, {threshold - p.distance:.4g} m inside the "
                f"{threshold:.4g} m they must keep, {rounds}",
                "Collision",
                result,
                f"collision margin of {p.pair}",
                p.time,
                threshold - p.distance,
            )


def guess_through(problem, guess) -> str | None:
    """Where the guess ``guess`` (a :class:`~balance_opt.optimal.problem.Solution` of
    ``problem``) breaks a collision row's bound by more than :data:`COLLISION_SLACK`: the row,
    the time and by how much, in words; ``None`` where it keeps them all.

    The analytic law knows no bodies: its motion may drive a link through another (the UR5
    satellite's turns the wrist through the forearm). Started inside a body, Ipopt can end at a
    point of least infeasibility, where the row's two sides pull the link both ways."""
    setup = problem.collision
    X, _ = guess.points()
    n_M, n_B = setup.geometry.robot.mission.dof, problem.model.n_B
    q = np.vstack([problem.mission_samples[:n_M], X[3 : 3 + n_B]])  # (n, n_points)
    E, e = setup.geometry.robot.mimic_matrix
    f = problem.model.collisions.function(setup.rows, problem.model.maps.joint_placements_fun())
    shortfall = problem.bounds.collision - np.array(f.map(q.shape[1])(E @ q + e[:, None]))
    row, point = np.unravel_index(int(np.argmax(shortfall)), shortfall.shape)
    if shortfall[row, point] <= COLLISION_SLACK:
        return None
    return (
        f"{setup.rows.labels[row]} {shortfall[row, point]:.3g} m below its bound at "
        f"t = {problem.point_times[point]:.3f} s"
    )
