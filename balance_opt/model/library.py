"""Ready-made robots: the paper's Table 1 robot and Baxter on a floating base."""

from __future__ import annotations

from typing import Mapping

from balance_opt.model.resources import example_robot_urdf, shipped_urdf
from balance_opt.model.robot import FloatingRobot

PAPER_MISSION_JOINTS = ("mission_joint1", "mission_joint2", "mission_joint3")
PAPER_BALANCE_JOINTS = ("balance_joint1", "balance_joint2", "balance_joint3")
BAXTER_LEFT_ARM = tuple(f"left_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))
BAXTER_RIGHT_ARM = tuple(f"right_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))


def paper_robot(limits: Mapping[str, Mapping[str, float]] | None = None) -> FloatingRobot:
    """The two-arm robot of the paper's Table 1 (``urdf/paper_robot.urdf``).

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
