"""The 3D scene (balance_opt/report/scene.py) and ``balance-opt view``: every link with geometry is
in the scene at the placement numeric Pinocchio gives at the plan's samples, the centre of mass
on its free-flight line (across a capture too), the packed animation holds those placements,
meshes are simplified, the page loads nothing from outside, and the view command opens it."""

import base64
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import umsgpack

from balance_opt.cli import main
from balance_opt.model.capture import Target
from balance_opt.motion.result import BalanceResult
from balance_opt.motion.so3 import (
    matrix_from_quaternion,
    quaternion_from_rotvec,
    relative_rotation,
    rotvec_from_quaternion,
)
from balance_opt.report.outputs import write_trajectory_npz
from balance_opt.report.scene import (
    ARM_COLOURS,
    BASE_COLOUR,
    NEAR_COLOUR,
    TOUCH_COLOUR,
    build_scene,
    scene_html,
    write_scene,
)
from balance_opt.report.scene_meshes import cluster_vertices, visual_model

ROOT = Path(__file__).resolve().parents[1]
ATOL = 1e-9
#: The animation is packed as float32: positions [m] and quaternions to about this.
FLOAT32 = 2e-6
H0 = np.array([0.6, -0.3, 0.2, 0.0, 0.0, 0.0])  # linear momentum [N s], none angular


def _result(robot, seed=0, samples=41, duration=2.0, method="test"):
    """A random smooth motion of every arm joint with a random attitude history."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration, samples)
    a, w = rng.uniform(-0.5, 0.5, robot.n), rng.uniform(0.5, 2.0, robot.n)
    q = robot.neutral() + a * np.sin(np.outer(t, w))
    q_dot = a * w * np.cos(np.outer(t, w))
    phi = np.outer(t, rng.uniform(-0.05, 0.05, 3))
    M, B = robot.mission_indices, robot.balance_indices
    zeros = np.zeros_like(q)
    return BalanceResult(
        method=method, t=t, mission_joints=tuple(robot.joint_names[i] for i in M),
        balance_joints=tuple(robot.joint_names[i] for i in B),
        q_M=q[:, M], q_dot_M=q_dot[:, M], q_ddot_M=zeros[:, M],
        q_B=q[:, B], q_dot_B=q_dot[:, B], q_ddot_B=zeros[:, B],
        quaternion=quaternion_from_rotvec(phi), omega=np.zeros((samples, 3)),
        momentum_residual=np.zeros(samples), sigma_min=np.ones(samples), info={},
    )  # fmt: skip


def _pin_q(robot, res, k, base: pin.SE3) -> np.ndarray:
    """Pinocchio's configuration of sample ``k`` built by joint name (not through the robot's
    own conversion), the base at ``base``."""
    model = robot.model
    q = pin.neutral(model)
    q[:7] = pin.SE3ToXYZQUAT(base)
    names = (*res.mission_joints, *res.balance_joints)
    values = np.r_[res.q_M[k], res.q_B[k]]
    for name, value in zip(names, values):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:
            q[joint.idx_q : joint.idx_q + 2] = [np.cos(value), np.sin(value)]
        else:
            q[joint.idx_q] = value
    return q


def _unpack(blob: str) -> dict:
    return umsgpack.unpackb(base64.b64decode(blob))


def _floats(ext) -> np.ndarray:
    assert ext.type == 0x17  # the viewer's code for a Float32Array
    return np.frombuffer(ext.data, dtype="<f4")


@pytest.fixture(scope="module")
def paper_scene(paper):
    res = _result(paper, 1)
    return res, build_scene(paper, {"test": res}, H0, fps=10)


# ------------------------------------------------------------------------------------- geometry
def test_every_link_with_geometry_is_in_the_scene_coloured_by_arm(paper, paper_scene):
    _, scene = paper_scene
    gmodel = visual_model(paper)
    assert [o.name for o in scene.objects] == [g.name for g in gmodel.geometryObjects]
    assert len(scene.objects) == 7  # the base box and three links per arm (urdf/paper_robot.urdf)
    colours = {}
    for o in scene.objects:
        colours.setdefault(o.name.split("_")[0], set()).add(o.mesh.material.color)
    assert colours == {
        "base": {int(BASE_COLOUR[1:], 16)},
        "mission": {int(ARM_COLOURS[0][1:], 16)},
        "balance": {int(ARM_COLOURS[1][1:], 16)},
    }


def test_links_sit_where_pinocchio_puts_them(paper, paper_scene):
    """At sample times, each geometry's world placement (its joint node's animated placement
    times its fixed placement) is Pinocchio's ``updateGeometryPlacements`` at the plan's joint
    values and attitude, and the centre of mass is on its free-flight line."""
    res, scene = paper_scene
    pose = scene.poses["test|1"]
    model, data = paper.model, paper.model.createData()
    gmodel = visual_model(paper)
    gdata = gmodel.createData()
    node = {j: k for k, j in enumerate(scene.nodes)}
    assert set(scene.nodes) == {o.joint for o in scene.objects}
    com0 = None
    for i in (0, 7, len(pose["t"]) - 1):
        k = pose["index"][i]
        assert pose["t"][i] == res.t[k]
        R = matrix_from_quaternion(res.quaternion[k])
        np.testing.assert_allclose(pose["base"][i][:3, :3], R, rtol=0, atol=ATOL)
        q = _pin_q(paper, res, k, pin.SE3(pose["base"][i]))
        pin.updateGeometryPlacements(model, data, gmodel, gdata, q)
        for o, expected in zip(scene.objects, gdata.oMg):
            placed = pose["joints"][i][node[o.joint]] @ o.placement.homogeneous
            np.testing.assert_allclose(placed, expected.homogeneous, rtol=0, atol=ATOL)
        com = pin.centerOfMass(model, data, q)
        com0 = com if com0 is None else com0
        line = com0 + (res.t[k] - res.t[0]) * H0[:3] / paper.total_mass
        np.testing.assert_allclose(com, line, rtol=0, atol=ATOL)
    np.testing.assert_allclose(pose["base"][0][:3, 3], 0.0, rtol=0, atol=ATOL)  # base starts at 0


def test_the_packed_animation_holds_the_placements(paper, paper_scene):
    _, scene = paper_scene
    command = _unpack(scene.animations["test|1"])
    assert command["type"] == "set_animation" and command["options"]["play"] is False
    clips = {a["path"]: a["clip"] for a in command["animations"]}
    assert set(clips) == {"/meshcat/robot/base", *(f"/meshcat/robot/{j}" for j in (
        "mission_joint1", "mission_joint2", "mission_joint3",
        "balance_joint1", "balance_joint2", "balance_joint3"))}  # fmt: skip
    pose = scene.poses["test|1"]
    for k, j in enumerate(scene.nodes):
        name = "base" if j == 1 else paper.model.names[j]
        position, quaternion = clips[f"/meshcat/robot/{name}"]["tracks"]
        np.testing.assert_allclose(_floats(position["times"]), pose["t"], rtol=0, atol=FLOAT32)
        placed = _floats(position["values"]).reshape(-1, 3)
        np.testing.assert_allclose(placed, pose["joints"][:, k, :3, 3], rtol=0, atol=FLOAT32)
        xyzw = _floats(quaternion["values"]).reshape(-1, 4)
        R = np.array([pin.Quaternion(x.astype(float)).matrix() for x in xyzw])  # x, y, z, w
        np.testing.assert_allclose(R, pose["joints"][:, k, :3, :3], rtol=0, atol=10 * FLOAT32)
    # each piece of geometry is placed once, at its fixed placement in its joint's frame
    setup = [_unpack(b) for b in scene.setup]
    objects = [c for c in setup if c["type"] == "set_object" and "/meshcat/robot/" in c["path"]]
    assert len(objects) == len(scene.objects) + 1  # and the base's axes


def test_a_magnified_rotation_is_the_plan_s_rotation_scaled(paper, paper_scene):
    res, scene = paper_scene
    (factor,) = (f for f in scene.meta["factors"] if f != 1)
    assert factor > 1
    pose = scene.poses[f"test|{factor:g}"]
    q = res.quaternion[pose["index"]]
    planned = rotvec_from_quaternion(relative_rotation(q[:1], q))
    R0 = matrix_from_quaternion(q[0])
    for R, phi in zip(pose["base"][:, :3, :3], planned):
        shown = pin.log3(R0.T @ R)
        np.testing.assert_allclose(shown, factor * phi, rtol=0, atol=1e-9)


def test_the_target_flies_free_then_rides_the_end_effector(paper):
    """Before the capture the target moves at its own constant velocities; after it, it sits at
    its CoM offset in the mission end-effector frame and the CoM of robot and target moves with
    the momentum of both."""
    target = Target(
        time=1.0, mass=50.0, inertia=[2.083, 0, 0, 2.083, 0, 2.083], com=[0.25, 0, 0],
        linear_velocity=[-0.15, 0.13, 0.0], angular_velocity=[0.03, -0.05, 0.06],
    )  # fmt: skip
    res = _result(paper, 2, samples=81)
    scene = build_scene(paper, {"test": res}, H0, target, fps=20)
    pose = scene.poses["test|1"]
    t, T = pose["t"], pose["target"]
    before, after = np.flatnonzero(t < 1.0), np.flatnonzero(t >= 1.0)
    assert before.size > 3 and after.size > 3
    for i in before:
        dt = t[i] - t[after[0]]
        np.testing.assert_allclose(
            T[i, :3, 3], T[after[0], :3, 3] + dt * target.linear_velocity, rtol=0, atol=ATOL
        )
        turned = T[i, :3, :3] @ T[after[0], :3, :3].T
        np.testing.assert_allclose(pin.log3(turned), dt * target.angular_velocity, atol=1e-9)
    model, data = paper.model, paper.model.createData()
    ee = model.getFrameId(paper.mission.ee_frame)
    total = paper.total_mass + target.mass
    coms = []
    for i in after:
        q = _pin_q(paper, res, pose["index"][i], pin.SE3(pose["base"][i]))
        pin.framesForwardKinematics(model, data, q)
        expected = data.oMf[ee] * pin.SE3(np.eye(3), target.com)
        np.testing.assert_allclose(T[i], expected.homogeneous, rtol=0, atol=ATOL)
        c = pin.centerOfMass(model, data, q)
        coms.append((paper.total_mass * c + target.mass * expected.translation) / total)
    velocity = (H0[:3] + target.mass * target.linear_velocity) / total
    np.testing.assert_allclose(
        np.diff(coms, axis=0), np.outer(np.diff(t[after]), velocity), rtol=0, atol=ATOL
    )
    sides, axes = target.box()
    np.testing.assert_allclose(sides, 0.5, rtol=1e-3)  # the 0.5 m cube of its inertia
    assert np.linalg.det(axes) == pytest.approx(1.0)


def test_vertex_clustering_keeps_the_shape_and_drops_collapsed_triangles():
    # a finely meshed unit square (two triangles per cell)
    n = 40
    xs = np.linspace(0.0, 1.0, n + 1)
    vertices = np.array([[x, y, 0.0] for y in xs for x in xs])
    faces = []
    for r in range(n):
        for c in range(n):
            a = r * (n + 1) + c
            faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    v, f = cluster_vertices(vertices, np.array(faces), 0.1)
    assert len(v) < len(vertices) / 10 and len(f) < len(faces) / 10
    assert f.min() == 0 and f.max() == len(v) - 1  # no vertex unused, none missing
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    assert len(np.unique(f, axis=0)) == len(f)
    # still the square: its corners within a cell, the area nearly all there, normals up
    np.testing.assert_allclose(v.min(axis=0)[:2], 0.0, atol=0.1)
    np.testing.assert_allclose(v.max(axis=0)[:2], 1.0, atol=0.1)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(cross[:, 2] > 0)
    assert 0.5 * cross[:, 2].sum() == pytest.approx(1.0, rel=0.25)


# ------------------------------------------------------------------------------------------ page
#: Anything that would load a resource from elsewhere: an http(s) address in a src or href
#: attribute, a CSS url() or @import, a JavaScript import, a <link> or a <script src>.
EXTERNAL = re.compile(
    r"""(?:src|href)\s*=\s*["']?\s*(?:https?:)?//|url\(\s*["']?\s*(?:https?:)?//"""
    r"""|@import|\bimport\s*\(\s*["'](?:https?:)?//|<link\b|<script[^>]*\bsrc\s*=""",
    re.IGNORECASE,
)


def test_the_external_resource_pattern_catches_what_it_should():
    for bad in (
        '<script src="https://cdn.example/three.js">',
        "<img src=http://x/y.png>",
        '<a href="//host/page">',
        '<link rel="stylesheet" href="s.css">',
        "body { background: url('https://x/y.png') }",
        "@import 'x.css';",
        'import("https://esm.sh/three")',
    ):
        assert EXTERNAL.search(bad), bad
    assert not EXTERNAL.search('document.createElementNS("http://www.w3.org/1999/xhtml", "a")')


def test_the_page_is_self_contained(paper, paper_scene, tmp_path):
    res, _ = paper_scene
    scene = build_scene(paper, {"mission-only": res, "optimal": res}, H0)
    path = write_scene(tmp_path / "scene.html", scene, title="t")
    text = path.read_text()
    assert EXTERNAL.search(text) is None
    assert "MeshCat.Viewer" in text and text.count("<script>") == 2  # the bundle, the player
    assert '<option value="mission-only">mission arm alone</option>' in text
    assert '<option value="optimal">optimal plan</option>' in text
    assert '<input id="scene-t" type="range"' in text
    data = json.loads(re.search(r"const S = (\{.*?\});\n", text).group(1))
    assert set(data["animations"]) == {f"{m}|{f:g}" for m in ("mission-only", "optimal")
                                       for f in data["factors"]}  # fmt: skip
    assert path.stat().st_size < 3e6


def _headless(url: str) -> subprocess.CompletedProcess:
    """The page at ``url`` after 3 s of headless Chromium's virtual time, as its DOM."""
    return subprocess.run(
        ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=3000",
         "--dump-dom", url],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium is not installed")
def test_the_page_runs_in_a_browser(paper, paper_scene, tmp_path):
    """Headless Chromium opens the page from disk (offline), the viewer starts, the player
    shows the time and the base rotation of the plan and time asked for in the URL, and plays."""
    res, scene = paper_scene
    path = tmp_path / "scene.html"
    path.write_text(scene_html(scene))
    proc = _headless(f"{path.as_uri()}#method=test&t=1.2")
    label = re.search(r'<span id="scene-label">([^<]*)</span>', proc.stdout)
    assert label, proc.stderr[-2000:]
    angle = scene.meta["methods"]["test"]["angle"][12]  # the sample at 1.2 s
    assert scene.meta["methods"]["test"]["angle_t"][12] == 1.2
    text = f"t = 1.20 s of 2.00 s; base rotation from the start {angle:.3g} rad"
    assert label.group(1).startswith(text)
    assert "<canvas" in proc.stdout  # the viewer's WebGL canvas
    # "play" runs the viewer's player: the time shown moves on from where it started
    proc = _headless(f"{path.as_uri()}#method=test&t=1.2&play")
    shown = re.search(r'<span id="scene-label">t = ([0-9.]+) s of 2.00 s', proc.stdout)
    assert shown and 1.2 < float(shown.group(1)) <= 2.0, proc.stdout[-500:]


@pytest.mark.slow
def test_baxter_meshes_are_in_the_scene_simplified(baxter, tmp_path):
    res = _result(baxter, 3, samples=11, duration=1.0)
    path = write_scene(tmp_path / "scene.html", build_scene(baxter, {"test": res}))
    gmodel = visual_model(baxter)
    text = path.read_text()
    setup = json.loads(re.search(r"const S = (\{.*?\});\n", text).group(1))["setup"]
    placed = {_unpack(b)["path"].rsplit("/", 1)[-1] for b in setup}
    assert {g.name for g in gmodel.geometryObjects} <= placed
    meshes = [g for g in gmodel.geometryObjects if g.meshPath.lower().endswith(".dae")]
    full = sum(g.geometry.num_vertices for g in meshes)
    kept, sent = 0, 0
    for command in map(_unpack, setup):
        if command["type"] != "set_object" or command["object"]["object"]["type"] != "Mesh":
            continue  # (the base's axes are lines)
        geometry = command["object"]["geometries"][0]
        if geometry["type"] == "BufferGeometry":
            kept += len(_floats(geometry["data"]["attributes"]["position"]["array"])) // 3
            sent += 1
    assert 0 < kept < full / 3
    # a mesh that both arms carry (the same file) is sent once, the other link points to it
    page = json.loads(re.search(r"const S = (\{.*?\});\n", text).group(1))
    mesh_of = {g.name: g.meshPath for g in meshes}
    pairs = [(a.rsplit("/", 1)[-1], b.rsplit("/", 1)[-1]) for a, b in page["shared"]]
    assert pairs and all(mesh_of[a] == mesh_of[b] and a != b for a, b in pairs)
    assert sent == len(set(mesh_of.values())) and page["vertices"] == kept  # each file once
    assert EXTERNAL.search(text) is None and path.stat().st_size < 15e6


# ------------------------------------------------------------------------------------------- CLI
def _browser(monkeypatch, found: bool = True) -> list[str]:
    """The URLs ``balance-opt view`` hands to the browser (``found``: whether one opens)."""
    import webbrowser

    opened = []

    def open_url(url, new=0):
        opened.append(url)
        return found

    monkeypatch.setattr(webbrowser, "open", open_url)
    return opened


def test_view_opens_a_scene_built_from_a_result_folder(paper, monkeypatch, tmp_path, capsys):
    res = _result(paper, 4)
    folder = tmp_path / "run"
    folder.mkdir()
    write_trajectory_npz(folder / "analytic.npz", res)
    task = ROOT / "examples" / "capture_task.yaml"
    (folder / "metrics.json").write_text(json.dumps({"task": {"file": str(task)}}))
    opened = _browser(monkeypatch)
    assert main(["view", str(folder)]) == 0
    page = Path(capsys.readouterr().out.strip())
    assert opened == [page.as_uri()] and page.name == "scene.html"
    text = page.read_text()  # there after the command: no server to stop
    assert "MeshCat.Viewer" in text and '<option value="analytic">analytic law</option>' in text
    assert EXTERNAL.search(text) is None
    assert not (folder / "scene.html").exists()  # the result folder is left as it was
    shutil.rmtree(page.parent)


def test_view_opens_the_scene_a_run_wrote(monkeypatch, tmp_path, capsys):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "scene.html").write_text("<!DOCTYPE html><title>written by the run</title>")
    opened = _browser(monkeypatch)
    assert main(["view", str(folder)]) == 0
    page = (folder / "scene.html").resolve()
    assert capsys.readouterr().out == f"{page}\n" and opened == [page.as_uri()]


def test_view_without_a_browser_prints_the_path(monkeypatch, tmp_path, capsys, caplog):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "scene.html").write_text("<!DOCTYPE html><title>written by the run</title>")
    page = (folder / "scene.html").resolve()
    opened = _browser(monkeypatch, found=False)
    assert main(["view", str(folder)]) == 0
    assert capsys.readouterr().out == f"{page}\n" and "no browser found" in caplog.text
    assert main(["view", str(folder), "--no-browser"]) == 0
    assert capsys.readouterr().out == f"{page}\n" and len(opened) == 1  # not asked again


def test_view_of_a_folder_that_is_no_result_is_exit_2(tmp_path, capsys, monkeypatch):
    import tempfile

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    assert main(["view", str(tmp_path), "--no-browser"]) == 2
    assert "no scene.html and no metrics.json: not a result folder" in capsys.readouterr().err
    assert not any(scratch.iterdir())  # no folder left for a page never written


def _paper_task(tmp_path: Path, urdf_text: str | None = None) -> Path:
    """A short version of examples/capture_task.yaml, analytic only, on its own URDF copy."""
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(urdf_text or (ROOT / "urdf" / "paper_robot.urdf").read_text())
    text = (ROOT / "examples" / "capture_task.yaml").read_text()
    text = text.replace("shipped: paper_robot.urdf", f"urdf: {urdf}")
    text = text.replace("goal: [1.2, 0.9, -1.6]", "goal: [0.6, 0.6, -1.1]")
    text = text.replace("duration: 10.0", "duration: 3.0")
    task = tmp_path / "task.yaml"
    task.write_text(text)
    return task


def test_a_run_writes_the_scene_and_its_report_frames_it(tmp_path):
    out = tmp_path / "out"
    assert main(["plan", str(_paper_task(tmp_path)), "-m", "analytic", "-o", str(out), "-q"]) == 0
    report = (out / "report.html").read_text()
    assert '<iframe src="scene.html"' in report and EXTERNAL.search(report) is None
    scene = (out / "scene.html").read_text()
    assert '<option value="analytic">analytic law</option>' in scene


def test_a_missing_mesh_leaves_the_scene_out_not_the_run(tmp_path, caplog):
    urdf = (ROOT / "urdf" / "paper_robot.urdf").read_text()
    urdf = urdf.replace(
        '<geometry><box size="1.0 1.0 1.0"/></geometry>',
        '<geometry><mesh filename="package://no_such_package/base.stl"/></geometry>',
    )
    out = tmp_path / "out"
    task = _paper_task(tmp_path, urdf)
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out)]) == 0
    assert "3D scene not written" in caplog.text and "robot.urdf" in caplog.text
    assert not (out / "scene.html").exists()
    assert "<iframe" not in (out / "report.html").read_text()


@pytest.mark.slow
def test_view_of_a_task_plans_it_and_opens_its_scene(monkeypatch, capsys):
    opened = _browser(monkeypatch)
    task = ROOT / "examples" / "capture_tumbling_target.yaml"
    assert main(["view", str(task), "-q"]) == 0
    page = Path(capsys.readouterr().out.strip())
    text = page.read_text()
    for option in ("mission arm alone", "analytic law", "optimal plan"):
        assert f">{option}</option>" in text
    assert '"target":{"time":5.0' in text and opened == [page.as_uri()]
    shutil.rmtree(page.parent)


# ------------------------------------------------------------------------------ bodies too close
MARGIN = 0.03


def _through_the_base(robot, swing: float, duration=4.0, samples=161):
    """A motion of the capture task's robot that turns ``balance_joint2`` from 0 to ``swing``
    and back (the other joints still, the base not turning): at -1.6 rad ``balance_link3`` is
    deep in the base box, at 0 every pair is 0.42 m apart or more."""
    t = np.linspace(0.0, duration, samples)
    q = np.zeros((samples, robot.n))
    q[:, robot.joint_index("balance_joint2")] = swing * np.sin(np.pi * t / duration) ** 2
    M, B = robot.mission_indices, robot.balance_indices
    zeros = np.zeros_like(q)
    return BalanceResult(
        method="test", t=t, mission_joints=tuple(robot.joint_names[i] for i in M),
        balance_joints=tuple(robot.joint_names[i] for i in B),
        q_M=q[:, M], q_dot_M=zeros[:, M], q_ddot_M=zeros[:, M],
        q_B=q[:, B], q_dot_B=zeros[:, B], q_ddot_B=zeros[:, B],
        quaternion=np.tile([0.0, 0.0, 0.0, 1.0], (samples, 1)), omega=np.zeros((samples, 3)),
        momentum_residual=np.zeros(samples), sigma_min=np.ones(samples), info={},
    )  # fmt: skip


def _shown(clip, t: np.ndarray) -> np.ndarray:
    """A visibility clip's value at each time of ``t``: its last key at or before it."""
    (track,) = clip["tracks"]
    assert track["name"] == ".visible" and track["type"] == "bool"
    times, values = _floats(track["times"]), np.array(track["values"], dtype=bool)
    return values[np.searchsorted(times, t + FLOAT32, side="right") - 1]


@pytest.fixture(scope="module")
def capture_geometry(capture):
    from balance_opt.geometry.robot_geometry import RobotGeometry

    return RobotGeometry(capture.robot)


def test_links_are_red_exactly_at_the_frames_coal_finds_them_penetrating(capture, capture_geometry):
    """balance_link3 swung into the base box: its node and the base's show their red copy at the
    frames where coal's distance of a pair of theirs is negative, their amber copy where it is
    below the margin, their own colour elsewhere; the mission arm, never near, is not marked."""
    robot, geometry = capture.robot, capture_geometry
    res = _through_the_base(robot, -1.6)
    scene = build_scene(robot, {"swing": res}, fps=10, geometry=geometry, margin=MARGIN)
    pose = scene.poses["swing|1"]
    q = np.hstack([res.q_M, res.q_B])[pose["index"]]
    # coal, pair by pair, at the frames' configurations
    d = np.array([geometry.distances_along(q, p.index) for p in geometry.pairs]).T
    clips = {a["path"]: a["clip"] for a in _unpack(scene.animations["swing|1"])["animations"]}
    t = pose["t"] - pose["t"][0]
    model = robot.model
    marked = []
    for o in scene.objects:  # one piece per link on this robot, collision and visual alike
        node = "base" if o.joint == 1 else model.names[o.joint]
        mine = [p.index for p in geometry.pairs if o.link in p.links]
        closest = d[:, mine].min(axis=1) if mine else np.full(len(t), np.inf)
        red, amber = closest < 0.0, (closest >= 0.0) & (closest < MARGIN)
        here = f"/meshcat/robot/{node}/{o.link}"
        if not (red | amber).any():
            assert not any(path.startswith(here) for path in clips)
            continue
        marked.append(o.link)
        np.testing.assert_array_equal(_shown(clips[f"{here}_touch"], t), red)
        np.testing.assert_array_equal(_shown(clips[f"{here}_near"], t), amber)
        shown = _shown(clips[f"/meshcat/robot/{node}/{o.name}"], t)
        np.testing.assert_array_equal(shown, ~(red | amber))
    assert scene.meta["marked"] == marked
    assert {"base_link", "balance_link3"} <= set(marked)
    assert not any("mission" in n for n in marked)
    base = next(p.index for p in geometry.pairs if p.name == "base_link / balance_link3")
    assert 0 < (d[:, base] < 0).sum() < len(t)  # in the base box for part of the motion only
    # the label names the pair at the frames it penetrates
    keys = scene.meta["methods"]["swing"]["near"]
    text = [next(s for k, s in reversed(keys) if k <= tk + 1e-9) for tk in t]
    base = next(p.index for p in geometry.pairs if p.name == "base_link / balance_link3")
    for k in range(len(t)):
        penetrating = text[k].split(";")[0] if text[k].startswith("penetrating") else ""
        assert ("base_link / balance_link3" in penetrating) == (d[k, base] < 0.0)
        assert (text[k] == "") == (d[k].min() >= MARGIN)
    # the copies sit where the links do, red and amber, hidden until the animation shows them
    setup = [_unpack(b) for b in scene.setup]
    copies = {c["path"]: c for c in setup if c["type"] == "set_object"
              and c["path"].split("/")[-2].endswith(("_touch", "_near"))}  # fmt: skip
    assert len(copies) == 2 * sum(o.link in marked for o in scene.objects)
    for c in copies.values():
        colour = c["object"]["materials"][0]["color"]
        kind = c["path"].split("/")[-2].rsplit("_", 1)[1]
        assert colour == int((TOUCH_COLOUR if kind == "touch" else NEAR_COLOUR)[1:], 16)
    hidden = {c["path"] for c in setup if c["type"] == "set_property" and c["value"] is False}
    assert {c["path"].rsplit("/", 1)[0] for c in copies.values()} <= hidden


def test_a_plan_that_stays_clear_has_no_highlight(capture, capture_geometry):
    robot = capture.robot
    res = _through_the_base(robot, 0.0)
    assert capture_geometry.distances(np.zeros(robot.n)).min() > 0.4
    scene = build_scene(robot, {"still": res}, fps=10, geometry=capture_geometry, margin=MARGIN)
    assert scene.meta["marked"] == []
    assert scene.meta["methods"]["still"]["near"] == [[0.0, ""]]
    assert not any(level.any() for level in scene.levels["still"].values())
    command = _unpack(scene.animations["still|1"])
    assert all(len(a["clip"]["tracks"]) == 2 for a in command["animations"])  # placements only
    setup = [_unpack(b) for b in scene.setup]
    assert not any(c["path"].split("/")[-2].endswith(("_touch", "_near")) for c in setup)
    # without geometry (a robot without any): no highlighting and no legend for it
    plain = build_scene(robot, {"swing": _through_the_base(robot, -1.6)}, fps=10)
    assert plain.meta["proximity"] is None and plain.meta["marked"] == []
    assert "near" not in plain.meta["methods"]["swing"]
    assert "collision margin" not in scene_html(plain)
    assert "closer than the collision margin (0.03 m)" in scene_html(scene)


def test_a_run_s_scene_uses_the_run_s_geometry_and_margin(
    capture, capture_geometry, monkeypatch, tmp_path
):
    """``write_run_scene`` highlights with the geometry the run already has (none is built) and
    the task's collision margin; a run whose robot has no geometry (``False``) gets none."""
    import balance_opt.geometry.robot_geometry as robot_geometry
    from balance_opt.app.run_files import write_run_scene
    from balance_opt.app.task_run import TaskRun
    from balance_opt.tasks.task import load_task

    def no_rebuild(*args, **kwargs):
        raise AssertionError("the run's geometry was built again")

    monkeypatch.setattr(robot_geometry, "RobotGeometry", no_rebuild)
    task = load_task(_paper_task(tmp_path))
    margin = task.spec.optimal.planner.collision_margin
    results = {"swing": _through_the_base(capture.robot, -1.6)}
    run = TaskRun(task, results=results, geometry=capture_geometry)
    text = write_run_scene(run, tmp_path / "a.html").read_text()
    data = json.loads(re.search(r"const S = (\{.*?\});\n", text).group(1))
    assert data["proximity"]["margin"] == margin
    assert "base_link" in data["marked"] and "balance_link3" in data["marked"]
    run = TaskRun(task, results=results, geometry=False)
    text = write_run_scene(run, tmp_path / "b.html").read_text()
    data = json.loads(re.search(r"const S = (\{.*?\});\n", text).group(1))
    assert data["proximity"] is None and data["marked"] == []


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium is not installed")
def test_the_page_names_the_penetrating_pair(capture, capture_geometry, tmp_path):
    """In headless Chromium, the label at a time balance_link3 is in the base box names the
    pair; at the start it names none."""
    res = _through_the_base(capture.robot, -1.6)
    scene = build_scene(capture.robot, {"swing": res}, geometry=capture_geometry, margin=MARGIN)
    path = write_scene(tmp_path / "scene.html", scene)
    assert capture_geometry.distances(np.hstack([res.q_M, res.q_B])[80]).min() < 0  # t = 2 s
    labels = {}
    for t in (0, 2):
        proc = subprocess.run(
            ["chromium", "--headless", "--no-sandbox", "--disable-gpu",
             "--virtual-time-budget=3000", "--dump-dom", f"{path.as_uri()}#method=swing&t={t}"],
            capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
        label = re.search(r'<span id="scene-label">([^<]*)</span>', proc.stdout)
        assert label, proc.stderr[-2000:]
        labels[t] = label.group(1)
    penetrating = re.search(r"penetrating: ([^;]*)", labels[2])
    assert penetrating and "base_link / balance_link3" in penetrating.group(1).split(", ")
    assert "penetrating" not in labels[0] and "closer than" not in labels[0]
