"""Capturing an active target (issue 16): a non-zero total momentum in the optimal planner.

The planner's base rate with a momentum ``h0`` is checked against the analytic law's rollout
(a different code path: numeric Pinocchio, the quaternion integrated by the law's own
integrator), and a whole optimal plan with ``h0`` against an attitude recomputed here from the
exported joint motion alone, with numeric Pinocchio and nothing of the planner.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.analytic.rollout import rollout
from balance_opt.app.scenarios import paper_capture
from balance_opt.motion.so3 import rotvec_from_quaternion
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp

#: A total momentum [N s; N m s] that turns the paper robot's base by several degrees in 10 s.
H0 = np.array([0.3, -0.2, 0.1, 2.0, -1.5, 3.0])
#: Planner base rate against the law's at the same state [rad/s] (both numeric Pinocchio to
#: round-off).
RATE_TOLERANCE = 1e-9
#: NLP attitude at the nodes against the re-simulated one, relative to the drift (Hermite-Simpson
#: at N = 25 with this momentum: ~2e-3).
COLLOCATION_RELATIVE_ERROR = 5e-3
#: Independent attitude (RK4 at twice the exported step) against the exported one [rad].
ATTITUDE_TOLERANCE = 1e-6


@pytest.fixture(scope="module")
def capture():
    return paper_capture()


@pytest.fixture(scope="module")
def model(capture):
    return PlannerModel(capture.robot, compile=False)


def _points(result, h0):
    """Planner states and point data of a result's samples: ``x = [log R; q_B; q_dot_B]``,
    ``m = [q_M; q_dot_M; q_ddot_M; h0]``."""
    phi = rotvec_from_quaternion(result.quaternion)
    X = np.hstack([phi, result.q_B, result.q_dot_B]).T
    h0_rows = np.broadcast_to(h0, (result.t.size, 6))
    m = np.hstack([result.q_M, result.q_dot_M, result.q_ddot_M, h0_rows]).T
    return X, result.q_ddot_B.T, m


def test_planner_base_rate_with_momentum_matches_the_law_rollout(model, capture):
    """Along the law's rollout with ``h0`` (whose base rate includes ``R^T L0``), the planner's
    dynamics give the law's base rate at the law's attitude: the momentum turns with the base."""
    t = np.linspace(0.0, capture.mission.duration, 41)
    law = rollout(
        capture.robot, capture.mission, capture.q_B0, BalanceLawOptions(h0=tuple(H0)), t_eval=t
    )
    assert np.max(law.angle) > 0.05  # the momentum turns the base: the term matters
    X, U, m = _points(law, H0)
    _, omega = model.dynamics_fun("acceleration").map(t.size)(X, U, m)
    np.testing.assert_allclose(np.array(omega).T, law.omega, rtol=0, atol=RATE_TOLERANCE)
    # without the momentum the planner's rate differs by the momentum's share
    _, omega0 = model.dynamics_fun("acceleration").map(t.size)(X, U, _points(law, 0 * H0)[2])
    assert np.max(np.abs(np.array(omega0).T - law.omega)) > 1e-3


def _independent_attitude(robot, t, q, q_dot, h0) -> np.ndarray:
    """Base rotation matrices (every other sample) integrated from the joint motion alone: at
    each sample the base twist solves ``A_G(q, R) [v_b; q_dot] = h0`` (Pinocchio's centroidal
    map in world axes, the whole 6 x 6 base block), RK4 on ``R_dot = R [omega]_x`` with the
    odd samples as midpoints, re-orthonormalised after each step."""
    model, data = robot.model, robot.model.createData()

    def omega(k, R):
        qp = robot.pin_q(q[k], pin.SE3(R, np.zeros(3)))
        A = pin.computeCentroidalMap(model, data, qp)
        v = robot.pin_v(q_dot[k])
        v_b = np.linalg.solve(A[:, :6], h0 - A[:, 6:] @ v[6:])
        return v_b[3:]

    def rate(R, w):
        return R @ pin.skew(w)

    R = np.eye(3)
    out = [R]
    for k in range(0, t.size - 2, 2):
        dt = t[k + 2] - t[k]
        k1 = rate(R, omega(k, R))
        k2 = rate(R + 0.5 * dt * k1, omega(k + 1, R + 0.5 * dt * k1))
        k3 = rate(R + 0.5 * dt * k2, omega(k + 1, R + 0.5 * dt * k2))
        k4 = rate(R + dt * k3, omega(k + 2, R + dt * k3))
        R = R + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
        out.append(R)
    return np.array(out)


@pytest.mark.slow
def test_optimal_plan_with_momentum_matches_an_independent_attitude(model, capture):
    """An optimal plan with ``h0``: Ipopt succeeds, the NLP's attitude agrees with the
    re-simulation, and the exported attitude is the one recomputed here from the exported
    joint motion; another ``h0`` reuses the compiled NLP."""
    options = PlannerOptions(intervals=25, objective="integral")
    nlp = build_balance_nlp(model, capture.mission, capture.q_B0, options, h0=H0)
    plan = nlp.solve()
    assert plan.info["success"]
    defect = plan.info["resimulation"]["attitude_defect_max_rad"]
    assert defect < COLLOCATION_RELATIVE_ERROR * plan.max_drift
    assert np.max(plan.momentum_residual) < 1e-6
    t, q, q_dot = plan.t, np.hstack([plan.q_M, plan.q_B]), np.hstack([plan.q_dot_M, plan.q_dot_B])
    cols = np.r_[capture.robot.mission_indices, capture.robot.balance_indices]
    arm_q, arm_qd = np.empty_like(q), np.empty_like(q_dot)
    arm_q[:, cols], arm_qd[:, cols] = q, q_dot
    n = (t.size - 1) // 2 * 2 + 1
    R_ref = _independent_attitude(capture.robot, t[:n], arm_q[:n], arm_qd[:n], H0)
    R_out = np.array([pin.Quaternion(*qq[[3, 0, 1, 2]]).matrix() for qq in plan.quaternion[:n:2]])
    err = [np.linalg.norm(pin.log3(a.T @ b)) for a, b in zip(R_ref, R_out)]
    assert max(err) < ATTITUDE_TOLERANCE
    # the momentum turned the base: without the balance arm's help the drift would be larger
    assert np.linalg.norm(pin.log3(R_ref[-1])) > 1e-3
    cached = len(model.nlp_cache)
    build_balance_nlp(model, capture.mission, capture.q_B0, options, h0=-H0)
    assert len(model.nlp_cache) == cached
