"""The arms of a floating robot: which joints each arm moves, and the limits of those joints."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Limit kinds, in the order of :class:`JointLimits`' fields.
LIMIT_KEYS = ("lower", "upper", "velocity", "acceleration", "effort", "jerk")


@dataclass(frozen=True)
class JointLimits:
    """Limits of the arm joints, in arm order.

    Attributes:
        lower: lowest position [rad or m] (``-inf`` for continuous joints).
        upper: highest position [rad or m].
        velocity: largest speed [rad/s or m/s].
        acceleration: largest acceleration [rad/s^2]; URDF has none, so ``inf`` unless set.
        effort: largest torque [N m] or force [N].
        jerk: largest jerk [rad/s^3]; URDF has none, so ``inf`` unless set.
    """

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    effort: np.ndarray
    jerk: np.ndarray

    def subset(self, indices) -> JointLimits:
        """The limits of the joints at ``indices`` of the arm vector."""
        return JointLimits(*(getattr(self, k)[indices] for k in LIMIT_KEYS))


@dataclass(frozen=True)
class Arm:
    """One arm: its role, its joints (in the user's order) and its end-effector frame.

    Attributes:
        name: ``"mission"``, or the balance arm's name (``"balance"``, ``"balance2"``, ...).
        joints: joint names in the order the user gave.
        indices: positions of these joints in the robot's arm vector.
        ee_frame: name of the end-effector frame (a URDF link).
    """

    name: str
    joints: tuple[str, ...]
    indices: np.ndarray = field(repr=False)
    ee_frame: str

    @property
    def dof(self) -> int:
        return len(self.joints)
