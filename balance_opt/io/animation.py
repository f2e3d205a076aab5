"""A 3D animation of the plans for the HTML report: a stick figure of the robot (joint origins
and end effectors, the base's axes and, when the URDF's base has a box visual, the box), drawn
by a few lines of inline JavaScript on a canvas. No external file, library or network access.

The base pose at each sample: its attitude is the plan's; its position keeps the system's
centre of mass on its free-flight line (``c(t) = c(0) + t p0 / m``, ``p0`` the initial linear
momentum), which is what momentum conservation imposes on a free-floating robot.
"""

from __future__ import annotations

import html
import json
import xml.etree.ElementTree as ET
from collections.abc import Mapping

import numpy as np
import pinocchio as pin

from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.so3 import matrix_from_quaternion
from balance_opt.result import BalanceResult

#: Frames per second of the animation [1/s].
ANIMATION_FPS = 25
#: Length of the drawn base axes [m] (scaled to the robot's size below).
AXIS_FRACTION = 0.25
#: Decimals kept in the embedded coordinates [m].
DECIMALS = 4

_PLAYER = """
(function(){
const D = DATA, cv = document.getElementById(ID), ctx = cv.getContext('2d');
const sel = document.getElementById(ID + '-method'), sl = document.getElementById(ID + '-t');
const btn = document.getElementById(ID + '-play'), lab = document.getElementById(ID + '-label');
let az = 0.6, el = 0.35, k = 0, playing = false, last = 0, drag = null;
function proj(p){ const ca=Math.cos(az), sa=Math.sin(az), ce=Math.cos(el), se=Math.sin(el);
  const px = p[0] - D.center[0], py = p[1] - D.center[1], pz = p[2] - D.center[2];
  const x = ca*px + sa*py, y = -sa*px + ca*py;
  return [cv.width/2 + D.scale*x, cv.height/2 - D.scale*(ce*pz - se*y)]; }
function line(a, b, c, w){ const A = proj(a), B = proj(b); ctx.strokeStyle = c; ctx.lineWidth = w;
  ctx.beginPath(); ctx.moveTo(A[0], A[1]); ctx.lineTo(B[0], B[1]); ctx.stroke(); }
function draw(){ const m = D.methods[sel.value], f = m.frames[k];
  ctx.clearRect(0, 0, cv.width, cv.height);
  for (const [a, b] of D.box_edges) line(f.box[a], f.box[b], '#999', 1);
  for (const [i, j] of D.segments) line(f.points[i], f.points[j], m.colour, 3);
  const o = f.points[0], cols = ['#d62728', '#2ca02c', '#1f77b4'];
  for (let a = 0; a < 3; a++) line(o, f.axes[a], cols[a], 2);
  lab.textContent = 't = ' + m.t[k].toFixed(2) + ' s, base rotation ' + m.angle_deg[k].toFixed(3) + ' deg'; }
function tick(now){ if (!playing) return; if (now - last > 1000 / D.fps) { last = now;
  const n = D.methods[sel.value].frames.length; k = (k + 1) % n; sl.value = k; draw(); }
  requestAnimationFrame(tick); }
function reset(){ const n = D.methods[sel.value].frames.length; sl.max = n - 1; k = Math.min(k, n - 1); draw(); }
sel.onchange = reset; sl.oninput = function(){ k = +sl.value; draw(); };
btn.onclick = function(){ playing = !playing; btn.textContent = playing ? 'pause' : 'play';
  if (playing) requestAnimationFrame(tick); };
cv.onmousedown = function(e){ drag = [e.clientX, e.clientY, az, el]; };
window.addEventListener('mouseup', function(){ drag = null; });
cv.onmousemove = function(e){ if (!drag) return; az = drag[2] + (e.clientX - drag[0]) * 0.01;
  el = Math.max(-1.5, Math.min(1.5, drag[3] + (e.clientY - drag[1]) * 0.01)); draw(); };
reset();
})();
"""

_BOX_EDGES = [
    (0, 1),
    (1, 3),
    (3, 2),
    (2, 0),
    (4, 5),
    (5, 7),
    (7, 6),
    (6, 4),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
]


def _base_box(robot: FloatingRobot) -> tuple[np.ndarray, pin.SE3] | None:
    """Size and placement (in the base frame) of the root link's box visual, if it has one."""
    root = ET.fromstring(robot.locked_urdf)
    child_links = {
        j.find("child").get("link") for j in root.findall("joint") if j.find("child") is not None
    }
    for link in root.findall("link"):
        if link.get("name") in child_links:
            continue
        box = link.find("visual/geometry/box")
        if box is None:
            return None
        origin = link.find("visual/origin")
        xyz = [
            float(v)
            for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()
        ]
        rpy = [
            float(v)
            for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()
        ]
        size = np.array([float(v) for v in box.get("size").split()])
        return size, pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.array(xyz))
    return None


def skeleton(robot: FloatingRobot) -> tuple[list[int], list[tuple[int, int]]]:
    """Points of the stick figure (Pinocchio joint ids, then end-effector frame ids as negative
    ``-(1 + frame id)``) and the segments between them, as indices into the point list."""
    model = robot.model
    points = list(range(1, model.njoints))  # joint 1 is the free flyer: the base origin
    segments = [(points.index(model.parents[j]), points.index(j)) for j in points[1:]]
    for arm in robot.arms:
        frame = model.getFrameId(arm.ee_frame)
        parent = model.frames[frame].parentJoint
        points.append(-(1 + frame))
        segments.append((points.index(parent), len(points) - 1))
    return points, segments


def _frame(robot: FloatingRobot, data, points: list[int], q_arm, R, box, com0, offset):
    """One frame (the stick figure's points, the base attitude ``R``, the base box corners [m])
    and the CoM of the robot placed with its base at the origin. The frame is shifted so that
    the CoM is at ``com0 + offset`` (its free-flight line; ``com0=None``: the first frame)."""
    model = robot.model
    qp = robot.pin_q(q_arm, pin.SE3(R, np.zeros(3)))
    com = pin.centerOfMass(model, data, qp)
    shift = (com if com0 is None else com0) + offset - com
    pin.forwardKinematics(model, data, qp)
    pin.updateFramePlacements(model, data)
    pts = np.array(
        [data.oMi[p].translation if p > 0 else data.oMf[-p - 1].translation for p in points]
    )
    frame = {"points": pts + shift, "R": R}
    if box is not None:
        size, placement = box
        corners = np.array(
            [[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)]
        )
        frame["box"] = (
            R @ (placement.rotation @ (corners * size).T + placement.translation[:, None])
        ).T + frame["points"][0]
    return frame, com


def _method_frames(robot: FloatingRobot, res: BalanceResult, points, box, p0, fps: float):
    """Sample times, frame sample indices and frames of one plan at ``fps``."""
    data = robot.model.createData()
    t = np.arange(res.t[0], res.t[-1] + 1e-9, 1.0 / fps)
    idx = np.searchsorted(res.t, t).clip(0, res.t.size - 1)
    q = np.hstack([res.q_M, res.q_B])[idx]
    arm_q = np.empty_like(q)
    for k, joint in enumerate((*res.mission_joints, *res.balance_joints)):
        arm_q[:, robot.joint_index(joint)] = q[:, k]
    frames, com0, mass = [], None, robot.total_mass
    for i, k in enumerate(idx):
        R = matrix_from_quaternion(res.quaternion[k])
        offset = (t[i] - t[0]) * p0 / mass
        frame, com = _frame(robot, data, points, arm_q[i], R, box, com0, offset)
        com0 = com if com0 is None else com0
        frames.append(frame)
    return t, idx, frames


def animation_data(
    robot: FloatingRobot,
    results: Mapping[str, BalanceResult],
    h0=None,
    colours: Mapping[str, str] | None = None,
    fps: float = ANIMATION_FPS,
) -> dict:
    """Plain data of the animation: per method, the sample times and per frame the points of
    the stick figure, the base axes and box corners, world frame [m]."""
    points, segments = skeleton(robot)
    box = _base_box(robot)
    p0 = np.zeros(3) if h0 is None else np.asarray(h0, dtype=float)[:3]
    methods = {}
    for name, res in results.items():
        t, idx, frames = _method_frames(robot, res, points, box, p0, fps)
        methods[name] = {
            "t": t,
            "frames": frames,
            "angle_deg": np.degrees(res.angle[idx]),
            "colour": (colours or {}).get(name, "#333333"),
        }
    allpts = np.vstack(
        [
            np.vstack([f["points"], f.get("box", f["points"])])
            for m in methods.values()
            for f in m["frames"]
        ]
    )
    center = 0.5 * (allpts.min(axis=0) + allpts.max(axis=0))
    extent = max(float(np.abs(allpts - center).max()), 0.1)
    axis = extent * AXIS_FRACTION
    for m in methods.values():
        for f in m["frames"]:
            f["axes"] = f["points"][0] + axis * f.pop("R").T
    return {
        "fps": fps,
        "segments": segments,
        "box_edges": _BOX_EDGES if box is not None else [],
        "extent": extent,
        "center": center,
        "methods": methods,
    }


def _round(value):
    if isinstance(value, dict):
        return {k: _round(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_round(v) for v in value]
    if isinstance(value, np.ndarray):
        return _round(value.tolist())
    if isinstance(value, float):
        return round(value, DECIMALS)
    return value


def animation_html(
    robot: FloatingRobot,
    results: Mapping[str, BalanceResult],
    h0=None,
    colours: Mapping[str, str] | None = None,
    labels: Mapping[str, str] | None = None,
    element_id: str = "anim",
    size: int = 520,
) -> str:
    """An HTML fragment: a canvas, a method selector, a play button and a time slider, with the
    data of :func:`animation_data` inline. Drag on the canvas to turn the view."""
    data = animation_data(robot, results, h0, colours)
    data["scale"] = 0.45 * size / (data["extent"] * np.sqrt(2.0))  # any view direction fits
    options = "".join(
        f'<option value="{html.escape(name)}">{html.escape((labels or {}).get(name, name))}</option>'
        for name in results
    )
    script = _PLAYER.replace("ID", json.dumps(element_id)).replace(
        "DATA", json.dumps(_round(data), separators=(",", ":"))
    )
    return (
        f'<div class="animation"><canvas id="{element_id}" width="{size}" height="{size}" '
        f'style="border:1px solid #ddd;cursor:grab"></canvas><br>'
        f'<select id="{element_id}-method">{options}</select> '
        f'<button id="{element_id}-play" type="button">play</button> '
        f'<input id="{element_id}-t" type="range" min="0" max="0" value="0" style="width:300px"> '
        f'<span id="{element_id}-label"></span></div><script>{script}</script>'
    )
