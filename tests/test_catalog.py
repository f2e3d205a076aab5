"""The robot library: every example-robot-data robot by name, its joints by chain, and the
``balance-opt robots`` and ``balance-opt cache`` commands."""

import dataclasses
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from balance_opt import cache
from balance_opt.cli import main
from balance_opt.errors import InputError
from balance_opt.model.library import ALIASES, _chains, example_robots, example_urdf, robot_info
from balance_opt.model.robot import parse_urdf

pytest.importorskip("importlib.metadata")


def _names(chain):
    return [j.name for j in chain]


def test_every_urdf_of_the_package_has_a_unique_name():
    robots = example_robots()
    assert len(set(robots.values())) == len(robots) >= 60
    assert {"talos_reduced", "ur5_robot", "panda", "baxter"} <= set(robots)
    # two files named anymal.urdf: each named after its folder
    assert robots["anymal_b_simple"].parts[-3] == "anymal_b_simple_description"
    assert robots["anymal_c_simple"].parts[-3] == "anymal_c_simple_description"
    assert all(target in robots for target in ALIASES.values())


def test_unknown_name_suggests_the_closest():
    with pytest.raises(InputError) as err:
        example_urdf("tallos")
    assert str(err.value).startswith(
        "unknown example-robot-data robot 'tallos'; did you mean talos, talos_arm, talos_full?"
    )


@pytest.mark.parametrize(
    "name, dof, chains, mass",
    [("talos", 32, 6, 90.27), ("ur5", 6, 1, 21.0), ("panda", 9, 3, 17.5), ("baxter", 19, 7, 137.3)],
)
def test_robots_load_with_their_joints_by_chain(name, dof, chains, mass):
    info = robot_info(name)
    assert info.error == ""
    assert (info.dof, len(info.chains)) == (dof, chains)
    model = pin.buildModelFromUrdf(str(info.path), pin.JointModelFreeFlyer())
    assert info.mass == pytest.approx(sum(i.mass for i in model.inertias), rel=1e-12)
    assert info.mass == pytest.approx(mass, abs=0.1)
    # every movable joint of the file is in exactly one chain
    joints = [j.name for c in info.chains for j in c]
    movable = [j.get("name") for j in ET.parse(info.path).getroot().findall("joint")]
    movable = [n for n in movable if model.existJointName(n) or n in joints]
    assert sorted(joints) == sorted(set(movable))


def test_talos_arms_are_chains_and_panda_fingers_mimic():
    talos = robot_info("talos").chains
    assert [f"arm_left_{k}_joint" for k in range(1, 8)] + ["gripper_left_joint"] in map(
        _names, talos
    )
    panda = {j.name: j for c in robot_info("panda").chains for j in c}
    assert panda["panda_finger_joint2"].mimic[0] == "panda_finger_joint1"
    assert str(panda["panda_finger_joint1"]) == "panda_finger_joint1 (prismatic)"


def test_chains_split_at_branches_and_pass_fixed_joints():
    def joint(name, parent, child, kind="revolute"):
        return (
            f'<joint name="{name}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/></joint>'
        )

    links = "".join(f'<link name="{n}"/>' for n in ["b", "a1", "a2", "f", "c1", "c2", "d1", "d2"])
    joints = [
        joint("j1", "b", "a1"),
        joint("j2", "a1", "a2"),
        joint("fixed", "a2", "f", "fixed"),  # a fixed joint inside the chain
        joint("c1", "f", "c1"),  # branch: two movable joints under f
        joint("c2", "c1", "c2", "prismatic"),
        joint("d1", "f", "d1", "continuous"),
        joint("d2", "b", "d2"),  # a second chain from the root
    ]
    text = f'<robot name="t">{links}{"".join(joints)}</robot>'
    root, urdf_joints, _ = parse_urdf(text, "<URDF string>")
    expected = [["j1", "j2"], ["c1", "c2"], ["d1"], ["d2"]]
    assert [_names(c) for c in _chains(root, urdf_joints)] == expected


def test_a_task_names_talos_by_its_short_name(tmp_path):
    from balance_opt.tasks.task import load_task

    left = [f"arm_left_{k}_joint" for k in range(1, 8)]
    right = [f"arm_right_{k}_joint" for k in range(1, 8)]
    task = tmp_path / "talos.yaml"
    task.write_text(
        "name: talos\nrobot: {example: talos}\n"
        f"arms: {{mission: [{', '.join(left)}], balance: [{', '.join(right)}]}}\n"
        "mission: {type: ptp, start: [0, 0, 0, 0, 0, 0, 0], goal: [0.3, 0.2, 0, 0, 0, 0, 0],"
        " duration: 5.0}\n"
    )
    loaded = load_task(task)
    assert loaded.robot.n == 14 and loaded.robot.mission.dof == 7
    assert np.isclose(loaded.robot.total_mass, robot_info("talos").mass)


def test_a_task_with_an_unknown_robot_names_the_key(tmp_path, capsys):
    task = tmp_path / "bad.yaml"
    task.write_text(
        "name: bad\nrobot: {example: pandaa}\narms: {mission: [a], balance: [b]}\n"
        "mission: {type: ptp, start: [0], goal: [1], duration: 5.0}\n"
    )
    assert main(["validate", str(task)]) == 2
    err = capsys.readouterr().err
    assert (
        f"{task}:2: robot.example: unknown example-robot-data robot 'pandaa'; did you mean" in err
    )


@pytest.mark.slow
def test_robots_command_lists_loading_and_failing_robots(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out.splitlines()
    summary = next(line for line in out if " robots load; use robot: {example: NAME}" in line)
    failing = [line for line in out if line.startswith("does not load: ")]
    loaded, total = summary.split(" robots load")[0].split(" of ")
    assert int(total) == len(example_robots()) and int(loaded) + len(failing) == int(total)
    assert "talos_reduced (also: talos): 32 movable joints, 90.3 kg" in out
    assert all(": " in line[len("does not load: ") :] for line in failing)


def test_robots_command_one_robot(capsys):
    assert main(["robots", "ur5"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1] == f"  6 movable joints, 1 chain, {robot_info('ur5').mass:.2f} kg"
    assert out[2] == (
        "    chain 1: shoulder_pan_joint (revolute), shoulder_lift_joint (revolute), "
        "elbow_joint (revolute), wrist_1_joint (revolute), wrist_2_joint (revolute), "
        "wrist_3_joint (revolute)"
    )
    assert main(["robots", "ur55"]) == 2
    assert "did you mean ur5" in capsys.readouterr().err


def test_cache_command_shows_and_clears(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("BALANCE_OPT_CACHE", str(tmp_path))
    library = tmp_path / "balance_kernels_0123.so"
    library.write_bytes(b"\0" * 2000)
    cache.write_record(library)
    (tmp_path / "ipopt-options-casadi-3.8.2.json").write_text("{}")
    assert main(["cache"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"cache folder: {tmp_path} ($BALANCE_OPT_CACHE)"
    assert out[1].startswith("size: 2.1 kB (bound 2.15 GB, $BALANCE_OPT_CACHE_LIMIT)")
    assert out[2].startswith("planner kernels: 1 entry, ")
    assert out[3:] == ["Ipopt options: 1 entry, 2 B", "--list shows every entry"]  # a summary
    assert main(["cache", "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[2].startswith("planner kernels: 1 entry, ")
    assert out[3].startswith("  balance_kernels_0123.so  ")
    assert out[4] == "Ipopt options: 1 entry, 2 B"
    assert out[5].startswith("  ipopt-options-casadi-3.8.2.json  2 B  last used ")
    assert main(["cache", "--clear"]) == 0
    assert capsys.readouterr().out.splitlines()[1].startswith("deleted 2 entries (")
    assert list(tmp_path.iterdir()) == []


def test_robots_without_joints_print_no_blank_line(capsys, monkeypatch):
    from balance_opt.model import library

    infos = {
        "box": dataclasses.replace(robot_info("ur5"), name="box", chains=[]),
        "ur5": robot_info("ur5"),
    }
    monkeypatch.setattr(library, "example_robots", lambda: list(infos))
    monkeypatch.setattr(library, "robot_info", lambda name, robots=None: infos[name])
    assert main(["robots"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "" not in out
    assert out[0].startswith("box: 0 movable joints") and out[1].startswith("ur5")
