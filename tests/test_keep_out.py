"""Keep-out zones (issue 36): the task key's errors, the exact check of every plan, the
optimal planner keeping a zone clear (measured with coal apart from the package's geometry),
the mission arm's entry refused at load, and the cone's distance against coal."""

import re
from pathlib import Path

import casadi as cs
import coal
import numpy as np
import pinocchio as pin
import pytest

from balance_opt.config.yaml_lines import TaskFileError
from balance_opt.geometry import shapes
from balance_opt.geometry.keep_out import KeepOutZone, ZoneCone, zone_shape
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.model.symbolic import SymbolicMaps
from balance_opt.tasks.task import load_task

ROOT = Path(__file__).resolve().parents[1]
CAPTURE = (ROOT / "examples" / "capture_task.yaml").read_text()
#: The line of the first zone in a task written by :func:`_task`.
LINE = CAPTURE.count("\n") + 3


def _task(tmp_path, zones: str):
    """The capture task with the ``keep_out`` list ``zones`` (YAML lines), loaded."""
    path = tmp_path / "zones.yaml"
    path.write_text(CAPTURE + "\nkeep_out:\n" + zones)
    return load_task(path)


BOX = "box: {center: [0, 0, 2], size: [0.1, 0.1, 0.1]}"


@pytest.mark.parametrize(
    "zones, where, message",
    [
        (
            f"  - {{name: fov, frame: base_lnk, {BOX}}}\n",
            "keep_out[0].frame",
            (
                "paper_robot has no frame base_lnk; did you mean 'base_link', 'balance_link3', "
                "'balance_link2'?"
            ),
        ),
        (
            "  - {name: fov, frame: base_link, box: {center: [0, 0, 2], size: [0.1, 0, 0.1]}}\n",
            "keep_out[0].box.size[1]",
            "must be greater than 0 m, got 0",
        ),
        (
            f"  - {{name: fov, frame: base_link, arms: [balanse], {BOX}}}\n",
            "keep_out[0].arms[0]",
            "no arm balanse; the arms are mission, balance",
        ),
        (
            (
                f"  - {{name: fov, frame: base_link, {BOX}}}\n"
                f"  - {{name: fov, frame: base_link, {BOX}}}\n"
            ),
            "keep_out[1].name",
            "zone fov is named twice (also keep_out[0])",
        ),
        (
            "  - {name: fov, frame: base_link}\n",
            "keep_out[0]",
            "expected exactly one of box, cylinder, cone; got none",
        ),
        (
            (
                "  - {name: beam, frame: base_link, cone: {apex: [0, 0, 2], axis: [0, 0, 0], "
                "half_angle: 0.3, length: 1}}\n"
            ),
            "keep_out[0].cone.axis",
            "the axis must not be zero",
        ),
        (
            (
                "  - {name: beam, frame: base_link, cone: {apex: [0, 0, 2], axis: [0, 0, 1], "
                "half_angle: 1.6, length: 1}}\n"
            ),
            "keep_out[0].cone.half_angle",
            "must be below pi/2 rad, got 1.6",
        ),
        (
            (
                "  - {name: beam, frame: base_link, cylinder: {center: [0, 0, 2], axis: [0, 0, 1], "
                "radius: -0.1, length: 1}}\n"
            ),
            "keep_out[0].cylinder.radius",
            "must be greater than 0 m, got -0.1",
        ),
    ],
)
def test_zone_errors_name_the_file_line_and_key(tmp_path, zones, where, message):
    line = LINE + (1 if where.startswith("keep_out[1]") else 0)
    expected = f"{tmp_path / 'zones.yaml'}:{line}: {where}: {message}"
    with pytest.raises(TaskFileError, match=f"^{re.escape(expected)}$"):
        _task(tmp_path, zones)


def test_a_zone_the_mission_arm_enters_is_an_input_error(tmp_path):
    """The mission arm's link reaches a zone of every arm on the base: refused at load with the
    zone, its line, the link and the time; bound to the balance arm alone it loads."""
    zone = (
        "  - {name: dock, frame: base_link, box: {center: [0.4, 0.3, 1.4], size: [0.1, 0.1, 0.1]}"
    )
    expected = (
        f"{tmp_path / 'zones.yaml'}:{LINE}: keep_out[0]: zone dock: the mission arm's "
        "trajectory enters it: mission_link2 from t = 6.257 s, 0.0589 m deep at most; the "
        "planner cannot move the mission arm"
    )
    with pytest.raises(TaskFileError, match=f"^{re.escape(expected)}"):
        _task(tmp_path, zone + "}\n")
    task = _task(tmp_path, zone + ", arms: [balance]}\n")
    geometry = RobotGeometry(task.robot)
    zoned = [p.name for p in geometry.pairs if "keep_out:dock" in p.links]
    assert zoned == [f"balance_link{k} / keep_out:dock" for k in (1, 2, 3)]
    # the scene draws it on the base, translucent
    from balance_opt.report.scene_meshes import ZONE_OPACITY, scene_objects

    drawn = [o for o in scene_objects(task.robot, 1.0) if o.name == "keep_out:dock"]
    assert len(drawn) == 1 and drawn[0].joint == 1
    assert drawn[0].mesh.material.opacity == ZONE_OPACITY < 1
    np.testing.assert_allclose(drawn[0].placement.translation, [0.4, 0.3, 1.4])


def test_the_clearance_check_flags_a_mission_only_plan_through_a_zone(tmp_path):
    """A zone carried by the mission arm's yaw link sweeps through the resting balance arm:
    the run's clearance check (metrics, summary, report, figure) reports the zone's pair, as
    coal finds it apart from the package's geometry."""
    from balance_opt.app.pipeline import run_task

    task = _task(
        tmp_path,
        "  - {name: sweep, frame: mission_link1, arms: [balance], "
        "box: {center: [0, 0.5, 0.35], size: [0.4, 0.4, 0.4]}}\n",
    )
    run = run_task(task, methods=("mission-only",), robustness=False)
    report, _, _ = run.clearance["mission-only"]
    hit = report.first_penetration
    assert hit is not None and "keep_out:sweep" in hit.pair and hit.time > 0.5
    assert not report.collision_free
    # coal alone: the box on mission_link1's frame against balance_link1..3 at the same time
    res = run.results["mission-only"]
    k = int(np.searchsorted(res.t, hit.time + 0.05))
    q = np.r_[res.q_M[k], res.q_B[k]]
    assert _coal_distance(task, q, "mission_link1", "sweep") < 0.0
    assert _coal_distance(task, np.r_[res.q_M[0], res.q_B[0]], "mission_link1", "sweep") > 0.0


def _coal_distance(task, q, frame: str, zone_name: str) -> float:
    """The smallest distance of a task's zone and the balance arm's links by Pinocchio's
    URDF geometry and coal (the zone's placement computed here from its frame)."""
    robot = task.robot
    zone = next(z for z in task.spec.keep_out if z.name == zone_name)
    model = robot.model
    data = model.createData()
    geom = pin.buildGeomFromUrdfString(model, robot.locked_urdf, pin.COLLISION)
    gdata = pin.GeometryData(geom)
    pin.framesForwardKinematics(model, data, robot.pin_q(q))
    pin.updateGeometryPlacements(model, data, geom, gdata)
    box = coal.Box(*zone.box.size)
    M = data.oMf[model.getFrameId(frame)]
    centre = M.act(np.asarray(zone.box.center))
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    out = np.inf
    for k, obj in enumerate(geom.geometryObjects):
        if model.frames[obj.parentFrame].name.startswith("balance_"):
            result.clear()
            G = gdata.oMg[k]
            out = min(
                out,
                coal.distance(
                    obj.geometry,
                    coal.Transform3s(G.rotation, G.translation),
                    box,
                    coal.Transform3s(M.rotation, centre),
                    request,
                    result,
                ),
            )
    return out


@pytest.mark.slow
def test_the_optimal_plan_keeps_the_star_tracker_box_clear():
    """examples/capture_keep_out.yaml: capture_task's plan passes 0.19 m inside the box; with
    the zone every 1 ms sample of the plan keeps the balance arm at least the margin (less
    1 mm) from it, measured with coal apart from the package's geometry."""
    from balance_opt.app.pipeline import plan

    task = load_task(ROOT / "examples" / "capture_keep_out.yaml")
    result = plan(task, "optimal")
    t = np.arange(0.0, result.t[-1], 1e-3)
    q = np.hstack([result.q_M, result.q_B])
    grid = np.stack([np.interp(t, result.t, q[:, j]) for j in range(q.shape[1])], axis=1)
    smallest = min(_coal_distance(task, qk, "base_link", "star_tracker_fov") for qk in grid)
    assert smallest >= 0.03 - 1e-3
    assert result.max_drift <= 0.03


def _random_points(centre, n, seed=0):
    return centre + np.random.default_rng(seed).normal(size=(n, 3))


def test_cone_distance_is_coal_s():
    """The planner's signed distance from a cone, at points outside and inside it, is coal's
    (to its GJK/EPA tolerance)."""
    zone = KeepOutZone(
        name="beam",
        frame="base_link",
        cone=ZoneCone(apex=(0.1, -0.2, 0.3), axis=(0.3, 0.5, -0.8), half_angle=0.4, length=1.5),
    )
    shape, R, p = zone_shape(zone)
    axis = np.array(zone.cone.axis) / np.linalg.norm(zone.cone.axis)
    apex = np.array(zone.cone.apex)
    x = cs.SX.sym("x", 3)
    radius = zone.cone.length * np.tan(zone.cone.half_angle)
    f = cs.Function(
        "d", [x], [shapes.cone_distance(x, cs.DM(apex), cs.DM(apex + 1.5 * axis), radius)]
    )
    point = coal.Sphere(1e-9)
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    inside = 0
    for x in _random_points(p, 1000):
        result.clear()
        exact = coal.distance(
            shape, coal.Transform3s(R, p), point, coal.Transform3s(np.eye(3), x), request, result
        )
        inside += exact < 0
        assert float(f(x)) == pytest.approx(exact, abs=1e-5)
    assert inside > 10


def test_fitted_distances_to_a_cone_never_exceed_coal_s(capture):
    """A cone zone on the base: the planner's fitted capsule-to-cone distances, placed by its
    symbolic kinematics, are at most the exact distances (coal) at random configurations (when
    apart: inside each other, depths are not comparable), and within 2 cm of them often."""
    robot = capture.robot
    robot.keep_out = (
        KeepOutZone(
            name="beam",
            frame="base_link",
            cone=ZoneCone(
                apex=(-0.25, 0.0, 0.6), axis=(-1.0, 0.3, 1.0), half_angle=0.35, length=1.0
            ),
            arms=("balance",),
        ),
    )
    try:
        geometry = RobotGeometry(robot)
    finally:
        robot.keep_out = ()
    pairs = [p for p in geometry.pairs if "keep_out:beam" in p.links]
    moved = shapes.moved_by(geometry, [robot.joint_names[i] for i in robot.balance_indices])
    rows = shapes.clearance_rows(geometry, pairs, moved)
    assert [label for label, _ in rows.rows] == [
        f"balance_link{k} / keep_out:beam clearance" for k in (1, 2, 3)
    ]
    shape_pairs, distances = rows.pair_distances(SymbolicMaps(robot).joint_placements_fun())
    assert {rows.shapes[k].kind for _, k in shape_pairs} == {"cone"}
    E, e = robot.mimic_matrix
    rng = np.random.default_rng(1)
    lo, hi = robot.limits.lower, robot.limits.upper
    close = 0
    for _ in range(200):
        q = rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3))
        fitted = np.array(distances(E @ q + e)).ravel()
        exact = geometry.distances(q, [p.index for p in pairs])
        assert np.all(fitted <= np.maximum(exact, 0.0) + 1e-6)
        close += int(np.sum((exact > 0) & (exact - fitted < 0.02)))
    assert close > 10


def test_the_scene_draws_a_cone_with_its_apex_where_the_zone_has_it():
    """meshcat's cone and coal's point opposite ways: the drawn cone's point (the meshcat
    cylinder's end of radius 0) lands on the zone's apex, its wide end one length down the
    axis."""
    from pinocchio.visualize.meshcat_visualizer import loadPrimitive

    from balance_opt.geometry.keep_out import zone_object
    from balance_opt.model.library import paper_robot
    from balance_opt.report.scene_meshes import scene_objects

    zone = KeepOutZone(
        name="beam",
        frame="base_link",
        cone=ZoneCone(apex=(0.1, -0.2, 0.3), axis=(0.3, 0.5, -0.8), half_angle=0.4, length=1.5),
    )
    robot = paper_robot()
    robot.keep_out = (zone,)
    (drawn,) = [o for o in scene_objects(robot, 1.0) if o.name == "keep_out:beam"]
    cylinder = loadPrimitive(zone_object(zone, robot.model))
    assert cylinder.radiusBottom == 0  # three.js: the bottom end is at -y, the top at +y
    to_zone = drawn.placement.homogeneous @ cylinder.intrinsic_transform()
    half = cylinder.height / 2
    axis = np.array(zone.cone.axis) / np.linalg.norm(zone.cone.axis)
    np.testing.assert_allclose((to_zone @ [0, -half, 0, 1])[:3], zone.cone.apex, atol=1e-12)
    np.testing.assert_allclose(
        (to_zone @ [0, half, 0, 1])[:3], np.array(zone.cone.apex) + 1.5 * axis, atol=1e-12
    )
