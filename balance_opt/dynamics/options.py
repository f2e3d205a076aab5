"""Settings of the forward-dynamics simulation."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from balance_opt.errors import InputError

#: Default integration step [s].
DEFAULT_DT = 1e-3
#: Default closed-loop bandwidth of each joint's PD loop [rad/s] and its damping ratio.
DEFAULT_BANDWIDTH = 20.0
DEFAULT_DAMPING_RATIO = 1.0
INTEGRATORS = ("rk4", "dopri5")
CONTROLLERS = ("pd", "computed-torque")


@dataclass(frozen=True)
class SimulationOptions:
    """How to simulate.

    Attributes:
        integrator: ``"rk4"`` (fixed step ``dt``) or ``"dopri5"`` (adaptive, ``dt`` is its first step).
        dt: integration step [s].
        rtol, atol: error tolerances of ``"dopri5"`` (per component of the tangent increment;
            configuration components are scaled as if of unit size) [-, rad or m or rad/s].
        max_step: largest step of ``"dopri5"`` [s].
        output_dt: time between output samples [s]; by default every step of ``"rk4"`` and
            0.01 s for ``"dopri5"``. Rounded to a whole number of ``"rk4"`` steps.
        controller: ``"pd"`` or ``"computed-torque"`` (see the module docstring).
        kp: proportional gains [N m/rad], a scalar or one per arm joint (arm order); by default
            ``M_ii bandwidth^2`` with ``M_ii`` the joint's diagonal inertia at the start.
        kd: derivative gains [N m s/rad]; by default ``2 damping_ratio bandwidth M_ii``.
        bandwidth: natural frequency of the default gains [rad/s].
        damping_ratio: damping ratio of the default gains.
        clip_torque: saturate torques at the joints' effort limits.
        h0: the system's momentum ``[linear; angular about the CoM]`` in world axes [N s, N m s];
            zero by default.
    """

    integrator: str = "rk4"
    dt: float = DEFAULT_DT
    rtol: float = 1e-10
    atol: float = 1e-12
    max_step: float = 0.05
    output_dt: float | None = None
    controller: str = "pd"
    kp: float | tuple[float, ...] | None = None
    kd: float | tuple[float, ...] | None = None
    bandwidth: float = DEFAULT_BANDWIDTH
    damping_ratio: float = DEFAULT_DAMPING_RATIO
    clip_torque: bool = False
    h0: tuple[float, ...] | None = None

    def __post_init__(self):
        if self.integrator not in INTEGRATORS:
            raise InputError(
                f"simulation option 'integrator' must be one of {', '.join(INTEGRATORS)}, "
                f"got {self.integrator!r}"
            )
        if self.controller not in CONTROLLERS:
            raise InputError(
                f"simulation option 'controller' must be one of {', '.join(CONTROLLERS)}, "
                f"got {self.controller!r}"
            )
        for name in ("dt", "rtol", "atol", "max_step", "bandwidth", "damping_ratio"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise InputError(
                    f"simulation option '{name}' must be a positive number, got {value!r}"
                )
        if self.output_dt is not None and not (
            math.isfinite(self.output_dt) and self.output_dt > 0
        ):
            raise InputError(
                f"simulation option 'output_dt' must be a positive number, got {self.output_dt!r}"
            )
        if self.h0 is not None and np.shape(self.h0) != (6,):
            raise InputError(
                f"simulation option 'h0' must have 6 values [linear; angular], got {np.size(self.h0)}"
            )
        for name in ("kp", "kd"):  # store hashable tuples
            value = getattr(self, name)
            if value is not None and np.ndim(value) > 0:
                object.__setattr__(self, name, tuple(float(x) for x in np.ravel(value)))
