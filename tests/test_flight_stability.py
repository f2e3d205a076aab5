"""The fixed-step simulation stays stable under stiff joint loops (sub-steps), a run whose state
leaves every sane bound is stopped and named at once, and a closed-loop study counts such runs
apart from the ones that flew."""

import re

import numpy as np
import pytest

from balance_opt.app.closed_loop import ClosedLoopChunk, ClosedLoopStudy
from balance_opt.app.scenarios import capture_task
from balance_opt.commands.task_run import _more_summary
from balance_opt.dynamics import simulation
from balance_opt.dynamics.options import ClosedLoopOptions, SimulationOptions
from balance_opt.errors import DivergenceError
from balance_opt.motion.so3 import quaternion_conjugate, quaternion_multiply, rotation_angle

#: Damping ratios of the default gains that put the capture robot's fastest PD mode at about
#: 5 / dt (past RK4's limit of 2.78 / dt at the 1 ms step: 3 sub-steps keep it stable) and at
#: about 50 / dt (past what MAX_SUBSTEPS sub-steps can hold).
STIFF_DAMPING = 20.0
UNSTABLE_DAMPING = 200.0
#: ... and at about 250 / dt: the perturbed robots of a closed loop diverge whatever their error.
BLOWN_DAMPING = 1000.0
#: Attitude agreement of RK4 with sub-steps and the adaptive integrator on the stiff loop [rad].
INTEGRATOR_AGREEMENT = 1e-8


@pytest.fixture(scope="module")
def scenario():
    return capture_task()


def run(scenario, **options):
    return simulation.simulate(
        scenario.robot,
        scenario.mission,
        scenario.q_B0,
        SimulationOptions(**options),
        duration=0.5,
    )


@pytest.mark.slow
def test_stiff_joint_loop_takes_substeps_and_agrees_with_the_adaptive_integrator(
    scenario, monkeypatch
):
    sim = run(scenario, damping_ratio=STIFF_DAMPING)
    assert sim.info["substeps"] == 3
    adaptive = run(scenario, damping_ratio=STIFF_DAMPING, integrator="dopri5")
    gap = rotation_angle(
        quaternion_multiply(quaternion_conjugate(sim.quaternion), adaptive.quaternion)
    )
    assert gap.max() < INTEGRATOR_AGREEMENT
    assert np.abs(sim.q - adaptive.q).max() < INTEGRATOR_AGREEMENT
    # the same run at the step as given is past RK4's stability limit: it is stopped
    monkeypatch.setattr(simulation, "MAX_SUBSTEPS", 1)
    with pytest.raises(DivergenceError, match=r"diverged at t = 0\.\d+ s: "):
        run(scenario, damping_ratio=STIFF_DAMPING)


def test_default_gains_on_the_capture_robot_take_no_substep(scenario):
    assert run(scenario).info["substeps"] == 1


def test_a_diverging_simulation_is_stopped_and_named(scenario):
    with pytest.raises(
        DivergenceError,
        match=re.escape("the forward-dynamics simulation diverged at t = ")
        + r"0\.0\d+ s: joint \w+ at [\d.e+]+ rad/s, over 10 times its velocity limit and "
        r"its plan's rate",
    ) as caught:
        run(scenario, damping_ratio=UNSTABLE_DAMPING)
    assert caught.value.t < 0.1


def _flown(k, drift):
    t = np.linspace(0.0, 1.0, 3)
    return {
        "index": k,
        "t": t,
        "angle": drift * t,
        "max_drift": drift,
        "final_drift": drift,
        "min_clearance": 0.1,
        "limit_violations": [],
        "compute_s": [0.1],
        "failed": 0,
        "late": 0,
    }


def test_a_diverged_closed_loop_run_is_counted_and_named_not_averaged():
    runs = {"optimal": [_flown(0, 0.01), {"index": 1, "diverged": "boom"}, _flown(2, 0.03)]}
    study = ClosedLoopStudy(ClosedLoopOptions(), runs, 1.0)
    metrics = study.metrics("optimal")
    assert metrics["samples"] == 2 and metrics["diverged"] == {"1": "boom"}
    assert (
        metrics["max_drift"]["largest_rad"] == 0.03 and metrics["max_drift"]["median_rad"] == 0.02
    )
    assert study.worst()[1]["index"] == 2
    lines = _more_summary({"closed_loop": metrics})
    assert "closed loop: 1 simulations diverged: model 1 (boom)" in lines
    alone = ClosedLoopStudy(ClosedLoopOptions(), {"optimal": runs["optimal"][1:2]}, 1.0)
    assert alone.metrics("optimal") == {"samples": 0, "period_s": 0.5, "diverged": {"1": "boom"}}


@pytest.mark.slow
def test_a_closed_loop_flight_that_diverges_is_stopped_and_named(scenario):
    """The law's branch of a closed-loop chunk (no re-plan) on true robots whose joint loop is
    past every sub-step: each run is stopped at once and named, none raises or hangs."""
    chunk = ClosedLoopChunk(
        "analytic",
        scenario.robot,
        scenario.mission,
        scenario.q_B0,
        np.zeros(6),
        None,
        "pinocchio",
        SimulationOptions(damping_ratio=BLOWN_DAMPING),
        ClosedLoopOptions(samples=2, perturbation=0.1, seed=0),
        balance=scenario.q_B0,
    )
    runs = chunk([0, 1])
    assert [r["index"] for r in runs] == [0, 1]
    for r in runs:
        assert re.fullmatch(
            r"the forward-dynamics simulation diverged at t = 0\.0\d+ s: (non-finite state|"
            r"joint \w+ at [\d.e+]+ rad/s, over 10 times its velocity limit and its plan's "
            r"rate)",
            r["diverged"],
        )
