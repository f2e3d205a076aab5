"""A quick look at one result on matplotlib axes, for notebooks (``balance_opt.plot_result``):
it draws on axes the caller owns (or a new figure), writes nothing and leaves the caller's
matplotlib settings alone; each method looks as in the written figures."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from balance_opt.report.style import method_style

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
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots()
    style = method_style(result.method)
    if kind == "attitude":
        ax.plot(result.t, np.degrees(result.angle), **style)
    else:
        dashes = ("-", "--", ":", "-.")
        for j, name in enumerate(result.balance_joints):
            joint = {**style, "linestyle": dashes[j % len(dashes)], "marker": ""}
            ax.plot(result.t, result.q_B[:, j], **{**joint, "label": f"{style['label']}: {name}"})
    ax.set_xlabel("time [s]")
    ax.set_ylabel(KINDS[kind])
    ax.legend()
    return ax
