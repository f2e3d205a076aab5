"""Where robot files come from, and ready-made robots.

Robot files are the URDFs shipped in ``balance_opt/urdf/`` and those of ``example-robot-data``
(version 6 ships robot files only, with no Python loader: they are found through the installed
distribution's metadata). The ready-made robots are the paper's Table 1 robot and Baxter on a
floating base.
"""

from __future__ import annotations

import importlib.metadata
import importlib.resources
from collections.abc import Mapping
from pathlib import Path

from balance_opt.errors import InputError
from balance_opt.model.robot import FloatingRobot

PAPER_ROBOT = "paper_robot.urdf"
PAPER_MISSION_JOINTS = ("mission_joint1", "mission_joint2", "mission_joint3")
PAPER_BALANCE_JOINTS = ("balance_joint1", "balance_joint2", "balance_joint3")
BAXTER_LEFT_ARM = tuple(f"left_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))
BAXTER_RIGHT_ARM = tuple(f"right_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))

#: example-robot-data robots that balance-opt knows by name: (description folder, URDF file).
EXAMPLE_ROBOTS = {
    "baxter": ("baxter_description", "baxter.urdf"),
}


# ---------------------------------------------------------------------------------- robot files
def shipped_urdf(name: str = PAPER_ROBOT) -> Path:
    """Path of a URDF shipped with balance-opt (``urdf/`` in the repository)."""
    path = Path(str(importlib.resources.files("balance_opt.urdf") / name))
    if not path.is_file():
        available = sorted(p.name for p in path.parent.glob("*.urdf"))
        raise InputError(f"no shipped URDF '{name}'; available: {', '.join(available)}")
    return path


def example_robot_urdf(name: str) -> Path:
    """Path of an ``example-robot-data`` URDF, found through the package's installed files."""
    if name not in EXAMPLE_ROBOTS:
        raise InputError(
            f"unknown example-robot-data robot '{name}'; known: {', '.join(sorted(EXAMPLE_ROBOTS))}"
        )
    folder, filename = EXAMPLE_ROBOTS[name]
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        raise InputError(
            "example-robot-data is not installed (pip install example-robot-data)"
        ) from None
    suffix = f"robots/{folder}/urdf/{filename}"
    for f in dist.files or ():
        if str(f).replace("\\", "/").endswith(suffix):
            return Path(str(dist.locate_file(f)))
    raise InputError(f"example-robot-data {dist.version} has no file ending in {suffix}")


# ---------------------------------------------------------------------------------- robots
def paper_robot(limits: Mapping[str, Mapping[str, float]] | None = None) -> FloatingRobot:
    """The two-arm robot of the paper's Table 1 (``urdf/paper_robot.urdf``, ``docs/physics.md``,
    "The Table 1 robot").

    Mission arm ``mission_joint1..3`` and balance arm ``balance_joint1..3``, each yaw-pitch-pitch.
    """
    return FloatingRobot(shipped_urdf(), PAPER_MISSION_JOINTS, PAPER_BALANCE_JOINTS, limits=limits)


def baxter_floating(
    mission: str = "left", locked: Mapping[str, float] | None = None
) -> FloatingRobot:
    """Baxter from example-robot-data on a free-flying base: one 7-DOF arm for the mission, the
    other to balance; head and gripper joints locked (at 0 unless ``locked`` says otherwise)."""
    left, right = BAXTER_LEFT_ARM, BAXTER_RIGHT_ARM
    arms = (left, right) if mission == "left" else (right, left)
    return FloatingRobot(example_robot_urdf("baxter"), arms[0], arms[1], locked=locked)
