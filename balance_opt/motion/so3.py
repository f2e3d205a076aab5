"""Base attitude on SO(3), numeric and vectorised: unit quaternions (x, y, z, w, Pinocchio's
order), rotation matrices, roll-pitch-yaw (``R = Rz(yaw) Ry(pitch) Rx(roll)``, for reports only),
rotation vectors, ``[v]_x``, ``Jr^{-1}`` and body rates from sampled attitudes.
:mod:`balance_opt.motion.so3_casadi` shares :data:`SERIES_ANGLE` and the coefficients.
"""

from __future__ import annotations

import numpy as np

IDENTITY_QUATERNION = np.array([0.0, 0.0, 0.0, 1.0])
#: Rotation angle [rad] below which ``Jr^{-1}`` uses its series (the closed form is 0/0 at 0 and
#: loses ~eps / angle^2 to cancellation: 1e-12 here, while the series' first neglected term,
#: ~angle^6 / 1.2e6, is 1e-18).
SERIES_ANGLE = 1e-2
#: Angle [rad] below which ``exp`` uses the series of ``sin(a/2) / a`` (error ~a^4 / 3840).
_EXP_SERIES_ANGLE = 1e-4
#: Norm of a quaternion's vector part below which ``log`` uses its first-order form.
_LOG_SERIES_NORM = 1e-12
#: Samples of the polynomial fitted to an attitude history by :func:`body_rates_from_samples`.
RATE_STENCIL = 7


# ---------------------------------------------------------------------------------- quaternions
def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions (..., 4) in (x, y, z, w) order."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack(
        [
            aw * bx + bw * ax + ay * bz - az * by,
            aw * by + bw * ay + az * bx - ax * bz,
            aw * bz + bw * az + ax * by - ay * bx,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quaternion_conjugate(q: np.ndarray) -> np.ndarray:
    """The conjugate (the inverse, for unit quaternions) of quaternions (..., 4)."""
    out = np.array(q, dtype=float, copy=True)
    out[..., :3] *= -1.0
    return out


def relative_rotation(reference: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``reference^{-1} * q``: the attitudes ``q`` seen from ``reference`` (unit quaternions)."""
    return quaternion_multiply(quaternion_conjugate(reference), q)


def quaternion_rate(q: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``q_dot = 1/2 q * (omega, 0)`` for one unit quaternion (x, y, z, w) turning at the body
    rate ``omega`` [rad/s] (``R_dot = R [omega]_x``). Written out: the integrators' inner loop."""
    x, y, z, w = q
    a, b, c = omega
    return 0.5 * np.array(
        [
            w * a + y * c - z * b,
            w * b + z * a - x * c,
            w * c + x * b - y * a,
            -(x * a + y * b + z * c),
        ]
    )


# ---------------------------------------------------------------------------------- exp and log
def quaternion_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Unit quaternion of the rotation ``exp([phi]_x)``, for rotation vectors (..., 3)."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < _EXP_SERIES_ANGLE  # sin(a/2)/a by its series there: no 0/0
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([k * phi, np.cos(half)], axis=-1)


def rotvec_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotation vector ``log(R)`` (..., 3), angle in [0, pi], of unit quaternions (..., 4)."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:] < 0, -q, q)  # same rotation, angle <= pi
    v, w = q[..., :3], q[..., 3]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < _LOG_SERIES_NORM
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


# ---------------------------------------------------------------------------------- Jacobians
def skew(v: np.ndarray) -> np.ndarray:
    """``[v]_x`` (..., 3, 3), with ``[v]_x w = v x w``, of vectors (..., 3)."""
    v = np.asarray(v, dtype=float)
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)],
        -2,
    )


def jr_inverse_series(a2):
    """The ``K^2`` coefficient of ``Jr^{-1}`` as a series in ``a2 = |phi|^2`` (small angles).
    Plain arithmetic: evaluates NumPy arrays and CasADi expressions alike."""
    return 1.0 / 12.0 + a2 / 720.0 + a2 * a2 / 30240.0


def jr_inverse_closed(a2, a, cos_a, sin_a):
    """The ``K^2`` coefficient of ``Jr^{-1}`` in closed form, ``1/a^2 - (1 + cos a)/(2 a sin a)``,
    from ``a2 = a^2``, ``a``, ``cos a`` and ``sin a`` (NumPy or CasADi)."""
    return 1.0 / a2 - (1.0 + cos_a) / (2.0 * a * sin_a)


def inverse_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """``Jr^{-1}(phi)`` (..., 3, 3) of rotation vectors (..., 3): with ``R = exp([phi]_x)``,
    ``phi_dot = Jr^{-1}(phi) omega`` for the body rate ``omega``. Valid for ``|phi| < 2 pi``.

    ``Jr^{-1} = I + K/2 + c K^2`` with ``K = [phi]_x``; ``c`` by :func:`jr_inverse_closed`, or by
    :func:`jr_inverse_series` below :data:`SERIES_ANGLE`.
    """
    phi = np.asarray(phi, dtype=float)
    a2 = np.sum(phi * phi, axis=-1)
    small = a2 < SERIES_ANGLE**2
    a2_safe = np.where(small, 1.0, a2)  # the closed form is evaluated everywhere: keep it finite
    a = np.sqrt(a2_safe)
    c = np.where(small, jr_inverse_series(a2), jr_inverse_closed(a2_safe, a, np.cos(a), np.sin(a)))
    K = skew(phi)
    return np.eye(3) + 0.5 * K + c[..., None, None] * (K @ K)


# ---------------------------------------------------------------------------------- sampled
#: Relative spread of the sample spacing below which a time grid counts as uniform.
_UNIFORM_GRID = 1e-9


#: How many of a window polynomial's top coefficients measure its roughness: small for a smooth
#: motion (h^j f^(j) / j!), not across a corner. Two, because one can vanish across a corner
#: (the 6th difference of a kink placed symmetrically in the window is zero).
_ROUGHNESS_TERMS = 2


def _coefficient_weights(nodes: np.ndarray, degree) -> np.ndarray:
    """Weights (..., p) (or (..., k, p) for a slice of degrees) that give the ``degree``
    coefficients of the polynomial through p values at the scaled times ``nodes`` (..., p):
    rows of the inverse Vandermonde matrix."""
    V = nodes[..., :, None] ** np.arange(nodes.shape[-1])
    return np.linalg.inv(V)[..., degree, :]


def body_rates_from_samples(t, q, points: int = RATE_STENCIL) -> np.ndarray:
    """Body rates (T, 3) [rad/s] of an attitude history (T, 4), by finite differences: at each
    ``t_k`` the derivative of ``log(q_k^{-1} q(t))`` through ``points`` samples, taken over the
    smoothest window containing ``t_k`` (the smallest top coefficients, ENO-like), so corners
    of a collocated plan are differentiated from one side. NaN for a single sample."""
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    T = t.size
    if T < 2:
        return np.full((T, 3), np.nan)
    p = min(points, T)
    window = np.arange(p)
    idx = np.arange(T - p + 1)[:, None] + window  # (W, p): every window of p samples
    span = t[idx[:, -1]] - t[idx[:, 0]]
    steps = np.diff(t)
    uniform = np.ptp(steps) <= _UNIFORM_GRID * steps.mean()
    # roughness of each window: its polynomial's high coefficients, attitude seen from its start
    phi = rotvec_from_quaternion(relative_rotation(q[idx[:, :1]], q[idx]))
    nodes = window / (p - 1) if uniform else (t[idx] - t[idx[:, :1]]) / span[:, None]
    high = _coefficient_weights(nodes, slice(max(1, p - _ROUGHNESS_TERMS), p))
    high = np.broadcast_to(high, idx.shape[:1] + high.shape[-2:])
    roughness = np.linalg.norm(high @ phi, axis=-1).sum(axis=-1)
    # for each sample, the smoothest window that contains it
    k = np.arange(T)
    candidates = np.clip(k[:, None] - window, 0, T - p)  # (T, p) window starts containing k
    best = candidates[k, np.argmin(roughness[candidates], axis=1)]
    # the derivative at t_k of the polynomial through that window, attitude seen from q_k
    idx_k = best[:, None] + window
    phi_k = rotvec_from_quaternion(relative_rotation(q[:, None], q[idx_k]))
    if uniform:  # the nodes depend only on the offset of t_k in its window
        by_offset = _coefficient_weights((window - window[:, None]) / (p - 1), 1)
        slope = by_offset[k - best]
    else:
        slope = _coefficient_weights((t[idx_k] - t[:, None]) / span[best, None], 1)
    return np.einsum("kp,kpi->ki", slope, phi_k) / span[best, None]
