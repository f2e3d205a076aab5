"""The 3D scene of a run in one offline HTML file drawn by the meshcat viewer (``docs/viewer.md``).

No meshcat server, socket or subprocess: meshcat's geometry and command objects are lowered to
the dicts the viewer decodes, packed with msgpack and inlined in the page beside its bundle and
the page's player and style (package data: ``assets/scene_player.js``, ``assets/scene.css``).

One node per Pinocchio joint that carries geometry, animated with the joint's world placement,
so a mesh is stored once and a frame costs seven numbers per joint. The base moves so that the
centre of mass stays on its free-flight line ``c(t) = c(0) + t p0 / m``. Links too close get
amber and red copies whose visibility is keyed only where the state changes, so links that
never come close cost nothing."""

from __future__ import annotations

import base64
import html
import itertools
import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError
from balance_opt.model.meshes import MeshNotFoundError, resolved_urdf
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import (
    matrix_from_quaternion,
    quaternion_from_rotvec,
    relative_rotation,
    rotvec_from_quaternion,
)
from balance_opt.report.style import ARM_COLOURS, method_label

log = logging.getLogger(__name__)

#: Animation samples per second of motion [1/s] (the viewer interpolates between them).
SCENE_FPS = 25
#: Meshes are simplified by merging the vertices in each cell of a grid this many cells across
#: the robot (a cell of about 1 cm on a 2 m robot): the look is kept, the file stays small.
MESH_GRID = 200
#: Colour of the links that belong to no arm (the base and what is fixed to it).
BASE_COLOUR = "#A0A0A0"
TARGET_COLOUR = "#009E73"
#: Keep-out zones: translucent, so that the links show through them.
ZONE_COLOUR, ZONE_OPACITY = "#CC79A7", 0.25
#: Path of the robot's nodes in the viewer's scene tree.
ROOT = ("meshcat", "robot")
TARGET_NODE = "capture_target"
#: Colours of a link while one of its checked pairs is closer than the collision margin, and
#: while one penetrates (distance below zero).
NEAR_COLOUR = "#FFB000"
TOUCH_COLOUR = "#E8000B"
#: Opacity of a highlighted link: a link inside another shows through it.
HIGHLIGHT_OPACITY = 0.6
#: Names of a highlighted link's overlay nodes, by level (1: near, 2: penetrating).
_OVERLAYS = {1: ("near", NEAR_COLOUR), 2: ("touch", TOUCH_COLOUR)}
#: The magnified view turns the base by its rotation from the start times a factor chosen so
#: that the largest drift shows as about this angle [rad] (30 deg).
MAGNIFIED_ANGLE = np.radians(30.0)


def magnification(max_angle: float) -> float:
    """Factor of the magnified view of the base's rotation: 1, 2 or 5 times a power of ten, the
    largest that shows ``max_angle`` [rad] at no more than :data:`MAGNIFIED_ANGLE` (1 when the
    rotation is already that large, or nil)."""
    if not max_angle > 0 or max_angle >= MAGNIFIED_ANGLE:
        return 1.0
    want = MAGNIFIED_ANGLE / max_angle
    power = 10.0 ** np.floor(np.log10(want))
    return float(max(f * power for f in (1, 2, 5) if f * power <= want))


def magnified_rotation(quaternion: np.ndarray, factor: float) -> np.ndarray:
    """The base's attitudes (T, 3, 3) ``R0 exp(factor log(R0^T R))``: its rotation from the
    start ``R0``, magnified."""
    phi = rotvec_from_quaternion(relative_rotation(quaternion[:1], quaternion))
    R0 = matrix_from_quaternion(quaternion[0])
    return np.array([R0 @ matrix_from_quaternion(q) for q in quaternion_from_rotvec(factor * phi)])


@dataclass(frozen=True)
class SceneObject:
    """One piece of visual geometry: its node name, the Pinocchio joint it moves with, its
    placement in the joint frame, the meshcat object, its vertex count (meshes), the corners
    of its bounding box in the joint frame (8, 3) [m] and its link (frame) name."""

    name: str
    joint: int
    placement: pin.SE3
    mesh: Any  # a meshcat.geometry.Mesh
    vertices: int
    corners: np.ndarray
    link: str = ""


def visual_model(robot: FloatingRobot) -> pin.GeometryModel:
    """The URDF's visual geometry on ``robot.model`` (locked joints fixed where they are locked);
    meshes found as :mod:`~balance_opt.model.meshes` says (``robot.packages`` first)."""
    try:
        text = resolved_urdf(robot.locked_urdf, robot.source, robot.packages, "visual")
        return pin.buildGeomFromUrdfString(robot.model, text, pin.VISUAL)
    except MeshNotFoundError as exc:  # it names the URDF and the link
        raise InputError(f"cannot load the visual geometry: {exc}") from exc
    except (ValueError, RuntimeError, InputError) as exc:
        raise InputError(f"{robot.source}: cannot load the visual geometry: {exc}") from exc


def cluster_vertices(
    vertices: np.ndarray, faces: np.ndarray, cell: float
) -> tuple[np.ndarray, np.ndarray]:
    """A triangle mesh simplified by vertex clustering: the vertices in each cube of side
    ``cell`` [m] merged into their mean, the triangles that collapse dropped (and repeats)."""
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if cell <= 0 or faces.size == 0:
        return vertices, faces
    keys = np.floor(vertices / cell).astype(np.int64)
    _, cluster = np.unique(keys, axis=0, return_inverse=True)
    cluster = cluster.ravel()
    counts = np.bincount(cluster)
    merged = np.zeros((counts.size, 3))
    np.add.at(merged, cluster, vertices)
    merged /= counts[:, None]
    f = cluster[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    f = np.unique(f, axis=0)
    used, f = np.unique(f, return_inverse=True)
    return merged[used], f.reshape(-1, 3)


def _shape(obj: pin.GeometryObject, cell: float, meshes: dict):
    """meshcat geometry of a Pinocchio geometry object, or None (a shape meshcat cannot draw);
    ``meshes``: the meshes read so far, by file."""
    import coal
    import meshcat.geometry as mg
    from pinocchio.visualize.meshcat_visualizer import loadPrimitive

    g = obj.geometry
    if not isinstance(g, coal.BVHModelBase):
        return loadPrimitive(obj)  # with meshcat's turn of the axes (cylinders) built in
    key = (obj.meshPath, tuple(np.asarray(obj.meshScale)))
    if key not in meshes:
        faces = [[t[0], t[1], t[2]] for t in map(g.tri_indices, range(g.num_tris))]
        v, f = cluster_vertices(g.vertices(), faces, cell)
        meshes[key] = mg.TriangularMeshGeometry(v, f)
    return meshes[key]


def _joint_colours(robot: FloatingRobot) -> dict[int, str]:
    """Colour of each Pinocchio joint: its arm's (that of the nearest arm joint at or above it),
    :data:`BASE_COLOUR` for the base and what hangs from it outside the arms."""
    model, n = robot.model, len(ARM_COLOURS)
    own = {
        model.getJointId(j): ARM_COLOURS[a % n]
        for a, arm in enumerate(robot.arms)
        for j in arm.joints
    }
    return {
        j: next((own[k] for k in reversed(model.supports[j]) if k in own), BASE_COLOUR)
        for j in range(model.njoints)
    }


def _object(geometry, colour: str, opacity: float, flat: bool):
    """A meshcat mesh object; ``flat``: shaded flat (a simplified mesh: no normals to store)."""
    import meshcat.geometry as mg

    material = mg.MeshPhongMaterial(
        color=int(colour[1:], 16), opacity=opacity, **({"flatShading": True} if flat else {})
    )
    return mg.Mesh(geometry, material)


def scene_objects(robot: FloatingRobot, size: float) -> list[SceneObject]:
    """Every drawn piece of the robot's visual geometry, coloured by arm; ``size``: the robot's
    size [m], which sets the mesh simplification."""
    import meshcat.geometry as mg

    from balance_opt.geometry.keep_out import zone_object

    gmodel, meshes, colour = visual_model(robot), {}, _joint_colours(robot)
    cell = size / MESH_GRID
    out = []
    zones = [zone_object(zone, robot.model) for zone in robot.keep_out]
    pieces = [(obj, False) for obj in gmodel.geometryObjects] + [(obj, True) for obj in zones]
    for obj, zone in pieces:
        geometry = _shape(obj, cell, meshes)
        if geometry is None:
            continue
        opacity = float(min(obj.meshColor[3], 1.0)) if obj.meshColor[3] > 0 else 1.0
        mesh = isinstance(geometry, mg.TriangularMeshGeometry)
        tint, opacity = (ZONE_COLOUR, ZONE_OPACITY) if zone else (colour[obj.parentJoint], opacity)
        drawn = _object(geometry, tint, opacity, mesh)
        n = int(geometry.vertices.shape[0]) if mesh else 0
        obj.geometry.computeLocalAABB()
        box = obj.geometry.aabb_local
        corners = np.array(list(itertools.product(*zip(box.min_, box.max_))))
        corners = corners @ obj.placement.rotation.T + obj.placement.translation
        out.append(
            SceneObject(
                obj.name, obj.parentJoint, obj.placement, drawn, n, corners,
                obj.name if zone else robot.model.frames[obj.parentFrame].name,
            )
        )  # fmt: skip
    return out


def frame_index(t: np.ndarray, fps: float = SCENE_FPS) -> np.ndarray:
    """Indices into a plan's times ``t`` of the scene's frames: ``fps`` per second, each the
    plan's own sample at or after that time."""
    wanted = np.arange(t[0], t[-1] + 0.5 / fps, 1.0 / fps)
    return np.unique(np.searchsorted(t, wanted - 1e-9).clip(0, t.size - 1))


def scene_poses(
    robot: FloatingRobot,
    result: BalanceResult,
    joints: list[int],
    h0=None,
    target=None,
    factor: float = 1.0,
    fps: float = SCENE_FPS,
) -> dict[str, np.ndarray]:
    """World placements along a plan (at :func:`frame_index`) of the Pinocchio ``joints``, for
    the initial momentum ``h0`` (world frame, (6,); None: at rest), the base's rotation from its
    start magnified ``factor`` times: ``t`` (K,) the sample times [s], ``index`` (K,) their
    indices in the plan, ``base`` (K, 4, 4), ``joints`` (K, J, 4, 4) and, with a target,
    ``target`` (K, 4, 4) its box's centre and axes."""
    model, data = robot.model, robot.model.createData()
    index = frame_index(result.t, fps)
    t = result.t[index]
    q_plan = np.hstack([result.q_M, result.q_B])[index]
    q = np.empty_like(q_plan)
    for k, joint in enumerate((*result.mission_joints, *result.balance_joints)):
        q[:, robot.joint_index(joint)] = q_plan[:, k]
    R = magnified_rotation(result.quaternion[index], factor)
    p0 = np.zeros(3) if h0 is None else np.asarray(h0, dtype=float)[:3]
    mass, ee = robot.total_mass, model.getFrameId(robot.mission.ee_frame)
    t_c = target.time if target is not None else np.inf
    base = np.empty((t.size, 4, 4))
    placements = np.empty((t.size, len(joints), 4, 4))
    target_pose = np.empty((t.size, 4, 4))
    total = mass + (target.mass if target is not None else 0.0)
    com0 = line_after = None
    for i in range(t.size):
        # placed with the base at the origin, then moved: a translation moves every point alike
        com = pin.centerOfMass(model, data, robot.pin_q(q[i], pin.SE3(R[i], np.zeros(3))))
        pin.updateFramePlacements(model, data)
        com0 = com if com0 is None else com0  # the base starts at the origin
        if t[i] < t_c:
            shift = com0 + (t[i] - t[0]) * p0 / mass - com
        else:
            c_t = data.oMf[ee].act(target.com)
            if line_after is None:  # the capture: robot and target on one line from here on
                robot_at = com0 + (t_c - t[0]) * p0 / mass
                target_at = robot_at + c_t - com
                line_after = (
                    (mass * robot_at + target.mass * target_at) / total,
                    (p0 + target.mass * target.linear_velocity) / total,
                )
            both = (mass * com + target.mass * c_t) / total
            shift = line_after[0] + (t[i] - t_c) * line_after[1] - both
        base[i] = pin.SE3(R[i], shift).homogeneous
        placements[i] = [data.oMi[j].homogeneous for j in joints]
        placements[i, :, :3, 3] += shift
        if target is not None:
            target_pose[i] = (data.oMf[ee] * pin.SE3(np.eye(3), target.com)).homogeneous
            target_pose[i, :3, 3] += shift
    out = {"t": t, "index": index, "base": base, "joints": placements}
    if target is not None:
        out["target"] = _free_flight_before(target_pose, t, target)
    return out


def _free_flight_before(pose: np.ndarray, t: np.ndarray, target) -> np.ndarray:
    """The target's placements before the capture: from where the end effector takes it at the
    capture, back along its constant linear and angular velocities (world frame)."""
    after = np.flatnonzero(t >= target.time)
    if after.size == 0:
        return pose
    at = pose[after[0]]  # the first sample at or after the capture: the grasp
    out = pose.copy()
    for i in np.flatnonzero(t < target.time):
        dt = t[i] - t[after[0]]
        out[i, :3, :3] = pin.exp3(dt * target.angular_velocity) @ at[:3, :3]
        out[i, :3, 3] = at[:3, 3] + dt * target.linear_velocity
    return out


def _pack(command: dict) -> str:
    import umsgpack

    return base64.b64encode(umsgpack.packb(command)).decode("ascii")


def _float32(values) -> Any:
    import umsgpack

    return umsgpack.Ext(0x17, np.ascontiguousarray(values, dtype="<f4").tobytes())


def _animation(
    tracks: Mapping[Any, tuple[np.ndarray, np.ndarray]],
    t: np.ndarray,
    visible: Mapping[Any, np.ndarray] | None = None,
) -> dict:
    """The lowered ``set_animation`` command: per node (a meshcat path) its position and
    quaternion keys (times [s] from the start, three.js's (x, y, z, w) order); ``visible``: per
    node its visibility at each time of ``t`` (bool (K,)), stored as keys where it changes
    (three.js holds a boolean key until the next one).

    Key times and numeric values are float32 arrays, which three.js reads as they are, instead
    of meshcat's small map per key: a quarter of the size."""

    def clip(path, *tracks) -> dict:
        lowered = [
            {"name": "." + name, "type": kind, "times": _float32(times), "values": values}
            for name, kind, times, values in tracks
        ]  # key times in seconds: fps 1
        return {"path": path.lower(), "clip": {"fps": 1.0, "name": "default", "tracks": lowered}}

    clips = [
        clip(
            path,
            ("position", "vector3", t, _float32(position)),
            ("quaternion", "quaternion", t, _float32(quaternion)),
        )
        for path, (position, quaternion) in tracks.items()
    ]
    for path, shown in (visible or {}).items():
        shown = np.asarray(shown, dtype=bool)
        # the last key too: every clip lasts the whole motion
        keys = np.unique(np.r_[0, np.flatnonzero(shown[1:] != shown[:-1]) + 1, shown.size - 1])
        clips.append(clip(path, ("visible", "bool", t[keys], [bool(v) for v in shown[keys]])))
    options = {"play": False, "repetitions": 1}
    return {"type": "set_animation", "animations": clips, "options": options, "path": ""}


def _tracks(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (K, 3) and unit quaternions (K, 4) (x, y, z, w) of placements (K, 4, 4), each
    quaternion on the side of its predecessor (the same rotations, no half-turn between keys)."""
    quaternions = np.array([pin.Quaternion(M[:3, :3]).coeffs() for M in poses])
    turns = np.einsum("ij,ij->i", quaternions[1:], quaternions[:-1]) < 0
    sides = np.cumprod(np.r_[1.0, np.where(turns, -1.0, 1.0)])
    return poses[:, :3, 3], quaternions * sides[:, None]


@dataclass
class Scene:
    """A run's scene: the static commands (objects, their placements, camera) and one animation
    per ``"<method>|<factor>"``, each a base64 msgpack blob, and what the page shows about them.
    ``poses`` keeps the node placements of each animation (tests compare them with Pinocchio)."""

    setup: list[str]
    animations: dict[str, str]
    meta: dict[str, Any]
    objects: list[SceneObject] = field(repr=False)
    poses: dict[str, dict[str, np.ndarray]] = field(repr=False)
    nodes: list[int] = field(repr=False)
    #: per method, the level of each drawn link at each frame (:func:`proximity_levels`);
    #: empty without geometry
    levels: dict[str, dict[str, np.ndarray]] = field(default_factory=dict, repr=False)


def _path(*names: str):
    """The meshcat path of a node under :data:`ROOT`; ``"/Grid"``: of the viewer's own."""
    from meshcat.path import Path as MeshcatPath

    if names and names[0].startswith("/"):
        return MeshcatPath(tuple(names[0].strip("/").split("/")))
    return MeshcatPath((*ROOT, *names))


def _node_name(robot: FloatingRobot, joint: int) -> str:
    return "base" if joint == 1 else robot.model.names[joint]


def build_scene(
    robot: FloatingRobot,
    results: Mapping[str, BalanceResult],
    h0=None,
    target=None,
    labels: Mapping[str, str] | None = None,
    fps: float = SCENE_FPS,
    geometry=None,
    margin: float = 0.0,
) -> Scene:
    """The scene of a run's plans ``{method: plan}``; ``h0``: the initial momentum, world frame
    (6,); ``labels``: display names (default :func:`~balance_opt.report.style.method_label`).
    With the robot's collision ``geometry``, the links of a checked pair closer than ``margin``
    [m] are drawn amber at those frames, those of a pair that penetrates red
    (:func:`proximity_levels`)."""
    import meshcat.geometry as mg
    from meshcat.commands import SetObject, SetProperty, SetTransform

    first = next(iter(results.values()))
    joints_all = list(range(1, robot.model.njoints))
    start = scene_poses(robot, first, joints_all, h0, None, 1.0, fps)
    points = start["joints"][0][:, :3, 3]
    size = max(float(np.ptp(points, axis=0).max()), 0.2)
    objects = scene_objects(robot, size)
    nodes = sorted({1, *(o.joint for o in objects)})
    setup, carrier, shared, sent = [], {}, [], 0

    def send(*commands) -> None:
        setup.extend(_pack(c.lower()) for c in commands)

    def place(obj: SceneObject, path, colour: str | None = None) -> None:
        # a mesh already sent is handed over by the page: a mesh file several links carry is
        # sent once
        nonlocal sent
        shape = obj.mesh.geometry
        if obj.vertices and id(shape) in carrier:
            shared.append([path.lower(), carrier[id(shape)]])
            shape = mg.Box([0.0, 0.0, 0.0])
        elif obj.vertices:
            carrier[id(shape)] = path.lower()
            sent += obj.vertices
        if colour is not None:
            drawn = _object(shape, colour, HIGHLIGHT_OPACITY, bool(obj.vertices))
        else:
            drawn = mg.Mesh(shape, obj.mesh.material)
        send(SetObject(drawn, path=path), SetTransform(obj.placement.homogeneous, path))

    for obj in objects:
        place(obj, _path(_node_name(robot, obj.joint), obj.name))
    links = {o.link: o.joint for o in objects}
    levels, texts = {}, {}
    if geometry is not None:
        for name, res in results.items():
            q = np.hstack([res.q_M, res.q_B])[frame_index(res.t, fps)]
            distances = np.array([geometry.distances(qk) for qk in q]).reshape(len(q), -1)
            levels[name], texts[name] = proximity_levels(geometry, distances, margin, links)
    marked = [lk for lk in links if any(lv[lk].any() for lv in levels.values())]
    for link in marked:  # a copy of the link's pieces per colour, shown only while it applies
        node = _node_name(robot, links[link])
        for kind, colour in _OVERLAYS.values():
            for obj in (o for o in objects if o.link == link):
                place(obj, _path(node, f"{link}_{kind}", obj.name), colour)
            send(SetProperty("visible", False, _path(node, f"{link}_{kind}")))
    send(SetObject(mg.triad(0.6 * size), path=_path("base", "axes")))
    if target is not None:
        sides, axes = target.box()
        path = _path(TARGET_NODE, "box")
        box = _object(mg.Box(list(sides)), TARGET_COLOUR, 0.85, False)
        send(SetObject(box, path=path), SetTransform(pin.SE3(axes, np.zeros(3)).homogeneous, path))
    # the view: the grid under the robot, the camera orbiting about its middle
    H = {o.joint: start["joints"][0][o.joint - 1] for o in objects}  # at the first sample
    pieces = [o.corners @ H[o.joint][:3, :3].T + H[o.joint][:3, 3] for o in objects]
    hull = np.vstack([start["joints"][:, :, :3, 3].reshape(-1, 3), *pieces])  # + the joints
    lo, hi = hull.min(axis=0), hull.max(axis=0)
    centre, extent = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    grid = pin.SE3(np.eye(3), np.array([*centre[:2], lo[2] - 0.15 * extent])).homogeneous
    cam = pin.SE3(np.eye(3), centre).homogeneous
    d = 0.45 * extent + 0.2
    send(
        SetTransform(grid, _path("/Grid")),
        SetTransform(cam, _path("/Cameras/default")),
        SetProperty(
            "position", [1.0 * d, 0.55 * d, 0.75 * d], _path("/Cameras/default/rotated/<object>")
        ),
        SetProperty("visible", False, _path("/Axes")),
    )

    largest = max(float(np.max(res.angle)) for res in results.values())
    factor = magnification(largest)
    factors = [1.0] if factor == 1.0 else [1.0, factor]
    animations, poses, meta_methods = {}, {}, {}
    for name, res in results.items():
        for f in factors:
            pose = scene_poses(robot, res, nodes, h0, target, f, fps)
            tracks = {
                _path(_node_name(robot, j)): _tracks(pose["joints"][:, k])
                for k, j in enumerate(nodes)
            }
            if target is not None:
                tracks[_path(TARGET_NODE)] = _tracks(pose["target"])
            visible = {}
            for link in marked:
                level, node = levels[name][link], _node_name(robot, links[link])
                for obj in (o for o in objects if o.link == link):
                    visible[_path(node, obj.name)] = level == 0
                for lv, (kind, _) in _OVERLAYS.items():
                    visible[_path(node, f"{link}_{kind}")] = level == lv
            key = f"{name}|{f:g}"
            animations[key] = _pack(_animation(tracks, pose["t"] - pose["t"][0], visible))
            poses[key] = pose
        pose = poses[f"{name}|1"]
        times = [round(float(x - pose["t"][0]), 4) for x in pose["t"]]  # from the start
        meta_methods[name] = {
            "label": (labels or {}).get(name) or method_label(name),
            "t0": float(pose["t"][0]),
            "duration": float(pose["t"][-1] - pose["t"][0]),
            "angle_t": times,
            "angle": [float(f"{a:.4g}") for a in res.angle[pose["index"]]],
        }
        if name in texts:  # the label's text where it changes
            text = texts[name]
            meta_methods[name]["near"] = [
                [times[k], text[k]] for k in range(len(text)) if k == 0 or text[k] != text[k - 1]
            ]
    arms = [
        {"label": f"{arm.name} arm", "colour": ARM_COLOURS[a % len(ARM_COLOURS)]}
        for a, arm in enumerate(robot.arms)
    ]
    meta = {
        "methods": meta_methods,
        "factors": factors,
        "arms": arms,
        "base_colour": BASE_COLOUR,
        "target": None
        if target is None
        else {"time": float(target.time), "colour": TARGET_COLOUR, "mass": float(target.mass)},
        "robot": robot.name,
        "proximity": None
        if geometry is None
        else {"margin": float(margin), "near": NEAR_COLOUR, "touch": TOUCH_COLOUR},
        "marked": marked,
        "vertices": sent,
        "shared": shared,
    }
    return Scene(setup, animations, meta, objects, poses, nodes, levels)


def proximity_levels(
    geometry, distances: np.ndarray, margin: float, links: Mapping[str, int]
) -> tuple[dict[str, np.ndarray], list[str]]:
    """How close the drawn ``links`` (each with its body, a Pinocchio joint) come at each frame,
    from the distances (K, P) [m] of the ``geometry``'s checked pairs: per link its level at each
    frame (2 where a pair of it penetrates, 1 where one is closer than ``margin`` [m], 0
    otherwise) and per frame the label's text naming those pairs ("" when none). A pair's link
    that is not drawn (a collision-only link) stands for every drawn link of its body."""
    d = np.asarray(distances, dtype=float)
    pair_level = np.where(d < 0.0, 2, np.where(d < margin, 1, 0))
    out = {link: np.zeros(d.shape[0], dtype=int) for link in links}
    for pair in geometry.pairs:
        for obj in (pair.first, pair.second):
            link = geometry.link(obj)
            drawn = [link] if link in links else [
                lk for lk, j in links.items() if j == geometry.body(obj)
            ]  # fmt: skip
            for lk in drawn:
                out[lk] = np.maximum(out[lk], pair_level[:, pair.index])
    texts = []
    for row in pair_level:
        parts = [
            f"{what}: " + ", ".join(p.name for p in geometry.pairs if row[p.index] == lv)
            for lv, what in ((2, "penetrating"), (1, f"closer than {margin:g} m"))
            if (row == lv).any()
        ]
        texts.append("; ".join(parts))
    return out, texts


def _asset(name: str) -> str:
    """A file of the page shipped with the package (``balance_opt/report/assets``)."""
    from importlib.resources import files

    return (files("balance_opt.report") / "assets" / name).read_text(encoding="utf-8")


def scene_html(scene: Scene, title: str = "") -> str:
    """The scene as one self-contained HTML page: the meshcat viewer's bundle, the commands,
    a method selector, a base-rotation selector, a play button and a time slider (the URL's
    ``#method=optimal&t=5&magnify=10`` opens a given method, time and magnification; ``&play``
    starts playing)."""
    from meshcat import viewer_assets_path

    bundle = (Path(viewer_assets_path()) / "dist" / "main.min.js").read_text(encoding="utf-8")
    meta = scene.meta
    options = "".join(
        f'<option value="{html.escape(name)}">{html.escape(m["label"])}</option>'
        for name, m in meta["methods"].items()
    )
    rotations = "".join(
        f'<option value="{f:g}">{"as planned" if f == 1 else f"magnified x {f:g}"}</option>'
        for f in meta["factors"]
    )

    def key(colour: str, text: str) -> str:
        return f'<span class="key" style="background:{colour}"></span>{text}'

    keys = [key(a["colour"], html.escape(a["label"])) for a in meta["arms"]]
    keys.append(key(meta["base_colour"], "base"))
    if meta["target"]:
        keys.append(key(meta["target"]["colour"], "target"))
    if near := meta["proximity"]:
        keys.append(key(near["near"], f"closer than the collision margin ({near['margin']:g} m)"))
        keys.append(key(near["touch"], "penetrating"))
    data = {k: v for k, v in meta.items() if k != "robot"}
    data.update(setup=scene.setup, animations=scene.animations)
    player, style = _asset("scene_player.js"), _asset("scene.css")
    script = player.replace("SCENE_DATA", json.dumps(data, separators=(",", ":")))
    heading = html.escape(title or meta["robot"])
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>balance-opt scene: {heading}</title><style>{style}</style></head><body>"
        '<div id="scene-pane"></div><div id="scene-bar">'
        f'<select id="scene-method" title="plan">{options}</select>'
        f'<select id="scene-mag" title="base rotation">{rotations}</select>'
        '<button id="scene-play" type="button">play</button>'
        '<input id="scene-t" type="range" min="0" max="1" step="0.01" value="0"> '
        f'<span id="scene-label"></span><div id="scene-note"></div>'
        f'<div class="meta">{heading}: {"".join(keys)}; base axes red x, green y, blue z. '
        "Drag to turn, scroll to zoom.</div></div>"
        f"<script>{bundle}</script><script>{script}</script></body></html>"
    )


def write_scene(
    path: str | Path,
    robot: FloatingRobot,
    results: Mapping[str, BalanceResult],
    h0=None,
    target=None,
    labels: Mapping[str, str] | None = None,
    title: str = "",
    geometry=None,
    margin: float = 0.0,
) -> Path:
    """Write the page of :func:`build_scene` to ``path``."""
    path = Path(path)
    scene = build_scene(robot, results, h0, target, labels, geometry=geometry, margin=margin)
    path.write_text(scene_html(scene, title), encoding="utf-8")
    megabytes = path.stat().st_size / 1e6
    log.info("scene: %s, %.1f MB (%d mesh vertices)", path.name, megabytes, scene.meta["vertices"])
    return path
