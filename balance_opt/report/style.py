"""The one look of every figure: a colour, line style and marker per method, display names,
font sizes for one and two paper columns, and PNG/PDF saving.

``"<method>:sim"`` keeps its plan's colour and marker shape (a reader ties it to its plan) with
its own line style and hollow markers; ``"<method>:kinematic"`` is a wide pale band under the
simulation. The method colours are 0.30 or more apart in luminance (black, blue ``#0072B2``,
orange ``#E69F00``) and each has its own dash pattern, so figures survive greyscale printing."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

#: Widths of a figure [in]: one paper column, a whole page (two columns).
WIDTHS = {"column": 3.5, "page": 7.0}
#: Resolution of the PNG of a paper figure [dpi] (line art: at least 300 for most journals).
PRINT_DPI = 300
#: Resolution of every PNG embedded in the HTML report [dpi]: one value, so that all its
#: figures show their fonts at one size; 150 dpi draws in half the time of 300 dpi.
SCREEN_DPI = 150

_LABELS = {
    "mission-only": "mission arm alone",
    "analytic": "analytic law",
    "optimal": "optimal plan",
    "optimal-given": "optimal plan, given timing",
    "sum": "sum of arms",
    "arm:mission": "mission arm",
}
#: Suffixes of a method name: the forward-dynamics simulation, the kinematic model.
SIM, KINEMATIC = ":sim", ":kinematic"
_SUFFIX_LABELS = {SIM: " (forward dynamics)", KINEMATIC: " (momentum model)"}

_BLACK, _BLUE, _ORANGE, _GREY = "#000000", "#0072B2", "#E69F00", "#808080"

#: Markers every this fraction of the axes' diagonal (markers at even spacing whatever the
#: sampling, a dozen or so per curve), the first one this far along (so that the markers of
#: curves that overlap do not sit on each other).
MARK_EVERY = 0.09
_MARK_START = {"mission-only": 0.0, "analytic": 0.03, "optimal": 0.06, "optimal-given": 0.045}

_HOLLOW = {"fillstyle": "none"}
_STYLES: dict[str, dict[str, Any]] = {
    "mission-only": {"color": _BLACK, "linestyle": (0, (5.0, 2.0)), "marker": "s"},
    "analytic": {"color": _ORANGE, "linestyle": (0, (6.0, 1.5, 1.5, 1.5)), "marker": "^"},
    "optimal": {"color": _BLUE, "linestyle": "-", "marker": "o"},
    # a free mission timing's optimal plan at the given timing (compare): blue, dotted
    "optimal-given": {"color": _BLUE, "linestyle": (0, (1.2, 1.4)), "marker": "D"},
    "mission-only:sim": {"color": _BLACK, "linestyle": "-", "marker": "s", **_HOLLOW},
    "analytic:sim": {
        "color": _ORANGE,
        "linestyle": (0, (5.0, 1.2, 1.2, 1.2, 1.2, 1.2)),
        "marker": "^",
        **_HOLLOW,
    },
    "optimal:sim": {"color": _BLUE, "linestyle": (0, (9.0, 2.5)), "marker": "o", **_HOLLOW},
    "optimal-given:sim": {
        "color": _BLUE,
        "linestyle": (0, (3.0, 1.5)),
        "marker": "D",
        **_HOLLOW,
    },
    "sum": {"color": _BLACK, "linestyle": "-", "marker": "", "linewidth": 1.4},
    "arm:mission": {"color": _GREY, "linestyle": (0, (1.0, 1.3)), "marker": "", "linewidth": 1.1},
}
#: Methods with a style, in legend order.
METHODS = tuple(_STYLES)
#: A plan's kinematic model drawn under its forward-dynamics run (paper Fig. 2): a wide pale
#: band in the plan's colour, so that the thin simulated curve on top shows where they agree.
_KINEMATIC_BAND = {"linestyle": "-", "marker": "", "linewidth": 4.0, "alpha": 0.3, "zorder": 1.5}
#: Colour of each arm in the 3D scene, in arm order (mission, balance,
#: balance2, ...): none of them a method's colour (black, blue, orange, grey: a reader of the
#: report ties orange to the analytic law) nor the base axes' red, green and blue.
ARM_COLOURS = ("#7B3294", "#A6611A", "#CC79A7", "#DFC27D", "#5E3C99")
#: Colours of names without a style (a plan the user named): Okabe-Ito, after the ones above.
_EXTRA = ("#009E73", "#CC79A7", "#56B4E9", "#D55E00")

#: Font sizes [pt] per figure width, readable once printed at that width: ``base`` (labels),
#: ``tick``, ``legend``.
FONTS = {
    "column": {"base": 8.0, "tick": 7.0, "legend": 7.0},
    "page": {"base": 9.0, "tick": 8.0, "legend": 8.0},
}


def _base(name: str) -> tuple[str, str]:
    for suffix in (SIM, KINEMATIC):
        if name.endswith(suffix):
            return name[: -len(suffix)], suffix
    return name, ""


def method_label(name: str) -> str:
    """Display name of a method (``"optimal"`` -> ``"optimal plan"``, ``"optimal:sim"`` ->
    ``"optimal plan (forward dynamics)"``); an unknown name is its own label."""
    base, suffix = _base(name)
    return _LABELS.get(base, base) + _SUFFIX_LABELS.get(suffix, "")


def method_colour(name: str) -> str:
    return method_style(name)["color"]


def method_style(name: str, *, markers: bool = True) -> dict[str, Any]:
    """Keyword arguments of ``Axes.plot`` for method ``name``: colour, line style, width,
    marker (sparse, unless ``markers`` is off) and label. A name without a style gets a solid
    line in a colour derived from the name (stable between runs)."""
    base, suffix = _base(name)
    if suffix == KINEMATIC:
        return {**_KINEMATIC_BAND, "color": method_colour(base), "label": method_label(name)}
    if name in _STYLES:
        style = dict(_STYLES[name])
    else:
        colour = _EXTRA[sum(map(ord, name)) % len(_EXTRA)]
        style = {"color": colour, "linestyle": "-", "marker": "D", **_HOLLOW}
    style.setdefault("linewidth", 1.2)
    if style["marker"] and markers:
        start = _MARK_START.get(base, 0.0)
        style.update(markevery=(start, MARK_EVERY), markersize=3.5, markeredgewidth=0.8)
    else:
        style["marker"] = ""
    style["label"] = method_label(name)
    return style


@contextlib.contextmanager
def styled(width: str = "column") -> Iterator[None]:
    """Matplotlib settings of a figure ``width`` wide for the block (nothing global changes)."""
    import matplotlib as mpl

    font = FONTS[width]
    rc = {
        "font.size": font["base"],
        "axes.labelsize": font["base"],
        "axes.titlesize": font["base"],
        "xtick.labelsize": font["tick"],
        "ytick.labelsize": font["tick"],
        "legend.fontsize": font["legend"],
        "legend.frameon": False,
        "lines.linewidth": 1.2,
        "axes.linewidth": 0.6,
        "xtick.major.width": 0.6,
        "ytick.major.width": 0.6,
        "xtick.major.size": 2.5,
        "ytick.major.size": 2.5,
        "grid.linewidth": 0.4,
        "grid.color": "0.85",
        "axes.grid": True,
        "font.family": "DejaVu Sans",
        "pdf.fonttype": 42,  # TrueType in the PDF: editable, accepted by publishers
        "ps.fonttype": 42,
        "path.simplify": True,
        "axes.formatter.useoffset": False,
    }
    with mpl.rc_context(rc):
        yield


def figure(width: str = "column", height: float = 2.6):
    """A ``matplotlib.figure.Figure`` (no pyplot state) ``width`` wide and ``height`` [in]
    tall, its panels placed by the caller (:func:`balance_opt.report.plots.layout`); build its
    artists inside :func:`styled` with the same width so that fonts fit."""
    from matplotlib.figure import Figure

    if width not in WIDTHS:
        raise ValueError(f"figure width must be one of {', '.join(WIDTHS)}, got {width!r}")
    return Figure(figsize=(WIDTHS[width], height))


def save(
    fig,
    path_without_suffix: str | Path,
    formats: Sequence[str] = ("png", "pdf"),
    dpi: int = PRINT_DPI,
) -> list[Path]:
    """Write ``fig`` (made by :func:`figure`) as ``<path>.<format>`` for each format (PNG at
    ``dpi``), the folder created when missing; returns the files. Written in the settings of
    the figure's width (:func:`styled`): ticks are made as a figure is drawn, and a PDF gets
    TrueType fonts."""
    width = next((name for name, inches in WIDTHS.items() if inches == fig.get_figwidth()), None)
    if width is None:
        raise ValueError(
            f"a figure {fig.get_figwidth():g} in wide is not one of style.figure's widths "
            f"({', '.join(f'{k} {v:g} in' for k, v in WIDTHS.items())})"
        )
    stem = Path(path_without_suffix)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    with styled(width):
        for fmt in formats:
            path = stem.with_name(f"{stem.name}.{fmt}")
            # no creation date in a PDF, so the same figure gives the same file
            metadata = {"CreationDate": None} if fmt == "pdf" else None
            fig.savefig(path, dpi=dpi, format=fmt, metadata=metadata)
            paths.append(path)
    return paths


def asset(name: str) -> str:
    """A file of the pages shipped with the package (``balance_opt/report/assets``): the
    report's and the 3D scene's style, the scene's player."""
    from importlib.resources import files

    return (files("balance_opt.report") / "assets" / name).read_text(encoding="utf-8")
