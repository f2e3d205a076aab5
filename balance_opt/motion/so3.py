"""Base attitude on SO(3): unit quaternions (x, y, z, w, Pinocchio's order), roll-pitch-yaw and
rotation angles, vectorised over time.

Attitude is always integrated on the group (``R_dot = R [omega]_x`` with ``omega`` in the base
frame), never through Euler angles; roll-pitch-yaw is only a way to report it, with Pinocchio's
convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import numpy as np

IDENTITY_QUATERNION = np.array([0.0, 0.0, 0.0, 1.0])


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions (..., 4) in (x, y, z, w) order."""
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    v = aw * bv + bw * av + np.cross(av, bv)
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    return np.concatenate([v, w], axis=-1)


def quaternion_conjugate(q: np.ndarray) -> np.ndarray:
    out = np.array(q, dtype=float, copy=True)
    out[..., :3] *= -1.0
    return out


def quaternion_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Unit quaternion of the rotation ``exp([phi]_x)``, for rotation vectors (..., 3)."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a, with its series below 1e-4 rad to avoid 0/0
    small = angle < 1e-4
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([k * phi, np.cos(half)], axis=-1)


def rotvec_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotation vector ``log(R)`` (..., 3), angle in [0, pi], of unit quaternions (..., 4)."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:] < 0, -q, q)  # same rotation, angle <= pi
    v, w = q[..., :3], q[..., 3]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-12
    k = np.where(small, 2.0 / np.where(w == 0, 1.0, w), angle / np.where(small, 1.0, s))
    return k[..., None] * v


def rotation_angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle ``|log(R)|`` [rad] of unit quaternions (..., 4), in [0, pi]."""
    q = np.asarray(q, dtype=float)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3]))


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rpy_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw [rad] (..., 3) with ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    R = matrix_from_quaternion(q)
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2]))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def integrate_quaternion(q: np.ndarray, omega: np.ndarray, dt: float) -> np.ndarray:
    """Attitude after turning at the constant body rate ``omega`` [rad/s] for ``dt`` [s]:
    ``q * exp(omega dt)``, exact on SO(3)."""
    out = quaternion_multiply(q, quaternion_from_rotvec(np.asarray(omega) * dt))
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def inverse_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """``Jr^{-1}(phi)`` (3 x 3): with ``R = exp(phi)``, ``phi_dot = Jr^{-1}(phi) omega`` for the
    body rate ``omega``. Valid for ``|phi| < 2 pi``."""
    phi = np.asarray(phi, dtype=float)
    a2 = float(phi @ phi)
    a = np.sqrt(a2)
    K = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if a < 1e-3:
        c = 1 / 12 + a2 / 720 + a2 * a2 / 30240
    else:
        c = 1 / a2 - (1 + np.cos(a)) / (2 * a * np.sin(a))
    return np.eye(3) + 0.5 * K + c * K @ K
