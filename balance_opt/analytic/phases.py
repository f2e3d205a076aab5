"""The paper's two phases and its attitude figures, each a :class:`BalanceResult`.

* Phase I (:func:`phase_one`, paper Fig. 2): the mission arm moves alone, the balance arm is held
  at its start; the base turns as momentum conservation forces it (Eq. 26 integrated).
* Phase II (:func:`balance_opt.analytic.rollout.rollout`): the balance trajectory computed by
  the analytic law (Eq. 31, 32).
* :func:`balance_only` (Fig. 3): the balance motion replayed with the mission arm held still.
  The motion is non-holonomic, so this is not simply the negative of Fig. 2.
* :func:`both` (Fig. 5): the attitude with both arms moving, replayed from the two motions.

:func:`paper_phases` runs all four for one mission.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.analytic.rollout import rollout
from balance_opt.errors import InputError
from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.replay import replay
from balance_opt.motion.trajectories import (
    PointToPoint,
    SampledTrajectory,
    TrajectoryLike,
    as_sampler,
)
from balance_opt.result import BalanceResult


def _motion(motion: TrajectoryLike | BalanceResult, arm: str):
    """A trajectory of ``arm`` (``"mission"`` or ``"balance"``) from a trajectory or a result."""
    if isinstance(motion, BalanceResult):
        return SampledTrajectory.from_result(motion, arm)
    return motion


def _hold(q, duration: float) -> PointToPoint:
    """Joints at rest at ``q`` for ``duration`` [s]."""
    q = np.asarray(q, dtype=float).ravel()
    return PointToPoint(q, q, duration)


def _duration(robot, motion, arm, t_eval) -> float:
    if t_eval is not None:
        return float(np.max(t_eval))
    n = robot.mission_indices.size if arm == "mission" else robot.balance_indices.size
    _, duration = as_sampler(motion, n, arm)
    if duration is None:
        raise InputError(
            f"output times are needed: the {arm} motion is a plain callable with no duration"
        )
    return duration


def phase_one(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    q_B0,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
    quaternion0=None,
) -> BalanceResult:
    """Phase I (Fig. 2): base attitude with the mission arm moving and the balance arm held at
    ``q_B0`` [rad]. ``method="mission-only"``. Other arguments as in :func:`replay`."""
    hold = _hold(q_B0, _duration(robot, mission, "mission", t_eval))
    return replay(
        robot,
        mission,
        hold,
        h0=h0,
        integration=integration,
        t_eval=t_eval,
        quaternion0=quaternion0,
        method="mission-only",
    )


def balance_only(
    robot: FloatingRobot,
    balance: TrajectoryLike | BalanceResult,
    q_M0,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
    quaternion0=None,
) -> BalanceResult:
    """Fig. 3: base attitude with the balance motion replayed and the mission arm held at
    ``q_M0`` [rad] (its start). ``balance`` is a trajectory of the balance joints or a result
    (its balance samples, interpolated). ``method="balance-only"``."""
    balance = _motion(balance, "balance")
    hold = _hold(q_M0, _duration(robot, balance, "balance", t_eval))
    return replay(
        robot,
        hold,
        balance,
        h0=h0,
        integration=integration,
        t_eval=t_eval,
        quaternion0=quaternion0,
        method="balance-only",
    )


def both(
    robot: FloatingRobot,
    mission: TrajectoryLike | BalanceResult,
    balance: TrajectoryLike | BalanceResult,
    *,
    h0=None,
    integration: IntegrationOptions | None = None,
    t_eval=None,
    quaternion0=None,
) -> BalanceResult:
    """Fig. 5: base attitude with both arms moving, replayed from the two motions (trajectories
    or results). ``method="simulation"``."""
    return replay(
        robot,
        _motion(mission, "mission"),
        _motion(balance, "balance"),
        h0=h0,
        integration=integration,
        t_eval=t_eval,
        quaternion0=quaternion0,
        method="simulation",
    )


@dataclass
class PaperPhases:
    """The four results of the paper's study for one mission.

    Attributes:
        mission_only: Phase I, Fig. 2.
        analytic: Phase II, the law's balance trajectory (and its own attitude).
        balance_only: Fig. 3, the balance motion alone.
        both: Fig. 5, both arms, replayed.
    """

    mission_only: BalanceResult
    analytic: BalanceResult
    balance_only: BalanceResult
    both: BalanceResult


def paper_phases(
    robot: FloatingRobot,
    mission: TrajectoryLike,
    q_B0,
    options: BalanceLawOptions | None = None,
    *,
    integration: IntegrationOptions | None = None,
    t_eval=None,
) -> PaperPhases:
    """Phase I, Phase II, Fig. 3 and Fig. 5 for one mission, on the same output times."""
    options = options or BalanceLawOptions()
    first = phase_one(robot, mission, q_B0, h0=options.h0, integration=integration, t_eval=t_eval)
    t = first.t
    analytic = rollout(robot, mission, q_B0, options, integration=integration, t_eval=t)
    alone = balance_only(
        robot, analytic, first.q_M[0], h0=options.h0, integration=integration, t_eval=t
    )
    together = both(robot, mission, analytic, h0=options.h0, integration=integration, t_eval=t)
    return PaperPhases(first, analytic, alone, together)
