"""Figures of the paper's study (Figs. 2-5), sized for a paper column.

Every function takes a mapping ``{name: result}`` of the plans to overlay (any object with
``t`` and ``rpy``, such as :class:`~balance_opt.result.BalanceResult` or
:class:`~balance_opt.dynamics.simulation.SimulationResult`; for torques, simulation results), draws
one curve per plan and component, writes the figure as PNG and PDF and returns the
``matplotlib.figure.Figure`` and the files. Known names (``"analytic"``, ``"optimal"``, ...)
get fixed colours and labels so that a plan looks the same in every figure; other names get the
next colour of a colour-blind-safe palette and are labelled by their name.

Figures are built with :class:`matplotlib.figure.Figure` (no pyplot state) inside a local
``matplotlib.rc_context``: nothing global changes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib as mpl
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

#: Width of a paper column [in].
COLUMN_WIDTH = 3.5
#: Resolution of the PNG files [dpi].
PNG_DPI = 300
FORMATS = ("png", "pdf")

#: Okabe-Ito colours: distinct for colour-blind readers and in greyscale print.
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9")
PLAN_COLOURS = {
    "analytic": PALETTE[0],
    "optimal": PALETTE[1],
    "mission-only": "#000000",
    "kinematic": PALETTE[2],
}
PLAN_LABELS = {
    "analytic": "analytic (damped LS)",
    "optimal": "optimal plan",
    "mission-only": "mission arm alone",
    "kinematic": "kinematic (momentum)",
}
#: Line style of each part of the reaction torque (Fig. 4).
TORQUE_PARTS = {"total": ("-", 1.3), "mission": ((0, (4, 1.5)), 0.8), "balance": ((0, (1, 1)), 0.9)}
TORQUE_PART_LABELS = {"total": "sum of arms", "mission": "mission arm", "balance": "balance arm"}

STYLE = {
    "font.size": 8,
    "axes.labelsize": 8,
    "axes.titlesize": 8,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "legend.fontsize": 7,
    "lines.linewidth": 1.1,
    "axes.linewidth": 0.6,
    "xtick.major.width": 0.6,
    "ytick.major.width": 0.6,
    "grid.linewidth": 0.4,
    "grid.alpha": 0.5,
    "axes.grid": True,
    "font.family": "DejaVu Sans",
    "pdf.fonttype": 42,  # TrueType in the PDF: editable, accepted by publishers
    "savefig.dpi": PNG_DPI,
}

ATTITUDE_AXES = ("roll", "pitch", "yaw")
TORQUE_AXES = ("x", "y", "z")


def plan_colour(name: str, index: int) -> str:
    """The colour of plan ``name`` (the ``index``-th in its figure)."""
    return PLAN_COLOURS.get(name, PALETTE[index % len(PALETTE)])


def plan_label(name: str) -> str:
    return PLAN_LABELS.get(name, name)


def save_figure(fig: Figure, stem: str | Path, formats: Sequence[str] = FORMATS) -> list[Path]:
    """Write ``fig`` as ``<stem>.<format>`` for each format (PNG at :data:`PNG_DPI`)."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        path = stem.with_suffix(f".{fmt}")
        fig.savefig(path, dpi=PNG_DPI)
        paths.append(path)
    return paths


def _stacked_axes(rows: int, height: float, title: str | None):
    fig = Figure(figsize=(COLUMN_WIDTH, height), layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True)
    if title:
        fig.suptitle(title)
    return fig, axes


def _blank() -> Line2D:
    return Line2D([], [], alpha=0.0, label=" ")


def _legend_above(ax, handles, ncol: int) -> None:
    """A frameless legend above the top panel (constrained layout makes room for it), read row
    by row in the order of ``handles``."""
    rows = -(-len(handles) // ncol)
    handles = list(handles) + [_blank() for _ in range(rows * ncol - len(handles))]
    handles = [
        handles[r * ncol + c] for c in range(ncol) for r in range(rows)
    ]  # legends fill by column
    labels = [h.get_label() for h in handles]
    ax.legend(
        handles,
        labels,
        loc="lower center",
        bbox_to_anchor=(0.5, 1.02),
        ncol=ncol,
        frameon=False,
        handlelength=2.4,
        borderaxespad=0.0,
        columnspacing=1.0,
        handletextpad=0.5,
    )


def _finish_time_axis(axes, t_end: float) -> None:
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(0.0, t_end)
    for ax in axes:
        ax.margins(x=0, y=0.1)  # head room: flat extremes must not sit on the frame
        ax.yaxis.set_major_locator(mpl.ticker.MaxNLocator(4))


def attitude_figure(
    results: Mapping[str, Any],
    stem: str | Path,
    *,
    title: str | None = None,
    dashed: Mapping[str, Any] | None = None,
    formats: Sequence[str] = FORMATS,
) -> tuple[Figure, list[Path]]:
    """Base roll, pitch and yaw [deg] against time [s], one panel each (paper Figs. 2, 3, 5).

    Args:
        results: ``{name: result}``, each with ``t`` (T,) [s] and ``rpy`` (T, 3) [rad]; one
            solid curve per plan and panel.
        stem: output path without suffix.
        title: figure title.
        dashed: more results drawn dashed, for reference (for example a kinematic replay).
        formats: file formats to write.

    Returns:
        The figure and the files written. Each curve's label is its plan's label.
    """
    with mpl.rc_context(STYLE):
        fig, axes = _stacked_axes(3, 3.9, title)
        t_end = 0.0
        curves = [(name, res, "-") for name, res in results.items()]
        curves += [(name, res, "--") for name, res in (dashed or {}).items()]
        for i, (name, res, style) in enumerate(curves):
            deg = np.degrees(res.rpy)
            t_end = max(t_end, float(res.t[-1]))
            for k, ax in enumerate(axes):
                ax.plot(
                    res.t,
                    deg[:, k],
                    style,
                    color=plan_colour(name, i),
                    label=plan_label(name),
                    lw=1.0 if style != "-" else 1.4,
                )
        for ax, name in zip(axes, ATTITUDE_AXES):
            ax.set_ylabel(f"{name} [deg]")
        _finish_time_axis(axes, t_end)
        _legend_above(axes[0], axes[0].get_legend_handles_labels()[0], ncol=min(2, len(curves)))
        paths = save_figure(fig, stem, formats)
    return fig, paths


def reaction_torque_figure(
    simulations: Mapping[str, Any],
    stem: str | Path,
    *,
    title: str | None = None,
    formats: Sequence[str] = FORMATS,
) -> tuple[Figure, list[Path]]:
    """Torque the arms exert on the base, per arm and summed [N m], base axes, against time
    (paper Fig. 4).

    Args:
        simulations: ``{name: SimulationResult}``; colour tells the plan, line style the part:
            solid the sum, dashed the mission arm, dotted the balance arm(s).
        stem: output path without suffix.
        title: figure title.
        formats: file formats to write.

    Returns:
        The figure and the files written. Each curve is labelled ``"<plan label>: <part>"``.
    """
    with mpl.rc_context(STYLE):
        fig, axes = _stacked_axes(3, 4.3, title)
        t_end = 0.0
        for i, (name, sim) in enumerate(simulations.items()):
            colour = plan_colour(name, i)
            t_end = max(t_end, float(sim.t[-1]))
            parts = {
                "mission": sim.arm_wrenches["mission"],
                "balance": sum(w for arm, w in sim.arm_wrenches.items() if arm != "mission"),
                "total": sim.total_wrench,
            }
            for part, wrench in parts.items():
                style, width = TORQUE_PARTS[part]
                for k, ax in enumerate(axes):
                    ax.plot(
                        sim.t,
                        wrench[:, 3 + k],
                        linestyle=style,
                        lw=width,
                        color=colour,
                        label=f"{plan_label(name)}: {TORQUE_PART_LABELS[part]}",
                    )
        for ax, name in zip(axes, TORQUE_AXES):
            ax.set_ylabel(f"torque {name} [N m]")
        _finish_time_axis(axes, t_end)
        # legend: plans (colours) on the first row, parts (line styles) on the second
        plans = [
            Line2D([], [], color=plan_colour(n, i), lw=1.3, label=plan_label(n))
            for i, n in enumerate(simulations)
        ]
        parts = [
            Line2D(
                [],
                [],
                color="0.3",
                linestyle=TORQUE_PARTS[p][0],
                lw=TORQUE_PARTS[p][1],
                label=TORQUE_PART_LABELS[p],
            )
            for p in ("total", "mission", "balance")
        ]
        ncol = max(len(plans), len(parts))
        handles = plans + [_blank()] * (ncol - len(plans)) + parts
        _legend_above(axes[0], handles, ncol=ncol)
        paths = save_figure(fig, stem, formats)
    return fig, paths


def curve_labels(fig: Figure) -> list[list[str]]:
    """The labels of the curves in each panel of a figure (to check what it shows)."""
    return [[line.get_label() for line in ax.get_lines()] for ax in fig.axes]
