"""Self-collision pairs of a robot without an SRDF, computed as MoveIt's setup assistant does
(issue 34): a pair in contact in nearly every configuration is disabled, one in contact only
sometimes is checked, and every part of a run uses the same pairs."""

import json
import re

import numpy as np
import pytest
from conftest import urdf_task

from balance_opt.geometry import self_collision
from balance_opt.geometry.clearance import clearance
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.model.robot import FloatingRobot

INERTIA = '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'


def _link(name, mass, *collisions):
    shapes = "".join(
        f'<collision><origin xyz="{xyz}"/><geometry>{g}</geometry></collision>'
        for xyz, g in collisions
    )
    return (
        f'<link name="{name}"><inertial><mass value="{mass}"/>{INERTIA}</inertial>{shapes}</link>'
    )


def _joint(name, parent, child, xyz, axis, limit):
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
        f'<limit lower="-{limit}" upper="{limit}" velocity="2" effort="50"/></joint>'
    )


def wrist_urdf() -> str:
    """A 0.2 m cube; on top (0.6 m up) a mission arm ``j1`` (about z) - ``j2`` (about z) -
    ``j3`` whose link ``l3`` is a sphere of radius 0.02 at 0.2 m from ``j2``'s axis; ``l1``
    carries two slabs 0.04 m either side of that axis' plane: the sphere is inside one of them
    unless ``|sin q2| < 0.1``, in 3.3 % of ``q2``'s range [-3, 3] (clear at zero). Below the
    cube, the balance arm's ``paddle`` (0.3 m along x, ``k2`` about y, 0.05 m below the cube,
    turned about z by ``k1`` through a link without geometry: the cube and the paddle are not
    adjacent) swings into the cube from about 0.3 rad up, in a third of its range."""
    slab = '<box size="0.6 0.26 0.1"/>'
    return (
        '<robot name="wrists">'
        + _link("base", 100.0, ("0 0 0", '<box size="0.2 0.2 0.2"/>'))
        + _link("l1", 2.0, ("0 0.17 0", slab), ("0 -0.17 0", slab))
        + _link("l2", 1.0)
        + _link("l3", 1.0, ("0 0 0", '<sphere radius="0.02"/>'))
        + _link("paddle", 2.0, ("0.15 0 0", '<box size="0.3 0.04 0.04"/>'))
        + _joint("j1", "base", "l1", "0 0 0.6", "0 0 1", 3.0)
        + _joint("j2", "l1", "l2", "0 0 0", "0 0 1", 3.0)
        + _joint("j3", "l2", "l3", "0.2 0 0", "1 0 0", 3.0)
        + _link("hub", 1.0)
        + _joint("k1", "base", "hub", "0 0 -0.15", "0 0 1", 3.0)
        + _joint("k2", "hub", "paddle", "0 0 0", "0 1 0", 2.0)
        + "</robot>"
    )


@pytest.fixture(scope="module")
def wrists():
    return FloatingRobot(wrist_urdf(), ["j1", "j2", "j3"], ["k1", "k2"])


def _in_contact(geometry, links, samples=2000, seed=7):
    """Configurations (another seed than the rule's) and whether the pair of ``links`` is in
    contact at each."""
    q = self_collision.sample_configurations(geometry.robot, samples, seed)
    return q, geometry.smallest_along(q, _object_pairs(geometry, links)) <= 0.0


def _object_pairs(geometry, links):
    return [p.index for p in geometry.pairs if set(p.links) == set(links)]


def test_pairs_in_contact_nearly_always_are_disabled_the_others_checked(wrists):
    bare = RobotGeometry(wrists, disabled={})  # no SRDF, nothing computed
    assert bare.samples == 0 and bare.srdf is None
    q, touch = _in_contact(bare, ("l1", "l3"))
    gap = 0.2 * np.abs(np.sin(q[:, 1])) - 0.02  # how far the sphere reaches into a slab
    assert np.array_equal(touch[np.abs(gap) > 1e-6], gap[np.abs(gap) > 1e-6] > 0.0)
    assert 0.95 < touch.mean() < 1.0 and not touch[np.abs(q[:, 1]) < 0.09].any()
    assert 0.2 < _in_contact(bare, ("base", "paddle"))[1].mean() < 0.5
    geometry = RobotGeometry(wrists)
    assert geometry.srdf is None and geometry.samples == self_collision.SAMPLES == 1000
    assert geometry.ignored == {
        ("base", "l1"): "adjacent",
        ("l1", "l3"): "always",
    }
    assert {frozenset(p.links) for p in geometry.pairs} == {
        frozenset(p.links) for p in bare.pairs
    } - {frozenset(("l1", "l3"))}
    assert "paddle" in {link for p in geometry.pairs for link in p.links}
    # the same robot gives the same pairs
    assert RobotGeometry(wrists).ignored == geometry.ignored


def test_a_pair_in_contact_in_the_reference_pose_is_disabled_as_default(wrists):
    """With ``j2`` limited to [0.3, 3] rad the sphere sits inside a slab in every pose, the
    reference pose (``j2`` at 0.3 rad, zero moved inside the limits) among them: contact in the
    reference pose is the reason given."""
    narrow = FloatingRobot(
        wrist_urdf(), ["j1", "j2", "j3"], ["k1", "k2"], limits={"j2": {"lower": 0.3}}
    )
    assert narrow.neutral()[1] == 0.3
    geometry = RobotGeometry(narrow)
    assert geometry.ignored[("l1", "l3")] == "default"
    assert geometry.summary(narrow.neutral())["link_pairs_ignored"]["default"] == 1


def _wrist_task(tmp_path, srdf=None):
    body = (
        "arms: {mission: [j1, j2, j3], balance: [k1, k2]}\n"
        "initial: {balance: [0.0, 0.0]}\n"
        "mission: {type: ptp, start: [0.0, 0.5, 0.0], goal: [0.8, 1.5, 1.0], duration: 2.0}\n"
    )
    return urdf_task(tmp_path, "wrists", wrist_urdf(), body, srdf)


def test_a_plan_through_always_overlapping_wrists_reports_no_collision(tmp_path, wrists):
    from balance_opt.cli import main

    out = tmp_path / "out"
    argv = ["plan", str(_wrist_task(tmp_path)), "-m", "mission-only", "-o", str(out), "-q"]
    assert main(argv) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    geometry = metrics["geometry"]
    assert (geometry["srdf"], geometry["samples"]) == (None, 1000)
    assert geometry["link_pairs_ignored"]["always"] == 1
    assert geometry["initial_contacts"] == []
    reference = metrics["methods"]["mission-only"]["clearance"]
    assert reference["collision_free"] and reference["first_penetration"] is None
    # the wrists overlap on the whole motion: checked, they would be a collision from t = 0
    from balance_opt.app.pipeline import plan
    from balance_opt.tasks.task import load_task

    result = plan(load_task(tmp_path / "wrists.yaml"), "mission-only")
    q = np.hstack([result.q_M, result.q_B])
    bare = RobotGeometry(wrists, disabled={})
    pairs = _object_pairs(bare, ("l1", "l3"))
    assert bare.smallest_along(q, pairs).max() < 0.0
    assert clearance(bare, result.t, q, pairs=pairs).first_penetration.time == 0.0


def test_an_optimal_plan_starts_with_the_wrists_overlapping(wrists):
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    model = PlannerModel(wrists, compile=False, store=False)
    mission = PointToPoint([0.0, 0.5, 0.0], [0.8, 1.5, 1.0], 2.0)
    nlp = build_balance_nlp(model, mission, [0.0, 0.0], PlannerOptions(intervals=10))
    assert nlp.collision.geometry.ignored[("l1", "l3")] == "always"
    kept = {frozenset(p.links) for p in nlp.collision.pairs}
    assert frozenset(("base", "paddle")) in kept and frozenset(("l1", "l3")) not in kept


def test_write_srdf_round_trips_and_keeps_an_existing_file(tmp_path, capsys):
    from balance_opt.cli import main
    from balance_opt.tasks.task import load_task

    task = _wrist_task(tmp_path)
    srdf = tmp_path / "reviewed.srdf"
    assert main(["inspect", str(task), "--write-srdf", str(srdf)]) == 0
    out = capsys.readouterr().out
    assert (
        "geometry from the URDF's <collision> elements: 5 pairs checked; link pairs left out: "
        "0 same body, 1 adjacent, 0 by the SRDF, 1 computed, 0 ignored by the task\n"
        "  pairs left out computed (no SRDF): 1 adjacent, 0 in the reference pose, 1 in nearly "
        "every sampled configuration, 0 one body apart and never more than 0.02 m apart "
        "(1000 samples)\n"
        "    nearly always: l1 / l3\n"
    ) in out
    assert f"wrote {srdf}: 2 disabled link pairs\n" in out
    assert srdf.read_text() == (
        '<robot name="wrists">\n'
        '  <disable_collisions link1="base" link2="l1" reason="Adjacent" />\n'
        '  <disable_collisions link1="l1" link2="l3" reason="Always" />\n'
        "</robot>\n"
    )
    computed = RobotGeometry(load_task(task).robot)
    given = load_task(_wrist_task(tmp_path, srdf="reviewed.srdf"))
    loaded = RobotGeometry(given.robot, srdf=given.planner_options().collision_srdf)
    assert loaded.srdf == srdf and loaded.samples == 0
    assert [p.links for p in loaded.pairs] == [p.links for p in computed.pairs]
    assert main(["inspect", str(tmp_path / "wrists.yaml")]) == 0
    assert f"  pairs left out by the SRDF {srdf}\n" in capsys.readouterr().out
    # an existing file is kept unless --force
    srdf.write_text("<robot/>")
    assert main(["inspect", str(task), "--write-srdf", str(srdf)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (
        f"balance-opt: error: {srdf} exists; use --force to replace it, or choose another file\n"
    )
    assert srdf.read_text() == "<robot/>"
    task = _wrist_task(tmp_path)  # without robot.srdf again: the pairs computed
    assert main(["inspect", str(task), "--write-srdf", str(srdf), "--force"]) == 0
    assert 'reason="Always"' in srdf.read_text()


def flap_urdf() -> str:
    """The 0.2 m cube of :func:`wrist_urdf` with a mission arm ``j1`` far above it (``l1``: a
    sphere 0.6 m up), and a balance arm ``f1`` - ``f2`` (both about z, at 0.3 m along x from
    the cube's centre, through a link without geometry: not adjacent to the cube) whose
    ``flap``, a bar 0.14 m long from 0.08 m to 0.22 m of the axis, reaches 0.02 m into the cube
    at zero and clears it unless ``f1 + f2`` turns it back within about 0.4 rad."""
    return (
        '<robot name="flap">'
        + _link("base", 100.0, ("0 0 0", '<box size="0.2 0.2 0.2"/>'))
        + _link("l1", 1.0, ("0 0 0", '<sphere radius="0.02"/>'))
        + _joint("j1", "base", "l1", "0 0 0.6", "1 0 0", 3.0)
        + _link("mount", 1.0)
        + _link("flap", 1.0, ("-0.15 0 0", '<box size="0.14 0.04 0.04"/>'))
        + _joint("f1", "base", "mount", "0.3 0 0", "0 0 1", 3.0)
        + _joint("f2", "mount", "flap", "0 0 0", "0 0 1", 3.0)
        + "</robot>"
    )


def test_a_pair_in_contact_in_the_reference_pose_but_rarely_else_is_checked():
    """The flap starts in the cube at zero, the reference pose, and is clear of it in most
    configurations: the pair is kept (MoveIt's reference-pose rule alone would disable it for
    the whole motion, and a start there would not be refused)."""
    flap = FloatingRobot(flap_urdf(), ["j1"], ["f1", "f2"])
    bare = RobotGeometry(flap, disabled={})
    pairs = _object_pairs(bare, ("base", "flap"))
    assert bare.distances(flap.neutral(), pairs)[0] == pytest.approx(-0.02, abs=1e-6)
    q, touch = _in_contact(bare, ("base", "flap"))
    # the bar's near end reaches x = 0.1 (the cube's face) within |f1 + f2| < 0.43 rad about
    turn = np.angle(np.exp(1j * (q[:, 1] + q[:, 2])))
    assert not touch[np.abs(turn) > 0.6].any() and touch[np.abs(turn) < 0.3].all()
    assert 0.05 < touch.mean() < self_collision.DEFAULT
    geometry = RobotGeometry(flap)
    assert geometry.ignored == {("base", "l1"): "adjacent"}
    assert geometry.computed == []
    assert {frozenset(p.links) for p in geometry.pairs} == {frozenset(p.links) for p in bare.pairs}
    assert [p.name for p in geometry.contacts(flap.neutral())] == ["base / flap"]


def _flap_task(folder, initial=""):
    body = (
        "arms: {mission: [j1], balance: [f1, f2]}\n"
        f"{initial}"
        "mission: {type: ptp, start: [0.0], goal: [0.5], duration: 2.0}\n"
    )
    task = urdf_task(folder, "flap", flap_urdf(), body)
    # adam: the planner model without the Pinocchio bridge's build
    task.write_text(task.read_text().replace("robot:\n", "robot:\n  backend: adam\n"))
    return task


def test_a_start_in_contact_on_a_kept_reference_pair_is_refused_at_its_key(tmp_path):
    """The default balance start is the reference pose, where the flap is in the cube: the
    optimal plan is refused (the pair is checked), naming the task's key, before the planner's
    kinematics are built; the start given is named by its line."""
    from balance_opt.app.pipeline import plan
    from balance_opt.cli import main
    from balance_opt.config.yaml_lines import TaskFileError
    from balance_opt.tasks.task import load_task, start_error

    contact = (
        "flap: the initial configuration is in collision: base / flap (0.0200 m deep); move it, "
        "or leave the pairs out (robot.srdf, optimal.collision.ignore) if the geometry overlaps "
        "there by design"
    )
    task = _flap_task(tmp_path)
    message = (
        f"{task}: initial.balance: {contact} (not given: the balance arm starts at zero, inside "
        "its limits)"
    )
    with pytest.raises(TaskFileError, match=f"^{re.escape(message)}$"):
        plan(load_task(task), "optimal")
    out = tmp_path / "out"
    assert main(["plan", str(task), "-m", "optimal", "-o", str(out), "-q"]) == 2
    assert not out.exists()
    given = _flap_task(tmp_path, "initial:\n  balance: [0.1, 0.0]\n")
    with pytest.raises(
        TaskFileError, match=r"flap\.yaml:7: initial\.balance: flap: the initial configuration "
    ):
        plan(load_task(given), "optimal")
    # pairs of the mission arm alone: its start
    mission = start_error(load_task(given), "in collision", balance=False)
    assert str(mission) == f"{given}:8: mission.start: in collision"
    # the other methods plan; the clearance check reports the contact from t = 0
    result = plan(load_task(task), "analytic")
    geometry = RobotGeometry(load_task(task).robot)
    report = clearance(geometry, result.t, np.hstack([result.q_M, result.q_B]))
    assert report.first_penetration.pair == "base / flap"
    assert report.first_penetration.time == 0.0


def test_a_run_names_the_computed_pairs_in_its_log_and_metrics(tmp_path, caplog):
    import logging

    from balance_opt.app.pipeline import run_task
    from balance_opt.tasks.task import load_task

    caplog.set_level(logging.INFO, logger="balance_opt")
    out = tmp_path / "out"
    run_task(load_task(_wrist_task(tmp_path)), methods=("analytic",), output_dir=out)
    said = [r.getMessage() for r in caplog.records if "as computed" in r.getMessage()]
    assert said == [
        (
            "wrists: no SRDF: link pairs left out as computed (robot.srdf to choose): "
            "l1 / l3 (always)"
        )
    ]
    geometry = json.loads((out / "metrics.json").read_text())["geometry"]
    assert geometry["computed_disabled"] == [{"pair": "l1 / l3", "reason": "always"}]


def test_the_run_and_the_planner_share_one_geometry_per_robot_limits(tmp_path, monkeypatch):
    """The pairs computed without an SRDF (a thousand samples) once per run: the run's
    clearance check takes the planner's geometry from the model cache; a robot of the same
    kinematics with other limits gets its own (its samples are drawn inside its limits)."""
    from balance_opt.app.models import ModelCache
    from balance_opt.app.pipeline import run_task
    from balance_opt.optimal.collision import check_start
    from balance_opt.tasks.task import load_task

    path = _wrist_task(tmp_path)
    path.write_text(path.read_text().replace("robot:\n", "robot:\n  backend: adam\n"))
    task = load_task(path)
    computed = []
    disabled_pairs = self_collision.disabled_pairs

    def counted(*args):
        computed.append(args)
        return disabled_pairs(*args)

    monkeypatch.setattr(self_collision, "disabled_pairs", counted)
    models = ModelCache(compile=False)
    model = models.planner_model(task.robot, "adam")
    options = task.planner_options()
    geometry = check_start(model.collisions, options, task.q0, task.robot)  # as plan_part does
    run = run_task(task, methods=("analytic",), models=models)
    assert run.geometry is geometry and len(computed) == 1
    assert run_task(task, methods=("analytic",)).geometry is not geometry  # no planner model
    assert len(computed) == 2
    narrow = FloatingRobot(
        wrist_urdf(), ["j1", "j2", "j3"], ["k1", "k2"], limits={"j2": {"lower": 0.3}}
    )
    other = model.collisions.geometry(options.collision_ignore, options.collision_srdf, narrow)
    assert other is not geometry and len(computed) == 3
    assert (geometry.ignored[("l1", "l3")], other.ignored[("l1", "l3")]) == ("always", "default")


def near_urdf() -> str:
    """A 0.2 m cube with two arms alike but for one offset: ``a1`` (about z) turns a 0.3 m
    post (radius 0.03) whose top is ``gap`` below ``a2`` (about y, a link without geometry),
    which swings a 0.3 m rod (radius 0.03) starting 0.01 m from ``a2``; post and rod are one
    body apart. The balance arm's gap is 5 mm: post and rod are never more than 15 mm apart,
    and touch as the rod swings down. The mission arm's gap is 0.1 m: they are up to 0.11 m
    apart."""
    post, rod = '<cylinder radius="0.03" length="0.3"/>', '<cylinder radius="0.03" length="0.3"/>'
    out = '<robot name="near">' + _link("base", 100.0, ("0 0 0", '<box size="0.2 0.2 0.2"/>'))
    for arm, y, gap in (("m", 0.5, 0.1), ("b", -0.5, 0.005)):
        out += (
            _link(f"{arm}_post", 2.0, ("0 0 0.15", post))
            + _link(f"{arm}_hub", 1.0)
            + _link(f"{arm}_rod", 2.0, ("0 0 0.16", rod))
            + _joint(f"{arm}1", "base", f"{arm}_post", f"0 {y} 0.1", "0 0 1", 3.0)
            + _joint(f"{arm}2", f"{arm}_post", f"{arm}_hub", f"0 0 {0.3 + gap}", "0 1 0", 1.5)
            + _joint(f"{arm}3", f"{arm}_hub", f"{arm}_rod", "0 0 0", "0 0 1", 3.0)
        )
    return out + "</robot>"


def test_bodies_one_apart_never_clear_of_each_other_are_disabled_as_near():
    """A pair of bodies one body apart that never gets 2 cm clear (the balance arm's post and
    rod, 5 mm apart at best, by an independent grid over the joint that moves them apart) is
    disabled as ``near``: no motion can keep it clear, as none can keep adjacent bodies apart;
    the same pair with a 0.1 m gap (the mission arm's) is checked, and so is the base against
    each rod (one body apart too, but far). Written as an SRDF, the pair is ``Adjacent``."""
    robot = FloatingRobot(near_urdf(), ["m1", "m2", "m3"], ["b1", "b2", "b3"])
    geometry = RobotGeometry(robot, srdf=False)
    near = {k for k, r in geometry.ignored.items() if r == "near"}
    assert near == {("b_post", "b_rod")}
    checked = {tuple(sorted(p.links)) for p in geometry.pairs}
    assert {("m_post", "m_rod"), ("b_rod", "base"), ("base", "m_rod")} <= checked
    every = RobotGeometry(robot, disabled={})  # nothing computed: every pair's distance
    grid = np.zeros((301, robot.n))
    grid[:, [1, 4]] = np.linspace(-1.5, 1.5, 301)[:, None]  # m2 and b2 over their range
    along = {
        links: every.smallest_along(grid, _object_pairs(every, links))
        for links in (("b_post", "b_rod"), ("m_post", "m_rod"))
    }
    far = {links: d.max() for links, d in along.items()}
    assert far[("b_post", "b_rod")] == pytest.approx(0.015, abs=1e-6)
    assert along[("b_post", "b_rod")].min() < 0.0  # it can collide: the rule is not "never"
    assert far[("m_post", "m_rod")] > 0.1
    assert 'link1="b_post" link2="b_rod" reason="Adjacent"' in self_collision.srdf_text(
        "near", geometry.disabled
    )
