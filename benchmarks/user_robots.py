"""Robots as users bring them (issue 34): URDF and meshes copied out of example-robot-data into a
folder of their own, their ``package://`` names turned into a ROS package's (no SRDF copied),
each planned by the installed ``balance-opt`` with collision avoidance on.

* Talos, arms 7 + 7, legs and torso locked at half-sitting (the values of example-robot-data's
  SRDF); its meshes found through the task's ``robot.packages``;
* Baxter, arms 7 + 7, as ``examples/baxter_floating.yaml``; its meshes found above the URDF
  (``baxter_description/urdf/baxter.urdf``);
* a box satellite (1.2 m, 300 kg) carrying two UR5 arms (links and meshes of example-robot-data's
  ``ur_description``), the mission arm one, the balance arm the other; meshes found through
  ``ROS_PACKAGE_PATH``.

Each task is run as ``balance-opt plan TASK --method optimal`` (its scene included); the table
gives the exit code, the wall time of the command (process start to end: imports, model, the
kernels' compilation on a first run, the plan, its re-simulation, the files), the CPU time of
the command and its compilers (user and system: less inflated by a loaded machine than the
wall time), the peak drift,
the smallest clearance on the continuous motion, the penetrations reported, and the scene (its
size, the mesh objects of the robot's visual geometry and the vertices drawn). Run:
``python benchmarks/user_robots.py [--dir DIR] [ROBOT ...]``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from balance_opt.model.library import BAXTER_LEFT_ARM, BAXTER_RIGHT_ARM, example_urdf
from balance_opt.model.meshes import EXAMPLE_PACKAGE, PACKAGE

ERD = f"{PACKAGE}{EXAMPLE_PACKAGE}/robots/"
#: The mission move of the 7-joint arms (examples/talos_arms.yaml, examples/baxter_floating.yaml).
PTP = "  type: ptp\n  start: {start}\n  goal: {goal}\n  duration: 8.0\n"
UR5_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")


def talos_arm(side: str) -> list[str]:
    return [f"arm_{side}_{k}_joint" for k in range(1, 8)]


def _copy_package(description: Path, target: Path, package: str, urdf: Path) -> str:
    """Copy the meshes of example-robot-data's ``description`` folder into ``target`` and return
    the URDF ``urdf``'s text with its ``package://example-robot-data/robots/<folder>/`` names
    turned into ``package://<package>/``."""
    shutil.copytree(description / "meshes", target / "meshes", dirs_exist_ok=True)
    text = urdf.read_text()
    return text.replace(f"{ERD}{description.name}/", f"{PACKAGE}{package}/")


def talos(folder: Path) -> tuple[Path, dict]:
    """Talos with its meshes in ``folder/packages/talos_data``, the URDF and the task in
    ``folder/talos``, ``robot.packages: [../packages]``."""
    source = example_urdf("talos")
    data = source.parent.parent  # .../robots/talos_data
    text = _copy_package(data, folder / "packages" / "talos_data", "talos_data", source)
    home = folder / "talos"
    home.mkdir(parents=True)
    (home / "talos.urdf").write_text(text)
    srdf = ET.parse(data / "srdf" / "talos.srdf").getroot()
    state = next(s for s in srdf.iter("group_state") if s.get("name") == "half_sitting")
    locked = {
        j.get("name"): float(j.get("value"))
        for j in state.iter("joint")
        if j.get("name").startswith(("leg_", "torso_"))
    }
    right = talos_arm("right")
    task = home / "talos.yaml"
    task.write_text(
        "name: talos_user\nrobot:\n  urdf: talos.urdf\n  packages: [../packages]\n"
        f"arms:\n  mission: {talos_arm('left')}\n  balance: {right}\n"
        f"  locked: {json.dumps(locked)}\n"
        "initial:\n  balance: [0.2, -0.4, 0.0, -1.0, 0.0, 0.3, 0.0]\n"
        "mission:\n"
        + PTP.format(
            start="[-0.2, 0.4, 0.0, -1.0, 0.0, 0.3, 0.0]",
            goal="[-0.8, 0.9, 0.5, -1.6, 0.4, -0.3, 0.2]",
        )
        + "limits:\n"
        + "".join(f"  {j}: {{acceleration: 2.0}}\n" for j in right)
        + "optimal:\n  collision: {avoid: true}\n"
    )
    return task, {}


def baxter(folder: Path) -> tuple[Path, dict]:
    """Baxter laid out as its ROS package, ``folder/baxter_description/{urdf,meshes}``, the task
    beside the URDF: its meshes are found above the URDF."""
    source = example_urdf("baxter")
    package = folder / "baxter_description"
    text = _copy_package(source.parent.parent, package, package.name, source)
    (package / "urdf").mkdir(parents=True)
    (package / "urdf" / "baxter.urdf").write_text(text)
    task = package / "urdf" / "baxter.yaml"
    # examples/baxter_floating.yaml's untucked arms bend the wrist (w1) to 1.26 rad, where
    # the URDF's wrist and forearm-cover cylinders overlap by 9.8 mm (a pair Baxter's own SRDF
    # leaves out by hand, "User"): without it the start is in collision, and a user moves it
    untucked = "[0.0, -0.55, 0.0, 0.75, 0.0, 0.6, 0.0]"
    task.write_text(
        "name: baxter_user\nrobot:\n  urdf: baxter.urdf\n"
        f"arms:\n  mission: {list(BAXTER_LEFT_ARM)}\n  balance: {list(BAXTER_RIGHT_ARM)}\n"
        f"initial:\n  balance: {untucked}\n"
        "mission:\n"
        + PTP.format(start=untucked, goal="[-0.6, -0.2, -0.5, 1.3, 0.4, 0.6, 0.3]")
        + "limits:\n"
        + "".join(f"  {j}: {{acceleration: 2.0}}\n" for j in BAXTER_RIGHT_ARM)
        + "optimal:\n  collision: {avoid: true}\n"
    )
    return task, {}


#: The satellite: a uniform box [m] of this mass [kg] (a small satellite's), the two UR5 bases
#: on its top face at these y [m], both arms turned to face +x.
SATELLITE_SIZE, SATELLITE_MASS, MOUNTS_Y = 1.2, 300.0, {"mission": 0.35, "balance": -0.35}


def satellite_urdf(ur5: Path) -> str:
    """A box satellite with two UR5 arms, ``mission_*`` and ``balance_*``, their links, joints
    and meshes those of ``ur5`` (its ``world`` link, transmissions and Gazebo tags left out)."""
    root = ET.parse(ur5).getroot()
    side = SATELLITE_SIZE
    inertia = SATELLITE_MASS * 2 * side**2 / 12
    out = ET.Element("robot", name="ur5_satellite")
    box = f'<box size="{side} {side} {side}"/>'
    out.append(
        ET.fromstring(
            f'<link name="satellite"><inertial><origin xyz="0 0 0"/>'
            f'<mass value="{SATELLITE_MASS}"/><inertia ixx="{inertia}" iyy="{inertia}" '
            f'izz="{inertia}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f"<visual><geometry>{box}</geometry></visual>"
            f"<collision><geometry>{box}</geometry></collision></link>"
        )
    )
    for arm, y in MOUNTS_Y.items():
        out.append(
            ET.fromstring(
                f'<joint name="{arm}_mount" type="fixed"><parent link="satellite"/>'
                f'<child link="{arm}_base_link"/><origin xyz="0 {y} {side / 2}"/></joint>'
            )
        )
        for el in root:
            if el.tag not in ("link", "joint") or el.get("name") in ("world", "world_joint"):
                continue
            copy = ET.fromstring(ET.tostring(el))
            copy.set("name", f"{arm}_{copy.get('name')}")
            for ref in (copy.find("parent"), copy.find("child")):
                if ref is not None:
                    ref.set("link", f"{arm}_{ref.get('link')}")
            out.append(copy)
    return ET.tostring(out, encoding="unicode")


def ur5_satellite(folder: Path) -> tuple[Path, dict]:
    """The UR5 satellite, its meshes in ``folder/ros/ur_description`` (on ``ROS_PACKAGE_PATH``),
    its URDF and task in ``folder/ur5_satellite``."""
    source = example_urdf("ur5")
    description = source.parent.parent
    target = folder / "ros" / "ur_description" / "meshes" / "ur5"
    shutil.copytree(description / "meshes" / "ur5", target)
    home = folder / "ur5_satellite"
    home.mkdir(parents=True)
    text = satellite_urdf(source).replace(f"{ERD}ur_description/", f"{PACKAGE}ur_description/")
    (home / "ur5_satellite.urdf").write_text(text)
    joints = {arm: [f"{arm}_{j}_joint" for j in UR5_JOINTS] for arm in MOUNTS_Y}
    task = home / "ur5_satellite.yaml"
    task.write_text(
        "name: ur5_satellite\nrobot:\n  urdf: ur5_satellite.urdf\n"
        f"arms:\n  mission: {joints['mission']}\n  balance: {joints['balance']}\n"
        "initial:\n  balance: [0.0, -1.57, 1.57, -1.57, -1.57, 0.0]\n"
        "mission:\n"
        + PTP.format(
            start="[0.0, -1.57, 1.57, -1.57, -1.57, 0.0]",
            goal="[1.2, -0.8, 1.0, -1.2, -1.0, 0.6]",
        )
        + "limits:\n"
        + "".join(f"  {j}: {{acceleration: 2.0}}\n" for j in joints["balance"])
        + "optimal:\n  collision: {avoid: true}\n"
    )
    return task, {"ROS_PACKAGE_PATH": str(folder / "ros")}


ROBOTS = {"talos": talos, "baxter": baxter, "ur5_satellite": ur5_satellite}


def _command() -> list[str]:
    """The ``balance-opt`` of this interpreter's environment."""
    script = Path(sys.executable).with_name("balance-opt")
    return [str(script)] if script.is_file() else ["balance-opt"]


def _mesh_objects(task_path: Path, env: dict) -> int:
    """The mesh objects of the task robot's visual geometry, found as the run found them."""
    from balance_opt.report.scene_meshes import visual_model
    from balance_opt.tasks.task import load_task

    before = os.environ.get("ROS_PACKAGE_PATH")
    os.environ.update(env)
    try:
        model = visual_model(load_task(task_path).robot)
    finally:
        if "ROS_PACKAGE_PATH" in env:
            os.environ.pop("ROS_PACKAGE_PATH")
            if before is not None:
                os.environ["ROS_PACKAGE_PATH"] = before
    return sum(Path(o.meshPath).is_file() for o in model.geometryObjects)


def run(name: str, folder: Path) -> dict:
    task, env = ROBOTS[name](folder)
    out = folder / "results" / name
    started, before = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(
        [*_command(), "plan", str(task), "--method", "optimal", "--output", str(out), "--force"],
        env={**os.environ, **env},
        check=False,  # a failed plan is a row of the table
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    (folder / "results").mkdir(exist_ok=True)
    (folder / "results" / f"{name}.log").write_text(proc.stdout + proc.stderr)
    row = {"robot": name, "exit": proc.returncode, "wall_s": wall, "cpu_s": cpu}
    metrics = out / "metrics.json"
    if metrics.is_file():
        m = json.loads(metrics.read_text())["methods"]["optimal"]
        clearance = m.get("clearance") or {}
        row.update(
            drift=m["max_drift_rad"],
            clearance=clearance.get("min_distance_m"),
            pair=clearance.get("closest_pair"),
            collisions=m["limit_violations_by_kind"].get("collision", 0),
        )
    scene = out / "scene.html"
    vertices = re.search(r"scene: scene\.html, [\d.]+ MB \((\d+) mesh vertices\)", proc.stderr)
    row["scene"] = (
        f"{scene.stat().st_size / 2**20:.1f} MB, {_mesh_objects(task, env)} meshes, "
        f"{vertices.group(1) if vertices else '?'} vertices"
        if scene.is_file()
        else "not written"
    )
    warnings = [
        line for line in proc.stderr.splitlines() if "not written" in line or "not found" in line
    ]
    row["notes"] = "; ".join(warnings[:2])
    return row


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("robots", nargs="*", metavar="ROBOT", help=", ".join(ROBOTS))
    parser.add_argument("--dir", type=Path, help="folder of the copies (default: a temporary one)")
    args = parser.parse_args(argv)
    unknown = set(args.robots) - set(ROBOTS)
    if unknown:
        parser.error(f"unknown robots {sorted(unknown)}; known: {', '.join(ROBOTS)}")
    folder = args.dir or Path(tempfile.mkdtemp(prefix="user_robots_"))
    folder.mkdir(parents=True, exist_ok=True)
    print(f"robots copied into {folder} (logs and results in {folder / 'results'})")
    print(
        "| robot | exit | wall [s] | CPU [s] | peak drift [rad] | smallest clearance [m] (pair) "
        "| collisions | scene |\n| --- | --- | --- | --- | --- | --- | --- | --- |"
    )
    for name in args.robots or ROBOTS:
        row = run(name, folder)
        drift = f"{row['drift']:.4g}" if "drift" in row else "-"
        clear = (
            f"{row['clearance']:.4g} ({row['pair']})" if row.get("clearance") is not None else "-"
        )
        print(
            f"| {name} | {row['exit']} | {row['wall_s']:.1f} | {row['cpu_s']:.1f} | {drift} "
            f"| {clear} "
            f"| {row.get('collisions', '-')} | {row['scene']} |",
            flush=True,
        )
        if row["notes"]:
            print(f"  ({name}: {row['notes']})", flush=True)


if __name__ == "__main__":
    main()
