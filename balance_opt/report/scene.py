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

import html
import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult
from balance_opt.report.scene_meshes import (
    BASE_COLOUR,
    SceneObject,
    mesh_object,
    scene_objects,
)
from balance_opt.report.scene_poses import (
    SCENE_FPS,
    animation,
    frame_index,
    magnification,
    pack,
    scene_poses,
    tracks_of,
)
from balance_opt.report.style import ARM_COLOURS, asset, method_label

log = logging.getLogger(__name__)

TARGET_COLOUR = "#009E73"
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


class _Setup:
    """The scene's static commands, packed as they are sent; a mesh several links carry (one
    file) is sent once and handed over by the page (``shared``)."""

    def __init__(self) -> None:
        self.commands: list[str] = []
        self.carrier: dict[int, str] = {}
        self.shared: list[list[str]] = []
        self.vertices = 0

    def send(self, *commands) -> None:
        self.commands.extend(pack(c.lower()) for c in commands)

    def place(self, obj: SceneObject, path, colour: str | None = None) -> None:
        """``obj`` at ``path``, in its own colour or ``colour`` (a highlight)."""
        import meshcat.geometry as mg
        from meshcat.commands import SetObject, SetTransform

        shape = obj.mesh.geometry
        if obj.vertices and id(shape) in self.carrier:
            self.shared.append([path.lower(), self.carrier[id(shape)]])
            shape = mg.Box([0.0, 0.0, 0.0])
        elif obj.vertices:
            self.carrier[id(shape)] = path.lower()
            self.vertices += obj.vertices
        if colour is not None:
            drawn = mesh_object(shape, colour, HIGHLIGHT_OPACITY, bool(obj.vertices))
        else:
            drawn = mg.Mesh(shape, obj.mesh.material)
        self.send(SetObject(drawn, path=path), SetTransform(obj.placement.homogeneous, path))


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
    first = next(iter(results.values()))
    joints_all = list(range(1, robot.model.njoints))
    start = scene_poses(robot, first, joints_all, h0, None, 1.0, fps)
    points = start["joints"][0][:, :3, 3]
    size = max(float(np.ptp(points, axis=0).max()), 0.2)
    objects = scene_objects(robot, size)
    nodes = sorted({1, *(o.joint for o in objects)})
    setup = _Setup()
    for obj in objects:
        setup.place(obj, _path(_node_name(robot, obj.joint), obj.name))
    links = {o.link: o.joint for o in objects}
    levels, texts = {}, {}
    if geometry is not None:
        for name, res in results.items():
            q = np.hstack([res.q_M, res.q_B])[frame_index(res.t, fps)]
            distances = np.array([geometry.distances(qk) for qk in q]).reshape(len(q), -1)
            levels[name], texts[name] = proximity_levels(geometry, distances, margin, links)
    marked = [lk for lk in links if any(lv[lk].any() for lv in levels.values())]
    _send_statics(setup, robot, objects, marked, links, target, size, start)

    largest = max(float(np.max(res.angle)) for res in results.values())
    factor = magnification(largest)
    factors = [1.0] if factor == 1.0 else [1.0, factor]
    animations, poses, meta_methods = {}, {}, {}
    for name, res in results.items():
        for f in factors:
            pose = scene_poses(robot, res, nodes, h0, target, f, fps)
            shown = {link: levels[name][link] for link in marked}
            key = f"{name}|{f:g}"
            animations[key] = _animation_of(robot, pose, nodes, objects, shown, links, target)
            poses[key] = pose
        meta_methods[name] = _method_meta(name, res, poses[f"{name}|1"], labels, texts)
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
        "vertices": setup.vertices,
        "shared": setup.shared,
    }
    return Scene(setup.commands, animations, meta, objects, poses, nodes, levels)


def _send_statics(setup: _Setup, robot, objects, marked, links, target, size, start) -> None:
    """The highlight copies of the ``marked`` links, the base's axes, the target's box, and the
    view: the grid under the robot, the camera orbiting about its middle (at the first sample
    of ``start``, the first plan's placements of every joint)."""
    import meshcat.geometry as mg
    from meshcat.commands import SetObject, SetProperty, SetTransform

    for link in marked:  # a copy of the link's pieces per colour, shown only while it applies
        node = _node_name(robot, links[link])
        for kind, colour in _OVERLAYS.values():
            for obj in (o for o in objects if o.link == link):
                setup.place(obj, _path(node, f"{link}_{kind}", obj.name), colour)
            setup.send(SetProperty("visible", False, _path(node, f"{link}_{kind}")))
    setup.send(SetObject(mg.triad(0.6 * size), path=_path("base", "axes")))
    if target is not None:
        sides, axes = target.box()
        path = _path(TARGET_NODE, "box")
        box = mesh_object(mg.Box(list(sides)), TARGET_COLOUR, 0.85, False)
        setup.send(
            SetObject(box, path=path), SetTransform(pin.SE3(axes, np.zeros(3)).homogeneous, path)
        )
    H = {o.joint: start["joints"][0][o.joint - 1] for o in objects}  # at the first sample
    pieces = [o.corners @ H[o.joint][:3, :3].T + H[o.joint][:3, 3] for o in objects]
    hull = np.vstack([start["joints"][:, :, :3, 3].reshape(-1, 3), *pieces])  # + the joints
    lo, hi = hull.min(axis=0), hull.max(axis=0)
    centre, extent = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    grid = pin.SE3(np.eye(3), np.array([*centre[:2], lo[2] - 0.15 * extent])).homogeneous
    cam = pin.SE3(np.eye(3), centre).homogeneous
    d = 0.45 * extent + 0.2
    setup.send(
        SetTransform(grid, _path("/Grid")),
        SetTransform(cam, _path("/Cameras/default")),
        SetProperty(
            "position", [1.0 * d, 0.55 * d, 0.75 * d], _path("/Cameras/default/rotated/<object>")
        ),
        SetProperty("visible", False, _path("/Axes")),
    )


def _animation_of(robot, pose, nodes, objects, levels, links, target) -> str:
    """One animation (packed): every node's track along ``pose``, the target's, and the
    visibility of the highlighted links' pieces and copies from their ``levels``."""
    tracks = {
        _path(_node_name(robot, j)): tracks_of(pose["joints"][:, k]) for k, j in enumerate(nodes)
    }
    if target is not None:
        tracks[_path(TARGET_NODE)] = tracks_of(pose["target"])
    visible = {}
    for link, level in levels.items():
        node = _node_name(robot, links[link])
        for obj in (o for o in objects if o.link == link):
            visible[_path(node, obj.name)] = level == 0
        for lv, (kind, _) in _OVERLAYS.items():
            visible[_path(node, f"{link}_{kind}")] = level == lv
    return pack(animation(tracks, pose["t"] - pose["t"][0], visible))


def _method_meta(name, res, pose, labels, texts) -> dict:
    """What the page shows of one plan: its label, times, drift angle at the frames of
    ``pose`` (as planned) and, with proximity ``texts``, the label's text where it changes."""
    times = [round(float(x - pose["t"][0]), 4) for x in pose["t"]]  # from the start
    meta = {
        "label": (labels or {}).get(name) or method_label(name),
        "t0": float(pose["t"][0]),
        "duration": float(pose["t"][-1] - pose["t"][0]),
        "angle_t": times,
        "angle": [float(f"{a:.4g}") for a in res.angle[pose["index"]]],
    }
    if name in texts:  # the label's text where it changes
        text = texts[name]
        meta["near"] = [
            [times[k], text[k]] for k in range(len(text)) if k == 0 or text[k] != text[k - 1]
        ]
    return meta


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
    player, style = asset("scene_player.js"), asset("scene.css")
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


def write_scene(path: str | Path, scene: Scene, title: str = "") -> Path:
    """Write the page of a scene (:func:`build_scene`) to ``path``."""
    path = Path(path)
    path.write_text(scene_html(scene, title), encoding="utf-8")
    megabytes = path.stat().st_size / 1e6
    log.info("scene: %s, %.1f MB (%d mesh vertices)", path.name, megabytes, scene.meta["vertices"])
    return path
