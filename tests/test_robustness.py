"""Drift under model error (issue 25): physical perturbations of the inertial parameters, the
batched replay against Pinocchio's own, and the drift's spread."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.app.scenarios import capture_task
from balance_opt.errors import InputError
from balance_opt.motion.options import IntegrationOptions, RobustnessOptions
from balance_opt.motion.replay import replay
from balance_opt.motion.robustness import (
    drift_under_model_error,
    log_cholesky,
    perturbed_inertia,
    perturbed_robot,
    second_moment,
)
from balance_opt.motion.trajectories import PointToPoint, SampledTrajectory

#: The batched replay against a full replay of the same perturbed model [rad].
REPLAY_TOLERANCE = 1e-12
RK4 = IntegrationOptions(method="rk4", step=0.01)


@pytest.fixture(scope="module")
def scenario():
    return capture_task()


@pytest.fixture(scope="module")
def plan(scenario):
    """A joint motion of the capture robot (a smooth move of the balance arm against the
    mission's), replayed with fixed-step RK4 as the planner replays its plans."""
    q_B0 = np.asarray(scenario.q_B0)
    balance = PointToPoint(q_B0, q_B0 + np.array([0.6, -0.3, 0.4]), scenario.mission.duration)
    return replay(scenario.robot, scenario.mission, balance, integration=RK4, method="plan")


def test_perturbed_inertias_are_physical():
    rng = np.random.default_rng(3)
    bodies = []
    for _ in range(5):  # random physical bodies: I_c = tr(Sigma) 1 - Sigma, Sigma > 0
        A = rng.standard_normal((3, 3))
        sigma = A @ A.T + 1e-3 * np.eye(3)
        I_c = np.trace(sigma) * np.eye(3) - sigma
        bodies.append(pin.Inertia(rng.uniform(0.1, 10), rng.standard_normal(3), I_c))
    bodies.append(pin.Inertia(5.0, np.array([0.0, 0.0, 0.25]), np.diag([0.1, 0.1, 0.004])))
    bodies.append(pin.Inertia(2.0, np.zeros(3), np.zeros((3, 3))))  # a point mass
    log_mass = []
    for size in (0.1, 0.5, 2.0):
        for body in bodies:
            for _ in range(40):
                new = perturbed_inertia(body, size, rng)
                moments = np.linalg.eigvalsh(new.inertia)  # about the centre of mass
                assert new.mass > 0 and moments.min() > 0
                assert moments[2] <= moments[0] + moments[1] + 1e-12  # triangle inequality
                assert np.linalg.eigvalsh(second_moment(new)).min() > 0
                if size == 0.1:
                    log_mass.append(np.log(new.mass / body.mass))
    # the stated relative size: the mass's log-normal spread
    assert np.std(log_mass) == pytest.approx(0.1, rel=0.15)
    same = perturbed_inertia(bodies[0], 0.0, rng)
    np.testing.assert_allclose(same.matrix(), bodies[0].matrix(), rtol=0, atol=0)


def test_perturbation_changes_every_body(scenario):
    robot = scenario.robot
    other = perturbed_robot(robot, 0.1, np.random.default_rng(0))
    assert other.model is not robot.model
    for i in range(1, robot.model.njoints):
        a, b = robot.model.inertias[i], other.model.inertias[i]
        assert abs(b.mass / a.mass - 1) > 1e-4
        assert np.abs(b.lever - a.lever).max() > 1e-5
        assert np.abs(b.inertia - a.inertia).max() > 1e-7


def test_zero_perturbation_replays_the_plan(scenario, plan):
    study = drift_under_model_error(
        scenario.robot, {"plan": plan}, RobustnessOptions(samples=3, perturbation=0.0)
    )
    spread = study.methods["plan"]
    np.testing.assert_allclose(spread.peak, plan.max_drift, rtol=1e-9)
    np.testing.assert_allclose(spread.final, plan.final_drift, rtol=1e-9)
    np.testing.assert_allclose(study.attitude_p95["plan"], plan.angle, rtol=1e-9, atol=1e-15)


def test_batched_replay_is_pinocchios(scenario, plan):
    """The drift of every perturbed model by the shared kinematics equals a full replay of that
    model (Pinocchio's centroidal maps), with and without momentum."""
    options = RobustnessOptions(samples=3, perturbation=0.2, seed=7)
    study = drift_under_model_error(scenario.robot, {"plan": plan}, options)
    rng = np.random.default_rng(7)
    mission = SampledTrajectory.from_result(plan, "mission")
    balance = SampledTrajectory.from_result(plan, "balance")
    for k in range(3):
        model = perturbed_robot(scenario.robot, 0.2, rng)
        full = replay(model, mission, balance, integration=RK4, t_eval=plan.t)
        assert study.methods["plan"].peak[k] == pytest.approx(full.max_drift, abs=REPLAY_TOLERANCE)
        assert study.methods["plan"].final[k] == pytest.approx(
            full.final_drift, abs=REPLAY_TOLERANCE
        )
    # with momentum the rate depends on the attitude: every model replayed in full
    h0 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.5)
    spinning = drift_under_model_error(scenario.robot, {"plan": plan}, options, h0=h0)
    model = perturbed_robot(scenario.robot, 0.2, np.random.default_rng(7))
    full = replay(model, mission, balance, h0=h0, integration=RK4, t_eval=plan.t)
    assert spinning.methods["plan"].peak[0] == pytest.approx(full.max_drift, abs=REPLAY_TOLERANCE)


def test_spread_grows_with_the_perturbation(scenario, plan):
    p95, median_gap = [], []
    for size in (0.02, 0.1, 0.3):
        study = drift_under_model_error(
            scenario.robot, {"plan": plan}, RobustnessOptions(samples=20, perturbation=size)
        )
        spread = study.methods["plan"]
        p95.append(study.to_dict()["methods"]["plan"]["final_drift"]["p95_rad"])
        median_gap.append(np.median(np.abs(spread.peak - plan.max_drift)))
    assert p95[0] < p95[1] < p95[2]
    assert median_gap[0] < median_gap[1] < median_gap[2]
    d = study.to_dict()
    assert (d["samples"], d["perturbation"], d["seed"]) == (20, 0.3, 0)
    entry = d["methods"]["plan"]
    assert entry["nominal_max_drift_rad"] == plan.max_drift
    assert set(entry["max_drift"]) == {"median_rad", "p95_rad", "largest_rad"}
    assert entry["max_drift"]["median_rad"] <= entry["max_drift"]["p95_rad"]
    assert entry["max_drift"]["p95_rad"] <= entry["max_drift"]["largest_rad"]


def test_robustness_options():
    assert RobustnessOptions().runs_in("compare") and not RobustnessOptions().runs_in("plan")
    assert RobustnessOptions(enabled=True).runs_in("plan")
    with pytest.raises(InputError, match="robustness option 'samples': must be at least 1"):
        RobustnessOptions(samples=0)


def test_the_perturbation_is_in_pinocchios_log_cholesky_coordinates():
    """The coordinates are Pinocchio's (they give the body back), and each perturbed body is
    ``LogCholeskyParameters(theta + size * scale * z)`` with standard normal ``z``: the mass
    and the factor's diagonal move by ``size z / 2`` in their logarithm, the centre of mass by
    ``size z`` radii of gyration; the shape ``Sigma / m`` is kept as the mass changes."""
    body = pin.Inertia(3.0, np.array([0.1, -0.2, 0.3]), np.diag([0.05, 0.04, 0.02]))
    theta = log_cholesky(body)
    back = pin.LogCholeskyParameters(theta).toInertia()
    np.testing.assert_allclose(back.matrix(), body.matrix(), rtol=0, atol=1e-14)
    assert theta[0] == pytest.approx(0.5 * np.log(3.0)) and np.allclose(theta[7:], body.lever)
    rho = np.sqrt(np.trace(second_moment(body)) / body.mass)
    rng, size = np.random.default_rng(11), 0.1
    moved = np.array([log_cholesky(perturbed_inertia(body, size, rng)) - theta for _ in range(400)])
    z = np.hstack([moved[:, :4] / (0.5 * size), moved[:, 7:] / (size * rho)])
    np.testing.assert_allclose(z.std(axis=0), 1.0, atol=0.12)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.15)
    # a heavier draw of the same shape: only the mass moved, the inertia follows it
    one = pin.LogCholeskyParameters(theta + np.r_[0.1, np.zeros(9)]).toInertia()
    np.testing.assert_allclose(one.inertia, np.exp(0.2) * body.inertia, rtol=1e-12, atol=1e-15)
