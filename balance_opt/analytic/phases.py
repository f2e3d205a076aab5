"""The paper's phases and its attitude figures, each a :class:`BalanceResult`: Phase I (the
mission arm alone, Fig. 2), Phase II (:func:`balance_opt.analytic.rollout.rollout`) and both
arms replayed (Fig. 5)."""

from __future__ import annotations

import numpy as np

from balance_opt.errors import InputError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.replay import replay
from balance_opt.motion.trajectories import PointToPoint, TrajectoryLike, as_sampler
from balance_opt.result import BalanceResult


def phase_one(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    q_B0,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
) -> BalanceResult:
    """Phase I (Fig. 2): base attitude with the mission arm moving and the balance arm held at
    ``q_B0`` [rad]. ``method="mission-only"``. Other arguments as in :func:`replay`."""
    if t_eval is not None:
        duration = float(np.max(t_eval))
    else:
        duration = as_sampler(mission, robot.mission.dof, "mission")[1]
        if duration is None:
            raise InputError(
                "output times are needed: the mission motion is a plain callable with no duration"
            )
    q_B0 = np.asarray(q_B0, dtype=float).ravel()
    return replay(
        robot,
        mission,
        PointToPoint(q_B0, q_B0, duration),
        h0=h0,
        integration=integration,
        t_eval=t_eval,
        method="mission-only",
    )


def both(
    robot: FloatingRobot,
    mission: TrajectoryLike | BalanceResult,
    balance: TrajectoryLike | BalanceResult,
    **kwargs,
) -> BalanceResult:
    """Fig. 5: base attitude with both arms moving, replayed from the two motions (trajectories
    or results). ``method="simulation"``; keyword arguments as in :func:`replay`."""
    return replay(robot, mission, balance, method="simulation", **kwargs)
