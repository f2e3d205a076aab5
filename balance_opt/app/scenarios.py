"""The paper's capture scenario on the Table 1 robot, defined once for the study, the
examples, the benchmarks and the tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.model.library import paper_robot
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.trajectories import PointToPoint

#: Mission arm start and capture configurations [rad], and the move's duration [s].
PAPER_MISSION_START = (0.0, 0.3, -0.6)
PAPER_MISSION_GOAL = (1.2, 0.9, -1.6)
PAPER_DURATION = 10.0
#: Balance arm start [rad]: elbow bent, away from the straight-arm singularity of J_wB.
PAPER_BALANCE_START = (0.0, 0.5, -1.0)
#: Balance joint acceleration limit [rad/s^2] (URDF carries none).
PAPER_BALANCE_ACCELERATION = 2.0


@dataclass(frozen=True)
class Scenario:
    """A robot, a mission trajectory and the balance arm's start."""

    robot: FloatingRobot
    mission: PointToPoint
    q_B0: np.ndarray

    @property
    def q0(self) -> np.ndarray:
        """Initial arm vector (mission start, balance start)."""
        return np.r_[self.mission.start, self.q_B0]


def paper_capture() -> Scenario:
    """The Table 1 robot, a 10 s point-to-point capture move of the mission arm (the paper's
    PTP), the balance arm starting bent, joint accelerations limited."""
    limits = {
        j: {"acceleration": PAPER_BALANCE_ACCELERATION}
        for j in ("balance_joint1", "balance_joint2", "balance_joint3")
    }
    robot = paper_robot(limits=limits)
    mission = PointToPoint(PAPER_MISSION_START, PAPER_MISSION_GOAL, PAPER_DURATION)
    return Scenario(robot, mission, np.array(PAPER_BALANCE_START))
