"""Settings of the analytic balance law, declared once for Python calls and the ``analytic``
section of task files."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.config.typed_config import check_settings, setting
from balance_opt.errors import InputError

#: ``sigma_min(J_wB)`` below which damping starts [rad of base rotation per rad of joint motion].
#: On the paper robot a random configuration has sigma_min ~ 5e-4, the best ones ~ 5e-3.
DEFAULT_DAMPING_THRESHOLD = 1e-3
#: Damping at an exactly singular ``J_wB`` (``lambda_max``), same unit as ``sigma_min``.
DEFAULT_MAX_DAMPING = 1e-2
#: Gain of the null-space pull toward the goal configuration [1/s].
DEFAULT_NULL_SPACE_GAIN = 1.0


@dataclass(frozen=True)
class BalanceLawOptions:
    """Settings of the analytic balance law (how they act:
    :mod:`balance_opt.analytic.least_squares`). ``h0`` comes from the task's
    ``initial.momentum``.

    Raises:
        InputError: a field that does not fit its declaration (``"balance law option
            'max_damping': must be at least 0, got -1"``), ``h0`` with neither 3 nor 6 values,
            or no damping at a singular ``J_wB`` while damping is on.
    """

    damping_threshold: float = setting(
        DEFAULT_DAMPING_THRESHOLD,
        minimum=0.0,
        doc="sigma_min(J_wB) below which damped least squares replaces the exact solve "
        "(0: always exact)",
    )
    max_damping: float = setting(
        DEFAULT_MAX_DAMPING, minimum=0.0, doc="damping at a singular J_wB (lambda_max)"
    )
    null_space_gain: float = setting(
        DEFAULT_NULL_SPACE_GAIN,
        minimum=0.0,
        unit="1/s",
        doc="gain of the null-space pull toward null_space_goal (redundant balance arms)",
    )
    null_space_goal: tuple[float, ...] | None = setting(
        None,
        unit="rad",
        per="balance joint",
        doc="null-space goal, one value per balance joint (default: middle of each joint's range)",
    )
    attitude_gain: float = setting(
        0.0,
        minimum=0.0,
        unit="1/s",
        doc="gain K of the attitude feedback -K log(R_0^T R) (0: open loop)",
    )
    h0: tuple[float, ...] | None = setting(
        None,
        in_file=False,
        unit="N s; N m s",
        doc="initial momentum, constant in the world frame: [linear; angular about the CoM] as "
        "in the rows of A_G, or the 3 angular values (default: zero, the paper's); only the "
        "angular part affects the attitude",
    )

    def __post_init__(self):
        check_settings(self, "balance law option")
        if self.damping_threshold > 0 and self.max_damping == 0:
            raise InputError(
                "balance law option 'max_damping' must be > 0 when 'damping_threshold' is > 0"
            )
        if self.h0 is not None and len(self.h0) not in (3, 6):
            raise InputError(f"balance law option 'h0' must have 3 or 6 values, got {len(self.h0)}")

    @property
    def angular_momentum(self) -> np.ndarray:
        """Initial angular momentum about the CoM in world axes (3,) [N m s]."""
        if self.h0 is None:
            return np.zeros(3)
        return np.array(self.h0[-3:])

    def as_dict(self) -> dict:
        """Plain data (for ``BalanceResult.info``)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}
