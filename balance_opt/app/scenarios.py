"""balance-opt's scenarios on the Table 1 robot, defined once for the study, the examples, the
benchmarks and the tests (``examples/capture_task.yaml`` and ``examples/paper_fig5.yaml`` hold
the same numbers). The paper gives no start, goal, duration, joint axes or mount points: every
number here is balance-opt's choice."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.model.library import paper_robot, paper_robot_fig5
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.trajectories import PointToPoint

#: Mission arm start and capture configurations [rad].
CAPTURE_MISSION_START = (0.0, 0.3, -0.6)
CAPTURE_MISSION_GOAL = (1.2, 0.9, -1.6)
#: Balance joint acceleration limit [rad/s^2] (URDF carries none).
CAPTURE_BALANCE_ACCELERATION = 2.0


@dataclass(frozen=True)
class Scenario:
    """A robot, a mission trajectory and the balance arm's start; a name and the settings of
    the analytic law it is studied with (``None``: the defaults)."""

    robot: FloatingRobot
    mission: PointToPoint
    q_B0: np.ndarray
    name: str = "scenario"
    law: BalanceLawOptions | None = None

    @property
    def q0(self) -> np.ndarray:
        """Initial arm vector (mission start, balance start)."""
        return np.r_[self.mission.start, self.q_B0]


def _balance_acceleration_limits() -> dict:
    joints = ("balance_joint1", "balance_joint2", "balance_joint3")
    return {j: {"acceleration": CAPTURE_BALANCE_ACCELERATION} for j in joints}


def capture_task() -> Scenario:
    """The hard case: the shipped reading of Table 1, a 10 s point-to-point capture move of the
    mission arm, balance joint accelerations limited to 2 rad/s^2, and the balance arm starting
    bent where ``J_wB`` is exactly singular (singular values 0.090, 0.059, 3e-19): with both
    arms in the base's x-z plane the pitch joints turn the base only about y and the yaw joint
    only about one direction of that plane, so no balance rate cancels a base rate along
    (-0.73, 0, 0.69) and Eq. 31 has no solution."""
    # the mission joints' acceleration limits: for a free mission timing only (issue 37)
    mission = {
        f"mission_joint{i}": {"acceleration": CAPTURE_BALANCE_ACCELERATION} for i in (1, 2, 3)
    }
    robot = paper_robot(limits={**mission, **_balance_acceleration_limits()})
    mission = PointToPoint(CAPTURE_MISSION_START, CAPTURE_MISSION_GOAL, 10.0)
    return Scenario(robot, mission, np.array([0.0, 0.5, -1.0]), "capture_task")


def paper_fig5() -> Scenario:
    """The Fig. 5 study's choice (``docs/paper_fig5_study.md``): the reading
    :data:`~balance_opt.model.table1.FIG5_READING`, its balance start and mission, balance joint
    accelerations limited to 2 rad/s^2, and the exact law (no damping)."""
    robot = paper_robot_fig5(limits=_balance_acceleration_limits())
    mission = PointToPoint((0.0, 0.3, -0.6), (0.8, 0.7, -1.2), 10.0)
    law = BalanceLawOptions(damping_threshold=0.0)
    return Scenario(robot, mission, np.array([-0.36, 0.46, -0.41]), "paper_fig5", law)
