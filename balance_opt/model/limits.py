"""Joint limits of a robot's arms: the URDF's, a mimic follower's carried to its driver, the
task's overrides, each checked (a limit no joint can have is blamed on the override that set
it, else on the URDF)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from balance_opt.config.typed_config import suggest
from balance_opt.errors import JointError, URDFLoadError
from balance_opt.model.joints import narrow_driver_limits

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


class LimitOverrideError(JointError):
    """A limit override that no joint can have; ``key`` is the override at fault."""

    def __init__(self, joint: str, source: str, key: str, reason: str):
        self.key = key
        super().__init__(joint, source, reason)


def joint_limits(
    model: pin.Model,
    joint_names: Sequence[str],
    followers,
    pin_indices: tuple,
    overrides: Mapping[str, Mapping[str, float]],
    source: str,
) -> JointLimits:
    """The limits of the arm joints ``joint_names``: the URDF's (in the Pinocchio ``model``,
    ``pin_indices`` = each joint's ``(nq, idx_q, idx_v)``), narrowed by the mimic
    ``followers``' own, then the ``overrides`` (``{joint: {kind: value}}``), each checked.

    Raises:
        JointError: an override of a joint in no arm, or of an unknown kind.
        LimitOverrideError: an override no joint can have; URDFLoadError: the URDF's.
    """
    pin_nq, pin_idx_q, pin_idx_v = pin_indices
    values = {k: np.full(len(joint_names), np.inf) for k in LIMIT_KEYS}
    values["lower"] = -values["lower"]
    for i, j in enumerate(joint_names):
        if pin_nq[i] == 1:
            values["lower"][i] = model.lowerPositionLimit[pin_idx_q[i]]
            values["upper"][i] = model.upperPositionLimit[pin_idx_q[i]]
        values["velocity"][i] = model.velocityLimit[pin_idx_v[i]]
        values["effort"][i] = model.effortLimit[pin_idx_v[i]]
    narrow_driver_limits(values, model, joint_names, followers)
    for j, over in overrides.items():
        if j not in joint_names:
            raise JointError(
                j,
                source,
                "limit override for a joint that is in no arm" + suggest(j, joint_names),
            )
        for key, value in over.items():
            if key not in LIMIT_KEYS:
                raise JointError(
                    j,
                    source,
                    f"unknown limit '{key}'; expected one of {', '.join(LIMIT_KEYS)}",
                )
            values[key][joint_names.index(j)] = float(value)
    for i, j in enumerate(joint_names):
        _check_limits_of(j, {k: values[k][i] for k in LIMIT_KEYS}, overrides.get(j, {}), source)
    return JointLimits(**values)


def _check_limits_of(joint: str, value: dict, given: Mapping[str, float], source: str) -> None:
    """Limits of ``joint`` that no joint can have, blamed on the override that set them
    (:class:`LimitOverrideError`), else on the URDF."""
    lo, hi = value["lower"], value["upper"]
    if not lo <= hi:
        if "lower" not in given and "upper" not in given:
            raise URDFLoadError(
                source, f"joint '{joint}': <limit> has lower {lo:g} above upper {hi:g}"
            )
        key = "lower" if "lower" in given else "upper"
        other = "upper" if key == "lower" else "lower"
        raise LimitOverrideError(
            joint,
            source,
            key,
            f"lower limit {lo:g} is above upper limit {hi:g}"
            + ("" if other in given else f" ({other} limit from the URDF)"),
        )
    for key in ("velocity", "acceleration", "effort", "jerk"):
        if not value[key] > 0:
            if key not in given:
                raise URDFLoadError(
                    source,
                    f"joint '{joint}': <limit> has {key} {value[key]:g}; it must be positive",
                )
            raise LimitOverrideError(
                joint, source, key, f"{key} limit must be positive, got {value[key]:g}"
            )
