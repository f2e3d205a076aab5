"""Margins of a grid of panels computed from the font sizes and the tick labels, in inches.

Constrained layout renders every text once per file written, which is slow. balance-opt's
figures have a known shape (panels sharing the time axis, a y label left of the first column, a
legend above), so their margins follow from font sizes and tick-label lengths alone, estimated
from the DejaVu Sans glyph widths."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from balance_opt.report.style import WIDTHS, font_sizes

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
    """Estimated width of ``text`` in inches at ``size_pt`` (mathtext counted as 4 glyphs)."""
    if text.startswith("$"):
        return 4 * _DIGIT_EM * size_pt * _PT
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


def legend_columns(labels: Sequence[str], width: str, handle_em: float = 2.6) -> int:
    """How many legend columns fit across a figure of ``width``, the entries filling rows
    (a column is as wide as its widest entry)."""
    size = font_sizes(width)["legend"]
    entries = [text_width(s, size) + (handle_em + 0.5 + 1.2) * size * _PT for s in labels]
    room = WIDTHS[width] - 2 * _EDGE
    for ncol in range(len(entries), 1, -1):
        if sum(max(entries[c::ncol]) for c in range(ncol)) <= room:
            return ncol
    return 1


def arrange(
    fig,
    axes: np.ndarray,
    width: str,
    *,
    legend_rows: int = 0,
    column_titles: bool = False,
    inner_x_labels: bool = False,
) -> tuple[float, float]:
    """Place a grid of panels: margins from the tick labels and fonts, room above for a legend
    of ``legend_rows`` rows and for column titles.

    Call after the data are drawn (the y tick labels depend on the data). Returns the figure
    coordinates ``(x_centre, y_top)`` of the room left for the legend.
    """
    axes = np.atleast_2d(axes)
    fonts = font_sizes(width)
    tick, base, leg = fonts["tick"], fonts["base"], fonts["legend"]
    fig_w, fig_h = fig.get_size_inches()
    n_rows, n_cols = axes.shape
    extents = [max(_y_extent(ax, tick, base) for ax in axes[:, c]) for c in range(n_cols)]
    left = _EDGE + extents[0]
    gap = max(extents[1:], default=0.0) + 0.12
    x_text = _TICK_PAD + _LINE * tick * _PT
    bottom = _EDGE + x_text + (_LABEL_PAD + _LINE * base * _PT if axes[-1, 0].get_xlabel() else 0)
    right = _EDGE + 0.12  # half of the last x tick label
    legend_h = legend_rows * 1.45 * leg * _PT + (0.04 if legend_rows else 0.0)
    top = _EDGE + legend_h + (_LINE * base * _PT + 0.04 if column_titles else 0.06)
    row_gap = _ROW_GAP + (x_text if inner_x_labels else 0.0)
    panel_w = (fig_w - left - right - (n_cols - 1) * gap) / n_cols
    panel_h = (fig_h - top - bottom - (n_rows - 1) * row_gap) / n_rows
    fig.subplots_adjust(
        left=left / fig_w,
        right=1 - right / fig_w,
        bottom=bottom / fig_h,
        top=1 - top / fig_h,
        wspace=gap / panel_w if n_cols > 1 else 0.2,
        hspace=row_gap / panel_h if n_rows > 1 else 0.2,
    )
    return (left + (fig_w - left - right) / 2) / fig_w, 1 - _EDGE / fig_h


def legend_above(fig, handles, width: str, anchor: tuple[float, float], ncol: int) -> None:
    """A frameless legend in the room :func:`arrange` left above the panels, filled row by row."""
    rows = math.ceil(len(handles) / ncol)
    order = [r * ncol + c for c in range(ncol) for r in range(rows)]  # legends fill by column
    from matplotlib.lines import Line2D

    padded = list(handles) + [Line2D([], [], alpha=0, label=" ")] * (rows * ncol - len(handles))
    cells = [padded[i] for i in order]
    fig.legend(
        cells,
        [h.get_label() for h in cells],
        loc="upper center",
        bbox_to_anchor=anchor,
        ncol=ncol,
        frameon=False,
        handlelength=2.6,
        handletextpad=0.5,
        columnspacing=1.2,
        borderaxespad=0.0,
        borderpad=0.0,
        fontsize=font_sizes(width)["legend"],
    )


def column_title(ax, text: str, width: str) -> None:
    """Name a column of panels (a plan, a joint) above its top panel. Placed at a fixed height
    (:func:`arrange` leaves room): matplotlib's automatic placement measures the axis at every
    draw."""
    ax.set_title(text, fontsize=font_sizes(width)["base"], y=1.0, pad=3.0)
