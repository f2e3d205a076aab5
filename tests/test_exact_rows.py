"""Rows on the exact distance of the pairs the fitted shapes cannot hold (issue 34): their
gradient against finite differences of coal's distance, and two fat cylinders meeting end to
end, whose capsules overlap from the start, held apart by them on the continuous motion."""

import numpy as np
import pytest
from test_collision import _joint, _link
from test_planner_pairs import ALONG_X

from balance_opt.geometry.clearance import clearance
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.model.robot import FloatingRobot

#: The margin of the plans [m].
MARGIN = 0.02
BALANCE = ["turn", "lift", "fold", "twist"]
#: The balance arm's start: the fore arm folded a little. At 0 the cylinders' ends are
#: parallel, where their distance has a kink (its witness points' gradient is 0: a row
#: linearised there holds nothing).
START = np.array([0.0, 0.0, 0.15, 0.0])


def ends_urdf() -> str:
    """A 0.6 m cube with a one-joint mission arm (``yaw``: the mast) and a four-joint balance
    arm: ``turn`` (z) carries the 0.4 m ``tower``, ``lift`` (y) on its top the ``upper`` arm,
    ``fold`` (y) 2 cm past its end a small ``knuckle``, ``twist`` (x) on it the ``fore`` arm.
    Upper and fore arm are fat cylinders (radius 0.06 m, 0.3 m long) along x, end to end 4 cm
    apart at 0; folding the fore arm past about 0.6 rad swings its rim into the upper arm's end.
    A capsule reaches a radius past a cylinder's end: their capsules overlap by 8 cm."""
    fat = '<cylinder radius="0.06" length="0.3"/>'
    return (
        '<robot name="ends">'
        + _link("base", 100.0, '<box size="0.6 0.6 0.6"/>')
        + _link("mast", 2.0, '<cylinder radius="0.03" length="0.3"/>', "0 0 0.15")
        + _link("tower", 2.0, '<cylinder radius="0.04" length="0.4"/>', "0 0 0.2")
        + _link("upper", 2.0, fat, "0.15 0 0", ALONG_X)
        + _link("knuckle", 0.5, '<sphere radius="0.01"/>')
        + _link("fore", 2.0, fat, "0.17 0 0", ALONG_X)
        + _joint("yaw", "base", "mast", "0.2 0.2 0.3", "0 0 1")
        + _joint("turn", "base", "tower", "-0.15 -0.1 0.3", "0 0 1")
        + _joint("lift", "tower", "upper", "0 0 0.4", "0 1 0")
        + _joint("fold", "upper", "knuckle", "0.32 0 0", "0 1 0")
        + _joint("twist", "knuckle", "fore", "0 0 0", "1 0 0")
        + "</robot>"
    )


def _robot() -> FloatingRobot:
    return FloatingRobot(ends_urdf(), ["yaw"], BALANCE)


def test_the_exact_distance_gradient_is_coals_by_finite_differences():
    """The gradient from coal's witness points and normal and the frames' Jacobians agrees with
    central differences of coal's distance, apart and in contact (negative distance). GJK and
    EPA stop at 1e-6 by default, noise that 1 mrad steps turn into 1e-3 in the quotients: the
    distances here are solved to 1e-10."""
    from balance_opt.optimal.exact_rows import distance_gradient

    geometry = RobotGeometry(_robot())
    pair = next(p for p in geometry.pairs if p.name == "upper / fore")
    request = geometry.geometry_data.distanceRequests[pair.index]
    request.gjk_tolerance = request.epa_tolerance = 1e-10
    rng = np.random.default_rng(3)
    configurations = [rng.uniform(-1.5, 1.5, 5) for _ in range(6)]
    configurations.append(np.array([0.3, 0.2, 0.1, 0.9, 0.4]))  # the fore arm into the upper
    signs = set()
    for q in configurations:
        d, grad = distance_gradient(geometry, q, pair.index)
        assert d == pytest.approx(geometry.distances(q, [pair.index])[0], abs=1e-9)
        h = 1e-3
        steps = np.eye(q.size) * h
        fd = [
            (
                geometry.distances(q + e, [pair.index])[0]
                - geometry.distances(q - e, [pair.index])[0]
            )
            / (2 * h)
            for e in steps
        ]
        assert np.allclose(grad, fd, atol=1e-5), (q, grad, fd)
        signs.add(bool(d > 0))
    assert signs == {True, False}  # both sides of contact were tested


def _plan(avoid: bool):
    """The ends robot's plan whose rest pull (the fore arm folded 1.5 rad) drags the fore arm
    through the upper arm's end unless the planner keeps it out."""
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import CostWeights, PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    options = PlannerOptions(
        objective="integral",
        intervals=20,
        weights=CostWeights(rest=100.0),
        rest_configuration=(0.0, 0.0, 1.5, 0.0),
        end="free",
        collision_avoidance=avoid,
        collision_margin=MARGIN,
    )
    model = PlannerModel(_robot(), compile=False, store=False)
    nlp = build_balance_nlp(model, PointToPoint([0.0], [0.6], 3.0), START, options)
    return nlp, nlp.solve("rest")


@pytest.mark.slow
def test_fat_cylinders_end_to_end_are_held_apart_by_their_exact_rows():
    """The fitted capsules of the two fat cylinders overlap from the start (4 cm apart end to
    end at 0, 3.1 cm at the start): their row is watched, no bound on it can hold them.
    Without avoidance the pull drives the fore arm into the upper arm; with it the pair's
    exact rows (linearised with the arm at rest, and again at each plan the check finds too
    close) keep every checked pair at least the margin apart on the continuous motion (coal at
    every sample and the check's certified bound between them)."""
    from balance_opt.geometry.shapes import clearance_rows, moved_by

    robot = _robot()
    geometry = RobotGeometry(robot)
    pair = next(p for p in geometry.pairs if p.name == "upper / fore")
    assert geometry.distances(np.zeros(robot.n), [pair.index])[0] == pytest.approx(0.04, abs=1e-6)
    moved = moved_by(geometry, BALANCE)
    shapes = clearance_rows(geometry, [pair], moved).shapes
    upper, fore = (next(s for s in shapes if s.name == n) for n in ("upper", "fore"))
    gap = np.linalg.norm(fore.a + [0.32, 0, 0] - upper.b) - upper.radius - fore.radius
    assert gap == pytest.approx(-0.08, abs=1e-6)  # the capsules 8 cm into each other

    _, free = _plan(avoid=False)
    inside = clearance(geometry, free.t, np.hstack([free.q_M, free.q_B]))
    assert inside.closest.pair == "upper / fore" and inside.min_distance < -0.01

    nlp, safe = _plan(avoid=True)
    assert [p.name for p in nlp.collision.exact] == ["upper / fore"]
    assert safe.solver.checks.collision_pairs["watched"] == ["upper / fore"]
    q = np.hstack([safe.q_M, safe.q_B])
    at_samples = np.array([geometry.distances(qk) for qk in q])
    assert at_samples.min() >= MARGIN - 1e-6
    report = clearance(geometry, safe.t, q, watch=1.0)
    assert min(p.lower_bound for p in report.pairs) >= MARGIN - 1e-6
    # the pull still acts: the fore arm folds on, up to the margin from the upper arm
    assert report.closest.pair == "upper / fore" and report.closest.distance < MARGIN + 0.005
    assert safe.q_B[:, 2].max() > START[2] + 0.1
