"""Meshes found as users lay them out (issue 34): ``package://`` resolved through the task's
``robot.packages``, ``ROS_PACKAGE_PATH`` and the folders above the URDF, for the collision
geometry and the 3D scene alike; a mesh not found names every folder searched."""

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from balance_opt.errors import InputError
from balance_opt.geometry.robot_geometry import RobotGeometry
from balance_opt.model.library import example_urdf
from balance_opt.model.meshes import MeshNotFoundError, package_folders, resolve_mesh
from balance_opt.model.robot import FloatingRobot
from balance_opt.report.scene_meshes import visual_model
from balance_opt.tasks.task import load_task

PACKAGE = "meshy_description"
URI = f"package://{PACKAGE}/meshes/shoulder.stl"


def _urdf(mesh: str) -> str:
    """A box base with a one-joint mission arm whose link is ``mesh`` (collision and visual)
    and a one-joint balance arm (a cylinder)."""
    inertia = '<inertia ixx="0.05" iyy="0.05" izz="0.05" ixy="0" ixz="0" iyz="0"/>'

    def link(name, mass, shape):
        return (
            f'<link name="{name}"><inertial><mass value="{mass}"/>{inertia}</inertial>'
            f"<visual><geometry>{shape}</geometry></visual>"
            f"<collision><geometry>{shape}</geometry></collision></link>"
        )

    def joint(name, child, xyz):
        return (
            f'<joint name="{name}" type="revolute"><parent link="base"/><child link="{child}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="0 0 1"/>'
            '<limit lower="-3" upper="3" velocity="2" effort="50"/></joint>'
        )

    return (
        '<robot name="meshy">'
        + link("base", 50.0, '<box size="0.4 0.4 0.4"/>')
        + link("arm", 2.0, f'<mesh filename="{mesh}"/>')
        + link("post", 2.0, '<cylinder radius="0.03" length="0.3"/>')
        + joint("reach", "arm", "0.0 0.0 0.35")
        + joint("swing", "post", "0.3 0.3 0.35")
        + "</robot>"
    )


@pytest.fixture
def layout(tmp_path, monkeypatch):
    """A user's robot: ``work/robot/meshy.urdf`` naming ``package://meshy_description/...``,
    the package under ``work/pkgs/``, out of reach of the folders above the URDF; no
    ``ROS_PACKAGE_PATH``."""
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    stl = example_urdf("ur5").parent.parent / "meshes" / "ur5" / "collision" / "shoulder.stl"
    mesh = tmp_path / "work" / "pkgs" / PACKAGE / "meshes" / "shoulder.stl"
    mesh.parent.mkdir(parents=True)
    shutil.copy(stl, mesh)
    urdf = tmp_path / "work" / "robot" / "meshy.urdf"
    urdf.parent.mkdir()
    urdf.write_text(_urdf(URI))
    return urdf, mesh


def _task(urdf, packages=None):
    path = urdf.parent / "meshy.yaml"
    path.write_text(
        f"name: meshy\nrobot:\n  urdf: {urdf.name}\n"
        + (f"  packages: {packages}\n" if packages is not None else "")
        + "arms: {mission: [reach], balance: [swing]}\n"
        "mission: {type: ptp, start: [0.0], goal: [0.6], duration: 3.0}\n"
    )
    return path


def _meshes(model) -> list[str]:
    """The mesh files of a Pinocchio geometry model (primitives have a ``meshPath`` too)."""
    return [o.meshPath for o in model.geometryObjects if o.meshPath.endswith(".stl")]


def _distances_with_absolute_path(urdf, mesh, q):
    """The distances of the same robot whose URDF names the mesh by its absolute path."""
    robot = FloatingRobot(_urdf(str(mesh)), ["reach"], ["swing"])
    return RobotGeometry(robot).distances(q)


def test_a_missing_mesh_names_every_folder_searched(layout):
    urdf, _ = layout
    robot = FloatingRobot(urdf, ["reach"], ["swing"])
    folder = urdf.parent
    above = [folder, folder.parent, folder.parent.parent, folder.parent.parent.parent]
    expected = (
        f"{urdf}: link arm: mesh {URI} not found; folders searched: "
        + "; ".join(f"{p} (above the URDF)" for p in above)
        + f"; add the folder that holds {PACKAGE}/ to robot.packages in the task file "
        "(or to ROS_PACKAGE_PATH)"
    )
    with pytest.raises(MeshNotFoundError, match=f"^{re.escape(expected)}$") as caught:
        RobotGeometry(robot)
    assert [p for p, _ in caught.value.searched] == above
    # the 3D scene's visual geometry says the same, after the file it comes from
    with pytest.raises(
        InputError, match=f"^{re.escape(f'cannot load the visual geometry: {expected}')}$"
    ):
        visual_model(robot)
    # a URDF as text: no file to name; the link still
    text = FloatingRobot(_urdf(URI), ["reach"], ["swing"])
    with pytest.raises(MeshNotFoundError, match=f"^URDF text: link arm: mesh {URI} not found; "):
        RobotGeometry(text)


def test_the_folders_above_the_urdf_stop_before_the_root(monkeypatch):
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    folders = package_folders(PACKAGE, Path("/srv/robots/meshy.urdf"))
    assert folders == [(Path("/srv/robots"), "above the URDF"), (Path("/srv"), "above the URDF")]


def test_meshes_found_through_robot_packages(layout):
    urdf, mesh = layout
    task = load_task(_task(urdf, "[../pkgs]"))
    assert task.robot.packages == (mesh.parents[2],)
    geometry = RobotGeometry(task.robot)
    assert _meshes(geometry.geometry_model) == [str(mesh)]
    q = np.array([0.4, -0.2])
    assert geometry.distances(q) == pytest.approx(_distances_with_absolute_path(urdf, mesh, q))
    assert _meshes(visual_model(task.robot)) == [str(mesh)]
    # a folder named after the package is taken as the package itself
    named = load_task(_task(urdf, f"[../pkgs/{PACKAGE}]"))
    assert resolve_mesh(URI, urdf, named.robot.packages) == mesh


def test_meshes_found_through_ros_package_path_and_above_the_urdf(layout, monkeypatch):
    urdf, mesh = layout
    robot = FloatingRobot(urdf, ["reach"], ["swing"])
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"/nonexistent:{mesh.parents[2]}")
    geometry = RobotGeometry(robot)
    assert _meshes(geometry.geometry_model) == [str(mesh)]
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    # the URDF moved inside its package (PACKAGE/urdf/): found above it
    inside = mesh.parents[1] / "urdf" / "meshy.urdf"
    inside.parent.mkdir()
    shutil.copy(urdf, inside)
    assert resolve_mesh(URI, inside) == mesh
    # robot.packages comes first: a folder of its own wins over ROS_PACKAGE_PATH
    other = urdf.parent / "other" / PACKAGE / "meshes" / "shoulder.stl"
    other.parent.mkdir(parents=True)
    shutil.copy(mesh, other)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(mesh.parents[2]))
    assert resolve_mesh(URI, urdf, [other.parents[2]]) == other


def test_relative_meshes_and_the_packages_key(layout):
    urdf, mesh = layout
    relative = urdf.parent / "relative.urdf"
    relative.write_text(_urdf(f"../pkgs/{PACKAGE}/meshes/shoulder.stl"))
    geometry = RobotGeometry(FloatingRobot(relative, ["reach"], ["swing"]))
    assert _meshes(geometry.geometry_model) == [str(mesh)]
    relative.write_text(_urdf("meshes/none.stl"))
    with pytest.raises(
        MeshNotFoundError,
        match=re.escape(
            f"{relative}: link arm: mesh meshes/none.stl not found; folders searched: "
            f"{urdf.parent} (the URDF's "
            "folder); a mesh path without package:// is relative to the URDF file"
        ),
    ):
        RobotGeometry(FloatingRobot(relative, ["reach"], ["swing"]))
    with pytest.raises(
        InputError, match=r"meshy\.yaml:4: robot\.packages\[1\]: no such folder: .*/work/nope$"
    ):
        load_task(_task(urdf, "[../pkgs, ../nope]"))


def test_a_missing_mesh_is_found_before_planning_at_the_task_key(layout):
    """``validate`` and ``plan`` refuse a task whose collision meshes are nowhere before
    anything is computed, at the key that says where meshes are; the analytic law and a plan
    without avoidance need no mesh."""
    from balance_opt.tasks.task import check_methods

    urdf, _ = layout
    task = load_task(_task(urdf))
    check_methods(task, ("mission-only", "analytic"))
    searched = f"folders searched: {urdf.parent} (above the URDF); "
    with pytest.raises(
        InputError,
        match=re.escape(f"meshy.yaml:3: robot.urdf: {urdf}: link arm: mesh {URI} not found; ")
        + ".*"
        + re.escape(searched)
        + ".*; or plan without collision avoidance \\(optimal.collision.avoid: false\\)$",
    ):
        check_methods(task, ("optimal",))
    wrong = load_task(_task(urdf, "[.]"))
    with pytest.raises(InputError, match=r"^.*meshy\.yaml:4: robot\.packages: "):
        check_methods(wrong, ("optimal",))
    check_methods(load_task(_task(urdf, "[../pkgs]")), ("optimal",))


@pytest.mark.slow
def test_planning_with_a_missing_mesh_fails_naming_it_and_writes_nothing(layout, capsys):
    from balance_opt.cli import main

    urdf, _ = layout
    out = urdf.parent / "out"
    assert main(["plan", str(_task(urdf)), "--method", "optimal", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"balance-opt: error: {urdf.parent / 'meshy.yaml'}:3: robot.urdf: {urdf}: link arm: "
        f"mesh {URI} not found; folders searched: {urdf.parent} "
    )
    assert f"add the folder that holds {PACKAGE}/ to robot.packages in the task file" in err
    assert not out.exists()
    # the same task with the folder listed plans, avoidance on, and its scene shows the mesh
    assert main(["plan", str(_task(urdf, "[../pkgs]")), "--method", "optimal", "-o", str(out)]) == 0
    assert "3D scene not written" not in capsys.readouterr().err
    assert (out / "scene.html").is_file()


def _wrist_urdf(mesh: str) -> str:
    """A box base; a mission arm ``lift`` - ``pitch`` - ``roll``, three joints about one
    vertical axis, whose first link ``forearm`` and last link ``hand`` carry the same ``mesh``
    at that axis (``knuckle`` between them, a 0.02 m sphere 0.1 m out): the two meshes share
    the axis in every pose, as wrist meshes modelled around one joint do, and are not
    adjacent; a balance arm ``swing`` (a cylinder) beside it."""
    inertia = '<inertia ixx="0.05" iyy="0.05" izz="0.05" ixy="0" ixz="0" iyz="0"/>'

    def link(name, mass, shape, xyz="0 0 0"):
        geometry = f'<origin xyz="{xyz}"/><geometry>{shape}</geometry>'
        return (
            f'<link name="{name}"><inertial><mass value="{mass}"/>{inertia}</inertial>'
            f"<visual>{geometry}</visual><collision>{geometry}</collision></link>"
        )

    def joint(name, parent, child, xyz, axis):
        return (
            f'<joint name="{name}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{xyz}"/><axis xyz="{axis}"/>'
            '<limit lower="-3" upper="3" velocity="2" effort="50"/></joint>'
        )

    shape = f'<mesh filename="{mesh}"/>'
    return (
        '<robot name="wrist_meshes">'
        + link("base", 50.0, '<box size="0.4 0.4 0.4"/>')
        + link("forearm", 2.0, shape)
        + link("knuckle", 0.5, '<sphere radius="0.02"/>', "0.1 0 0")
        + link("hand", 1.0, shape)
        + link("post", 2.0, '<cylinder radius="0.03" length="0.3"/>')
        + joint("lift", "base", "forearm", "0 0 0.6", "0 0 1")
        + joint("pitch", "forearm", "knuckle", "0 0 0", "0 0 1")
        + joint("roll", "knuckle", "hand", "0 0 0", "0 0 1")
        + joint("swing", "base", "post", "0.5 0.5 0.35", "0 0 1")
        + "</robot>"
    )


def test_wrist_meshes_overlapping_in_every_pose_are_left_out_without_an_srdf(layout, tmp_path):
    """Two meshes of a user's arm (found through robot.packages, no SRDF) that overlap in
    every configuration: the computed pairs leave them out, the exact check of a plan then
    reports no collision, though the bare geometry has them in contact at every sample."""
    from balance_opt.cli import main
    from balance_opt.geometry import self_collision

    urdf, mesh = layout
    urdf.write_text(_wrist_urdf(URI))
    task = urdf.parent / "wrist.yaml"
    task.write_text(
        f"name: wrist_meshes\nrobot:\n  urdf: {urdf.name}\n  packages: [../pkgs]\n"
        "arms: {mission: [lift, pitch, roll], balance: [swing]}\n"
        "initial: {balance: [0.0]}\n"
        "mission: {type: ptp, start: [0.0, 0.0, 0.0], goal: [1.0, 1.5, -2.0], duration: 2.0}\n"
    )
    robot = load_task(task).robot
    bare = RobotGeometry(robot, disabled={})
    pairs = [p.index for p in bare.pairs if set(p.links) == {"forearm", "hand"}]
    assert pairs and all(
        str(mesh) == o.meshPath
        for o in bare.geometry_model.geometryObjects
        if o.name.startswith(("forearm", "hand"))
    )
    q = self_collision.sample_configurations(robot, 300, seed=11)
    assert (bare.smallest_along(q, pairs) < 0.0).all()  # in contact at every sample
    geometry = RobotGeometry(robot)
    assert geometry.srdf is None
    assert geometry.ignored[("forearm", "hand")] in ("default", "always")
    assert not any(set(p.links) == {"forearm", "hand"} for p in geometry.pairs)
    out = tmp_path / "out"
    assert main(["plan", str(task), "-m", "mission-only", "-o", str(out), "-q"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["geometry"]["srdf"] is None and metrics["geometry"]["initial_contacts"] == []
    assert metrics["methods"]["mission-only"]["clearance"]["collision_free"]


def test_example_robot_data_meshes_found_in_the_installed_package(tmp_path, monkeypatch):
    """``package://example-robot-data/...`` (a URDF copied out of it, as users do) resolves
    to the installed package's file, with no ROS_PACKAGE_PATH and nothing above the URDF."""
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    installed = example_urdf("ur5").parent.parent / "meshes" / "ur5" / "collision" / "wrist1.stl"
    uri = "package://example-robot-data/robots/ur_description/meshes/ur5/collision/wrist1.stl"
    found = resolve_mesh(uri, tmp_path / "robot" / "ur5.urdf")
    assert found.samefile(installed)


def test_a_missing_mesh_of_a_robot_with_keep_out_zones_is_located_at_the_task_key(layout):
    """Keep-out zones are checked against the robot's bodies when the task loads: a mesh found
    nowhere is then an error at the key that tells where meshes are, not a bare one."""
    urdf, _ = layout
    zone = "keep_out:\n  - {name: box, frame: base, box: {center: [0, 0, -1], size: [0.1, 0.1, 0.1]}}\n"

    def zoned(path):
        path.write_text(path.read_text() + zone)
        return path

    with pytest.raises(
        InputError,
        match=re.escape(f"meshy.yaml:3: robot.urdf: {urdf}: link arm: mesh {URI} not found; ")
        + ".*"
        + re.escape("(the keep-out zones need the robot's bodies)")
        + "$",
    ):
        load_task(zoned(_task(urdf)))
    assert len(load_task(zoned(_task(urdf, "[../pkgs]"))).spec.keep_out) == 1
