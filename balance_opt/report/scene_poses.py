"""Where the 3D scene's nodes are along a plan: the frames' samples, the base's rotation (as
planned or magnified), the world placement of every joint with the centre of mass on its
free-flight line, the captured target's flight; and those placements as the viewer's
animation tracks."""

from __future__ import annotations

import base64
from collections.abc import Mapping
from typing import Any

import numpy as np
import pinocchio as pin

from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import (
    matrix_from_quaternion,
    quaternion_from_rotvec,
    relative_rotation,
    rotvec_from_quaternion,
)

#: Animation samples per second of motion [1/s] (the viewer interpolates between them).
SCENE_FPS = 25


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


def pack(command: dict) -> str:
    import umsgpack

    return base64.b64encode(umsgpack.packb(command)).decode("ascii")


def _float32(values) -> Any:
    import umsgpack

    return umsgpack.Ext(0x17, np.ascontiguousarray(values, dtype="<f4").tobytes())


def animation(
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


def tracks_of(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (K, 3) and unit quaternions (K, 4) (x, y, z, w) of placements (K, 4, 4), each
    quaternion on the side of its predecessor (the same rotations, no half-turn between keys)."""
    quaternions = np.array([pin.Quaternion(M[:3, :3]).coeffs() for M in poses])
    turns = np.einsum("ij,ij->i", quaternions[1:], quaternions[:-1]) < 0
    sides = np.cumprod(np.r_[1.0, np.where(turns, -1.0, 1.0)])
    return poses[:, :3, 3], quaternions * sides[:, None]
