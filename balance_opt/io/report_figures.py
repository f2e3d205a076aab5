"""Figures of the comparison report that the paper has no counterpart for: the balance joints of
each plan against their limits. Same look as :mod:`balance_opt.io.plots` (its style, colours and
labels), built without pyplot state."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.figure import Figure

from balance_opt.io.plots import COLUMN_WIDTH, PNG_DPI, STYLE, plan_colour, plan_label
from balance_opt.model.robot import FloatingRobot
from balance_opt.result import BalanceResult

#: Rows of the figure: (result field, limit field, axis label).
_ROWS = (
    ("q_B", "position", "position [rad]"),
    ("q_dot_B", "velocity", "rate [rad/s]"),
    ("q_ddot_B", "acceleration", "acceleration [rad/s$^2$]"),
)
#: Largest number of joint columns drawn (a 7-DOF arm still fits a page).
MAX_COLUMNS = 7


def joint_limits_figure(
    results: Mapping[str, BalanceResult], robot: FloatingRobot, path: str | Path
) -> Path:
    """Balance joint positions, rates and accelerations of each plan against time, one column
    per joint, the joint's limits dotted. Writes a PNG at ``path`` and returns it.

    The y range covers both the limits and every plan, so a violation is seen at a glance.
    """
    path = Path(path)
    first = next(iter(results.values()))
    joints = list(first.balance_joints)[:MAX_COLUMNS]
    lim = robot.limits
    with mpl.rc_context(STYLE):
        width = max(COLUMN_WIDTH, 1.6 * len(joints))
        fig = Figure(figsize=(width, 4.2), layout="constrained")
        axes = np.atleast_2d(fig.subplots(len(_ROWS), len(joints), sharex=True, squeeze=False))
        for c, joint in enumerate(joints):
            i = robot.joint_index(joint)
            k = list(first.balance_joints).index(joint)
            for r, (field, kind, label) in enumerate(_ROWS):
                ax = axes[r, c]
                for n, (name, res) in enumerate(results.items()):
                    ax.plot(
                        res.t,
                        getattr(res, field)[:, k],
                        color=plan_colour(name, n),
                        label=plan_label(name),
                        lw=1.1,
                    )
                bounds = (
                    (lim.lower[i], lim.upper[i])
                    if kind == "position"
                    else (-getattr(lim, kind)[i], getattr(lim, kind)[i])
                )
                for b in bounds:
                    if np.isfinite(b):
                        ax.axhline(b, color="0.35", ls=":", lw=0.9)
                if r == 0:
                    ax.set_title(joint, fontsize=7)
                if c == 0:
                    ax.set_ylabel(label)
                if r == len(_ROWS) - 1:
                    ax.set_xlabel("time [s]")
                ax.yaxis.set_major_locator(mpl.ticker.MaxNLocator(4))
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(
            handles, labels, loc="outside upper center", ncol=max(1, len(handles)), frameon=False
        )
        fig.savefig(path, dpi=PNG_DPI // 2)
    return path
