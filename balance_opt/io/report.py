"""The comparison report: one self-contained HTML file (nothing external: no linked file, library
or network access) with the task, a table comparing the methods side by side, the limit
violations, the figures embedded as base64 PNG and, when the task's ``outputs.animation`` asks
for it, the 3D animation of :mod:`balance_opt.io.animation` (an inline script, passed in as
``extra_html``).

The table reads ``metrics.json`` content (:func:`balance_opt.io.outputs.run_metrics`), so the
report and the metrics never disagree.
"""

from __future__ import annotations

import base64
import datetime
import html
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from balance_opt.io.capture_metrics import capture_table
from balance_opt.result import LIMIT_TOLERANCE

#: Order and labels of the methods in the table.
METHOD_LABELS = {
    "mission-only": "Mission arm alone (Phase I)",
    "analytic": "Analytic law (Eq. 31)",
    "optimal": "Optimal planner",
}

_STYLE = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; margin: 2em auto;
       max-width: 1100px; color: #222; line-height: 1.4; padding: 0 1em; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.7em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
thead th { background: #f2f2f2; } tr.section td { background: #fafafa; font-weight: bold; text-align: left; }
td.bad { color: #b00020; font-weight: bold; } td.good { color: #1b5e20; }
.meta { color: #555; font-size: 0.9em; } figure { margin: 1.5em 0; }
figure img { max-width: 100%; border: 1px solid #eee; } figcaption { color: #555; font-size: 0.9em; }
code { background: #f5f5f5; padding: 0 0.2em; } .failure { color: #b00020; font-weight: bold; }
"""


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "&ndash;"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "&infin;" if value > 0 else "&minus;&infin;"
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def _get(metrics: Mapping[str, Any], path: str):
    value: Any = metrics
    for part in path.split("."):
        if not isinstance(value, Mapping) or part not in value:
            return None
        value = value[part]
    return value


def _deg(x):
    return None if x is None else math.degrees(x)


def _margin_class(x) -> str:
    return "" if x is None else ("bad" if x < -LIMIT_TOLERANCE else "good")


#: Rows of the comparison table: (label, getter of a method's metrics, cell class or None).
_ROWS: list[tuple[str, Callable[[Mapping], Any], Callable[[Any], str] | None]] = [
    ("Attitude", None, None),
    ("max attitude drift [deg]", lambda m: _deg(_get(m, "max_drift_rad")), None),
    ("final attitude drift [deg]", lambda m: _deg(_get(m, "final_drift_rad")), None),
    ("max base angular rate [deg/s]", lambda m: _deg(_get(m, "max_base_rate_rad_s")), None),
    ("max relative angular momentum residual", lambda m: _get(m, "max_momentum_residual"), None),
    ("Balance arm", None, None),
    ("peak balance joint rate [rad/s or m/s]", lambda m: _get(m, "peak_balance_rate_rad_s"), None),
    (
        "position limit margin [rad or m]",
        lambda m: _get(m, "balance_limit_margin.position"),
        _margin_class,
    ),
    (
        "velocity limit margin [rad/s or m/s]",
        lambda m: _get(m, "balance_limit_margin.velocity"),
        _margin_class,
    ),
    (
        "acceleration limit margin [rad/s^2 or m/s^2]",
        lambda m: _get(m, "balance_limit_margin.acceleration"),
        _margin_class,
    ),
    (
        "limit violations (all arms)",
        lambda m: _get(m, "limit_violations"),
        lambda x: "" if x is None else ("bad" if x > 0 else "good"),
    ),
    ("smallest singular value of J_wB", lambda m: _get(m, "min_sigma_min"), None),
    ("Solver", None, None),
    ("status", lambda m: _get(m, "solver.status"), None),
    ("iterations", lambda m: _get(m, "solver.iterations"), None),
    ("solve time [s]", lambda m: _get(m, "solver.solve_time_s"), None),
    ("Forward-dynamics simulation", None, None),
    ("max attitude drift [deg]", lambda m: _deg(_get(m, "simulation.max_drift_rad")), None),
    ("final attitude drift [deg]", lambda m: _deg(_get(m, "simulation.final_drift_rad")), None),
    (
        "max joint tracking error [rad]",
        lambda m: _get(m, "simulation.max_tracking_error_rad"),
        None,
    ),
    (
        "peak total reaction torque on the base [N m]",
        lambda m: _get(m, "simulation.peak_reaction_torque_Nm.total"),
        None,
    ),
    (
        "max relative momentum residual",
        lambda m: _get(m, "simulation.max_relative_momentum_residual"),
        None,
    ),
]


def comparison_table(methods: Mapping[str, Mapping[str, Any]]) -> str:
    """HTML table, one column per method, rows of :data:`_ROWS` (empty sections left out)."""
    order = [m for m in METHOD_LABELS if m in methods] + [
        m for m in methods if m not in METHOD_LABELS
    ]
    head = "".join(f"<th>{html.escape(METHOD_LABELS.get(m, m))}</th>" for m in order)
    body, section, section_rows = [], None, []

    def flush():
        if section is not None and section_rows:
            body.append(
                f'<tr class="section"><td colspan="{len(order) + 1}">{html.escape(section)}</td></tr>'
            )
            body.extend(section_rows)

    for label, getter, css in _ROWS:
        if getter is None:
            flush()
            section, section_rows = label, []
            continue
        values = [getter(methods[m]) for m in order]
        if all(v is None for v in values):
            continue
        cells = "".join(f'<td class="{css(v) if css else ""}">{_fmt(v)}</td>' for v in values)
        section_rows.append(f"<tr><td>{html.escape(label)}</td>{cells}</tr>")
    flush()
    return f"<table><thead><tr><th></th>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _violations(methods: Mapping[str, Mapping[str, Any]]) -> str:
    parts = []
    for name, m in methods.items():
        found = m.get("violations") or []
        if not found:
            continue
        shown = "".join(f"<li>{html.escape(v)}</li>" for v in found[:20])
        more = f"<li>... and {len(found) - 20} more</li>" if len(found) > 20 else ""
        parts.append(f"<h3>{html.escape(METHOD_LABELS.get(name, name))}</h3><ul>{shown}{more}</ul>")
    return "".join(parts) or "<p>None: every plan stays inside every joint limit.</p>"


def _figure(title: str, png: Path) -> str:
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    return (
        f'<figure><img alt="{html.escape(title)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{html.escape(title)}</figcaption></figure>"
    )


def render_report(
    metrics: Mapping[str, Any],
    figures: Sequence[tuple[str, Path]] = (),
    description: str | None = None,
    extra_html: str = "",
) -> str:
    """The report as one HTML string.

    Args:
        metrics: the content of ``metrics.json`` (:func:`balance_opt.io.outputs.run_metrics`).
        figures: ``(caption, PNG file)`` pairs, embedded in that order.
        description: the task's description.
        extra_html: trusted HTML appended at the end (e.g. an animation).
    """
    task = metrics.get("task", {})
    versions = ", ".join(f"{k} {v}" for k, v in metrics.get("versions", {}).items())
    failures = "".join(
        f'<p class="failure">{html.escape(k)}: {html.escape(v)}</p>'
        for k, v in (metrics.get("failures") or {}).items()
    )
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>balance-opt: {html.escape(str(task.get('name', 'report')))}</title>",
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>balance-opt report: {html.escape(str(task.get('name', '')))}</h1>",
        (
            f'<p class="meta">task file <code>{html.escape(str(task.get("file", "")))}</code>, sha256 '
            f"<code>{html.escape(str(task.get('sha256', ''))[:16])}</code>&hellip;; {stamp}; {html.escape(versions)}</p>"
        ),
    ]
    if description:
        parts.append(f"<p>{html.escape(description)}</p>")
    parts.append(failures)
    parts.append("<h2>Comparison</h2>")
    parts.append(comparison_table(metrics.get("methods", {})))
    parts.append(
        '<p class="meta">Attitude drift: rotation angle of the base from its initial attitude, '
        "|log(R<sub>0</sub><sup>T</sup> R)|. Margins are the smallest distance to a balance-joint "
        "limit over the motion (negative: the limit is broken). The plan rows are the kinematic "
        "motion each method produces (the optimal plan re-simulated on a fine grid); the "
        "simulation rows are the same plans tracked by joint controllers in forward dynamics.</p>"
    )
    parts.append("<h2>Limit violations</h2>")
    parts.append(_violations(metrics.get("methods", {})))
    parts.append(capture_table(metrics.get("capture")))  # issue 16: "" without a capture
    if figures:
        parts.append("<h2>Figures</h2>")
        parts.extend(_figure(title, png) for title, png in figures)
    parts.append(extra_html)
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(
    path: str | Path,
    metrics: Mapping[str, Any],
    figures: Sequence[tuple[str, Path]] = (),
    description: str | None = None,
    extra_html: str = "",
) -> Path:
    """Write :func:`render_report` to ``path`` and return it."""
    path = Path(path)
    path.write_text(render_report(metrics, figures, description, extra_html), encoding="utf-8")
    return path
