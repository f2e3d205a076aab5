"""Figures of a plan's base attitude and of the torque on the base (paper Figs. 2-5).

Every function takes ``{name: result}`` of the curves to overlay; the name is a method of
:mod:`balance_opt.report.style` and gives the curve its look and label. The figures carry no
title (a caption belongs to the text around them) and touch no pyplot state. Given ``axes=`` a
function draws into the caller's axes; given no ``stem`` it writes nothing."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.report import style
from balance_opt.report.figure_layout import arrange, column_title, legend_above, legend_columns

FORMATS = ("png", "pdf")
ATTITUDE_AXES = ("roll", "pitch", "yaw")
TORQUE_AXES = ("x", "y", "z")
#: Height of a three-panel figure [in].
STACK_HEIGHT = 3.9


def _finish(fig, stem, formats, dpi) -> list[Path]:
    return [] if stem is None else style.save(fig, stem, formats, dpi=dpi)


def _time_axes(axes, t_end: float, labels: Sequence[str]) -> None:
    from matplotlib.ticker import MaxNLocator

    for ax, label in zip(axes, labels):
        ax.set_ylabel(label)
        ax.margins(x=0, y=0.12)  # head room: flat extremes must not sit on the frame
        ax.yaxis.set_major_locator(MaxNLocator(4))
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(0.0, t_end)


def draw_attitude(axes, results: Mapping[str, Any]) -> list:
    """Draw roll, pitch and yaw [deg] of each result into three axes, or, into one axes, the
    base's rotation angle from its start [deg]. Returns the curves of the first axes."""
    axes = list(np.atleast_1d(axes))
    for name, res in results.items():
        kwargs = style.method_style(name)
        if len(axes) == 1:
            axes[0].plot(res.t, np.degrees(res.angle), **kwargs)
            continue
        deg = np.degrees(res.rpy)
        for k, ax in enumerate(axes):
            ax.plot(res.t, deg[:, k], **kwargs)
    return axes[0].get_lines()


def attitude_figure(
    results: Mapping[str, Any],
    stem: str | Path | None = None,
    *,
    dashed: Mapping[str, Any] | None = None,
    formats: Sequence[str] = FORMATS,
    dpi: int = style.PRINT_DPI,
    axes=None,
) -> tuple[Any, list[Path]]:
    """Base roll, pitch and yaw [deg] against time [s], one panel each (paper Figs. 2, 3, 5),
    one column wide; returns the figure and the files written.

    ``dashed``: more results drawn after ``results`` (a reference such as the mission arm alone).
    ``axes``: three axes to draw into.
    """
    curves = {**results, **(dashed or {})}
    t_end = max(float(res.t[-1]) for res in curves.values())
    if axes is not None:
        draw_attitude(axes, curves)
        return np.atleast_1d(axes)[0].figure, []
    with style.styled("column"):
        fig = style.figure("column", STACK_HEIGHT)
        axes = fig.subplots(3, 1, sharex=True)
        handles = draw_attitude(axes, curves)
        _time_axes(axes, t_end, [f"{a} [deg]" for a in ATTITUDE_AXES])
        ncol = legend_columns([h.get_label() for h in handles], "column")
        rows = -(-len(handles) // ncol)
        anchor = arrange(fig, axes[:, None], "column", legend_rows=rows)
        legend_above(fig, handles, "column", anchor, ncol)
        return fig, _finish(fig, stem, formats, dpi)


def model_error_figure(
    results: Mapping[str, Any],
    bands: Mapping[str, np.ndarray],
    stem: str | Path | None = None,
    *,
    perturbation: float,
    formats: Sequence[str] = FORMATS,
    dpi: int = style.PRINT_DPI,
) -> tuple[Any, list[Path]]:
    """The base's rotation from its start [deg] of each plan as planned (the line) and the 95th
    percentile over perturbed models (the band up to the dotted edge), one column wide.

    Args:
        results: ``{name: result}`` with ``t`` and ``angle``.
        bands: ``{name: p95 angle at result.t}`` [rad] (a plan without one has no band).
        stem: output path without suffix; ``None`` writes nothing.
        perturbation: the relative model error the bands are for (named in the legend).
        formats: file formats to write.
        dpi: resolution of the PNG.
    """
    with style.styled("column"):
        fig = style.figure("column", 2.4)
        ax = fig.subplots(1, 1)
        for name, res in results.items():
            kwargs = style.method_style(name)
            ax.plot(res.t, np.degrees(res.angle), **kwargs)
            if name in bands:
                band = np.degrees(bands[name])
                colour = kwargs.get("color")
                ax.fill_between(res.t, np.degrees(res.angle), band, color=colour, alpha=0.18,
                                linewidth=0)
                ax.plot(res.t, band, color=colour, linestyle=":", linewidth=0.9)
        handles = [line for line in ax.get_lines() if line.get_linestyle() != ":"]
        handles += ax.plot([], [], color="0.3", linestyle=":", linewidth=0.9,
                           label=f"95th percentile, {perturbation:.0%} model error")
        _time_axes([ax], max(float(r.t[-1]) for r in results.values()), ["rotation [deg]"])
        ncol = legend_columns([h.get_label() for h in handles], "column")
        anchor = arrange(fig, np.array([[ax]]), "column", legend_rows=-(-len(handles) // ncol))
        legend_above(fig, handles, "column", anchor, ncol)
        return fig, _finish(fig, stem, formats, dpi)


def clearance_figure(
    curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
    margin: float | None,
    stem: str | Path | None = None,
    *,
    formats: Sequence[str] = FORMATS,
    dpi: int = style.PRINT_DPI,
) -> tuple[Any, list[Path]]:
    """The smallest distance between any two bodies that may touch [m] against time, one curve
    per motion ``{name: (t, distance)}``, with zero (contact) and the planner's ``margin``
    (dotted) marked; one column wide."""
    with style.styled("column"):
        fig = style.figure("column", 2.4)
        ax = fig.subplots(1, 1)
        for name, (t, d) in curves.items():
            ax.plot(t, d, **style.method_style(name))
        ax.axhline(0.0, color="0.2", linewidth=0.8)
        if margin is not None:
            ax.axhline(margin, color="0.4", linestyle=":", linewidth=0.9)
            ax.annotate(f"margin {margin:g} m", (0.01, margin), xycoords=("axes fraction", "data"),
                        ha="left", va="bottom", fontsize="small", color="0.3")
        t_end = max(float(t[-1]) for t, _ in curves.values())
        _time_axes([ax], t_end, ["smallest distance [m]"])
        handles = ax.get_lines()[: len(curves)]
        ncol = legend_columns([h.get_label() for h in handles], "column")
        anchor = arrange(fig, np.array([[ax]]), "column", legend_rows=-(-len(handles) // ncol))
        legend_above(fig, handles, "column", anchor, ncol)
        return fig, _finish(fig, stem, formats, dpi)


def _torque_parts(name: str, sim) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """(wrench, plot kwargs) of the sum, the mission arm and the balance arm(s) of one plan."""
    balance = sum(w for arm, w in sim.arm_wrenches.items() if arm != "mission")
    sim_name = name if name.endswith(style.SIM) else f"{name}{style.SIM}"
    balance_style = {**style.method_style(sim_name), "label": f"{style.method_label(name)}: "}
    balance_style["label"] += "balance arm"
    # Where the balance arm carries most of the sum (the optimal plan's torques), the two
    # curves coincide: the balance arm wide and pale under the thin sum keeps both readable,
    # in greyscale too.
    balance_style.update(linewidth=2.6, alpha=0.55, zorder=1.8)
    return [
        (sim.total_wrench, {**style.method_style("sum"), "zorder": 2.5}),
        (sim.arm_wrenches["mission"], style.method_style("arm:mission")),
        (balance, balance_style),
    ]


def draw_torque(axes, name: str, sim) -> None:
    """Torque on the base [N m] of one plan's simulation into three axes (x, y, z): the sum of
    the arms, the mission arm's part, the balance arm's part."""
    for wrench, kwargs in _torque_parts(name, sim):
        for k, ax in enumerate(np.atleast_1d(axes)):
            ax.plot(sim.t, wrench[:, 3 + k], **kwargs)


def reaction_torque_figure(
    simulations: Mapping[str, Any],
    stem: str | Path | None = None,
    *,
    formats: Sequence[str] = FORMATS,
    dpi: int = style.PRINT_DPI,
) -> tuple[Any, list[Path]]:
    """Torque the arms exert on the base [N m], base axes, against time (paper Fig. 4): one
    column of panels per plan, each with its own scale (the analytic law's torques are tens of
    times smaller than the optimal plan's); a page wide for two plans or more. Returns the figure
    and the files written.
    """
    width = "page" if len(simulations) > 1 else "column"
    with style.styled(width):
        fig = style.figure(width, 4.0 if width == "page" else STACK_HEIGHT)
        axes = fig.subplots(3, len(simulations), sharex=True, squeeze=False)
        t_end = max(float(sim.t[-1]) for sim in simulations.values())
        handles = []
        for c, (name, sim) in enumerate(simulations.items()):
            draw_torque(axes[:, c], name, sim)
            handles += axes[0, c].get_lines()[(0 if c == 0 else 2) :]
            _time_axes(axes[:, c], t_end, [f"torque {a} [N m]" for a in TORQUE_AXES])
            if c:
                for ax in axes[:, c]:
                    ax.set_ylabel("")
            column_title(axes[0, c], style.method_label(name), width)
        ncol = legend_columns([h.get_label() for h in handles], width)
        rows = -(-len(handles) // ncol)
        anchor = arrange(fig, axes, width, legend_rows=rows, column_titles=True)
        legend_above(fig, handles, width, anchor, ncol)
        return fig, _finish(fig, stem, formats, dpi)


def paper_figure_set(
    output_dir: Path,
    stems: Mapping[str, str],
    formats: Sequence[str],
    mission_only,
    kinematic,
    balance_only,
    balanced,
) -> tuple[dict[str, list[Path]], dict[str, Any]]:
    """The paper's Figs. 2-5 of one study, as ``({"fig2": [files], ...}, {"fig2": Figure})``.

    Args:
        output_dir: the folder.
        stems: file name without suffix of ``"fig2"`` ... ``"fig5"``.
        formats: file formats.
        mission_only: simulation of the mission arm alone (Fig. 2 solid, Fig. 5 reference).
        kinematic: the mission arm alone under the momentum model (Fig. 2 dashed).
        balance_only: ``{method: simulation}`` of each plan's balance arm alone (Fig. 3).
        balanced: ``{method: simulation}`` of each plan, both arms moving (Figs. 4, 5).
    """

    def sims(results):
        return {f"{name}{style.SIM}": res for name, res in results.items()}

    figures, objects = {}, {}
    curves = {
        "fig2": {"mission-only:sim": mission_only, "mission-only:kinematic": kinematic},
        "fig3": sims(balance_only),
        "fig5": {**sims(balanced), "mission-only:sim": mission_only},
    }
    for key, results in curves.items():
        objects[key], figures[key] = attitude_figure(
            results, output_dir / stems[key], formats=formats
        )
    objects["fig4"], figures["fig4"] = reaction_torque_figure(
        balanced, output_dir / stems["fig4"], formats=formats
    )
    return dict(sorted(figures.items())), dict(sorted(objects.items()))


def curve_labels(fig) -> list[list[str]]:
    """The labels of the curves in each panel of a figure (to check what it shows)."""
    return [[line.get_label() for line in ax.get_lines()] for ax in fig.axes]
