"""Every figure of a run and of the paper's study: the base attitude, the torque on the base
(paper Figs. 2-5), the balance joints against their limits, clearance, model error and the
capture.

Every function takes ``{name: result}`` of the curves to overlay; the name is a method of
:mod:`balance_opt.report.style` and gives the curve its look and label. The figures carry no
title (a caption belongs to the text around them) and touch no pyplot state; each returns its
figure, which :func:`balance_opt.report.style.save` writes. :func:`plot_result`
(``balance_opt.plot_result``) is a quick look at one result for notebooks, on axes the caller
owns (or a new figure).

Constrained layout renders every text once per file written, which is slow. These figures have a
known shape (panels sharing the time axis, a y label left of the first column, a legend above),
so their margins follow from font sizes and tick-label lengths alone, estimated from the DejaVu
Sans glyph widths (:func:`layout`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from balance_opt.model.robot import FloatingRobot
from balance_opt.motion.result import BalanceResult, limit_bounds
from balance_opt.report import style
from balance_opt.report.outputs import capture_drifts
from balance_opt.report.style import FONTS, WIDTHS

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Widths of glyphs [em] (DejaVu Sans, rounded up); lower-case letters count as 0.58 em, other
#: characters as 0.7 em.
_GLYPH_EM = {".": 0.32, "-": 0.84, "\N{MINUS SIGN}": 0.84, "+": 0.84, " ": 0.32, "e": 0.62}
_DIGIT_EM = 0.64
#: Gaps [in]: around the figure, between a tick label and its axis (tick included), between
#: a label and its tick labels, between panels of one column.
_EDGE, _TICK_PAD, _LABEL_PAD, _ROW_GAP = 0.04, 0.07, 0.06, 0.08
#: Height of a line of text in units of its font size.
_LINE = 1.25
_PT = 1.0 / 72.0


def text_width(text: str, size_pt: float) -> float:
    """Estimated width of ``text`` [in] at ``size_pt``."""
    em = sum(
        _DIGIT_EM if c.isdigit() else _GLYPH_EM.get(c, 0.58 if c.islower() else 0.7) for c in text
    )
    return em * size_pt * _PT


def _tick_labels(axis) -> list[str]:
    lo, hi = sorted(axis.get_view_interval())
    span = (hi - lo) or 1.0
    locs = [v for v in axis.get_major_locator()() if lo - 1e-9 * span <= v <= hi + 1e-9 * span]
    return [s for s in axis.get_major_formatter().format_ticks(locs) if s]


def _y_extent(ax, tick_pt: float, label_pt: float) -> float:
    """Width left of an axes taken by its y tick labels and y label [in]."""
    ticks = _tick_labels(ax.yaxis)
    width = _TICK_PAD + max((text_width(s, tick_pt) for s in ticks), default=0.0)
    if ax.get_ylabel():
        width += _LABEL_PAD + _LINE * label_pt * _PT
    return width


def _legend_columns(labels: Sequence[str], width: str) -> int:
    """How many legend columns fit across a figure of ``width``, the entries filling rows
    (a column is as wide as its widest entry)."""
    size = FONTS[width]["legend"]
    entries = [text_width(s, size) + (2.6 + 0.5 + 1.2) * size * _PT for s in labels]
    room = WIDTHS[width] - 2 * _EDGE
    for ncol in range(len(entries), 1, -1):
        if sum(max(entries[c::ncol]) for c in range(ncol)) <= room:
            return ncol
    return 1


def _fitted_titles(titles: Sequence[str], room: float, size: float) -> tuple[list[str], float, int]:
    """Column titles that fit ``room`` [in] each at ``size`` [pt] (long joint names, such as
    Talos's ``arm_right_1_joint`` over seven columns, ran into each other): a wider one broken
    in two at the separator (``_``, ``-``, space) that balances its lines best, then the font
    made smaller if a line is still too wide. Returns the titles, their font size [pt] and
    their number of lines."""

    def broken(title: str) -> str:
        cuts = [i + 1 for i, c in enumerate(title[:-1]) if c in "_- "]
        if text_width(title, size) <= room or not cuts:
            return title
        k = min(cuts, key=lambda i: max(text_width(title[:i], size), text_width(title[i:], size)))
        return f"{title[:k]}\n{title[k:]}"

    out = [broken(t) for t in titles]
    widest = max((text_width(line, size) for t in out for line in t.split("\n")), default=0.0)
    lines = max((t.count("\n") + 1 for t in out), default=1)
    return out, min(size, size * room / widest) if widest else size, lines


def layout(fig, axes: np.ndarray, handles, width: str, column_titles: Sequence[str] = ()) -> None:
    """Place a grid of panels (margins from the tick labels and fonts), the titles of its
    columns (a plan, a joint) and a frameless legend of ``handles`` above them, in as many
    columns as fit. Call after the data are drawn (the y tick labels depend on the data)."""
    from matplotlib.lines import Line2D

    ncol = _legend_columns([h.get_label() for h in handles], width)
    rows = math.ceil(len(handles) / ncol)
    axes = np.atleast_2d(axes)
    tick, base, leg = FONTS[width]["tick"], FONTS[width]["base"], FONTS[width]["legend"]
    fig_w, fig_h = fig.get_size_inches()
    n_rows, n_cols = axes.shape
    extents = [max(_y_extent(ax, tick, base) for ax in axes[:, c]) for c in range(n_cols)]
    left = _EDGE + extents[0]
    gap = max(extents[1:], default=0.0) + 0.12
    x_text = _TICK_PAD + _LINE * tick * _PT
    bottom = _EDGE + x_text + (_LABEL_PAD + _LINE * base * _PT if axes[-1, 0].get_xlabel() else 0)
    right = _EDGE + 0.12  # half of the last x tick label
    legend_h = rows * 1.45 * leg * _PT + (0.04 if rows else 0.0)
    panel_w = (fig_w - left - right - (n_cols - 1) * gap) / n_cols
    column_titles, title_pt, lines = _fitted_titles(column_titles, panel_w + gap - 0.08, base)
    top = _EDGE + legend_h + (lines * _LINE * title_pt * _PT + 0.04 if column_titles else 0.06)
    panel_h = (fig_h - top - bottom - (n_rows - 1) * _ROW_GAP) / n_rows
    fig.subplots_adjust(
        left=left / fig_w,
        right=1 - right / fig_w,
        bottom=bottom / fig_h,
        top=1 - top / fig_h,
        wspace=gap / panel_w if n_cols > 1 else 0.2,
        hspace=_ROW_GAP / panel_h if n_rows > 1 else 0.2,
    )
    order = [r * ncol + c for c in range(ncol) for r in range(rows)]  # legends fill by column
    padded = list(handles) + [Line2D([], [], alpha=0, label=" ")] * (rows * ncol - len(handles))
    cells = [padded[i] for i in order]
    for ax, title in zip(axes[0], column_titles):
        # at a fixed height: matplotlib's own placement measures the axis at every draw
        ax.set_title(title, fontsize=title_pt, y=1.0, pad=3.0)
    fig.legend(
        cells,
        [h.get_label() for h in cells],
        loc="upper center",
        bbox_to_anchor=((left + (fig_w - left - right) / 2) / fig_w, 1 - _EDGE / fig_h),
        ncol=ncol,
        frameon=False,
        handlelength=2.6,
        handletextpad=0.5,
        columnspacing=1.2,
        borderaxespad=0.0,
        borderpad=0.0,
        fontsize=leg,
    )


FORMATS = ("png", "pdf")
#: Height of a three-panel figure [in].
STACK_HEIGHT = 3.9


def _time_axes(axes, t_end: float, labels: Sequence[str]) -> None:
    from matplotlib.ticker import MaxNLocator

    for ax, label in zip(axes, labels):
        ax.set_ylabel(label)
        ax.margins(x=0, y=0.12)  # head room: flat extremes must not sit on the frame
        ax.yaxis.set_major_locator(MaxNLocator(4))
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(0.0, t_end)


def attitude_figure(results: Mapping[str, Any]) -> Figure:
    """Base roll, pitch and yaw [deg] against time [s], one panel each (paper Figs. 2, 3, 5)."""
    with style.styled("column"):
        fig = style.figure("column", STACK_HEIGHT)
        axes = fig.subplots(3, 1, sharex=True)
        for name, res in results.items():
            kwargs = style.method_style(name)
            for k, ax in enumerate(axes):
                ax.plot(res.t, np.degrees(res.rpy[:, k]), **kwargs)
        t_end = max(float(res.t[-1]) for res in results.values())
        _time_axes(axes, t_end, [f"{a} [deg]" for a in ("roll", "pitch", "yaw")])
        layout(fig, axes[:, None], axes[0].get_lines(), "column")
        return fig


def timing_figure(timing: Mapping[str, Any], results: Mapping[str, Any]) -> Figure:
    """A free mission timing (``info["timing"]`` of the plan): the path progress ``s(t)``
    [s] against time with the given timing (``s = t``, dotted), and the attitude drift [deg] of
    ``results`` (the optimal plans at the free and at the given timing)."""
    with style.styled("column"):
        fig = style.figure("column", STACK_HEIGHT * 2 / 3)
        axes = fig.subplots(2, 1, sharex=True)
        t, s = np.asarray(timing["progress_t"]), np.asarray(timing["progress_s"])
        given = float(timing["given_duration_s"])
        axes[0].plot(t, s, **style.method_style("optimal"))
        axes[0].plot([0.0, given], [0.0, given], **style.method_style("optimal-given"))
        for name, res in results.items():
            axes[1].plot(res.t, np.degrees(res.angle), **style.method_style(name))
        t_end = max([float(t[-1]), given] + [float(r.t[-1]) for r in results.values()])
        _time_axes(axes, t_end, ["path progress s [s]", "drift [deg]"])
        handles = axes[1].get_lines() if results else axes[0].get_lines()
        layout(fig, axes[:, None], handles, "column")
        return fig


def model_error_figure(
    results: Mapping[str, Any],
    bands: Mapping[str, np.ndarray],
    *,
    perturbation: float,
) -> Figure:
    """The base's rotation from its start [deg] of each plan as planned (the line) and the 95th
    percentile over perturbed models (``bands``: ``{name: p95 angle at result.t}`` [rad]; the
    band up to the dotted edge); ``perturbation``, the relative model error, is named in the
    legend."""
    with style.styled("column"):
        fig = style.figure("column", 2.4)
        ax = fig.subplots(1, 1)
        for name, res in results.items():
            kwargs = style.method_style(name)
            ax.plot(res.t, np.degrees(res.angle), **kwargs)
            if name in bands:
                band = np.degrees(bands[name])
                colour = kwargs.get("color")
                ax.fill_between(
                    res.t, np.degrees(res.angle), band, color=colour, alpha=0.18, linewidth=0
                )
                ax.plot(res.t, band, color=colour, linestyle=":", linewidth=0.9)
        handles = [line for line in ax.get_lines() if line.get_linestyle() != ":"]
        handles += ax.plot(
            [],
            [],
            color="0.3",
            linestyle=":",
            linewidth=0.9,
            label=f"95th percentile, {perturbation:.0%} model error",
        )
        _time_axes([ax], max(float(r.t[-1]) for r in results.values()), ["rotation [deg]"])
        layout(fig, ax, handles, "column")
        return fig


def closed_loop_figure(
    results: Mapping[str, Any],
    open_bands: Mapping[str, np.ndarray],
    closed_bands: Mapping[str, tuple[np.ndarray, np.ndarray]],
    *,
    perturbation: float,
) -> Figure:
    """One panel per method of ``closed_bands`` (``{name: (t, p95 angle)}`` [s, rad]): the plan
    as planned (its line), the 95th percentile over perturbed true models flown open loop
    (``open_bands``, at ``results[name].t``; dotted) and closed loop (dashed, shaded) [deg]."""
    names = list(closed_bands)
    with style.styled("column"):
        fig = style.figure("column", 1.6 * len(names) + 0.8)
        axes = np.atleast_1d(fig.subplots(len(names), 1, sharex=True))
        for ax, name in zip(axes, names):
            res, kwargs = results[name], style.method_style(name)
            colour = kwargs.get("color")
            ax.plot(res.t, np.degrees(res.angle), **kwargs)
            if name in open_bands:
                ax.plot(
                    res.t, np.degrees(open_bands[name]), color=colour, linestyle=":", linewidth=0.9
                )
            t, band = closed_bands[name]
            ax.fill_between(t, 0.0, np.degrees(band), color=colour, alpha=0.18, linewidth=0)
            ax.plot(t, np.degrees(band), color=colour, linestyle="--", linewidth=0.9)
        handles = [ax.get_lines()[0] for ax in axes]
        handles += axes[0].plot(
            [],
            [],
            color="0.3",
            linestyle=":",
            linewidth=0.9,
            label=f"95th percentile open loop, {perturbation:.0%} model error",
        )
        handles += axes[0].plot(
            [], [], color="0.3", linestyle="--", linewidth=0.9, label="95th percentile closed loop"
        )
        t_end = max(float(results[n].t[-1]) for n in names)
        _time_axes(list(axes), t_end, ["rotation [deg]"] * len(names))
        layout(fig, axes[:, None], handles, "column")
        return fig


def clearance_figure(
    curves: Mapping[str, tuple[np.ndarray, np.ndarray]],
    margin: float | None,
) -> Figure:
    """The smallest distance between any two bodies that may touch [m] against time, one curve
    per motion ``{name: (t, distance)}``, with zero (contact) and the planner's ``margin``
    (dotted) marked."""
    with style.styled("column"):
        fig = style.figure("column", 2.4)
        ax = fig.subplots(1, 1)
        for name, (t, d) in curves.items():
            ax.plot(t, d, **style.method_style(name))
        ax.axhline(0.0, color="0.2", linewidth=0.8)
        if margin is not None:
            ax.axhline(margin, color="0.4", linestyle=":", linewidth=0.9)
            ax.annotate(
                f"margin {margin:g} m",
                (0.01, margin),
                xycoords=("axes fraction", "data"),
                ha="left",
                va="bottom",
                fontsize="small",
                color="0.3",
            )
        t_end = max(float(t[-1]) for t, _ in curves.values())
        _time_axes([ax], t_end, ["smallest distance [m]"])
        handles = ax.get_lines()[: len(curves)]
        layout(fig, ax, handles, "column")
        return fig


def _torque_parts(name: str, sim) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """(wrench, plot kwargs) of the sum, the mission arm and the balance arm(s) of one plan."""
    balance = sum(w for arm, w in sim.arm_wrenches.items() if arm != "mission")
    sim_name = name if name.endswith(style.SIM) else f"{name}{style.SIM}"
    # Where the balance arm carries most of the sum (the optimal plan's torques), the two
    # curves coincide: the balance arm wide and pale under the thin sum keeps both readable,
    # in greyscale too.
    balance_style = {**style.method_style(sim_name), "linewidth": 2.6, "alpha": 0.55, "zorder": 1.8}
    balance_style["label"] = f"{style.method_label(name)}: balance arm"
    return [
        (sim.total_wrench, {**style.method_style("sum"), "zorder": 2.5}),
        (sim.arm_wrenches["mission"], style.method_style("arm:mission")),
        (balance, balance_style),
    ]


def reaction_torque_figure(simulations: Mapping[str, Any]) -> Figure:
    """Torque the arms exert on the base [N m], base axes, against time (paper Fig. 4): one
    column of panels per plan, each with its own scale (the analytic law's torques are tens of
    times smaller than the optimal plan's); a page wide for two plans or more."""
    width = "page" if len(simulations) > 1 else "column"
    with style.styled(width):
        fig = style.figure(width, 4.0 if width == "page" else STACK_HEIGHT)
        axes = fig.subplots(3, len(simulations), sharex=True, squeeze=False)
        t_end = max(float(sim.t[-1]) for sim in simulations.values())
        handles = []
        for c, (name, sim) in enumerate(simulations.items()):
            for wrench, kwargs in _torque_parts(name, sim):
                for k, ax in enumerate(axes[:, c]):
                    ax.plot(sim.t, wrench[:, 3 + k], **kwargs)
            handles += axes[0, c].get_lines()[(0 if c == 0 else 2) :]
            labels = [f"torque {a} [N m]" if c == 0 else "" for a in "xyz"]
            _time_axes(axes[:, c], t_end, labels)
        titles = [style.method_label(name) for name in simulations]
        layout(fig, axes, handles, width, column_titles=titles)
        return fig


def paper_figure_set(
    output_dir: Path,
    stems: Mapping[str, str],
    formats: Sequence[str],
    mission_only,
    kinematic,
    balance_only,
    balanced,
) -> tuple[dict[str, list[Path]], dict[str, Figure]]:
    """The paper's Figs. 2-5 of one study, files named ``stems``, as ``({"fig2": [files], ...},
    {"fig2": Figure})``: Fig. 2 the simulation of the ``mission_only`` arm over its
    ``kinematic`` model, Fig. 3 the simulations ``{method: simulation}`` of each plan's
    ``balance_only`` arm, Figs. 4 and 5 those of each plan with both arms moving (``balanced``),
    Fig. 5 with the mission arm alone."""

    def sims(results):
        return {f"{name}{style.SIM}": res for name, res in results.items()}

    figures = {
        "fig2": attitude_figure(
            {"mission-only:sim": mission_only, "mission-only:kinematic": kinematic}
        ),
        "fig3": attitude_figure(sims(balance_only)),
        "fig4": reaction_torque_figure(balanced),
        "fig5": attitude_figure({**sims(balanced), "mission-only:sim": mission_only}),
    }
    files = {key: style.save(fig, output_dir / stems[key], formats) for key, fig in figures.items()}
    return files, figures


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
LIMIT_STYLE = {"color": "0.35", "linestyle": (0, (1.0, 1.0)), "linewidth": 0.9, "label": "limit"}


def joint_limits_figure(results: Mapping[str, BalanceResult], robot: FloatingRobot) -> Figure:
    """Balance joint positions, rates and accelerations of each plan against time, one column
    per joint, the joint's limits dotted. The y range covers both the limits and every plan,
    so a violation is seen at a glance."""
    from matplotlib.lines import Line2D

    first = next(iter(results.values()))
    joints = list(first.balance_joints)[:MAX_COLUMNS]
    width = "column" if len(joints) <= 2 else "page"
    with style.styled(width):
        fig = style.figure(width, 4.0)
        axes = fig.subplots(len(_ROWS), len(joints), sharex=True, squeeze=False)
        for k in range(len(joints)):
            _joint_column(axes[:, k], results, robot, k)
        handles = [*axes[0, 0].get_lines()[: len(results)], Line2D([], [], **LIMIT_STYLE)]
        layout(fig, axes, handles, width, column_titles=joints)
        return fig


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
        0.02,
        0.97,
        "\n".join(off),
        transform=ax.transAxes,
        va="top",
        ha="left",
        fontsize="x-small",
        color="0.2",
        bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
    )


def _joint_column(axes, results, robot: FloatingRobot, k: int) -> None:
    """The panels of balance joint ``k``."""
    from matplotlib.ticker import MaxNLocator

    first = next(iter(results.values()))
    i = robot.joint_index(first.balance_joints[k])
    for ax, (field, kind, label) in zip(axes, _ROWS):
        for name, res in results.items():
            ax.plot(res.t, getattr(res, field)[:, k], **style.method_style(name, markers=False))
        bounds = [b[i] for b in limit_bounds(robot.limits, kind) if np.isfinite(b[i])]
        if bounds:  # one line for both limits (NaN between): fewer artists than axhline
            t0, t1 = first.t[0], first.t[-1]
            ys = [y for b in bounds for y in (b, b, np.nan)]
            ax.plot([t0, t1, np.nan] * len(bounds), ys, **{**LIMIT_STYLE, "label": "_limit"})
        if len(bounds) == 2:
            _clip_off_scale(ax, results, field, k, bounds)
        if k == 0:
            ax.set_ylabel(label)
        ax.yaxis.set_major_locator(MaxNLocator(4))
        ax.margins(x=0)
    axes[-1].set_xlabel("time [s]")


def capture_figure(results: Mapping[str, object], t_c: float) -> Figure:
    """For each result (a plan or a simulation), ``|omega_b|`` [deg/s] and the drift [deg] from
    the start (thick) and from the attitude at the capture (thin, after it)."""
    with style.styled("column"):
        fig = style.figure("column", 4.2)
        axes = fig.subplots(2, 1, sharex=True)
        ax_w, ax_a = axes
        for name, r in results.items():
            kwargs = style.method_style(name)
            t = np.asarray(r.t)
            k, since = capture_drifts(r, t_c)
            ax_w.plot(t, np.degrees(np.linalg.norm(r.omega, axis=1)), **kwargs)
            ax_a.plot(t, np.degrees(r.angle), **kwargs)
            thin = {**kwargs, "linewidth": 0.6, "marker": "", "label": None}
            ax_a.plot(t[k:], np.degrees(since), **thin)
        t_end = max(float(r.t[-1]) for r in results.values())
        _time_axes(axes, t_end, ["|ω_b| [deg/s]", "drift [deg]"])
        for ax in axes:
            ax.axvline(t_c, color="0.4", linestyle=":", linewidth=0.8)
            ax.set_ylim(bottom=0.0)
        layout(fig, axes[:, None], ax_w.get_lines()[: len(results)], "column")
        return fig


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
    kwargs = style.method_style(result.method)
    if kind == "attitude":
        ax.plot(result.t, np.degrees(result.angle), **kwargs)
    else:
        dashes = ("-", "--", ":", "-.")
        for j, name in enumerate(result.balance_joints):
            joint = {**kwargs, "linestyle": dashes[j % len(dashes)], "marker": ""}
            ax.plot(result.t, result.q_B[:, j], **{**joint, "label": f"{kwargs['label']}: {name}"})
    ax.set_xlabel("time [s]")
    ax.set_ylabel(KINDS[kind])
    ax.legend()
    return ax
