"""Direct-collocation transcriptions (Hermite-Simpson, separated form, and trapezoidal) and the
continuous balance-arm trajectory they describe."""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

from balance_opt.motion.trajectories import JointTrajectory

TRANSCRIPTIONS = ("hermite-simpson", "trapezoidal")


@dataclass(frozen=True)
class Transcription:
    """One collocation scheme."""

    name: str  # one of TRANSCRIPTIONS (PlannerOptions checks it)

    @property
    def has_midpoints(self) -> bool:
        """States and controls are also decision variables at the intervals' midpoints."""
        return self.name == TRANSCRIPTIONS[0]

    @property
    def control_degree(self) -> int:
        """Degree of the control polynomial on an interval."""
        return 2 if self.has_midpoints else 0

    def n_points(self, N: int) -> int:
        return 2 * N + 1 if self.has_midpoints else N + 1

    def point_taus(self, N: int) -> np.ndarray:
        """Times of the collocation points in units of ``h``: nodes ``0..N``, then midpoints."""
        nodes = np.arange(N + 1, dtype=float)
        return np.r_[nodes, nodes[:-1] + 0.5] if self.has_midpoints else nodes

    def defects(self, X, Xm, F, Fm, h) -> list[tuple[str, object]]:
        """``(name, defect (n_x, N))`` of the rows that must vanish."""
        x0, x1, f0, f1 = X[:, :-1], X[:, 1:], F[:, :-1], F[:, 1:]
        if self.has_midpoints:
            return [
                ("Hermite midpoint", Xm - 0.5 * (x0 + x1) - (h / 8.0) * (f0 - f1)),
                ("Simpson", x1 - x0 - (h / 6.0) * (f0 + 4.0 * Fm + f1)),
            ]
        return [("trapezoidal", x1 - x0 - (h / 2.0) * (f0 + f1))]

    def quadrature_weights(self, N: int) -> np.ndarray:
        """Weights (in units of ``h``) of the running cost at the collocation points, in the order
        of :meth:`point_taus`: composite Simpson or trapezoidal rule."""
        w = np.ones(N + 1)
        w[0] = w[-1] = 0.5
        if self.has_midpoints:
            return np.r_[w / 3.0, np.full(N, 2.0 / 3.0)]
        return w

    def control_coefficients(self, U, Um) -> list:
        """Bernstein coefficients of the control polynomial of every interval, each (n_u, N)."""
        u0, u1 = U[:, :-1], U[:, 1:]
        if self.has_midpoints:
            return [u0, 2.0 * Um - 0.5 * (u0 + u1), u1]
        return [0.5 * (u0 + u1)]


def joint_chain_coefficients(transcription: Transcription, starts: list, U, Um, h) -> list[list]:
    """Bernstein coefficients of every derivative of the balance joints on every interval: the
    control's, then each integral ``start + int_0^tau c`` on ``[0, h]``, one degree higher."""
    levels = [transcription.control_coefficients(U, Um)]
    for start in reversed(starts):
        level = [start]
        for c in levels[-1]:
            level.append(level[-1] + (h / len(levels[-1])) * c)
        levels.append(level)
    return levels[::-1]


def bernstein_value(coefficients: list, s: float):
    """Value at ``s`` in [0, 1] of the polynomial with Bernstein ``coefficients`` (symbolic or
    numeric, each (n, N)): ``sum_i C(d, i) s^i (1 - s)^(d - i) c_i``."""
    degree = len(coefficients) - 1
    weights = [comb(degree, i) * s**i * (1.0 - s) ** (degree - i) for i in range(degree + 1)]
    total = 0
    for w, c in zip(weights, coefficients):
        if w != 0.0:
            total = total + w * c
    return total


def monomial_from_bernstein(degree: int) -> np.ndarray:
    """Matrix ``M`` with ``a = M b``: monomial coefficients ``a_j`` (of ``s^j``) of the polynomial
    with Bernstein coefficients ``b_i`` on [0, 1]: ``a_j = C(d, j) sum_i (-1)^(j-i) C(j, i) b_i``."""
    M = np.zeros((degree + 1, degree + 1))
    for j in range(degree + 1):
        for i in range(j + 1):
            M[j, i] = (-1) ** (j - i) * comb(degree, j) * comb(j, i)
    return M


class CollocatedTrajectory(JointTrajectory):
    """The balance-joint motion of a collocation solution as a continuous, piecewise polynomial
    trajectory (see the module docstring), sampled like every mission trajectory."""

    def __init__(self, h: float, levels: list[list[np.ndarray]]):
        self.h = float(h)
        # Bernstein coefficients (N, degree + 1, n) per level, and the same polynomials in the
        # monomial basis of s = (t - t_k) / h, for Horner evaluation
        self._coefficients = [
            np.stack([np.asarray(c, dtype=float).T for c in level], axis=1) for level in levels[:3]
        ]
        self._monomial = [
            np.einsum("ji,kin->kjn", monomial_from_bernstein(c.shape[1] - 1), c)
            for c in self._coefficients
        ]
        self.intervals = self._coefficients[0].shape[0]
        self.dof = self._coefficients[0].shape[2]
        self.duration = self.h * self.intervals

    def sample(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        u = np.minimum(np.maximum(t, 0.0), self.duration) / self.h
        k = np.minimum(u.astype(int), self.intervals - 1)
        s = (u - k)[:, None]
        out = []
        for a in self._monomial:
            a = a[k]
            value = a[:, -1]
            for j in range(a.shape[1] - 2, -1, -1):
                value = value * s + a[:, j]
            out.append(value)
        return tuple(out)

    def interval_ends(self) -> list[np.ndarray]:
        """Position, velocity and acceleration at the end of every interval (N, n)."""
        return [c[:, -1, :] for c in self._coefficients]
