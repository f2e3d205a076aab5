"""The results of a sweep: ``results.csv``, ``diagnostics.csv`` (columns: ``docs/sweeps.md``),
``summary.json`` and drift plots, each written atomically; floats in full precision (``repr``)
so two runs compare cell by cell."""

from __future__ import annotations

import csv
import json
import logging
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.report.output_dir import replaced_atomically
from balance_opt.report.style import SCREEN_DPI, WIDTHS, method_style, styled
from balance_opt.sweep.engine import write_json_atomic
from balance_opt.sweep.spec import canonical_json, is_number, parameter_columns

logger = logging.getLogger(__name__)

#: Leading columns of both tables: they identify a case.
KEY_COLUMNS = ("index", "case_id", "method")
#: Prefixes of the parameter, baseline and time columns.
PARAM_PREFIX, BASELINE_PREFIX, TIMING_PREFIX = "param.", "mission_only.", "time."
#: The figures of merit in ``results.csv`` (flattened ``metrics.json`` names), in this order; a
#: column appears when at least one case has it (``solver.*``: optimal cases; ``simulation.*``:
#: sweeps with ``simulate: true``).
METRICS = (
    "duration_s",
    "max_drift_rad",
    "final_drift_rad",
    "max_base_rate_rad_s",
    "peak_balance_rate_rad_s",
    "min_sigma_min",
    "max_momentum_residual",
    "limit_violations",
    "min_limit_margin.position",
    "min_limit_margin.velocity",
    "min_limit_margin.acceleration",
    "balance_limit_margin.position",
    "balance_limit_margin.velocity",
    "balance_limit_margin.acceleration",
    "solver.status",
    "solver.iterations",
    "solver.objective",
    "solver.max_constraint_violation",
    "simulation.max_drift_rad",
    "simulation.final_drift_rad",
    "simulation.max_tracking_error_rad",
    "simulation.max_relative_momentum_residual",
)
#: The baseline's figures in ``results.csv`` (after :data:`BASELINE_PREFIX`).
BASELINE = ("max_drift_rad", "final_drift_rad", "max_base_rate_rad_s")
#: The times in ``results.csv`` (after :data:`TIMING_PREFIX`) [s]: the whole case in its worker,
#: the worker's CPU time meanwhile, the plan, the baseline replay.
TIMES = ("case_s", "cpu_s", "plan_s", "baseline_s")
#: Metric names that hold wall times (they differ from run to run, unlike everything else:
#: ``solver.solve_time_s``, ``details.wall_time_s.build``, ...; not
#: ``details.max_violation_at.time_s``, a time along the motion).
_TIMING_METRIC = re.compile(r"(^|[._])(wall_time|solve_time|build_time|elapsed)(_s)?($|[._])")


def is_timing_column(name: str) -> bool:
    """True for columns that depend on when and where a case ran (wall times, process ids)."""
    if name.startswith(TIMING_PREFIX):
        return True
    return not name.startswith(PARAM_PREFIX) and bool(_TIMING_METRIC.search(name))


def _split(result: dict) -> tuple[dict[str, Any], dict[str, Any]]:
    """The cells of one case: ``(results row, diagnostics row)``."""
    keys = {key: result.get(key) for key in KEY_COLUMNS}
    tidy: dict[str, Any] = {**keys, "status": result.get("status")}
    extra: dict[str, Any] = dict(keys)
    for name, value in parameter_columns(result.get("parameters", {})).items():
        tidy[PARAM_PREFIX + name] = value
    metrics = parameter_columns(result.get("metrics") or {}, lists=False)
    metrics.pop("method", None)  # the key column
    for name in METRICS:
        if name in metrics:
            tidy[name] = metrics.pop(name)
    baseline = (result.get("info") or {}).get("mission_only") or {}
    for name in BASELINE:
        tidy[BASELINE_PREFIX + name] = baseline.get(name)
    error = result.get("error") or {}
    tidy["error_type"] = error.get("type")
    tidy["error_message"] = error.get("message")
    timing = dict(result.get("timing") or {})
    for name in TIMES:
        tidy[TIMING_PREFIX + name] = timing.pop(name, None)
    extra.update(metrics)
    extra["error_traceback"] = error.get("traceback")
    for name, value in timing.items():
        extra[TIMING_PREFIX + name] = value
    return tidy, extra


def results_table(results: Iterable[dict]) -> tuple[list[str], list[dict[str, Any]]]:
    """Columns and rows of ``results.csv`` (columns: ``docs/sweeps.md``), rows in case-index order."""
    rows = [_split(r)[0] for r in sorted(results, key=lambda r: r["index"])]
    if not rows:
        return [*KEY_COLUMNS, "status"], []
    params = [c for row in rows for c in row if c.startswith(PARAM_PREFIX)]
    order = [
        *KEY_COLUMNS,
        "status",
        *dict.fromkeys(params),
        *(m for m in METRICS if any(m in row for row in rows)),
        *(BASELINE_PREFIX + name for name in BASELINE),
        "error_type",
        "error_message",
        *(TIMING_PREFIX + name for name in TIMES),
    ]
    return [c for c in order if any(c in row for row in rows)], rows


def diagnostics_table(results: Iterable[dict]) -> tuple[list[str], list[dict[str, Any]]]:
    """Columns and rows of ``diagnostics.csv``: the key columns, then everything a case recorded
    that ``results.csv`` leaves out (first-seen order, timing columns last)."""
    rows = [_split(r)[1] for r in sorted(results, key=lambda r: r["index"])]
    seen = dict.fromkeys(KEY_COLUMNS if rows else ())
    for row in rows:
        seen.update(dict.fromkeys(row))
    timing = [c for c in seen if is_timing_column(c)]
    return [c for c in seen if c not in timing] + timing, rows


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return json.dumps(value)
    return str(value)


def write_table_csv(path: str | Path, columns: Sequence[str], rows: Sequence[dict]) -> Path:
    """Write a table as CSV atomically (floats as ``repr``; empty cell for missing)."""
    path = Path(path)
    with replaced_atomically(path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_cell(row.get(c)) for c in columns])
    return path


# ----------------------------------------------------------------------------------- plots

#: The metrics plotted: maximum and final base rotation from the start [rad].
MAX_DRIFT, FINAL_DRIFT = "max_drift_rad", "final_drift_rad"
#: Drift drawn at this floor on log axes when it is zero [rad].
DRIFT_FLOOR = 1e-12
#: Ratio of the largest to the smallest drift beyond which drift axes are logarithmic.
LOG_SCALE_RATIO = 30.0
#: Below this ratio of the largest to the smallest drift (two decades), a logarithmic drift
#: axis labels 1, 2 and 5 times the powers of ten, not the powers alone.
LABELLED_DECADES = 100.0
#: Largest number of distinct values of a list parameter plotted as categories.
MAX_CATEGORIES = 8
#: Margin of the parameter axes (a fraction of the range), so that no point sits on a border.
PARAMETER_MARGIN = 0.08
#: Margin around the drifts of the optimal-vs-analytic panel (a factor).
PAIRED_MARGIN = 1.2
#: Offset between methods at a categorical parameter value (in category widths).
CATEGORY_SPREAD = 0.2


def summarize(results: Sequence[dict]) -> dict[str, Any]:
    """Counts per status and method, and the median drifts of each method's successful cases."""
    out: dict[str, Any] = {
        "cases": len(results),
        "status": dict(sorted(Counter(r["status"] for r in results).items())),
        "methods": {},
    }
    for method in sorted({r["method"] for r in results}):
        mine = [r for r in results if r["method"] == method]
        ok = [r for r in mine if r["status"] == "ok"]
        entry: dict[str, Any] = {"cases": len(mine), "ok": len(ok)}
        for key in (MAX_DRIFT, FINAL_DRIFT):
            values = [r["metrics"][key] for r in ok if is_number((r.get("metrics") or {}).get(key))]
            entry[f"median_{key}"] = float(np.median(values)) if values else None
            entry[f"worst_{key}"] = float(np.max(values)) if values else None
        out["methods"][method] = entry
    return out


def _figure(n_rows: int, n_cols: int, height: float = 2.6):
    """Panels a paper column wide each, in the column fonts of :mod:`balance_opt.report.style`."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(WIDTHS["column"] * n_cols, height * n_rows), layout="constrained")
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    return fig, axes


def _save(fig, path: str | Path) -> Path:
    """Write a figure as PNG at the report's resolution, atomically."""
    with replaced_atomically(path) as tmp:
        fig.savefig(tmp, dpi=SCREEN_DPI, format="png")
    return Path(path)


def _method_style(method: str, **extra) -> dict[str, Any]:
    """Colour, label and marker of a method as in every other figure."""
    s = method_style(method)
    return {"color": s["color"], "label": s["label"], "marker": s["marker"] or "o", **extra}


def _drift_axis(ax, which: str, values) -> None:
    """A logarithmic drift axis beyond :data:`LOG_SCALE_RATIO`, else a linear one from zero."""
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

    axis = ax.xaxis if which == "x" else ax.yaxis
    values = np.asarray([v for v in values if v is not None], dtype=float)
    if values.size and values.min() > 0 and values.max() / values.min() > LOG_SCALE_RATIO:
        (ax.set_xscale if which == "x" else ax.set_yscale)("log")
        if values.max() / values.min() < LABELLED_DECADES:  # few decades: 1, 2, 5 labelled
            axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(FormatStrFormatter("%.3g"))
        else:
            axis.set_major_locator(LogLocator(base=10.0))
        axis.set_minor_formatter(NullFormatter())
        return
    axis.set_major_formatter(FormatStrFormatter("%.3g"))
    (ax.set_xlim if which == "x" else ax.set_ylim)(0.0)


def _drift(result: dict, key: str) -> float | None:
    value = (result.get("metrics") or {}).get(key)
    return max(float(value), DRIFT_FLOOR) if is_number(value) else None


#: Cases of a method at most whose cumulative distribution is drawn with markers.
FEW_CASES = 10


def plot_drift_distribution(results: Sequence[dict], path: str | Path) -> Path | None:
    """Cumulative distribution of the maximum and the final drift of each method and the optimal
    drift against the analytic one per parameter set; the file written, or None without drifts."""
    ok = [r for r in results if r["status"] == "ok"]
    methods = sorted({r["method"] for r in ok})
    if not any(_drift(r, MAX_DRIFT) is not None for r in ok):
        return None
    paired = _pairs(ok)
    with styled("column"):
        fig, axes = _figure(1, 3 if paired else 2)
        for ax, key, title in zip(
            axes[0], (MAX_DRIFT, FINAL_DRIFT), ("maximum drift", "final drift")
        ):
            _distribution_panel(ax, ok, methods, key, title)
        handles, labels = axes[0][0].get_legend_handles_labels()
        if paired:
            _paired_panel(axes[0][2], paired)
            more, more_labels = axes[0][2].get_legend_handles_labels()
            handles += more
            labels += [
                x if x == "equal" else f"{x} ({len(paired)} parameter sets)" for x in more_labels
            ]
        fig.legend(handles, labels, loc="outside upper center", ncol=len(handles))
        return _save(fig, path)


def _distribution_panel(ax, ok: Sequence[dict], methods: Sequence[str], key: str, title: str):
    """Cumulative distribution of drift ``key`` of each method's successful cases."""
    for method in methods:
        values = np.sort(
            [d for r in ok if r["method"] == method if (d := _drift(r, key)) is not None]
        )
        if values.size:
            ax.step(
                values,
                np.arange(1, values.size + 1) / values.size,
                where="post",
                **_method_style(method, linestyle=method_style(method)["linestyle"]),
            )
            ax.lines[-1].set_label(f"{ax.lines[-1].get_label()} ({values.size})")
            if values.size > FEW_CASES:  # markers only where a step through one point is invisible
                ax.lines[-1].set_marker("")
    _drift_axis(ax, "x", [_drift(r, key) for r in ok])
    ax.set_xlabel(f"{title} of the base attitude [rad]")
    ax.set_ylabel("fraction of cases")
    ax.set_ylim(0, 1.02)
    ax.grid(True, which="major", alpha=0.3)


def _paired_panel(ax, paired: Sequence[tuple[dict, dict]]) -> None:
    """Optimal against analytic drift of the same parameter sets, with the diagonal."""
    for key, label, style in (
        (MAX_DRIFT, "maximum drift", {"marker": "o", "facecolors": "none", "edgecolors": "black"}),
        (FINAL_DRIFT, "final drift", {"marker": "x", "color": "#808080"}),
    ):
        xy = np.array(
            [
                (a, o)
                for a_rec, o_rec in paired
                if (a := _drift(a_rec, key)) is not None and (o := _drift(o_rec, key)) is not None
            ]
        )
        if xy.size:
            ax.scatter(xy[:, 0], xy[:, 1], s=18, label=label, **style)
    drifts = [d for p in paired for r in p for k in (MAX_DRIFT, FINAL_DRIFT) if (d := _drift(r, k))]
    _drift_axis(ax, "x", drifts)
    _drift_axis(ax, "y", drifts)
    lo = min(drifts) / PAIRED_MARGIN if ax.get_xscale() == "log" else 0.0
    hi = max(drifts) * PAIRED_MARGIN
    ax.plot([lo, hi], [lo, hi], color="0.5", lw=0.8, ls="--", label="equal")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_xlabel("analytic drift [rad]")
    ax.set_ylabel("optimal drift [rad]")
    ax.grid(True, which="major", alpha=0.3)


def _pairs(ok: Sequence[dict]) -> list[tuple[dict, dict]]:
    """(analytic, optimal) results of the same parameter set, in index order."""
    by_params: dict[str, dict[str, dict]] = {}
    for r in sorted(ok, key=lambda r: r["index"]):
        by_params.setdefault(canonical_json(r["parameters"]), {})[r["method"]] = r
    return [
        (m["analytic"], m["optimal"])
        for m in by_params.values()
        if {"analytic", "optimal"} <= set(m)
    ]


def _axis_values(values: list[Any]) -> tuple[np.ndarray, list[str] | None]:
    """Numbers to plot a parameter at, and tick labels for a categorical parameter."""
    if all(is_number(v) for v in values):
        return np.array(values, dtype=float), None
    labels = sorted({_category_label(v) for v in values})
    return np.array([labels.index(_category_label(v)) for v in values], dtype=float), labels


def _category_label(value: Any) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, list) and all(is_number(v) for v in value):
        return "[" + ", ".join(f"{v:.3g}" for v in value) + "]"
    return canonical_json(value)


def _parameter_views(results: Sequence[dict], name: str) -> dict[str, dict[int, Any]]:
    """The columns a parameter is plotted against, each as case index -> value: the parameter
    itself when it is a scalar, or a list or mapping taking few distinct values (then as
    categories); else one column per item (``mission.goal[0]``, ...)."""
    values = {r["index"]: r["parameters"][name] for r in results}
    scalar = all(not isinstance(v, (list, dict)) for v in values.values())
    if scalar or len({canonical_json(v) for v in values.values()}) <= MAX_CATEGORIES:
        return {name: values}
    views: dict[str, dict[int, Any]] = {}
    for index, value in values.items():
        for column, item in parameter_columns({name: value}).items():
            views.setdefault(column, {})[index] = item
    order = sorted(
        views, key=lambda c: [int(x) if x.isdigit() else x for x in re.split(r"(\d+)", c)]
    )
    return {c: views[c] for c in order}


def plot_drift_against_parameter(
    results: Sequence[dict], name: str, path: str | Path
) -> Path | None:
    """Maximum (top) and final (bottom) drift against the varied parameter ``name``, one colour
    per method (a list parameter: one panel column per item, or categories when few distinct
    values); the file written, or None when no successful case has the parameter."""
    ok = [r for r in results if r["status"] == "ok" and name in r["parameters"]]
    if name.startswith("optimal."):  # the other methods do not depend on it
        ok = [r for r in ok if r["method"] == "optimal"]
    if not ok:
        return None
    views = _parameter_views(ok, name)
    failed = sum(1 for r in results if r["status"] != "ok" and name in r["parameters"])
    methods = sorted({r["method"] for r in ok})
    with styled("column"):
        fig, axes = _figure(2, len(views))
        _parameter_panels(axes, views, ok, methods)
        handles, labels = axes[0][0].get_legend_handles_labels()
        note = f"{failed} failed case{'s' if failed > 1 else ''} not shown" if failed else None
        fig.legend(handles, labels, loc="outside upper center", ncol=len(handles), title=note)
        return _save(fig, path)


def _parameter_panels(axes, views, ok: Sequence[dict], methods: Sequence[str]) -> None:
    """The panels of :func:`plot_drift_against_parameter`: one column per view."""
    for j, (column, values) in enumerate(views.items()):
        indices = sorted(values)
        x_all, labels = _axis_values([values[i] for i in indices])
        x_of = dict(zip(indices, x_all))
        for i, (key, what) in enumerate(((MAX_DRIFT, "maximum"), (FINAL_DRIFT, "final"))):
            ax = axes[i][j]
            for k, method in enumerate(methods):
                points = [
                    (x_of[r["index"]], d)
                    for r in ok
                    if r["method"] == method and r["index"] in x_of and (d := _drift(r, key))
                ]
                if not points:
                    continue
                x = np.array([p[0] for p in points])
                if labels is not None:  # categories: methods side by side around each tick
                    x = x + CATEGORY_SPREAD * (k - (len(methods) - 1) / 2)
                ax.scatter(x, [p[1] for p in points], s=16, alpha=0.8, **_method_style(method))
            if labels is not None:
                ax.set_xticks(range(len(labels)), labels, rotation=20, fontsize="small", ha="right")
                ax.set_xlim(-0.5, len(labels) - 0.5)
            else:
                ax.margins(x=PARAMETER_MARGIN)
            if labels is None and all(isinstance(values[i], int) for i in indices):
                from matplotlib.ticker import MaxNLocator

                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            _drift_axis(ax, "y", [_drift(r, key) for r in ok])
            ax.grid(True, which="major", alpha=0.3)
            ax.set_xlabel(column)
            if j == 0:
                ax.set_ylabel(f"{what} drift [rad]")


def write_report(
    out_dir: str | Path,
    results: Sequence[dict],
    varied: Sequence[str],
    plots: bool = True,
    extra_summary: dict | None = None,
) -> tuple[dict[str, Path], dict[str, Any]]:
    """Write the tables, ``summary.json`` and, with ``plots``, one plot per varied key path;
    returns name -> path of every file written, and the summary."""
    out_dir = Path(out_dir)
    written = {
        "table": write_table_csv(out_dir / "results.csv", *results_table(results)),
        "diagnostics": write_table_csv(out_dir / "diagnostics.csv", *diagnostics_table(results)),
    }
    summary = {**(extra_summary or {}), **summarize(results)}
    written["summary"] = out_dir / "summary.json"
    write_json_atomic(written["summary"], summary)
    if plots:
        plot_dir = out_dir / "plots"
        plot_dir.mkdir(exist_ok=True)
        p = plot_drift_distribution(results, plot_dir / "drift_distribution.png")
        if p is not None:
            written["drift_distribution"] = p
        for name in varied:
            file = "drift_vs_" + re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") + ".png"
            p = plot_drift_against_parameter(results, name, plot_dir / file)
            if p is not None:
                written[f"drift_vs:{name}"] = p
    return written, summary
