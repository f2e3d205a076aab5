"""Smooth shapes that contain the robot's bodies, and their distances as CasADi expressions of
the joint positions: the optimal planner's collision constraints (``docs/collision.md``).
Every body but the base gets one capsule; each base object a box or capsule. A row bounds the
soft minimum of a body's pairs, at most ``log(n) / beta`` below the smallest.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import casadi as cs
import numpy as np

from balance_opt.errors import InputError
from balance_opt.geometry.robot_geometry import RobotGeometry

#: Sharpness of the soft minimum [1/m]: with n distances it is at most log(n) / BETA below the
#: smallest (6 mm for 20). A sharper one bends the rows harder where two distances cross, and
#: Ipopt takes more iterations to follow them (benchmarks/bench_collision.py, docs/collision.md).
BETA = 500.0
#: Spacing of the spheres along a capsule against a box, in capsule radii: the spheres grow by
#: at most 12 % of the radius to cover the capsule; closer spheres only make the kernels larger.
SPHERE_SPACING = 1.0
#: Sides of the prism fitted around a cylinder (its circumscribed polygon).
PRISM_SIDES = 16
#: Radii tried above the smallest when fitting a capsule (factors).
RADIUS_FACTORS = np.linspace(1.0, 2.0, 21)


@dataclass(frozen=True)
class Shape:
    """A fitted shape in the frame of its body's joint (``body``, a joint of ``robot.model``):
    a ``"capsule"`` (segment ``a``-``b`` [m], ``radius``) or a ``"box"`` (centre ``a`` = ``b``,
    axes ``rotation``, ``half`` sides [m]), and the geometry ``objects`` it contains."""

    name: str
    body: int
    kind: str
    a: np.ndarray
    b: np.ndarray
    radius: float
    rotation: np.ndarray
    half: np.ndarray
    objects: tuple[int, ...]

    def numbers(self) -> list[float]:
        """Every number that defines it (for the content key)."""
        return [*self.a, *self.b, self.radius, *self.rotation.ravel(), *self.half]


def _capsule_of_primitive(obj) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The exact capsule of a cylinder, sphere or capsule object, in its joint's frame."""
    g, M = obj.geometry, obj.placement
    name = type(g).__name__
    if name in ("Cylinder", "Capsule"):
        ax = M.rotation[:, 2] * g.halfLength
        return M.translation - ax, M.translation + ax, float(g.radius)
    if name == "Sphere":
        return M.translation.copy(), M.translation.copy(), float(g.radius)
    return None


def _hull_points(obj, mesh_vertices: np.ndarray | None = None) -> np.ndarray:
    """Points whose convex hull contains the object, in its joint's frame; a mesh's are its
    ``mesh_vertices`` (every vertex, as the capsule was always fitted: the same capsules)."""
    g, M = obj.geometry, obj.placement
    name = type(g).__name__
    if name == "Box":
        h = np.asarray(g.halfSide)
        local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * h
    elif name in ("Cylinder", "Capsule", "Sphere"):
        r = float(g.radius)
        half = float(getattr(g, "halfLength", 0.0)) + (r if name != "Cylinder" else 0.0)
        angle = np.arange(PRISM_SIDES) * 2 * np.pi / PRISM_SIDES
        ring = np.stack([np.cos(angle), np.sin(angle)], axis=1) * r / np.cos(np.pi / PRISM_SIDES)
        local = np.vstack([np.hstack([ring, np.full((PRISM_SIDES, 1), z)]) for z in (-half, half)])
    elif mesh_vertices is not None:
        local = mesh_vertices
    elif hasattr(g, "points"):
        local = np.asarray(g.points())
    else:
        raise InputError(f"geometry object '{obj.name}': shape {name} has no capsule fit")
    return local @ M.rotation.T + M.translation


def fit_capsule(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule containing ``points`` (m, 3), of small volume: for each principal axis and
    radius (:data:`RADIUS_FACTORS` times the largest distance from the axis) the shortest
    segment that keeps every point within the radius; the smallest volume wins."""
    c = points.mean(axis=0)
    _, _, axes = np.linalg.svd(points - c, full_matrices=False)
    best = None
    for axis in axes:
        s = (points - c) @ axis
        rho = np.linalg.norm(points - c - np.outer(s, axis), axis=1)
        for factor in RADIUS_FACTORS:
            r = max(float(rho.max()) * factor, 1e-9)
            w = np.sqrt(np.maximum(r**2 - rho**2, 0.0))
            # point i is within r of [lo, hi] iff lo <= s_i + w_i and hi >= s_i - w_i
            lo, hi = float((s + w).min()), float((s - w).max())
            if lo > hi:  # any point of [hi, lo] will do
                lo = hi = 0.5 * (lo + hi)
            volume = np.pi * r**2 * (hi - lo) + 4.0 / 3.0 * np.pi * r**3
            if best is None or volume < best[0]:
                best = (volume, c + lo * axis, c + hi * axis, r * (1 + 1e-9))
    return best[1], best[2], best[3]


def fit_shapes(geometry: RobotGeometry) -> list[Shape]:
    """The fitted shapes of every body with geometry (see the module docstring)."""
    objs, meshes = geometry.geometry_model.geometryObjects, geometry.mesh_vertices
    root = min(int(o.parentJoint) for o in objs)
    by_body: dict[int, list[int]] = {}
    for i, o in enumerate(objs):
        by_body.setdefault(int(o.parentJoint), []).append(i)
    shapes = []
    eye, zero = np.eye(3), np.zeros(3)
    for body, members in sorted(by_body.items()):
        own = [i for i in members if i not in geometry.zones]
        groups = [[i] for i in own] if body == root else [own] if own else []
        for group in groups + [[i] for i in members if i in geometry.zones]:
            first = objs[group[0]]
            if group[0] in geometry.zones:
                shapes.append(zone_shape(first, body, group[0]))
                continue
            name = first.name if body == root else geometry.link(group[0])
            kind = type(first.geometry).__name__
            if body == root and kind not in ("Cylinder", "Capsule", "Sphere"):
                # a box, or the box around a mesh hull in its own frame
                M = first.placement
                box = first.geometry.aabb_local
                lo, hi = np.asarray(box.min_, dtype=float), np.asarray(box.max_, dtype=float)
                centre = M.translation + M.rotation @ (0.5 * (lo + hi))
                half = 0.5 * (hi - lo)
                rotation = M.rotation.copy()
                shapes.append(
                    Shape(name, body, "box", centre, centre, 0.0, rotation, half, tuple(group))
                )
                continue
            exact = _capsule_of_primitive(first) if len(group) == 1 else None
            if exact is None:
                exact = fit_capsule(
                    np.vstack([_hull_points(objs[i], meshes.get(i)) for i in group])
                )
            a, b, r = exact
            shapes.append(Shape(name, body, "capsule", a, b, r, eye, zero, tuple(group)))
    return shapes


def zone_shape(obj, body: int, index: int) -> Shape:
    """The fitted shape of keep-out zone object ``index``: its box, the capsule of its
    cylinder (which contains it), or its cone (``a`` the apex, ``b`` the base's centre,
    ``radius`` the base's; its distance is exact: :func:`cone_distance`)."""
    g, M = obj.geometry, obj.placement
    eye, zero = np.eye(3), np.zeros(3)
    kind = type(g).__name__
    if kind == "Box":
        centre = M.translation.copy()
        half = np.asarray(g.halfSide, dtype=float)
        return Shape(obj.name, body, "box", centre, centre, 0.0, M.rotation.copy(), half, (index,))
    if kind == "Cone":  # coal's cone: apex at +halfLength on its z axis
        ax = M.rotation[:, 2] * g.halfLength
        apex, base = M.translation + ax, M.translation - ax
        return Shape(obj.name, body, "cone", apex, base, float(g.radius), eye, zero, (index,))
    a, b, r = _capsule_of_primitive(obj)
    return Shape(obj.name, body, "capsule", a, b, r, eye, zero, (index,))


# ---------------------------------------------------------------------------------- kinematics
def joint_placements(placements: cs.Function, q_model) -> dict[int, tuple]:
    """``{joint: (R, p)}``: every joint frame of ``robot.model`` in the base frame as CasADi
    expressions of ``q_model`` (``robot.model_joint_names``), by ``placements``, the planner's
    own kinematics (:meth:`~balance_opt.model.symbolic.SymbolicMaps.joint_placements_fun`)."""
    oMi = placements(q_model)
    columns = range(1, oMi.shape[1] + 1)  # joint j in column j - 1 (the universe left out)
    return {j: (cs.reshape(oMi[:9, j - 1], 3, 3), oMi[9:, j - 1]) for j in columns}


# ---------------------------------------------------------------------------------- distances
def _clamp01(x):
    return cs.fmin(cs.fmax(x, 0.0), 1.0)


def segment_distance(p1, q1, p2, q2):
    """The distance between the segments ``[p1, q1]`` and ``[p2, q2]`` (CasADi; the closest
    points clamped onto both segments; segments of zero length are points)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = cs.dot(d1, d1) + 1e-12, cs.dot(d2, d2) + 1e-12
    b, c, f = cs.dot(d1, d2), cs.dot(d1, r), cs.dot(d2, r)
    denom = a * e - b * b  # 0 for parallel segments: start from s = 0 then
    s = cs.if_else(denom > 1e-9 * a * e, _clamp01((b * f - c * e) / denom), 0.0)
    t_free = (b * s + f) / e
    s = cs.if_else(t_free < 0, _clamp01(-c / a), cs.if_else(t_free > 1, _clamp01((b - c) / a), s))
    t = _clamp01(t_free)
    gap = p1 + s * d1 - p2 - t * d2
    return cs.sqrt(cs.dot(gap, gap) + 1e-12)


def box_distance(point, half):
    """Signed distance of ``point`` (box frame) from a box of half sides ``half``: outside the
    distance, inside minus the depth below the nearest face."""
    # |x| is exact here: its kink lies on the box's mid-planes, where the face it measures is
    # never the nearest one outside the box
    d = cs.fabs(point) - cs.DM(half)
    outside = cs.fmax(d, 0.0)
    return cs.sqrt(cs.dot(outside, outside) + 1e-12) + cs.fmin(cs.mmax(d), 0.0)


def cone_distance(point, apex, base, radius: float):
    """Signed distance of ``point`` from the solid cone of ``apex``, base centre ``base`` and
    base ``radius`` (CasADi; points and cone in one frame): in the plane through the axis the
    cone is the triangle apex, base centre, rim, and the distance is the exact one to it (its
    slant and base edges; inside, minus the depth below the nearer of the side and the base).
    The closest feature changes only where both edges' distances are the rim's, so the
    smallest of them is smooth (once) wherever the distance is positive."""
    axis = base - apex
    length = cs.sqrt(cs.dot(axis, axis))
    u = axis / length
    v = point - apex
    h = cs.dot(v, u)
    rho = cs.sqrt(cs.fmax(cs.dot(v, v) - h * h, 0.0) + 1e-12)
    slant = cs.sqrt(length**2 + radius**2)
    sin_a, cos_a = radius / slant, length / slant

    def to_segment(p0, p1):  # (rho, h) of the segment's ends
        d = (p1[0] - p0[0], p1[1] - p0[1])
        s = _clamp01(((rho - p0[0]) * d[0] + (h - p0[1]) * d[1]) / (d[0] ** 2 + d[1] ** 2))
        x, y = rho - p0[0] - s * d[0], h - p0[1] - s * d[1]
        return cs.sqrt(x * x + y * y + 1e-12)

    outside = cs.fmin(
        to_segment((0.0, 0.0), (radius, length)), to_segment((0.0, length), (radius, length))
    )
    depth = cs.fmin(length - h, h * sin_a - rho * cos_a)
    inside = cs.logic_and(cs.logic_and(h >= 0, h <= length), rho * cos_a <= h * sin_a)
    return cs.if_else(inside, -depth, outside)


def soft_min(values, beta: float = BETA):
    """``m - log(sum exp(-beta (v - m))) / beta``, ``m = min v``: smooth, ``log(n) / beta`` below
    at most."""
    values = cs.vertcat(*values)
    m = cs.mmin(values)
    return m - cs.log(cs.sum1(cs.exp(-beta * (values - m)))) / beta


def _place(R, p, x):
    return p + R @ cs.DM(x)


def shape_distance(first: Shape, second: Shape, frames: dict):
    """The distance of two fitted shapes (one at least a capsule) as a CasADi expression."""
    if first.kind != "capsule":
        first, second = second, first
    R1, p1 = frames[first.body]
    a1, b1 = _place(R1, p1, first.a), _place(R1, p1, first.b)
    R2, p2 = frames[second.body]
    if second.kind == "capsule":
        a2, b2 = _place(R2, p2, second.a), _place(R2, p2, second.b)
        return segment_distance(a1, b1, a2, b2) - first.radius - second.radius
    # capsule against box or cone: spheres along the segment
    length = float(np.linalg.norm(first.b - first.a))
    spacing = SPHERE_SPACING * max(first.radius, 1e-6)
    n = max(2, int(np.ceil(length / spacing)) + 1)
    step = length / (n - 1)
    radius = float(np.sqrt(first.radius**2 + (step / 2) ** 2))
    R_box = R2 @ cs.DM(second.rotation)
    centre = _place(R2, p2, second.a)
    base = _place(R2, p2, second.b)
    out = []
    for s in np.linspace(0.0, 1.0, n):
        x = a1 + s * (b1 - a1)
        if second.kind == "cone":
            out.append(cone_distance(x, centre, base, second.radius) - radius)
        else:  # in the box's frame
            out.append(box_distance(R_box.T @ (x - centre), second.half) - radius)
    return soft_min(out)


# ---------------------------------------------------------------------------------- rows
@dataclass(frozen=True)
class ClearanceRows:
    """The planner's collision rows: per row, ``(label, ((shape, shape), ...))``, the shape the
    balance joints move first, and a content ``key`` of shapes, pairs and soft minimum."""

    shapes: tuple[Shape, ...]
    rows: tuple[tuple[str, tuple[tuple[int, int], ...]], ...]

    def row_of(self, pair) -> int | None:
        """The row that holds a geometry pair (:class:`Pair`), or ``None``."""
        shape = {i: k for k, s in enumerate(self.shapes) for i in s.objects}
        wanted = {(shape[pair.first], shape[pair.second]), (shape[pair.second], shape[pair.first])}
        return next((k for k, (_, pairs) in enumerate(self.rows) if wanted & set(pairs)), None)

    def pair_distances(self, placements: cs.Function) -> tuple[list, cs.Function]:
        """Every shape pair of the rows and ``d(q_model)``, their distances (the joints placed
        by ``placements``: :func:`joint_placements`)."""
        q = cs.SX.sym("q_model", placements.size1_in(0))
        frames = joint_placements(placements, q)
        pairs = [p for _, row in self.rows for p in row]
        d = [shape_distance(self.shapes[i], self.shapes[k], frames) for i, k in pairs]
        return pairs, cs.Function("shape_distances", [q], [cs.vertcat(*d)])

    @property
    def key(self) -> str:
        h = hashlib.sha256(repr((BETA, SPHERE_SPACING)).encode())
        for s in self.shapes:
            h.update(np.asarray(s.numbers(), dtype=float).round(12).tobytes())
        h.update(repr(self.rows).encode())
        return h.hexdigest()[:12]

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(label for label, _ in self.rows)

    def expressions(self, placements: cs.Function, q_model):
        """The rows' soft minima (n_rows,) as CasADi expressions of ``q_model`` (the joints
        placed by ``placements``: :func:`joint_placements`)."""
        frames = joint_placements(placements, q_model)
        out = []
        for _, pairs in self.rows:
            d = [shape_distance(self.shapes[i], self.shapes[k], frames) for i, k in pairs]
            out.append(soft_min(d) if len(d) > 1 else d[0])
        return cs.vertcat(*out)


def clearance_rows(
    geometry: RobotGeometry, pairs, moved_by_balance: set[int], alone=frozenset()
) -> ClearanceRows:
    """The planner's rows for the checked ``pairs`` that involve a body the balance joints move:
    each shape pair goes to the row of that body (the deeper one when both move), or to a row of
    its own if in ``alone``."""
    shapes = fit_shapes(geometry)
    of_object = {}
    for k, s in enumerate(shapes):
        for i in s.objects:
            of_object[i] = k
    depth = {j: len(geometry.model.supports[j]) for j in range(geometry.model.njoints)}
    rows: dict[int, set] = {}
    zoned = set()
    for p in pairs:
        s1, s2 = of_object[p.first], of_object[p.second]
        b1, b2 = shapes[s1].body, shapes[s2].body
        moved = [b for b in (b1, b2) if b in moved_by_balance]
        if not moved or s1 == s2:
            continue
        owner = max(moved, key=lambda b: depth[b])
        own, other = (s1, s2) if b1 == owner else (s2, s1)
        if {p.first, p.second} & geometry.zones.keys():
            own, other = (s1, s2) if p.second in geometry.zones else (s2, s1)
            zoned.add((own, other))
        else:
            rows.setdefault(owner, set()).add((own, other))
    out = []
    for body in sorted(rows):
        shared = sorted(p for p in rows[body] if p not in alone)
        if shared:
            out.append((f"{_body_name(geometry, body)} clearance", tuple(shared)))
        for i, k in sorted(p for p in rows[body] if p in alone):
            out.append((f"{shapes[i].name} / {shapes[k].name} clearance", ((i, k),)))
    return ClearanceRows(tuple(shapes), tuple(out + keep_out_rows(shapes, zoned)))


def keep_out_rows(shapes, zoned) -> list:
    """The planner's keep-out rows: one per pair of a body's shape and a zone's
    (``zoned``: their indices in ``shapes``), never shared (a zone is a volume the arm must
    stay out of, not a body beside it: its bound is the margin whatever the body's other
    pairs), each held, checked and refined as the other collision rows."""
    return [(f"{shapes[i].name} / {shapes[k].name} clearance", ((i, k),)) for i, k in sorted(zoned)]


def _body_name(geometry: RobotGeometry, body: int) -> str:
    """A body's name: the link of its first geometry object."""
    for i, obj in enumerate(geometry.geometry_model.geometryObjects):
        if int(obj.parentJoint) == body:
            return geometry.link(i)
    return geometry.model.names[body]


def moved_by(geometry: RobotGeometry, joints) -> set[int]:
    """Joints of ``robot.model`` moved by the given arm joints (names): them and all below."""
    model = geometry.model
    return set().union(*(model.subtrees[model.getJointId(j)] for j in joints))
