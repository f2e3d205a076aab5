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
from balance_opt.motion.so3 import (
    matrix_from_quaternion,
    quaternion_from_rotvec,
    relative_rotation,
    rotvec_from_quaternion,
)
from balance_opt.report.style import ARM_COLOURS, method_label
from balance_opt.result import BalanceResult

#: Frames per second of the animation [1/s].
ANIMATION_FPS = 25
#: Length of the drawn base axes [m] (scaled to the robot's size below).
AXIS_FRACTION = 0.25
#: Decimals kept in the embedded coordinates [m].
DECIMALS = 4
#: The magnified view turns the base by its rotation from the start times a factor chosen so
#: that the largest drift shows as about this angle [rad] (30 deg).
MAGNIFIED_ANGLE = np.radians(30.0)

_PLAYER = """
(function(){
const D = DATA, cv = document.getElementById(ID), ctx = cv.getContext('2d');
const sel = document.getElementById(ID + '-method'), sl = document.getElementById(ID + '-t');
const btn = document.getElementById(ID + '-play'), lab = document.getElementById(ID + '-label');
const AX = ['#d62728', '#2ca02c', '#1f77b4'], XYZ = ['x', 'y', 'z'];
let az = 0.6, el = 0.35, k = 0, playing = false, last = 0, drag = null;
function turn(p){ const ca=Math.cos(az), sa=Math.sin(az), ce=Math.cos(el), se=Math.sin(el);
  const x = ca*p[0] + sa*p[1], y = -sa*p[0] + ca*p[1]; return [x, -(ce*p[2] - se*y)]; }
function proj(p){ const r = turn([p[0] - D.center[0], p[1] - D.center[1], p[2] - D.center[2]]);
  return [cv.width/2 + D.scale*r[0], cv.height/2 + D.scale*r[1]]; }
function seg(A, B, c, w, dash){ ctx.strokeStyle = c; ctx.lineWidth = w; ctx.setLineDash(dash || []);
  ctx.beginPath(); ctx.moveTo(A[0], A[1]); ctx.lineTo(B[0], B[1]); ctx.stroke(); }
function line(a, b, c, w){ seg(proj(a), proj(b), c, w); }
function text(s, P, c, align){ ctx.fillStyle = c; ctx.textAlign = align || 'left'; ctx.fillText(s, P[0], P[1]); }
function inset(f){ const r = D.inset_radius, cx = cv.width - r - 12, cy = cv.height - r - 12;
  ctx.strokeStyle = '#bbb'; ctx.lineWidth = 1; ctx.setLineDash([]); ctx.beginPath();
  ctx.arc(cx, cy, r + 6, 0, 2*Math.PI); ctx.stroke();
  const m = D.methods[sel.value];
  for (let a = 0; a < 3; a++) { const u = turn(m.ref_axes[a]), v = turn(f.mag[a]);
    seg([cx, cy], [cx + r*u[0], cy + r*u[1]], '#aaa', 1, [3, 3]);
    seg([cx, cy], [cx + r*v[0], cy + r*v[1]], AX[a], 2);
    text(XYZ[a], [cx + (r + 2)*v[0], cy + (r + 2)*v[1]], AX[a]); }
  text('base rotation x ' + D.magnify, [cv.width - 6, cy - r - 24], '#333', 'right');
  text('(dashed: at the start)', [cv.width - 6, cy - r - 10], '#333', 'right'); }
function draw(){ const m = D.methods[sel.value], f = m.frames[k];
  ctx.clearRect(0, 0, cv.width, cv.height); ctx.font = '12px sans-serif';
  for (const [a, b] of D.box_edges) line(f.box[a], f.box[b], '#999', 1);
  D.segments.forEach(function(s, i){ line(f.points[s[0]], f.points[s[1]], D.arms[D.segment_arm[i]].colour, 3); });
  const o = f.points[0];
  for (let a = 0; a < 3; a++) { line(o, f.axes[a], AX[a], 2); text(XYZ[a], proj(f.axes[a]), AX[a]); }
  D.arms.forEach(function(arm, i){ if (arm.tip !== null) { const P = proj(f.points[arm.tip]);
      text(arm.label, [P[0] + 6, P[1] - 6], arm.colour); }
    ctx.fillStyle = arm.colour; ctx.fillRect(10, 10 + 16*i, 12, 12); text(arm.label, [28, 21 + 16*i], '#333'); });
  inset(f);
  lab.textContent = 't = ' + m.t[k].toFixed(2) + ' s, base rotation ' + m.angle[k].toPrecision(3) +
    ' rad (' + (m.angle[k] * 180 / Math.PI).toFixed(3) + ' deg)'; }
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


def segment_arms(robot: FloatingRobot, points: list[int], segments) -> list[int]:
    """Index of the arm each segment belongs to (the arm of the joint or end effector it ends
    at: the nearest arm joint at or above it), ``len(robot.arms)`` for none."""
    model = robot.model
    arm_of = {model.getJointId(j): a for a, arm in enumerate(robot.arms) for j in arm.joints}

    def arm(point: int) -> int:
        j = point if point > 0 else model.frames[-point - 1].parentJoint
        while j > 1 and j not in arm_of:
            j = model.parents[j]
        return arm_of.get(j, len(robot.arms))

    return [arm(points[child]) for _, child in segments]


def magnification(max_angle: float) -> float:
    """Factor of the magnified view of the base's rotation: 1, 2 or 5 times a power of ten, the
    largest that shows ``max_angle`` [rad] at no more than :data:`MAGNIFIED_ANGLE` (1 when the
    rotation is already that large, or nil)."""
    if not max_angle > 0 or max_angle >= MAGNIFIED_ANGLE:
        return 1.0
    want = MAGNIFIED_ANGLE / max_angle
    power = 10.0 ** np.floor(np.log10(want))
    return float(max(f * power for f in (1, 2, 5) if f * power <= want))


def magnified_axes(quaternion: np.ndarray, factor: float) -> np.ndarray:
    """Base axes (T, 3, 3) (rows: x, y, z in the world) of the attitude ``R0 exp(factor
    log(R0^T R))``: the rotation from the start ``R0``, magnified."""
    phi = rotvec_from_quaternion(relative_rotation(quaternion[:1], quaternion))
    R0 = matrix_from_quaternion(quaternion[0])
    R = np.array([R0 @ matrix_from_quaternion(q) for q in quaternion_from_rotvec(factor * phi)])
    return np.swapaxes(R, 1, 2)


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
    """Plain data of the animation: per method, the sample times, the base rotation from the
    start [rad] and per frame the points of the stick figure, the base axes and box corners
    (world frame [m]) and the magnified base axes (``mag``, unit vectors, rotation from the
    start times ``magnify``); the arm of each segment and each arm's label, colour and tip."""
    points, segments = skeleton(robot)
    box = _base_box(robot)
    p0 = np.zeros(3) if h0 is None else np.asarray(h0, dtype=float)[:3]
    methods = {}
    factor = magnification(max(float(res.angle.max()) for res in results.values()))
    for name, res in results.items():
        t, idx, frames = _method_frames(robot, res, points, box, p0, fps)
        for frame, mag in zip(frames, magnified_axes(res.quaternion[idx], factor)):
            frame["mag"] = mag
        methods[name] = {
            "t": t,
            "frames": frames,
            "angle": [float(f"{a:.6g}") for a in res.angle[idx]],
            "ref_axes": matrix_from_quaternion(res.quaternion[0]).T,
            "colour": (colours or {}).get(name, "#333333"),
        }
    arms = [
        {
            "label": f"{arm.name} arm",
            "colour": ARM_COLOURS[a % len(ARM_COLOURS)],
            "tip": len(points) - len(robot.arms) + a,
        }
        for a, arm in enumerate(robot.arms)
    ]
    seg_arms = segment_arms(robot, points, segments)
    if len(robot.arms) in seg_arms:  # a joint in no arm (a mimic follower on the base)
        arms.append({"label": "other", "colour": "#777777", "tip": None})
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
        "segment_arm": seg_arms,
        "arms": arms,
        "magnify": factor,
        "box_edges": _BOX_EDGES if box is not None else [],
        "extent": extent,
        "center": center,
        "methods": methods,
    }


def _round(value):
    """Coordinates to :data:`DECIMALS` decimals (the angles keep their 6 significant digits)."""
    if isinstance(value, dict):
        return {k: v if k == "angle" else _round(v) for k, v in value.items()}
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
    data of :func:`animation_data` inline, and a caption naming what is drawn (the arms by
    colour, the base axes, the magnified view and its factor). Drag on the canvas to turn the
    view. ``labels``: display name per method (default
    :func:`~balance_opt.report.style.method_label`)."""
    data = animation_data(robot, results, h0, colours)
    data["scale"] = 0.45 * size / (data["extent"] * np.sqrt(2.0))  # any view direction fits
    data["inset_radius"] = round(0.11 * size)
    options = "".join(
        f'<option value="{html.escape(name)}">'
        f"{html.escape((labels or {}).get(name) or method_label(name))}</option>"
        for name in results
    )
    arms = ", ".join(
        f'<span style="color:{a["colour"]};font-weight:bold">{html.escape(a["label"])}</span>'
        for a in data["arms"]
        if a["tip"] is not None
    )
    caption = (
        f'<p class="meta">Arms: {arms}. Base axes: red x, green y, blue z. Lower right: the base '
        f"axes turned by the base's rotation from its start magnified {data['magnify']:g} times "
        "(dashed: the axes at the start), so that a rotation of a few degrees shows.</p>"
    )
    script = _PLAYER.replace("ID", json.dumps(element_id)).replace(
        "DATA", json.dumps(_round(data), separators=(",", ":"))
    )
    return (
        f'{caption}<div class="animation"><canvas id="{element_id}" width="{size}" height="{size}" '
        f'style="border:1px solid #ddd;cursor:grab"></canvas><br>'
        f'<select id="{element_id}-method">{options}</select> '
        f'<button id="{element_id}-play" type="button">play</button> '
        f'<input id="{element_id}-t" type="range" min="0" max="0" value="0" style="width:300px"> '
        f'<span id="{element_id}-label"></span></div><script>{script}</script>'
    )
