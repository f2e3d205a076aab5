"""Collision geometry, the clearance check and collision avoidance in the optimal planner
(issue 24), against coal's exact distances and Pinocchio's kinematics."""

import casadi as cs
import coal
import numpy as np
import pinocchio as pin
import pytest
from conftest import urdf_task
from scipy.optimize import minimize
from scipy.spatial import ConvexHull, Delaunay

from balance_opt.errors import InputError
from balance_opt.geometry import shapes
from balance_opt.geometry.clearance import clearance
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.model.capture import Target, attach_target
from balance_opt.model.library import example_urdf
from balance_opt.model.robot import FloatingRobot
from balance_opt.model.symbolic import SymbolicMaps


def _link(name, mass, geometry, origin="0 0 0", rpy="0 0 0", tags=("collision",)):
    shapes_xml = "".join(
        f'<{tag}><origin xyz="{origin}" rpy="{rpy}"/><geometry>{geometry}</geometry></{tag}>'
        for tag in tags
    )
    return (
        f'<link name="{name}"><inertial><origin xyz="{origin}"/><mass value="{mass}"/>'
        f'<inertia ixx="0.05" iyy="0.05" izz="0.05" ixy="0" ixz="0" iyz="0"/></inertial>'
        f"{shapes_xml}</link>"
    )


def _joint(name, parent, child, xyz, axis, limit=3.0):
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
        f'<limit lower="-{limit}" upper="{limit}" velocity="2" effort="50"/></joint>'
    )


def toy_urdf(tags=("collision",)) -> str:
    """A 0.6 m cube with a one-joint mission arm and a two-joint balance arm on its top face:
    ``swing`` (balance joint 2, about y) turns ``boom`` (0.6 m, radius 0.03), level at 0
    (0.07 m above the cube), into the cube from about 0.45 rad down; the balance arm's
    ``post`` is two objects (a cylinder and a box: its capsule is fitted)."""
    cyl = '<cylinder radius="0.03" length="0.6"/>'
    return (
        '<robot name="toy">'
        + _link("base", 100.0, '<box size="0.6 0.6 0.6"/>', tags=tags)
        + _link("mast", 2.0, '<cylinder radius="0.03" length="0.3"/>', "0 0 0.15", tags=tags)
        + _link(
            "post", 2.0, '<cylinder radius="0.03" length="0.1"/>', "0 0 0.05", tags=tags
        ).replace("</link>", "")
        + "".join(
            f'<{tag}><origin xyz="0 0 0.08"/><geometry><box size="0.05 0.05 0.04"/></geometry>'
            f"</{tag}>"
            for tag in tags
        )
        + "</link>"
        + _link("boom", 4.0, cyl, "0.3 0 0", "0 1.5707963267948966 0", tags=tags)
        + _joint("yaw", "base", "mast", "0.2 0.2 0.3", "0 0 1")
        + _joint("turn", "base", "post", "-0.1 -0.2 0.3", "0 0 1")
        + _joint("swing", "post", "boom", "0 0 0.1", "0 1 0", limit=2.0)
        + "</robot>"
    )


@pytest.fixture(scope="module")
def toy():
    return FloatingRobot(toy_urdf(), ["yaw"], ["turn", "swing"])


@pytest.fixture(scope="module")
def captured(paper):
    """The paper robot holding a target whose box is turned in the end effector's frame."""
    turn = pin.rpy.rpyToMatrix(0.3, -0.5, 0.8)
    inertia = turn @ np.diag([2.0, 3.0, 4.0]) @ turn.T
    zero = np.zeros(3)
    return attach_target(paper, Target(5.0, 50.0, inertia, [0.3, 0.1, 0.0], zero, zero))


def test_geometry_source_pairs_and_errors(toy, baxter):
    geometry = RobotGeometry(toy)
    assert geometry.source == "collision"
    visual = FloatingRobot(toy_urdf(("visual",)), ["yaw"], ["turn", "swing"])
    assert RobotGeometry(visual).source == "visual"
    names = {frozenset(p.links) for p in geometry.pairs}
    # the boom is checked against the cube and the mast; the post is adjacent to both the cube
    # and the boom, its two objects one body
    assert names == {frozenset(p) for p in (("base", "boom"), ("mast", "post"), ("mast", "boom"))}
    assert geometry.ignored[("base", "post")] == "adjacent"
    ignored = RobotGeometry(toy, ignore=[["boom", "mast"]])
    assert ignored.ignored[("boom", "mast")] == "ignored"
    assert frozenset(("mast", "boom")) not in {frozenset(p.links) for p in ignored.pairs}
    with pytest.raises(InputError, match=r"ignore pair \['boom', 'nose'\].*no geometry on nose"):
        RobotGeometry(toy, ignore=[["boom", "nose"]])
    bax = RobotGeometry(baxter)
    assert bax.srdf is not None and bax.srdf.name == "baxter_manipulation.srdf"
    assert "srdf" in bax.ignored.values()


def _random_configurations(robot, n, seed):
    rng = np.random.default_rng(seed)
    low, high = np.maximum(robot.limits.lower, -np.pi), np.minimum(robot.limits.upper, np.pi)
    return rng.uniform(low, high, size=(n, robot.n))


@pytest.mark.parametrize("name", ["toy", "paper", "baxter", "captured"])
def test_symbolic_placements_match_pinocchio(name, request):
    robot = request.getfixturevalue(name)
    geometry = RobotGeometry(robot)
    q = cs.SX.sym("q", len(geometry.moving_joints))
    frames = shapes.joint_placements(SymbolicMaps(robot).joint_placements_fun(), q)
    joints = sorted(frames)
    f = cs.Function("frames", [q], [v for j in joints for v in frames[j]])
    E, e = robot.mimic_matrix
    data = robot.model.createData()
    for qk in _random_configurations(robot, 10, seed=3):
        values = f(E @ qk + e)
        pin.forwardKinematics(robot.model, data, robot.pin_q(qk))
        reference = data.oMi
        for k, j in enumerate(joints):
            np.testing.assert_allclose(np.array(values[2 * k]), reference[j].rotation, atol=1e-9)
            np.testing.assert_allclose(
                np.array(values[2 * k + 1]).ravel(), reference[j].translation, atol=1e-9
            )


@pytest.mark.parametrize("name", ["toy", "paper", "baxter", "captured"])
def test_fitted_shapes_never_farther_than_the_exact_geometry(name, request):
    """A fitted shape contains its body: its distance is at most coal's exact one (when the
    exact geometry is apart; inside each other, depths are not comparable)."""
    robot = request.getfixturevalue(name)
    geometry = RobotGeometry(robot)
    fitted = shapes.fit_shapes(geometry)
    of = {i: k for k, s in enumerate(fitted) for i in s.objects}
    q = cs.SX.sym("q", len(geometry.moving_joints))
    frames = shapes.joint_placements(SymbolicMaps(robot).joint_placements_fun(), q)
    pairs = [p for p in geometry.pairs if of[p.first] != of[p.second]]
    f = cs.Function(
        "d",
        [q],
        [
            cs.vertcat(
                *(
                    shapes.shape_distance(fitted[of[p.first]], fitted[of[p.second]], frames)
                    for p in pairs
                )
            )
        ],
    )
    E, e = robot.mimic_matrix
    close = 0
    for qk in _random_configurations(robot, 100, seed=11):
        fit = np.array(f(E @ qk + e)).ravel()
        exact = geometry.distances(qk, [p.index for p in pairs])
        assert np.all(fit <= np.maximum(exact, 0.0) + 1e-9), pairs[int(np.argmax(fit - exact))].name
        close += int(np.sum((exact > 0) & (exact - fit < 0.02)))
    assert close > 0  # some pairs come within 2 cm of their shapes: the fits are tight


def test_segment_distance_against_sampling():
    rng = np.random.default_rng(5)
    p = cs.SX.sym("p", 12)
    f = cs.Function("d", [p], [shapes.segment_distance(p[0:3], p[3:6], p[6:9], p[9:12])])
    s = np.linspace(0, 1, 401)
    for k in range(50):
        x = rng.normal(size=12)
        if k % 5 == 0:  # parallel segments, and a point
            x[9:12] = x[6:9] + (x[3:6] - x[0:3])
        if k % 7 == 0:
            x[3:6] = x[0:3]
        a = x[0:3] + s[:, None] * (x[3:6] - x[0:3])
        b = x[6:9] + s[:, None] * (x[9:12] - x[6:9])
        sampled = np.linalg.norm(a[:, None] - b[None], axis=2).min()
        assert float(f(x)) == pytest.approx(sampled, abs=1e-2 * np.linalg.norm(x) / 50 + 1e-6)
        assert float(f(x)) <= sampled + 1e-9


def test_clearance_finds_a_penetration_between_two_samples(toy):
    """The boom swept from level (0.07 m above the cube) on one side to nearly level on the
    other side, straight through the cube: both samples are clear, the motion is not."""
    geometry = RobotGeometry(toy)
    # the boom level forward, then nearly level backward: down through the cube in between
    q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi - 0.1]])
    at_samples = [geometry.distances(qk) for qk in q]
    assert min(d.min() for d in at_samples) > 0.0
    report = clearance(geometry, [0.0, 1.0], q)
    assert report.first_penetration is not None
    assert report.first_penetration.pair == "base / boom"
    assert 0.0 < report.first_penetration.time < 1.0
    assert report.min_distance < -0.05 and not report.collision_free
    data = report.to_dict()
    assert data["first_penetration"]["pair"] == "base / boom"
    assert data["geometry_source"] == "collision"
    # the same motion on a fine grid agrees with the smallest distance found
    t = np.linspace(0, 1, 2001)
    grid = np.stack([np.interp(t, [0, 1], q[:, j]) for j in range(3)], axis=1)
    pair = [p.name for p in geometry.pairs].index("base / boom")
    along = np.array([geometry.distances(qk)[pair] for qk in grid])
    exact = along.min()
    # it enters the cube where the fine grid first finds it inside
    assert report.first_penetration.time == pytest.approx(t[np.argmax(along <= 0)], abs=1e-3)
    assert report.first_penetration.depth == pytest.approx(-exact, abs=2e-3)
    assert report.pairs[pair].distance == pytest.approx(exact, abs=2e-3)
    assert report.pairs[pair].lower_bound <= exact + 1e-9


def test_clearance_of_a_clear_motion_is_certified(toy):
    geometry = RobotGeometry(toy)
    q = np.array([[0.0, 0.0, -0.2], [0.5, 0.3, -0.3], [1.0, 0.6, -0.1]])
    report = clearance(geometry, [0.0, 0.5, 1.0], q)
    assert report.first_penetration is None and report.collision_free
    for p in report.pairs:
        assert p.lower_bound <= p.distance
    boom = [p for p in report.pairs if p.pair == "base / boom"][0]
    assert 0.0 < boom.lower_bound < boom.distance < 0.1


def _pulled_into_the_cube(avoid: bool, caplog=None):
    """A plan whose rest pull (q_rest: the boom 1 rad down, inside the cube) drags the boom
    into the cube unless collision avoidance keeps it out."""
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import CostWeights, PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    robot = FloatingRobot(toy_urdf(), ["yaw"], ["turn", "swing"])
    model = PlannerModel(robot, compile=False, store=False)
    options = PlannerOptions(
        objective="integral",
        intervals=20,
        weights=CostWeights(rest=100.0),
        rest_configuration=(0.0, 1.0),
        end="free",
        collision_avoidance=avoid,
        collision_margin=0.02,
    )
    nlp = build_balance_nlp(model, PointToPoint([0.0], [0.6], 3.0), [0.0, 0.0], options)
    return nlp, nlp.solve("rest")


def test_planner_keeps_the_arm_out_of_the_base():
    nlp, free = _pulled_into_the_cube(avoid=False)
    geometry = RobotGeometry(nlp.robot)
    inside = clearance(geometry, free.t, np.hstack([free.q_M, free.q_B]))
    assert inside.min_distance < -0.05 and inside.closest.pair == "base / boom"
    nlp, safe = _pulled_into_the_cube(avoid=True)
    assert [b.name for b in nlp.structure.rows.blocks if b.name == "collision clearance"]
    report = clearance(geometry, safe.t, np.hstack([safe.q_M, safe.q_B]))
    assert report.min_distance >= 0.02 - 1e-5
    assert report.collision_free
    # the pull still acts: the boom rests on the margin, as far down as it may go
    assert report.min_distance < 0.03
    assert safe.q_B[-1, 1] > 0.05


def test_a_start_in_collision_is_refused_before_the_solve():
    """The boom 1 rad down starts 0.13 m inside the cube: a pair in contact only sometimes
    (neither in the reference pose nor nearly always), so the task's fault, not a pair to
    leave out of the plan."""
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal.collision import InitialCollisionError
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    robot = FloatingRobot(toy_urdf(), ["yaw"], ["turn", "swing"])
    model = PlannerModel(robot, compile=False, store=False)
    message = (
        r"^toy: the initial configuration is in collision: base / boom \(0\.1300 m deep\); "
        r"move it, or leave the pairs out \(robot\.srdf, optimal\.collision\.ignore\) if "
        r"the geometry overlaps there by design$"
    )
    with pytest.raises(InitialCollisionError, match=message) as caught:
        build_balance_nlp(
            model, PointToPoint([0.0], [0.6], 3.0), [0.0, 1.0], PlannerOptions(intervals=10)
        )
    assert caught.value.pairs == ["base / boom"]
    options = PlannerOptions(intervals=10, collision_ignore=(("base", "boom"),))
    nlp = build_balance_nlp(model, PointToPoint([0.0], [0.6], 3.0), [0.0, 1.0], options)
    assert "base / boom" not in {p.name for p in nlp.collision.pairs}
    bare = FloatingRobot(toy_urdf(tags=()), ["yaw"], ["turn", "swing"])
    with pytest.raises(InputError, match="has no <collision> or <visual> geometry"):
        RobotGeometry(bare)
    nlp = build_balance_nlp(
        PlannerModel(bare, compile=False, store=False),
        PointToPoint([0.0], [0.6], 3.0),
        [0.0, 0.0],
        PlannerOptions(intervals=10),
    )
    assert nlp.collision is None  # nothing to keep apart: the plan goes without
    off = build_balance_nlp(
        model,
        PointToPoint([0.0], [0.6], 3.0),
        [0.0, 0.0],
        PlannerOptions(intervals=10, collision_avoidance=False),
    )
    assert off.collision is None and off.structure.key.collision == ""


def _grid_clearance(geometry, result, step=1e-3):
    """The smallest exact distance of every checked pair on a ``step`` grid of the motion."""
    t = np.arange(0.0, result.t[-1] + 0.5 * step, step)
    q = np.hstack([result.q_M, result.q_B])
    grid = np.stack([np.interp(t, result.t, q[:, j]) for j in range(q.shape[1])], axis=1)
    return min(geometry.distances(qk).min() for qk in grid)


@pytest.mark.slow
def test_capture_task_plan_avoids_the_base_and_keeps_its_drift(capture):
    """The capture task's optimal plan without avoidance drives balance_link3 0.39 m into the
    base; with it (the default) every pair stays beyond the margin on a 1 ms grid, and the
    peak stays below 0.028 rad (restricting balance_joint2 to [0, 1.57] rad gives 0.0260)."""
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    model = PlannerModel(capture.robot)
    options = PlannerOptions()
    assert options.collision_avoidance and options.collision_margin == 0.03
    plan = build_balance_nlp(model, capture.mission, capture.q_B0, options).solve()
    geometry = RobotGeometry(capture.robot)
    assert _grid_clearance(geometry, plan) >= 0.03
    assert plan.max_drift <= 0.028
    assert plan.final_drift <= 1e-3
    assert plan.solver.checks.constraint_violations == ()


@pytest.mark.slow
def test_baxter_plan_is_collision_free():
    from balance_opt.app.pipeline import plan
    from balance_opt.tasks.task import load_task

    task = load_task("examples/baxter_floating.yaml")
    result = plan(task, "optimal")
    assert _grid_clearance(RobotGeometry(task.robot), result, step=5e-3) >= 0.03 - 1e-6


def _toy_task(tmp_path, balance, srdf=None):
    body = (
        "arms: {mission: [yaw], balance: [turn, swing]}\n"
        f"initial: {{balance: {list(balance)}}}\n"
        "mission: {type: ptp, start: [0.0], goal: [0.6], duration: 3.0}\n"
    )
    return urdf_task(tmp_path, "toy", toy_urdf(), body, srdf)


def test_geometry_summary_against_coal(toy):
    geometry = RobotGeometry(toy)
    q = np.array([0.0, 0.0, 1.0])  # the boom 1 rad down, inside the cube
    exact = dict(zip((p.name for p in geometry.pairs), geometry.distances(q)))
    s = geometry.summary(q, margin=0.05)
    assert (s["source"], s["srdf"], s["pairs_checked"]) == ("collision", None, 4)
    assert s["samples"] == 1000
    assert s["link_pairs_ignored"] == {
        "same body": 0, "adjacent": 3, "default": 0, "always": 0, "near": 0, "srdf": 0,
        "ignored": 0,
    }  # fmt: skip
    # coal's penetration depth (EPA, warm-started) varies in its last digits between calls
    [contact] = s["initial_contacts"]
    assert contact["pair"] == "base / boom"
    assert contact["distance_m"] == pytest.approx(exact["base / boom"], abs=1e-5)
    assert exact["base / boom"] < -0.1
    close = {n for n, d in exact.items() if 0.0 < d <= 0.05}
    assert {c["pair"] for c in s["initial_within_margin"]} == close
    level = geometry.summary(np.zeros(3), margin=0.08)  # the boom level, 0.07 m above the cube
    assert level["initial_contacts"] == []
    [near] = level["initial_within_margin"]
    assert near["pair"] == "base / boom" and near["distance_m"] == pytest.approx(0.07, abs=1e-6)


def test_inspect_says_what_is_checked_and_what_starts_in_contact(tmp_path, capsys):
    from balance_opt.cli import main

    (tmp_path / "toy.srdf").write_text(
        '<robot name="toy"><disable_collisions link1="mast" link2="boom" reason="Never"/></robot>'
    )
    task = _toy_task(tmp_path, [0.0, 1.0], srdf="toy.srdf")
    assert main(["inspect", str(task)]) == 0
    out = capsys.readouterr().out
    assert (
        "geometry from the URDF's <collision> elements: 3 pairs checked; link pairs left out: "
        "0 same body, 3 adjacent, 1 by the SRDF, 0 computed, 0 ignored by the task\n"
        f"  pairs left out by the SRDF {tmp_path / 'toy.srdf'}\n"
        "  in contact at the initial configuration: base / boom (-0."
    ) in out
    assert (
        "  (the task starts in collision: the optimal planner refuses it; move the initial "
        "configuration, or leave the pairs out with robot.srdf or optimal.collision.ignore)\n"
    ) in out
    # without robot.srdf, the SRDF named after the URDF beside it is found
    assert main(["inspect", str(_toy_task(tmp_path, [0.0, -0.5]))]) == 0
    assert f"  pairs left out by the SRDF {tmp_path / 'toy.srdf'}\n" in capsys.readouterr().out
    (tmp_path / "toy.srdf").unlink()
    assert main(["inspect", str(_toy_task(tmp_path, [0.0, -0.5]))]) == 0
    out = capsys.readouterr().out
    assert (
        "link pairs left out: 0 same body, 3 adjacent, 0 by the SRDF, 0 computed, 0 ignored by "
        "the task\n  pairs left out computed (no SRDF): 3 adjacent, 0 in the reference pose, 0 "
        "in nearly every sampled configuration, 0 one body apart and never more than 0.02 m "
        "apart (1000 samples)\n"
    ) in out
    assert "4 pairs checked" in out
    assert "  at the initial configuration every pair is at least 0.03 m apart\n" in out


def test_a_missing_srdf_is_an_error_at_its_key(tmp_path):
    from balance_opt.tasks.task import load_task

    with pytest.raises(
        InputError, match=r"toy\.yaml:4: robot\.srdf: no such SRDF file: .*nope\.srdf"
    ):
        load_task(_toy_task(tmp_path, [0.0, 0.0], srdf="nope.srdf"))


def test_metrics_say_what_is_checked_and_what_starts_in_contact(tmp_path):
    import json

    from balance_opt.cli import main

    task = _toy_task(tmp_path, [0.0, 1.0])
    out = tmp_path / "out"
    argv = ["plan", str(task), "-m", "mission-only", "-o", str(out), "-q"]
    assert main(argv) == 0
    geometry = json.loads((out / "metrics.json").read_text())["geometry"]
    assert geometry["source"] == "collision" and geometry["pairs_checked"] == 4
    assert geometry["srdf"] is None and geometry["margin_m"] == 0.03
    assert [c["pair"] for c in geometry["initial_contacts"]] == ["base / boom"]
    assert geometry["initial_contacts"][0]["distance_m"] < -0.1


def test_the_tasks_srdf_reaches_the_planner(tmp_path):
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.solve import build_balance_nlp
    from balance_opt.tasks.task import load_task

    srdf = tmp_path / "toy.srdf"
    srdf.write_text(
        '<robot name="toy"><disable_collisions link1="base" link2="boom" reason="x"/></robot>'
    )
    task = load_task(_toy_task(tmp_path, [0.0, 0.0], srdf="toy.srdf"))
    options = task.planner_options()
    assert options.collision_srdf == str(srdf.resolve())
    model = PlannerModel(task.robot, compile=False, store=False)
    nlp = build_balance_nlp(model, PointToPoint([0.0], [0.6], 3.0), [0.0, 0.0], options)
    assert nlp.collision.geometry.srdf == srdf.resolve()
    assert nlp.collision.geometry.ignored[("base", "boom")] == "srdf"
    assert "base / boom" not in {p.name for p in nlp.collision.pairs}


def test_a_mesh_next_to_the_urdf_is_found_after_a_capture(tmp_path):
    """The robot after a capture is built from URDF text: a mesh named relative to the URDF
    file must still load (its path made absolute), the target's box beside it."""
    (tmp_path / "meshes").mkdir()
    corners = ["0 0 0", "0.1 0 0", "0 0.1 0", "0 0 0.1"]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    stl = (
        "solid tip\n"
        + "".join(
            "facet normal 0 0 0\nouter loop\n"
            + "".join(f"vertex {corners[k]}\n" for k in face)
            + "endloop\nendfacet\n"
            for face in faces
        )
        + "endsolid tip\n"
    )
    (tmp_path / "meshes" / "tip.stl").write_text(stl)
    text = toy_urdf().replace(
        '<cylinder radius="0.03" length="0.3"/>', '<mesh filename="meshes/tip.stl"/>'
    )
    path = tmp_path / "toy.urdf"
    path.write_text(text)
    robot = FloatingRobot(path, ["yaw"], ["turn", "swing"])
    zero = np.zeros(3)
    after = attach_target(robot, Target(1.0, 2.0, np.eye(3) * 0.1, [0.1, 0, 0], zero, zero))
    names = {g.name.rsplit("_", 1)[0] for g in RobotGeometry(after).geometry_model.geometryObjects}
    assert {"mast", "capture_target"} <= names


def test_a_mesh_is_its_convex_hull_by_an_independent_computation():
    """Signed distances to a mesh are those of its vertices' convex hull, by scipy: a sphere
    centred inside the hull reads its depth below the nearest face (negative), one outside the
    distance to the hull found by a small QP (the hull's faces as linear constraints). The mesh's
    own ``buildConvexRepresentation`` kept every vertex, inner ones too, and read a sphere well
    inside the UR5 forearm's hull as 0.12 m away."""
    stl = example_urdf("ur5").parent.parent / "meshes" / "ur5" / "collision" / "forearm.stl"
    urdf = (
        '<robot name="meshy">'
        + _link("base", 50.0, '<box size="0.3 0.3 0.3"/>')
        + _link("fore", 2.0, f'<mesh filename="{stl}"/>', rpy="0.3 -0.2 0.5")
        + _link("post", 2.0, '<cylinder radius="0.03" length="0.3"/>', "0 0 0.15")
        + _joint("reach", "base", "fore", "0 0 0.4", "0 0 1")
        + _joint("swing", "base", "post", "0.5 0.5 0.2", "0 0 1")
        + "</robot>"
    )
    geometry = RobotGeometry(FloatingRobot(urdf, ["swing"], ["reach"]), srdf=False)
    objects = geometry.geometry_model.geometryObjects
    obj = next(o for o in objects if isinstance(o.geometry, coal.ConvexBase))
    vertices = np.asarray(coal.MeshLoader().load(str(stl), np.ones(3)).vertices())
    hull = ConvexHull(vertices)
    assert obj.geometry.num_points == len(hull.vertices) < len(vertices)
    A, b = hull.equations[:, :3], hull.equations[:, 3]  # inside: A x + b <= 0, |A_i| = 1
    radius = 0.01
    ball = coal.Sphere(radius)

    def coal_distance(p):
        return coal.distance(
            obj.geometry,
            coal.Transform3s(),
            ball,
            coal.Transform3s(np.eye(3), p),
            coal.DistanceRequest(),
            coal.DistanceResult(),
        )

    def qp_distance(p):
        start = vertices[hull.vertices].mean(axis=0)
        sol = minimize(
            lambda x: np.sum((x - p) ** 2),
            start,
            jac=lambda x: 2 * (x - p),
            method="SLSQP",
            constraints=[{"type": "ineq", "fun": lambda x: -(A @ x + b), "jac": lambda x: -A}],
            options={"ftol": 1e-14, "maxiter": 500},
        )
        assert sol.success
        return np.sqrt(sol.fun)

    rng = np.random.default_rng(3)
    points = rng.uniform(vertices.min(axis=0) - 0.1, vertices.max(axis=0) + 0.1, (300, 3))
    inside = Delaunay(vertices[hull.vertices]).find_simplex(points) >= 0
    assert 5 <= inside.sum() < len(points) - 5
    for p in points[inside]:
        assert coal_distance(p) == pytest.approx((A @ p + b).max() - radius, abs=1e-6)
    for p in points[~inside][:30]:
        assert coal_distance(p) == pytest.approx(qp_distance(p) - radius, abs=1e-6)


def test_first_contact_steps_over_samples_a_hair_apart():
    """Conservative advancement over a closed-loop flight's time grid, whose samples at a
    re-plan's switch lie 2e-13 s apart: the motion bound of that interval makes the speed so
    high that a step no longer moves the time. The search goes on past it (it stalled for
    100,000 rounds and returned the stall's time as the first contact)."""
    from balance_opt.geometry.clearance import _first_contact

    t = np.array([0.0, 1.0, 1.0 + 2e-13, 2.0])
    calls = []

    def apart(tau):  # 0.1 mm at the switch, 0.9 m/s from it: within the bound 1 m per interval
        calls.append(tau)
        return 1e-4 + 0.9 * abs(tau - 1.0)

    assert _first_contact(apart, t, lambda a, b: 1.0, until=1.2) == 1.2
    assert len(calls) < 50

    def closing(tau):  # ... then closing at 0.9 m/s from t = 1.25 until contact
        return max(apart(min(tau, 1.25)) - 0.9 * max(tau - 1.25, 0.0), 0.0)

    contact = 1.25 + apart(1.25) / 0.9
    assert contact - 2e-6 <= _first_contact(closing, t, lambda a, b: 1.0, until=2.0) <= contact
