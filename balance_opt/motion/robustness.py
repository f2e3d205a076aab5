"""Drift under model error (``docs/executable-plans.md``): every plan replayed on K seeded
models whose inertial parameters are perturbed in Pinocchio's log-Cholesky coordinates (always
physical),
the drift summarised by its median, 95th percentile and maximum.

At zero momentum the base twist is linear in the spatial inertias, so the kinematics are
computed once and each model costs a few batched products; with momentum each model is
replayed in full.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from balance_opt.model.maps import NumericMaps
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.integration import rk4_stage_times
from balance_opt.motion.options import IntegrationOptions, RobustnessOptions
from balance_opt.motion.replay import attitude_from_rates, replay
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import rotation_angle
from balance_opt.motion.trajectories import SampledTrajectory, arm_samples

#: Smallest eigenvalue of a body's second moment before it is perturbed, relative to its trace
#: (or its mass, in kg m^2, for a point mass).
SIGMA_FLOOR = 1e-12
#: Percentile reported besides the median and the largest value.
PERCENTILE = 95.0


def second_moment(inertia: pin.Inertia) -> np.ndarray:
    """``Sigma = tr(I_c) / 2 * 1 - I_c`` (3, 3) [kg m^2]: the second moment of the body's mass
    about its centre of mass."""
    I_c = np.asarray(inertia.inertia)
    return 0.5 * np.trace(I_c) * np.eye(3) - I_c


def log_cholesky(inertia: pin.Inertia) -> np.ndarray:
    """Pinocchio's log-Cholesky parameters ``(alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3)`` of
    a body (``m > 0``, ``Sigma`` positive definite): the inverse of
    ``pin.LogCholeskyParameters(theta).toPseudoInertia()``, from the upper triangular factor
    ``U = exp(alpha) [[A, c], [0, 1]]`` of its pseudo-inertia ``J = U U^T``: ``m = exp(2 alpha)``,
    ``A`` (``exp(d)`` on its diagonal, ``s`` above) the factor of ``Sigma / m``, ``t = c``."""
    J = pin.PseudoInertia.FromInertia(inertia).toMatrix()
    U = np.linalg.cholesky(J[::-1, ::-1])[::-1, ::-1]  # upper triangular, J = U U^T
    A = U / U[3, 3]
    return np.r_[np.log(U[3, 3]), np.log(np.diag(A)[:3]), A[0, 1], A[1, 2], A[0, 2], A[:3, 3]]


def perturbed_inertia(inertia: pin.Inertia, size: float, rng: np.random.Generator) -> pin.Inertia:
    """A physical body near ``inertia``, perturbed by about ``size``, relatively, in Pinocchio's
    log-Cholesky coordinates (:func:`log_cholesky`; Rucker and Wensing), where every point is a
    physical body: with standard normal draws ``z``, ``alpha`` and ``d`` move by ``size z / 2``
    (the mass and the factor's diagonal times ``exp(size z)``, ``exp(size z / 2)``), ``s_ij`` by
    ``(size / 2) z sqrt(A_ii A_jj)`` and ``c`` by ``size z rho``, ``rho = sqrt(tr(Sigma) / m)``
    the radius of gyration. The body keeps its shape ``Sigma / m`` as its mass changes."""
    m, c = float(inertia.mass), np.asarray(inertia.lever, dtype=float)
    z = rng.standard_normal(10)  # drawn for every body, so that bodies keep their draws
    if m <= 0.0 or size == 0.0:
        return pin.Inertia(inertia)
    # a body on the boundary (a point mass, a thin rod: Sigma singular) gets a vanishing
    # thickness first, so that its pseudo-inertia has a Cholesky factor
    w, V = np.linalg.eigh(second_moment(inertia))
    sigma = (V * np.maximum(w, SIGMA_FLOOR * max(w.sum(), m))) @ V.T
    theta = log_cholesky(pin.Inertia(m, c, np.trace(sigma) * np.eye(3) - sigma))
    a, rho = np.exp(theta[1:4]), np.sqrt(np.trace(sigma) / m)
    pairs = np.sqrt(a[[0, 1, 0]] * a[[1, 2, 2]])  # s12, s23, s13
    scale = np.r_[np.full(4, 0.5), 0.5 * pairs, np.full(3, rho)]
    return pin.LogCholeskyParameters(theta + size * scale * z).toInertia()


def perturbed_robot(robot: FloatingRobot, size: float, rng: np.random.Generator) -> FloatingRobot:
    """The robot with every body's inertia perturbed: a shallow copy, its own Pinocchio model."""
    out = copy.copy(robot)
    out.model = robot.model.copy()
    for i in range(1, robot.model.njoints):
        out.model.inertias[i] = perturbed_inertia(robot.model.inertias[i], size, rng)
    return out


@dataclass(frozen=True)
class DriftSpread:
    """The drift of one plan: its own peak and final drift, and those on each perturbed model
    (K,) [rad]."""

    nominal_peak: float
    nominal_final: float
    peak: np.ndarray
    final: np.ndarray

    def to_dict(self) -> dict:
        """Median, 95th percentile and largest value of the peak and final drift [rad]."""
        out = {
            "nominal_max_drift_rad": self.nominal_peak,
            "nominal_final_drift_rad": self.nominal_final,
        }
        for name, values in (("max_drift", self.peak), ("final_drift", self.final)):
            out[name] = {
                "median_rad": float(np.median(values)),
                "p95_rad": float(np.percentile(values, PERCENTILE)),
                "largest_rad": float(np.max(values)),
            }
        return out


@dataclass(frozen=True)
class RobustnessResult:
    """Drift under model error of one or more plans (the same perturbed models for all).

    Attributes:
        methods: per method, its :class:`DriftSpread`.
        attitude_p95: per method, the 95th percentile over the models of the attitude error
            ``|log R(t)|`` at each of the plan's samples (T,) [rad] (a band for figures).
        wall_time_s: time of the study [s].
    """

    options: RobustnessOptions
    methods: dict[str, DriftSpread]
    attitude_p95: dict[str, np.ndarray] = field(repr=False)
    wall_time_s: float

    def to_dict(self) -> dict:
        """Plain data (for ``metrics.json``)."""
        return {
            "samples": self.options.samples,
            "perturbation": self.options.perturbation,
            "seed": self.options.seed,
            "methods": {k: v.to_dict() for k, v in self.methods.items()},
            "wall_time_s": self.wall_time_s,
        }


def drift_under_model_error(
    robot: FloatingRobot,
    plans: dict[str, BalanceResult],
    options: RobustnessOptions | None = None,
    h0=None,
) -> RobustnessResult:
    """Replay every plan (by method name) on ``options.samples`` perturbed models of ``robot``,
    with the system's momentum ``h0`` (world frame, 3 angular or 6 values) as planned."""
    opts = options or RobustnessOptions()
    start = time.perf_counter()
    rng = np.random.default_rng(opts.seed)
    models = [perturbed_robot(robot, opts.perturbation, rng) for _ in range(opts.samples)]
    methods, bands = {}, {}
    for name, plan in plans.items():
        mission = SampledTrajectory.from_result(plan, "mission")
        balance = SampledTrajectory.from_result(plan, "balance")
        integration = _integration_of(plan)
        angles = np.empty((opts.samples, plan.t.size))
        if integration.method == "rk4" and (h0 is None or not np.any(h0)):
            times = rk4_stage_times(plan.t, integration)[0]
            omega = _base_rates(robot, mission, balance, times, models)
            angles[:] = rotation_angle(attitude_from_rates(omega, plan.t, integration))
        else:  # the rate depends on the attitude: every model replayed in full
            for k, model in enumerate(models):
                replayed = replay(
                    model, mission, balance, h0=h0, integration=integration, t_eval=plan.t
                )
                angles[k] = replayed.angle
        methods[name] = DriftSpread(
            plan.max_drift, plan.final_drift, angles.max(axis=1), angles[:, -1]
        )
        bands[name] = np.percentile(angles, PERCENTILE, axis=0)
    return RobustnessResult(opts, methods, bands, time.perf_counter() - start)


def _inertia_basis() -> np.ndarray:
    """``B`` (10, 6, 6) with a spatial inertia matrix ``sum_p pi_p B_p`` for Pinocchio's
    dynamic parameters ``pi = (m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz)`` (about the frame's
    origin): ``[[m 1, -[m c]_x], [[m c]_x, I_o]]``."""
    B = np.zeros((10, 6, 6))
    B[0, :3, :3] = np.eye(3)
    for p, axis in enumerate(np.eye(3)):
        cross = pin.skew(axis)
        B[1 + p, :3, 3:], B[1 + p, 3:, :3] = -cross, cross
    for p, (i, j) in enumerate(((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))):
        B[4 + p, 3 + i, 3 + j] = B[4 + p, 3 + j, 3 + i] = 1.0
    return B


def _base_rates(robot: FloatingRobot, mission, balance, times: np.ndarray, robots) -> np.ndarray:
    """The base angular velocity (K, T, 3) [rad/s, base frame] of each of ``robots`` (``robot``
    perturbed) along a joint motion at zero momentum: the composite inertia and the joint momentum
    at the base are linear in every body's dynamic parameters, so the kinematics are computed once
    (on ``robot``)."""
    maps = NumericMaps(robot)
    q, q_dot, _ = arm_samples(robot, mission.sample, balance.sample, times)
    qp, vp = maps.configurations(q), maps.velocities(q_dot)
    model, data = robot.model, robot.model.createData()
    nb = model.njoints - 1
    force = np.empty((times.size, nb, 6, 6))  # X_i^*: body forces to the base
    velocity = np.empty((times.size, nb, 6))  # v_i, body frame, base held
    for k in range(times.size):
        pin.forwardKinematics(model, data, qp[k], vp[k])
        for i in range(nb):
            force[k, i] = data.oMi[i + 1].toDualActionMatrix()
            velocity[k, i] = data.v[i + 1].vector
    FB = np.einsum("tiab,pbc->tipac", force, _inertia_basis())
    T = times.size
    # (T, 6, 6, nb * 10) and (T, 6, nb * 10): X^* B_p X^*T and X^* B_p v per body, parameter
    composite = FB @ np.swapaxes(force, -1, -2)[:, :, None]
    composite = np.moveaxis(composite, (1, 2), (3, 4)).reshape(T, 6, 6, nb * 10)
    momentum = (FB @ velocity[:, :, None, :, None])[..., 0]
    momentum = np.moveaxis(momentum, (1, 2), (2, 3)).reshape(T, 6, nb * 10)
    params = np.stack(
        [
            np.concatenate([r.model.inertias[i + 1].toDynamicParameters() for i in range(nb)])
            for r in robots
        ],
        axis=-1,
    )  # (nb * 10, K)
    composite = np.moveaxis(composite @ params, -1, 0)  # (K, T, 6, 6)
    momentum = np.moveaxis(momentum @ params, -1, 0)  # (K, T, 6)
    twist = -np.linalg.solve(composite, momentum[..., None])[..., 0]
    return twist[..., 3:]


def _integration_of(plan: BalanceResult) -> IntegrationOptions:
    """Fixed-step RK4 with the plan's own step when it was replayed so (a zero perturbation then
    gives the plan back exactly), else one step per sample interval: error control would cost a
    full replay per model, for a difference far below the drifts compared."""
    info = plan.info.get("integration") or {}
    if info.get("method") == "rk4" and info.get("step"):
        return IntegrationOptions(method="rk4", step=float(info["step"]))
    return IntegrationOptions(method="rk4", step=float(np.diff(plan.t).max()))
