"""Settings of the analytic balance law (Eq. 31, 32)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.errors import InputError

#: ``sigma_min(J_wB)`` below which damping starts [rad of base rotation per rad of joint motion].
#: On the paper robot a random configuration has sigma_min ~ 5e-4, the best ones ~ 5e-3.
DEFAULT_DAMPING_THRESHOLD = 1e-3
#: Damping at an exactly singular ``J_wB`` (``lambda_max``), same unit as ``sigma_min``.
DEFAULT_MAX_DAMPING = 1e-2
#: Gain of the null-space pull toward the goal configuration [1/s].
DEFAULT_NULL_SPACE_GAIN = 1.0


def _check_scalar(name: str, value, allow_zero: bool = True) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InputError(f"balance law option '{name}' must be a number, got {value!r}") from None
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"balance law option '{name}' must be finite and {bound}, got {value}")
    return value


def _check_vector(name: str, value, sizes) -> tuple[float, ...] | None:
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(
            f"balance law option '{name}' must be a list of numbers, got {value!r}"
        ) from None
    if sizes is not None and arr.size not in sizes:
        raise InputError(
            f"balance law option '{name}' must have {' or '.join(map(str, sizes))} values, "
            f"got {arr.size}"
        )
    if not np.all(np.isfinite(arr)):
        raise InputError(f"balance law option '{name}' has non-finite values: {arr.tolist()}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class BalanceLawOptions:
    """Settings of the analytic balance law (see the module docstring for the equations).

    Attributes:
        damping_threshold: ``epsilon``, the value of ``sigma_min(J_wB)`` below which damped least
            squares replaces the exact solve; 0 always solves exactly (a pseudo-inverse for
            a non-square ``J_wB``).
        max_damping: ``lambda_max``, the damping at a singular ``J_wB``; the damping is
            ``lambda = lambda_max (1 - (sigma_min / epsilon)^2)`` below the threshold, 0 above.
        null_space_gain: ``k`` [1/s] of the null-space term ``z = -k (q_B - q_goal)`` (only acts
            when the balance joints are more than 3).
        null_space_goal: ``q_goal`` [rad], one value per balance joint; ``None`` for the middle of
            each joint's range (its initial position if the joint has no finite limits).
        attitude_gain: ``K`` [1/s] of the attitude feedback ``-K log(R_0^T R)``; 0 is open loop.
        h0: initial momentum, constant in the world frame: 6 values [linear (N s); angular about
            the CoM (N m s)] as in the rows of ``A_G``, or the 3 angular values; ``None`` for
            zero (the paper). Only the angular part affects the attitude.
    """

    damping_threshold: float = DEFAULT_DAMPING_THRESHOLD
    max_damping: float = DEFAULT_MAX_DAMPING
    null_space_gain: float = DEFAULT_NULL_SPACE_GAIN
    null_space_goal: tuple[float, ...] | None = None
    attitude_gain: float = 0.0
    h0: tuple[float, ...] | None = None

    def __post_init__(self):
        for name in ("damping_threshold", "max_damping", "null_space_gain", "attitude_gain"):
            object.__setattr__(self, name, _check_scalar(name, getattr(self, name)))
        if self.damping_threshold > 0 and self.max_damping == 0:
            raise InputError(
                "balance law option 'max_damping' must be > 0 when 'damping_threshold' is > 0"
            )
        object.__setattr__(
            self, "null_space_goal", _check_vector("null_space_goal", self.null_space_goal, None)
        )
        object.__setattr__(self, "h0", _check_vector("h0", self.h0, (3, 6)))

    @property
    def angular_momentum(self) -> np.ndarray:
        """Initial angular momentum about the CoM in world axes (3,) [N m s]."""
        if self.h0 is None:
            return np.zeros(3)
        return np.array(self.h0[-3:])

    def as_dict(self) -> dict:
        """Plain data (for ``BalanceResult.info``)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}
