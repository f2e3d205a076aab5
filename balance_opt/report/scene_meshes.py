"""The robot's visual geometry as meshcat objects for the 3D scene (:mod:`.scene`): the URDF's
visual elements, meshes simplified by vertex clustering, coloured by arm."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from balance_opt.errors import InputError
from balance_opt.model.meshes import MeshNotFoundError, resolved_urdf
from balance_opt.model.robot import FloatingRobot
from balance_opt.report.style import ARM_COLOURS

#: Meshes are simplified by merging the vertices in each cell of a grid this many cells across
#: the robot (a cell of about 1 cm on a 2 m robot): the look is kept, the file stays small.
MESH_GRID = 200


#: Colour of the links that belong to no arm (the base and what is fixed to it).
BASE_COLOUR = "#A0A0A0"
#: Keep-out zones: translucent, so that the links show through them.
ZONE_COLOUR, ZONE_OPACITY = "#CC79A7", 0.25


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


def mesh_object(geometry, colour: str, opacity: float, flat: bool):
    """A meshcat mesh object; ``flat``: shaded flat (a simplified mesh: no normals to store)."""
    import meshcat.geometry as mg

    material = mg.MeshPhongMaterial(
        color=int(colour[1:], 16), opacity=opacity, **({"flatShading": True} if flat else {})
    )
    return mg.Mesh(geometry, material)


#: meshcat's cone (Pinocchio's ``loadPrimitive``) has its base where coal's has its apex (+z):
#: turned half a turn about x, it is drawn where the distances are computed.
_CONE_TURN = pin.SE3(np.diag([1.0, -1.0, -1.0]), np.zeros(3))


def _is_cone(obj: pin.GeometryObject) -> bool:
    import coal

    return isinstance(obj.geometry, coal.Cone)


def scene_objects(robot: FloatingRobot, size: float) -> list[SceneObject]:
    """Every drawn piece of the robot's visual geometry, coloured by arm, and its keep-out
    zones, translucent; ``size``: the robot's size [m], which sets the mesh simplification."""
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
        drawn = mesh_object(geometry, tint, opacity, mesh)
        n = int(geometry.vertices.shape[0]) if mesh else 0
        obj.geometry.computeLocalAABB()
        box = obj.geometry.aabb_local
        corners = np.array(list(itertools.product(*zip(box.min_, box.max_))))
        corners = corners @ obj.placement.rotation.T + obj.placement.translation
        placement = obj.placement * _CONE_TURN if _is_cone(obj) else obj.placement
        out.append(
            SceneObject(
                obj.name, obj.parentJoint, placement, drawn, n, corners,
                obj.name if zone else robot.model.frames[obj.parentFrame].name,
            )
        )  # fmt: skip
    return out
