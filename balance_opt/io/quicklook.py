"""A quick look at one result on matplotlib axes, for notebooks: :meth:`BalanceResult.plot`.

Unlike the figures of :mod:`balance_opt.io.plots` (which a run writes to files), this draws on
axes the caller owns (or on a new figure) and writes nothing; the colours and labels of the
methods are those of the written figures.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from balance_opt.result import BalanceResult

#: What :func:`plot_result` can draw: ``kind -> y-axis label``.
KINDS = {
    "attitude": "base rotation from start [deg]",
    "balance": "balance joint position [rad]",
}


def plot_result(result: BalanceResult, ax: Axes | None = None, kind: str = "attitude") -> Axes:
    """Draw ``result`` on ``ax`` (a new figure when ``None``) and return the axes.

    Args:
        result: the motion.
        ax: the axes; ``None`` makes a new figure with ``plt.subplots``.
        kind: ``"attitude"`` (the base rotation from the start, deg) or ``"balance"`` (each
            balance joint's position, rad).

    Raises:
        ValueError: an unknown ``kind``.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    from balance_opt.io.plots import plan_colour, plan_label

    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots()
    colour = plan_colour(result.method, len(ax.lines))
    label = plan_label(result.method)
    if kind == "attitude":
        ax.plot(result.t, np.degrees(result.angle), color=colour, label=label)
    else:
        styles = ("-", "--", ":", "-.")
        for j, name in enumerate(result.balance_joints):
            ax.plot(
                result.t,
                result.q_B[:, j],
                color=colour,
                linestyle=styles[j % len(styles)],
                label=f"{label}: {name}",
            )
    ax.set_xlabel("time [s]")
    ax.set_ylabel(KINDS[kind])
    ax.legend()
    return ax
