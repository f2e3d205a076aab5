"""Figures of the comparison report that the paper has no counterpart for: the balance joints of
each plan against their limits. Same look as :mod:`balance_opt.report.plots` (the styles and names
of :mod:`balance_opt.report.style`), built without pyplot state."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from balance_opt.model.robot import FloatingRobot
from balance_opt.report import style
from balance_opt.report.figure_layout import arrange, column_title, legend_above, legend_columns
from balance_opt.result import BalanceResult

#: Rows of the figure: (result field, limit field, axis label).
_ROWS = (
    ("q_B", "position", "position [rad]"),
    ("q_dot_B", "velocity", "rate [rad/s]"),
    ("q_ddot_B", "acceleration", "accel. [rad/s²]"),
)
#: Largest number of joint columns drawn (a 7-DOF arm still fits a page).
MAX_COLUMNS = 7
#: The y axis of a row reaches at most this many times a limit beyond it: a plan far outside
#: (a law that ran away) would otherwise squash every other plan and the limits to a line.
OFF_SCALE = 1.5
#: Style of the limit lines.
LIMIT_STYLE = {"color": "0.35", "linestyle": (0, (1.0, 1.0)), "linewidth": 0.9, "label": "limit"}


def _bounds(lim, kind: str, i: int) -> tuple[float, float]:
    if kind == "position":
        return lim.lower[i], lim.upper[i]
    value = getattr(lim, kind)[i]
    return -value, value


def joint_limits_figure(
    results: Mapping[str, BalanceResult],
    robot: FloatingRobot,
    path: str | Path | None = None,
    dpi: int = style.SCREEN_DPI,
):
    """Balance joint positions, rates and accelerations of each plan against time, one column
    per joint, the joint's limits dotted. The y range covers both the limits and every plan,
    so a violation is seen at a glance. Returns the path written, or the figure without ``path``.
    """
    first = next(iter(results.values()))
    joints = list(first.balance_joints)[:MAX_COLUMNS]
    width = "column" if len(joints) <= 2 else "page"
    with style.styled(width):
        fig = style.figure(width, 4.0)
        axes = fig.subplots(len(_ROWS), len(joints), sharex=True, squeeze=False)
        for c, joint in enumerate(joints):
            _joint_column(axes[:, c], results, robot, joint, list(first.balance_joints))
            column_title(axes[0, c], joint, width)
        handles = axes[0, 0].get_lines()
        handles = [h for h in handles if h.get_label() != "_limit"][: len(results)]
        handles.append(_limit_handle())
        ncol = legend_columns([h.get_label() for h in handles], width)
        anchor = arrange(fig, axes, width, legend_rows=-(-len(handles) // ncol), column_titles=True)
        legend_above(fig, handles, width, anchor, ncol)
        if path is None:
            return fig
        return style.save(fig, Path(path).with_suffix(""), ("png",), dpi=dpi)[0]


def _clip_off_scale(ax, results, field: str, k: int, bounds) -> None:
    """Limit the y axis to :data:`OFF_SCALE` times the limits (measured from their middle) when
    a plan goes beyond, and name the plans off the scale with their extreme value."""
    middle, half = (bounds[0] + bounds[1]) / 2, (bounds[1] - bounds[0]) / 2
    low, high = middle - OFF_SCALE * half, middle + OFF_SCALE * half
    off = []
    for name, res in results.items():
        values = getattr(res, field)[:, k]
        if values.size and (values.min() < low or values.max() > high):
            peak = values[np.argmax(np.abs(values - middle))]
            off.append(f"{style.method_label(name)} off scale (to {peak:.3g})")
    if not off:
        return
    ax.set_ylim(low, high)
    ax.text(
        0.02, 0.97, "\n".join(off), transform=ax.transAxes, va="top", ha="left",
        fontsize="x-small", color="0.2", bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
    )


def _limit_handle():
    from matplotlib.lines import Line2D

    return Line2D([], [], **LIMIT_STYLE)


def _joint_column(axes, results, robot: FloatingRobot, joint: str, balance_joints) -> None:
    from matplotlib.ticker import MaxNLocator

    i = robot.joint_index(joint)
    k = balance_joints.index(joint)
    first = next(iter(results.values()))
    for r, (field, kind, label) in enumerate(_ROWS):
        ax = axes[r]
        for name, res in results.items():
            ax.plot(res.t, getattr(res, field)[:, k], **style.method_style(name, markers=False))
        bounds = [b for b in _bounds(robot.limits, kind, i) if np.isfinite(b)]
        if bounds:  # one line for both limits (NaN between): fewer artists than axhline
            t0, t1 = first.t[0], first.t[-1]
            ys = [y for b in bounds for y in (b, b, np.nan)]
            ax.plot([t0, t1, np.nan] * len(bounds), ys, **{**LIMIT_STYLE, "label": "_limit"})
        if len(bounds) == 2:
            _clip_off_scale(ax, results, field, k, bounds)
        if joint == balance_joints[0]:
            ax.set_ylabel(label)
        ax.yaxis.set_major_locator(MaxNLocator(4))
        ax.margins(x=0)
    axes[-1].set_xlabel("time [s]")
