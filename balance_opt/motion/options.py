"""Settings of the attitude integration and of the model-error study, declared once for Python
calls and task files (integration keys in the ``analytic`` section)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from balance_opt.config.typed_config import check_settings, setting

#: Default relative and absolute tolerances of the adaptive integrator (quaternion, [rad]).
DEFAULT_RTOL = 1e-10
DEFAULT_ATOL = 1e-12
#: Default spacing of the output samples [s]: 100 Hz, what a report needs.
DEFAULT_OUTPUT_STEP = 0.01
INTEGRATION_METHODS = ("adaptive", "rk4")
#: Default budget of the adaptive integrator: far above what a sound law needs, far below what
#: a law whose rates run away would take.
DEFAULT_MAX_EVALUATIONS = 20_000


@dataclass(frozen=True)
class IntegrationOptions:
    """How to integrate the attitude (and the balance joints).

    ``atol`` is in quaternion units (~ [rad] / 2) for the attitude and [rad] for the joints.
    ``step`` bounds the step of either method (``"rk4"`` without it: ``output_step``).
    """

    method: Literal[INTEGRATION_METHODS] = setting(
        INTEGRATION_METHODS[0],
        key="integrator",
        doc="adaptive (DOP853, error-controlled) or rk4 (fixed step)",
    )
    rtol: float = setting(
        DEFAULT_RTOL, exclusive_minimum=0.0, doc="relative tolerance of the adaptive integrator"
    )
    atol: float = setting(
        DEFAULT_ATOL, exclusive_minimum=0.0, doc="absolute tolerance of the adaptive integrator"
    )
    step: float | None = setting(
        None,
        unit="s",
        exclusive_minimum=0.0,
        doc="largest integration step (rk4 default: output_step)",
    )
    output_step: float = setting(
        DEFAULT_OUTPUT_STEP,
        unit="s",
        exclusive_minimum=0.0,
        doc="spacing of the output samples",
    )

    max_evaluations: int = setting(
        DEFAULT_MAX_EVALUATIONS,
        minimum=1,
        in_file=False,  # a safeguard, not a setting of a task
        doc="right-hand side evaluations after which the adaptive integrator gives up "
        "(a law that runs away)",
    )

    def __post_init__(self):
        check_settings(self, "integration option")


@dataclass(frozen=True)
class RobustnessOptions:
    """The drift-under-model-error study (:mod:`balance_opt.motion.robustness`): every plan's
    joint motion replayed on ``samples`` robots whose masses, centres of mass and inertias are
    perturbed by ``perturbation`` (relative, physical by construction), seeded by ``seed``.

    ``enabled`` unset runs the study in ``compare`` and not in ``plan``.
    """

    enabled: bool | None = setting(None, doc="run the study (default: in compare, not in plan)")
    samples: int = setting(50, minimum=1, doc="perturbed models K")
    perturbation: float = setting(
        0.10,
        minimum=0.0,
        doc="relative size of the perturbation of every body's mass, centre of mass (times "
        "its radius of gyration) and second moments",
    )
    seed: int = setting(0, minimum=0, doc="seed of the perturbations")

    def __post_init__(self):
        check_settings(self, "robustness option")

    def runs_in(self, command: str) -> bool:
        """Whether the study runs in ``command`` (``"plan"`` or ``"compare"``)."""
        return self.enabled if self.enabled is not None else command == "compare"
