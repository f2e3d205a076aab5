"""Settings of the attitude integration (rollouts and replays)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from balance_opt.errors import InputError

#: Default relative and absolute tolerances of the adaptive integrator (quaternion, [rad]).
DEFAULT_RTOL = 1e-10
DEFAULT_ATOL = 1e-12
#: Default spacing of the output samples [s] (1 kHz).
DEFAULT_OUTPUT_STEP = 1e-3
INTEGRATION_METHODS = ("adaptive", "rk4")


@dataclass(frozen=True)
class IntegrationOptions:
    """How to integrate the attitude (and the balance joints).

    Attributes:
        method: ``"adaptive"`` (DOP853, error-controlled) or ``"rk4"`` (fixed step).
        rtol, atol: tolerances of ``"adaptive"`` (``atol`` in quaternion units, ~ [rad] / 2,
            and [rad] for the joints).
        step: ``"rk4"``: largest step [s] (default: the output spacing); ``"adaptive"``: largest
            step [s] (default: none).
        output_step: spacing of the output samples [s] when no output times are given.
    """

    method: str = "adaptive"
    rtol: float = DEFAULT_RTOL
    atol: float = DEFAULT_ATOL
    step: float | None = None
    output_step: float = DEFAULT_OUTPUT_STEP

    def __post_init__(self):
        if self.method not in INTEGRATION_METHODS:
            raise InputError(
                f"integration method '{self.method}' is unknown; expected one of "
                f"{', '.join(INTEGRATION_METHODS)}"
            )
        for name in ("rtol", "atol", "output_step") + (("step",) if self.step is not None else ()):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(
                    f"integration option '{name}' must be a positive number, got {value!r}"
                )
