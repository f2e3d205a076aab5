"""The volume of a robot's bodies: Pinocchio's geometry model (meshes as convex hulls, so
distances are signed and hold for the meshes), the pairs checked and exact distances (coal).
A *body* is a joint of the reduced model; pairs of one body, of adjacent bodies, named by an
SRDF (or, without one, computed as MoveIt's setup assistant does:
:mod:`~balance_opt.geometry.self_collision`) or by the caller are left out
(``docs/collision.md``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError
from balance_opt.geometry import keep_out, self_collision
from balance_opt.model.capture import TARGET_LINK
from balance_opt.model.meshes import geometry_kind, resolved_urdf
from balance_opt.model.robot import FloatingRobot

log = logging.getLogger(__name__)


class NoGeometryError(InputError):
    """A URDF without any ``<collision>`` or ``<visual>`` element."""


@dataclass(frozen=True)
class Pair:
    """A checked pair: its index among the collision pairs, the geometry objects' indices and
    their ``links``."""

    index: int
    first: int
    second: int
    links: tuple[str, str]

    @property
    def name(self) -> str:
        return f"{self.links[0]} / {self.links[1]}"


def default_srdf(urdf_path: Path | None) -> Path | None:
    """The SRDF beside a URDF: ``NAME.srdf`` next to ``NAME.urdf``, else the one shipped in
    ``../srdf/`` of its description folder (example-robot-data), if exactly one there or one
    named after the URDF."""
    if urdf_path is None:
        return None
    beside = urdf_path.resolve().with_suffix(".srdf")
    if beside.is_file():
        return beside
    folder = urdf_path.resolve().parent.parent / "srdf"
    found = sorted(folder.glob("*.srdf")) if folder.is_dir() else []
    named = [p for p in found if p.stem == urdf_path.stem]
    if named:
        return named[0]
    return found[0] if len(found) == 1 else None


def convex_hull(mesh: coal.BVHModelBase) -> coal.ConvexBase:
    """The convex hull of a mesh's vertices (qhull, through coal).

    Not the mesh's ``buildConvexRepresentation``: its ``convex`` keeps every vertex of the mesh,
    the inner ones included, and coal's GJK on such a point set reads points inside the hull as
    outside it (a sphere 0.12 m inside the UR5 forearm's hull read as 0.12 m away).
    """
    points = coal.StdVec_Vec3s()
    points.extend(list(np.array(mesh.vertices(), dtype=float)))
    return coal.Convex.convexHull(points, True, None)


class RobotGeometry:
    """The geometry of a floating robot and the pairs of objects checked for collision.

    Args:
        robot: the robot (its reduced model: locked joints are fixed).
        srdf: an SRDF whose ``<disable_collisions>`` pairs are left out; default: the one
            beside the URDF (:func:`default_srdf`), if any; ``False``: none. Without an SRDF
            the pairs in contact in the reference pose or in nearly every configuration are
            computed (:func:`~balance_opt.geometry.self_collision.disabled_pairs`).
        ignore: pairs of link names left out as well.
        disabled: link pairs to leave out with their reasons, instead of an SRDF's or computed
            ones (the robot after a capture takes those of the robot before it).
        packages: folders searched first for ``package://`` meshes (default: the robot's
            ``packages``; :mod:`~balance_opt.model.meshes` has the search order).

    Attributes:
        geometry_model: Pinocchio's geometry model (meshes as convex hulls), its collision pairs
            the checked ones.
        source: ``"collision"`` or ``"visual"``: the URDF elements the geometry was built from.
        srdf: the SRDF applied, or ``None`` (the pairs were computed, or ``disabled`` given).
        samples: the configurations sampled to compute the pairs (0: an SRDF or ``disabled``
            gave them).
        mesh_vertices: every vertex of each mesh object, by object index, in its frame (the
            fitted capsules contain them, so they contain the hull).
        pairs: the checked pairs (:class:`Pair`), in the geometry model's order.
        ignored: the pairs left out, ``{(link, link): reason}``.
        zones: the robot's keep-out zones (``robot.keep_out``) by object index
            (:mod:`~balance_opt.geometry.keep_out`).

    Raises:
        InputError: the URDF has no geometry, a mesh cannot be found, an ignored pair names a
            link without geometry.
    """

    def __init__(
        self,
        robot: FloatingRobot,
        srdf: str | Path | bool | None = None,
        ignore: Iterable[Sequence[str]] = (),
        disabled: Mapping[tuple[str, str], str] | None = None,
        packages: Sequence[str | Path] | None = None,
    ):
        self.robot = robot
        self.model = robot.model
        urdf_path = None if robot.source.startswith("<") else Path(robot.source)
        self.source = geometry_kind(robot.locked_urdf)
        kind = pin.COLLISION if self.source == "collision" else pin.VISUAL
        packages = robot.packages if packages is None else packages
        text = resolved_urdf(robot.locked_urdf, robot.source, packages, self.source)
        try:
            geom = pin.buildGeomFromUrdfString(self.model, text, kind)
        except ValueError as exc:
            raise InputError(
                f"geometry of {robot.source}: {exc} (plan without collision avoidance: "
                "optimal.collision.avoid: false)"
            ) from exc
        if geom.ngeoms == 0:
            raise NoGeometryError(f"{robot.source} has no <collision> or <visual> geometry")
        self.mesh_vertices: dict[int, np.ndarray] = {}
        for i, obj in enumerate(geom.geometryObjects):
            if isinstance(obj.geometry, coal.BVHModelBase):  # a mesh: its hull
                self.mesh_vertices[i] = np.array(obj.geometry.vertices(), dtype=float)
                obj.geometry = convex_hull(obj.geometry)
            obj.geometry.computeLocalAABB()
        self.geometry_model = geom
        self.ignored: dict[tuple[str, str], str] = {}
        geom.addAllCollisionPairs()
        self._drop(lambda a, b: a.parentJoint == b.parentJoint, "same body")
        parents = self.model.parents
        # a captured target is no link that meets its parent at a joint: it is checked
        # against the link before the one that holds it
        self._drop(
            lambda a, b: (
                TARGET_LINK not in (self._link(a), self._link(b))
                and (
                    parents[a.parentJoint] == b.parentJoint
                    or parents[b.parentJoint] == a.parentJoint
                )
            ),
            "adjacent",
        )
        self.srdf = None
        self.samples = 0
        path = None
        if srdf is not False and disabled is None:
            path = Path(srdf) if srdf not in (None, True) else default_srdf(urdf_path)
        if path is not None:
            if not path.is_file():
                raise InputError(f"SRDF {path}: no such file")
            before = self._pair_links()
            pin.removeCollisionPairs(self.model, geom, str(path))
            for links in before - self._pair_links():
                self.ignored.setdefault(links, "srdf")
            self.srdf = path
        else:
            if disabled is None:
                self.geometry_data = pin.GeometryData(geom)
                self.data = self.model.createData()
                self.pairs = self._make_pairs()
                self.samples = self_collision.SAMPLES
                disabled = self_collision.disabled_pairs(self, self.samples)
            for reason in dict.fromkeys(disabled.values()):
                chosen = {frozenset(k) for k, r in disabled.items() if r == reason}
                self._drop(lambda a, b: frozenset((self._link(a), self._link(b))) in chosen, reason)
        self._drop_ignored(ignore)
        self.zones = self._add_zones(robot.keep_out)
        self.geometry_data = pin.GeometryData(geom)
        self.data = self.model.createData()
        self.pairs: list[Pair] = self._make_pairs()

    def _drop_ignored(self, ignore: Iterable[Sequence[str]]) -> None:
        """Leave out the link pairs the task ignores, each checked to name two links with
        geometry (a pair of the captured target waits for the robot after the capture)."""
        names = {self.link(i) for i in range(self.geometry_model.ngeoms)}
        wanted = set()
        for pair in ignore:
            pair = tuple(pair)
            if TARGET_LINK in pair and TARGET_LINK not in names:
                continue  # a pair of the captured target: for the robot after the capture
            if len(pair) != 2 or not set(pair) <= names:
                unknown = [n for n in pair if n not in names]
                raise InputError(
                    f"collision ignore pair {list(pair)}: expected two links with geometry"
                    + (f"; no geometry on {', '.join(unknown)}" if unknown else "")
                )
            wanted.add(frozenset(pair))
        self._drop(lambda a, b: frozenset((self._link(a), self._link(b))) in wanted, "ignored")

    # ------------------------------------------------------------------ pairs
    def link(self, index: int) -> str:
        """The link (frame) geometry object ``index`` belongs to."""
        return self._link(self.geometry_model.geometryObjects[index])

    def _link(self, obj) -> str:
        if obj.name.startswith(keep_out.PREFIX):  # a zone: its pairs name it
            return obj.name
        return self.model.frames[obj.parentFrame].name

    def _add_zones(self, zones) -> dict[int, keep_out.KeepOutZone]:
        """Each keep-out zone as an object on its frame's joint, paired with every object of
        the bodies its arms move (not its own body): no pair of a zone is left out as adjacent,
        by an SRDF or computed, since a zone meets no link by design. Returns the zones by
        object index."""
        model, geom = self.model, self.geometry_model
        out = {}
        for zone in zones:
            obj = keep_out.zone_object(zone, model)
            index = geom.addGeometryObject(obj)
            out[index] = zone
            arms = zone.arms or [arm.name for arm in self.robot.arms]
            joints = [j for arm in arms for j in self.robot.arm(arm).joints]
            bodies = set().union(*(model.subtrees[model.getJointId(j)] for j in joints))
            bodies.discard(obj.parentJoint)
            for i, other in enumerate(geom.geometryObjects):
                if i not in out and other.parentJoint in bodies:
                    geom.addCollisionPair(pin.CollisionPair(i, index))
        return out

    def _pair_links(self) -> set[tuple[str, str]]:
        return {tuple(sorted(p.links)) for p in self._make_pairs()}

    def _drop(self, test, reason: str) -> None:
        geom = self.geometry_model
        objs = geom.geometryObjects
        # indices copied first: the pairs Python sees are views into a vector that shrinks
        for first, second in [(int(p.first), int(p.second)) for p in geom.collisionPairs]:
            a, b = objs[first], objs[second]
            if test(a, b):
                geom.removeCollisionPair(pin.CollisionPair(first, second))
                links = tuple(sorted((self._link(a), self._link(b))))
                self.ignored.setdefault(links, reason)

    def _make_pairs(self) -> list[Pair]:
        out = []
        for k, p in enumerate(self.geometry_model.collisionPairs):
            out.append(Pair(k, p.first, p.second, (self.link(p.first), self.link(p.second))))
        return out

    def body(self, index: int) -> int:
        """The body (joint of ``model``) of geometry object ``index``."""
        return int(self.geometry_model.geometryObjects[index].parentJoint)

    @cached_property
    def moving_joints(self) -> list[int]:
        """Joints of ``model`` that move: arm joints, then followers (root free-flyer excluded)."""
        return [self.model.getJointId(j) for j in self.robot.model_joint_names]

    # ------------------------------------------------------------------ distances
    def place(self, q) -> None:
        """Place every object at the arm configuration ``q``, base at the identity (distances
        between the robot's own bodies do not depend on the base pose)."""
        pin.updateGeometryPlacements(
            self.model, self.data, self.geometry_model, self.geometry_data, self.robot.pin_q(q)
        )

    def distances(self, q, pairs: Sequence[int] | None = None) -> np.ndarray:
        """Exact distances [m] (negative: penetration) of the ``pairs`` (default all) at ``q``."""
        self.place(q)
        pairs = range(len(self.geometry_model.collisionPairs)) if pairs is None else pairs
        return np.array(
            [
                pin.computeDistance(self.geometry_model, self.geometry_data, int(k)).min_distance
                for k in pairs
            ]
        )

    def smallest_along(self, q, pairs: Sequence[int] | None = None) -> np.ndarray:
        """The smallest distance [m] of the ``pairs`` (default all) at each row of ``q`` (T, n)."""
        if not self.pairs or (pairs is not None and not len(pairs)):
            return np.full(len(q), np.inf)
        return np.array([self.distances(qk, pairs).min() for qk in q])

    def distances_along(self, q, pair: int) -> np.ndarray:
        """The distance [m] of pair ``pair`` at every configuration of ``q`` (T, n)."""
        return np.array([self.distances(qk, [pair])[0] for qk in q])

    def contacts(self, q) -> list[Pair]:
        """The checked pairs in contact (distance <= 0) at the arm configuration ``q``."""
        d = self.distances(q)
        return [p for p in self.pairs if d[p.index] <= 0.0]

    @property
    def disabled(self) -> dict[tuple[str, str], str]:
        """The link pairs the robot leaves out, not the task (``ignored`` less the task's)."""
        return {k: r for k, r in self.ignored.items() if r != "ignored"}

    @property
    def computed(self) -> list[tuple[str, str]]:
        """The link pairs disabled by the rules of
        :mod:`~balance_opt.geometry.self_collision` (no SRDF), as ``(pair name, reason)``,
        sorted (empty with an SRDF)."""
        return sorted(
            (f"{a} / {b}", r) for (a, b), r in self.ignored.items() if r in ("default", "always")
        )

    def summary(self, q, margin: float = 0.0) -> dict:
        """What is checked, as plain data (``metrics.json``'s ``geometry``, ``inspect``): the
        geometry's source, the SRDF, the samples of computed pairs, the checked pairs, the pairs
        left out by reason, the computed ones by name, and the pairs closer than ``margin`` [m]
        at ``q``, closest first."""
        reasons = ("same body", "adjacent", "default", "always", "near", "srdf", "ignored")
        ignored = dict.fromkeys(reasons, 0)
        for reason in self.ignored.values():
            ignored[reason] += 1
        d = self.distances(q) if self.pairs else np.empty(0)
        close = sorted((float(d[p.index]), p.name) for p in self.pairs if d[p.index] <= margin)
        return {
            "source": self.source,
            "srdf": None if self.srdf is None else str(self.srdf),
            "samples": self.samples,
            "pairs_checked": len(self.pairs),
            "link_pairs_ignored": ignored,
            "computed_disabled": [{"pair": n, "reason": r} for n, r in self.computed],
            "margin_m": float(margin),
            "initial_contacts": [{"pair": n, "distance_m": x} for x, n in close if x <= 0.0],
            "initial_within_margin": [{"pair": n, "distance_m": x} for x, n in close if x > 0.0],
        }

    # ------------------------------------------------------------------ motion bound
    @cached_property
    def reach(self) -> np.ndarray:
        """(n_objects, n_moving) bound [m] on how far each moving joint's axis is from any point
        of each object below it, whatever the configuration (0 for joints not above it; 1 for a
        prismatic joint, which moves every point by its displacement)."""
        model, geom = self.model, self.geometry_model
        column = {j: c for c, j in enumerate(self.moving_joints)}
        out = np.zeros((geom.ngeoms, len(column)))
        for i, obj in enumerate(geom.geometryObjects):
            box = obj.geometry.aabb_local
            lo, hi = np.asarray(box.min_), np.asarray(box.max_)
            radius = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
            length = float(np.linalg.norm(obj.placement.translation)) + radius
            j = int(obj.parentJoint)
            while j > 0:
                if j in column:
                    prismatic = model.joints[j].shortname().startswith("JointModelP")
                    out[i, column[j]] = 1.0 if prismatic else length
                length += float(np.linalg.norm(model.jointPlacements[j].translation))
                j = int(model.parents[j])
        return out
