"""Where robot files come from, and ready-made robots.

Robot files are the URDFs shipped in ``balance_opt/urdf/`` and those of ``example-robot-data``,
by name (:mod:`balance_opt.model.catalog`). The ready-made robots are the paper's Table 1 robot and Baxter on a
floating base.
"""

from __future__ import annotations

import importlib.resources
from collections.abc import Mapping
from pathlib import Path

from balance_opt.errors import InputError
from balance_opt.model.catalog import example_urdf
from balance_opt.model.robot import FloatingRobot

PAPER_ROBOT = "paper_robot.urdf"
PAPER_MISSION_JOINTS = ("mission_joint1", "mission_joint2", "mission_joint3")
PAPER_BALANCE_JOINTS = ("balance_joint1", "balance_joint2", "balance_joint3")
BAXTER_LEFT_ARM = tuple(f"left_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))
BAXTER_RIGHT_ARM = tuple(f"right_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))


# ---------------------------------------------------------------------------------- robot files
def shipped_urdf(name: str = PAPER_ROBOT) -> Path:
    """Path of a URDF shipped with balance-opt (``urdf/`` in the repository)."""
    path = Path(str(importlib.resources.files("balance_opt.urdf") / name))
    if not path.is_file():
        available = sorted(p.name for p in path.parent.glob("*.urdf"))
        raise InputError(f"no shipped URDF '{name}'; available: {', '.join(available)}")
    return path


def example_robot_urdf(name: str) -> Path:
    """Path of the URDF of the example-robot-data robot ``name`` (``balance-opt robots`` lists
    them).

    Raises:
        InputError: example-robot-data is not installed, or no robot has that name (the message
            suggests the closest names).
    """
    return example_urdf(name)


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
