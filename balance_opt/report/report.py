"""The comparison report: one self-contained HTML file (no linked file, library or network
access). Its table reads ``metrics.json`` content, so the report and the metrics never disagree."""

from __future__ import annotations

import base64
import datetime
import html
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.motion.result import LIMIT_TOLERANCE, UNTRUSTED_RESIDUAL
from balance_opt.report.outputs import EFFORT_TOLERANCE
from balance_opt.report.style import asset, method_colour, method_label

#: Order of the methods in the tables (others follow in the order given).
METHOD_ORDER = ("mission-only", "analytic", "optimal")

#: Values whose magnitude is below these are numerical noise, printed "0 (< tolerance)".
ANGLE_TOLERANCE = 1e-12  # base attitude [rad]
RATE_TOLERANCE = 1e-12  # base angular rate [rad/s]
MOMENTUM_TOLERANCE = 1e-9  # relative momentum residual (the finite-difference check's floor)
TORQUE_TOLERANCE = 1e-9  # torques [N m]
SIGMA_TOLERANCE = 1e-12  # singular values of J_wB (rad of base per rad of joint)
#: A margin inside the limit by at most this fraction of the limit's size is "at the limit".
AT_LIMIT_BAND = 0.01


def format_value(value: Any, tolerance: float | None = None, unit: str = "") -> str:
    """A value as plain text: ``"0 (< 1e-12 rad)"`` when its magnitude is below ``tolerance``,
    ``"-"`` for None, ``"inf"``, else 4 significant digits, then the unit."""
    suffix = f" {unit}" if unit else ""
    if value is None:
        return "\u2013"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "inf" if value > 0 else "-inf"
        if tolerance is not None and abs(value) < tolerance:
            return f"0 (< {tolerance:g}{suffix})"
        return f"{value:.4g}{suffix}"
    return f"{value}{suffix}"


def format_angle(rad: float | None, tolerance: float = ANGLE_TOLERANCE, per: str = "") -> str:
    """An angle (or angular rate, ``per="/s"``) in radians and degrees, ``"0.0929 rad (5.323
    deg)"``; below ``tolerance`` [rad] ``"0 (< 1e-12 rad)"``."""
    if rad is None or not math.isfinite(rad) or abs(rad) < tolerance:
        return format_value(rad, tolerance, f"rad{per}")
    return f"{rad:.4g} rad{per} ({math.degrees(rad):.4g} deg{per})"


def margin_class(margin: float | None, relative: float | None, tolerance: float) -> str:
    """CSS class of a limit margin: ``"broken"`` (below ``-tolerance``), ``"at-limit"`` (within
    :data:`AT_LIMIT_BAND` of the limit's size, or within ``tolerance`` of it), ``"inside"``;
    ``""`` when there is no limit (``None`` or ``inf``)."""
    if margin is None or not math.isfinite(margin):
        return ""
    if margin < -tolerance:
        return "broken"
    if margin <= tolerance or (relative is not None and relative <= AT_LIMIT_BAND):
        return "at-limit"
    return "inside"


def _get(metrics: Mapping[str, Any], path: str):
    value: Any = metrics
    for part in path.split("."):
        if not isinstance(value, Mapping) or part not in value:
            return None
        value = value[part]
    return value


#: A table cell: its text (plain, escaped when rendered) and CSS class; None: no value.
Cell = tuple[str, str] | None


def _plain(tolerance=None, unit: str = "") -> Callable[[Any, Mapping], Cell]:
    return lambda v, m: (format_value(v, tolerance, unit), "")


def _angle(per: str = "", tolerance=ANGLE_TOLERANCE) -> Callable[[Any, Mapping], Cell]:
    return lambda v, m: (format_angle(v, tolerance, per), "")


def _kinematic_margin(kind: str) -> Callable[[Any, Mapping], Cell]:
    """The balance arm's smallest margin of one kind, with the smallest relative margin."""

    def show(margin, m):
        relative = _get(m, f"balance_relative_limit_margin.{kind}")
        if not math.isfinite(margin):
            return "no limit", ""
        text = format_value(margin, LIMIT_TOLERANCE)
        if relative is not None and abs(margin) >= LIMIT_TOLERANCE:  # else noise, as the margin
            text += f"; {100 * relative:.3g} % of the limit"
        return text, margin_class(margin, relative, LIMIT_TOLERANCE)

    return show


def _effort_margin(key: str) -> Callable[[Any, Mapping], Cell]:
    """The smallest relative effort margin (``None`` in the metrics: no joint has a limit)."""

    def show(effort, m):
        relative = effort.get(key)
        if relative is None:
            return "no limit", ""
        return f"{100 * relative:.4g} %", margin_class(relative, relative, EFFORT_TOLERANCE)

    return show


def _per_joint(key: str, fmt: str = "{:.3g}") -> Callable[[Any, Mapping], Cell]:
    """One figure of every balance joint, in joint order, joined by slashes."""

    def show(values, m):
        text = " / ".join(fmt.format(v[key]) for v in values.values() if key in v)
        return (text, "") if text else None

    return show


def _clearance(c, m) -> Cell:
    """The smallest distance between bodies and the pair, red where they penetrate."""
    if c.get("closest_pair") is None:
        return None
    text = f"{c['min_distance_m']:.4g} ({c['closest_pair']}, t = {c['closest_time_s']:.2f} s)"
    return text, ("inside" if c["collision_free"] else "broken")


def _replan_times(v, m) -> Cell:
    return f"{v['median']:.3g} / {v['max']:.3g}", ""


def _replan_failures(v, m) -> Cell:
    if "replans" not in v:  # no run flew
        return None
    return f"{v['failed_replans']} of {v['replans']}", "broken" if v["failed_replans"] else "inside"


def _diverged(v, m) -> Cell:
    text = "; ".join(f"model {k}: {reason}" for k, reason in v.items())
    return (text, "broken") if v else ("0", "inside")


def _count(v, m) -> Cell:
    return violation_count_text(v, m.get("limit_violations_by_kind")), "broken" if v else "inside"


def violation_count_text(total: int, by_kind: Mapping[str, int] | None) -> str:
    """``"116 (49 position/velocity/acceleration, 67 effort)"``: the count of ``metrics.json``'s
    ``limit_violations``, split by kind when there are any (``limit_violations_by_kind``)."""
    if not total or not by_kind:
        return str(total)
    kinematic = sum(by_kind.get(k, 0) for k in ("position", "velocity", "acceleration"))
    effort, collision = by_kind.get("effort", 0), by_kind.get("collision", 0)
    text = f"{total} ({kinematic} position/velocity/acceleration, {effort} effort"
    return text + (f", {collision} collision)" if collision else ")")


def _residual(v, m) -> Cell:
    """A relative momentum residual, flagged above :data:`UNTRUSTED_RESIDUAL`."""
    return format_value(v, MOMENTUM_TOLERANCE), "broken" if v > UNTRUSTED_RESIDUAL else ""


#: Rows of the comparison table: (label, path in a method's metrics, ``show(value, metrics)``
#: of the value there); a row without a path starts a section.
_ROWS: list[tuple[str, str | None, Callable[[Any, Mapping], Cell] | None]] = [
    ("Attitude", None, None),
    ("max attitude drift", "max_drift_rad", _angle()),
    ("final attitude drift", "final_drift_rad", _angle()),
    ("max base angular rate", "max_base_rate_rad_s", _angle("/s", RATE_TOLERANCE)),
    ("max relative angular momentum residual", "max_momentum_residual", _residual),
    ("Balance arm", None, None),
    ("peak balance joint rate [rad/s or m/s]", "peak_balance_rate_rad_s", _plain()),
    (
        "position limit margin [rad or m]",
        "balance_limit_margin.position",
        _kinematic_margin("position"),
    ),
    (
        "velocity limit margin [rad/s or m/s]",
        "balance_limit_margin.velocity",
        _kinematic_margin("velocity"),
    ),
    (
        "acceleration limit margin [rad/s^2 or m/s^2]",
        "balance_limit_margin.acceleration",
        _kinematic_margin("acceleration"),
    ),
    (
        "effort limit margin (smallest, of the limit)",
        "effort",
        _effort_margin("balance_min_relative_margin"),
    ),
    ("smallest singular value of J_wB", "min_sigma_min", _plain(SIGMA_TOLERANCE)),
    ("acceleration reversals, per joint", "smoothness", _per_joint("acceleration_reversals", "{}")),
    ("largest jerk, per joint [rad/s^3]", "smoothness", _per_joint("max_jerk_rad_s3")),
    ("largest torque rate, per joint [N m/s]", "smoothness", _per_joint("max_torque_rate_Nm_s")),
    ("All arms", None, None),
    (
        "effort limit margin (smallest, of the limit)",
        "effort",
        _effort_margin("min_relative_margin"),
    ),
    (
        "limit violations (position, rate, acceleration, effort, collision)",
        "limit_violations",
        _count,
    ),
    ("smallest distance between bodies [m]", "clearance", _clearance),
    ("Solver", None, None),
    ("status", "solver.status", _plain()),
    ("iterations", "solver.iterations", _plain()),
    ("solve time [s]", "solver.solve_time_s", _plain()),
    ("Under model error (perturbed masses, centres of mass, inertias)", None, None),
    ("max attitude drift, median", "robustness.max_drift.median_rad", _angle()),
    ("max attitude drift, 95th percentile", "robustness.max_drift.p95_rad", _angle()),
    ("final attitude drift, 95th percentile", "robustness.final_drift.p95_rad", _angle()),
    ("Closed loop (perturbed true robots, re-planned from the measured state)", None, None),
    ("max attitude drift, median", "closed_loop.max_drift.median_rad", _angle()),
    ("max attitude drift, 95th percentile", "closed_loop.max_drift.p95_rad", _angle()),
    ("final attitude drift, median", "closed_loop.final_drift.median_rad", _angle()),
    ("final attitude drift, 95th percentile", "closed_loop.final_drift.p95_rad", _angle()),
    ("re-plan time, median / largest [s]", "closed_loop.replan_time_s", _replan_times),
    ("re-plans failed or late, of all", "closed_loop", _replan_failures),
    ("smallest distance between bodies, every run [m]", "closed_loop.min_clearance_m", _plain()),
    ("limit violations, every run", "closed_loop.limit_violations", _plain()),
    ("simulations diverged (stopped, not counted above)", "closed_loop.diverged", _diverged),
    ("Forward-dynamics simulation", None, None),
    ("max attitude drift", "simulation.max_drift_rad", _angle()),
    ("final attitude drift", "simulation.final_drift_rad", _angle()),
    ("max joint tracking error", "simulation.max_tracking_error_rad", _angle()),
    ("smallest distance between bodies [m]", "simulation.clearance", _clearance),
    (
        "peak total reaction torque on the base [N m]",
        "simulation.peak_reaction_torque_Nm.total",
        _plain(TORQUE_TOLERANCE),
    ),
    (
        "max relative momentum residual",
        "simulation.max_relative_momentum_residual",
        _residual,
    ),
]


def _ordered(methods: Mapping[str, Any]) -> list[str]:
    return [m for m in METHOD_ORDER if m in methods] + [m for m in methods if m not in METHOD_ORDER]


def _method_head(name: str, failed: bool) -> str:
    swatch = f'<span class="swatch" style="background:{method_colour(name)}"></span>'
    label = swatch + html.escape(method_label(name))
    if failed:
        return f'<th class="failed">{label}<br><span class="flag">FAILED</span></th>'
    return f"<th>{label}</th>"


def comparison_table(
    methods: Mapping[str, Mapping[str, Any]], failures: Mapping[str, str] | None = None
) -> str:
    """HTML table, one column per method, rows of :data:`_ROWS` (empty sections left out); the
    columns of methods in ``failures`` are flagged FAILED and their cells greyed."""
    order = _ordered(methods)
    failed = {m for m in order if m in (failures or {})}
    head = "".join(_method_head(m, m in failed) for m in order)
    body, section = [], None
    for label, path, show in _ROWS:
        if path is None:
            section = label
            continue
        values = [_get(methods[m], path) for m in order]
        cells = [None if v is None else show(v, methods[m]) for v, m in zip(values, order)]
        if all(c is None for c in cells):
            continue
        if section is not None:  # the heading of a section goes before its first row
            body.append(f'<tr class="section"><td colspan="{len(order) + 1}">{section}</td></tr>')
            section = None
        row = "".join(_cell(c, m in failed) for c, m in zip(cells, order))
        body.append(f"<tr><td>{html.escape(label)}</td>{row}</tr>")
    return f"<table><thead><tr><th></th>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _cell(cell: Cell, failed: bool = False) -> str:
    text, css = cell if cell is not None else ("\u2013", "")
    css = " ".join(c for c in (css, "failed" if failed else "") if c)
    return f'<td class="{css}">{html.escape(text)}</td>'


def torque_sparkline(
    t: np.ndarray, tau: np.ndarray, limit: float | None, css: str, width=240, height=30
) -> str:
    """An inline SVG of ``|tau(t)|`` over the motion (the largest value of each of about 240
    time bins, so that no peak is lost), with the effort limit dashed when there is one."""
    magnitude = np.abs(np.asarray(tau, dtype=float))
    bins = np.linspace(0, magnitude.size, min(width, magnitude.size) + 1).astype(int)
    peaks = np.maximum.reduceat(magnitude, bins[:-1])
    top = 1.05 * max(float(magnitude.max()), limit or 0.0) or 1.0
    xs = np.linspace(0, width, peaks.size)
    ys = height - 1 - (height - 2) * peaks / top
    points = " ".join(f"{x:.1f},{y:.1f}" for x, y in zip(xs, ys))
    colour = _BAR_COLOURS.get(css, "#555")
    limit_line = ""
    if limit is not None:
        y = height - 1 - (height - 2) * limit / top
        limit_line = (
            f'<line x1="0" y1="{y:.1f}" x2="{width}" y2="{y:.1f}" stroke="#000" '
            'stroke-dasharray="3 2"/>'
        )
    return (
        f'<svg width="{width}" height="{height}" role="img" '
        f'aria-label="|torque| from t = {t[0]:g} s to {t[-1]:g} s">{limit_line}'
        f'<polyline points="{points}" fill="none" stroke="{colour}" stroke-width="1.2"/></svg>'
    )


def torque_table(
    effort: Mapping[str, Any], failed: bool = False, profile: tuple | None = None
) -> str:
    """One method's torque profile: per joint the peak ``|tau|`` and its time, the effort limit,
    the margin and the relative margin, coloured as the comparison table's margins, a bar of
    the peak against the limit and, given ``profile`` ``(t, tau)`` (tau (T, n), columns in the
    order of ``effort["joints"]``), ``|tau(t)|`` over the motion."""
    rows = []
    for k, (joint, e) in enumerate((effort.get("joints") or {}).items()):
        margin, relative = e.get("margin_Nm"), e.get("relative_margin")
        css = margin_class(relative, relative, EFFORT_TOLERANCE) if relative is not None else ""
        cells = [
            (format_value(e.get("peak_Nm"), TORQUE_TOLERANCE), ""),
            (format_value(e.get("peak_time_s")), ""),
            ("no limit", "") if e.get("limit_Nm") is None else (format_value(e["limit_Nm"]), ""),
            (format_value(margin, TORQUE_TOLERANCE), css) if margin is not None else None,
            (f"{100 * relative:.4g} %", css) if relative is not None else None,
        ]
        row = "".join(_cell(c, failed) for c in cells)
        bar = "" if relative is None else torque_bar(1 - relative, css)
        row += f'<td class="bar">{bar}</td>'
        if profile is not None:
            line = torque_sparkline(profile[0], profile[1][:, k], e.get("limit_Nm"), css)
            row += f'<td class="bar">{line}</td>'
        rows.append(f"<tr><td>{html.escape(joint)}</td>{row}</tr>")
    head = (
        "<tr><th>joint</th><th>peak |&tau;| [N m]</th><th>at t [s]</th>"
        "<th>limit [N m]</th><th>margin [N m]</th><th>margin / limit</th>"
        f"<th>peak / limit (0 to {_BAR_FULL:g})</th>"
        + ("<th>|&tau;(t)|, limit dashed</th>" if profile is not None else "")
        + "</tr>"
    )
    return f"<table><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table>"


_BAR_COLOURS = {"broken": "#c62828", "at-limit": "#f9a825", "inside": "#2e7d32"}
#: Largest peak / limit a torque bar shows (longer bars are cut, ending in a white notch).
_BAR_FULL = 1.25


def torque_bar(ratio: float, css: str, width: int = 220, height: int = 14) -> str:
    """An inline SVG bar of a peak torque as a fraction of its limit, coloured as its margin,
    with the limit as a dashed line at 1 and the at-the-limit band shaded."""

    def x(r):
        return width * min(r, _BAR_FULL) / _BAR_FULL

    notch = (
        f'<rect x="{width - 3}" y="0" width="3" height="{height}" fill="#fff"/>'
        if ratio > _BAR_FULL
        else ""
    )
    return (
        f'<svg width="{width}" height="{height}" role="img" '
        f'aria-label="{100 * ratio:.3g} % of the limit">'
        f'<rect x="{x(1 - AT_LIMIT_BAND):.1f}" y="0" width="{x(1) - x(1 - AT_LIMIT_BAND):.1f}" '
        f'height="{height}" fill="#ffe082"/><rect x="0" y="2" width="{x(ratio):.1f}" '
        f'height="{height - 4}" fill="{_BAR_COLOURS.get(css, "#888")}"/>{notch}'
        f'<line x1="{x(1):.1f}" y1="0" x2="{x(1):.1f}" y2="{height}" stroke="#000" '
        'stroke-dasharray="3 2"/></svg>'
    )


def _torque_profiles(methods: Mapping[str, Mapping[str, Any]], failures, torques) -> str:
    parts = []
    for name in _ordered(methods):
        effort = methods[name].get("effort")
        if not effort:
            continue
        failed = name in (failures or {})
        flag = ' <span class="flag">FAILED</span>' if failed else ""
        parts.append(f"<h3>{html.escape(method_label(name))}{flag}</h3>")
        parts.append(torque_table(effort, failed, (torques or {}).get(name)))
    return "".join(parts)


def _violations(methods: Mapping[str, Mapping[str, Any]]) -> str:
    parts = []
    for name in _ordered(methods):
        found = methods[name].get("violations") or []
        if not found:
            continue
        shown = "".join(f"<li>{html.escape(v)}</li>" for v in found[:20])
        more = f"<li>... and {len(found) - 20} more</li>" if len(found) > 20 else ""
        parts.append(f"<h3>{html.escape(method_label(name))}</h3><ul>{shown}{more}</ul>")
    return "".join(parts) or "<p>None: every plan stays inside every joint limit.</p>"


def headline(metrics: Mapping[str, Any]) -> str | None:
    """One sentence computed from ``metrics``: how much stiller the optimal plan (else the
    analytic law) keeps the base than the mission arm alone, and at what costs (``None``
    without both); and, when the analytic law's peak drift is the smaller (a redundant balance
    arm it cancels exactly), a second sentence that says so, with its limit violations."""
    methods = metrics.get("methods", {})
    reference = methods.get("mission-only")
    name = next((m for m in ("optimal", "analytic") if m in methods), None)
    if reference is None or name is None:
        return None
    plan = methods[name]
    a, b = plan.get("max_drift_rad"), reference.get("max_drift_rad")
    if not a or b is None:
        return None
    costs = [f"balance joints up to {plan.get('peak_balance_rate_rad_s', 0.0):.3g} rad/s"]
    margin = (plan.get("effort") or {}).get("balance_min_relative_margin")
    if margin is not None:
        costs.append(f"smallest effort margin {100 * margin:.3g} % of the limit")
    solver = plan.get("solver") or {}
    if solver.get("iterations") is not None and solver.get("solve_time_s") is not None:
        costs.append(f"{solver['iterations']} Ipopt iterations in {solver['solve_time_s']:.3g} s")
    count = plan.get("limit_violations")
    if count:
        by_kind = plan.get("limit_violations_by_kind")
        costs.append(f"{violation_count_text(count, by_kind)} limit violations")
    how = f"{b / a:.1f}x stiller than" if b >= a else f"{a / b:.1f}x less still than"
    failures = metrics.get("failures") or {}
    failed = " (FAILED: its solver's last iterate)" if name in failures else ""
    warned = " (WARNING: untrustworthy, see below)" if plan.get("warnings") else ""
    law = methods.get("analytic") if name == "optimal" else None
    better = ""
    if law and law.get("max_drift_rad") is not None and law["max_drift_rad"] < a:
        broken = law.get("limit_violations")
        kinds = law.get("limit_violations_by_kind")
        said = f", with {violation_count_text(broken, kinds)} limit violations" if broken else ""
        better = (
            f" The {method_label('analytic')} keeps it stiller still (peak drift "
            f"{law['max_drift_rad']:.3g} rad{said})."
        )
    return (
        f"The {method_label(name)}{failed}{warned} keeps the base {how} the "
        f"{method_label('mission-only')} (peak drift {a:.3g} vs {b:.3g} rad), at these costs: "
        f"{'; '.join(costs)}.{better}"
    )


def _pair(values) -> str:
    """``|linear| / |angular|`` of a 6-vector."""
    return f"{np.linalg.norm(values[:3]):.3g} / {np.linalg.norm(values[3:]):.3g}"


def capture_table(block: Mapping[str, Any] | None) -> str:
    """The report's HTML section of a ``capture`` block ("" without one)."""
    if not block:
        return ""

    def row(name, m):
        cells = [
            f"{math.degrees(m['omega_jump_norm_rad_s']):.3g}",
            _pair(m["base_momentum_jump"]),
            _pair(m["base_impulse_coupling"]),
            f"{math.degrees(m['max_drift_before_rad']):.3g}",
            f"{math.degrees(m['max_drift_after_rad']):.3g}",
            f"{math.degrees(m['final_drift_since_capture_rad']):.3g}",
        ]
        return f"<tr><td>{html.escape(name)}</td>" + "".join(f"<td>{c}</td>" for c in cells)

    rows = [row(n, m) for n, m in block["methods"].items()]
    rows += [row(f"{n} (simulation)", m) for n, m in block["simulated"].items()]
    t = block["target"]
    return (
        f"<h2>Capture at t = {block['time_s']:g} s</h2>"
        f"<p>Target {t['mass_kg']:g} kg, angular velocity "
        f"{math.degrees(np.linalg.norm(t['angular_velocity_rad_s'])):.3g} deg/s.</p>"
        "<table><tr><th>method</th><th>|&Delta;&omega;<sub>b</sub>| [deg/s]</th>"
        "<th>base momentum jump [N s / N m s]</th><th>N<sup>-T</sup> impulse [N s / N m s]</th>"
        "<th>max drift before [deg]</th><th>max drift after [deg]</th>"
        "<th>final drift since capture [deg]</th></tr>" + "".join(rows) + "</table>"
        '<p class="meta">The base momentum jump is the base body\'s own momentum change with the '
        "joints held through the impact; the N<sup>-T</sup> impulse is the end-effector impulse "
        "carried by the coupling factors (Eq. 25, Moore-Penrose form for an arm of fewer than "
        "six joints). Drift after the capture is measured from the attitude at the capture.</p>"
    )


def _figure(title: str, png: Path) -> str:
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    return (
        f'<figure><img alt="{html.escape(title)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{html.escape(title)}</figcaption></figure>"
    )


_NOTES = (
    '<p class="meta">Attitude drift: rotation angle of the base from its initial attitude, '
    "|log(R<sub>0</sub><sup>T</sup> R)|, in radians (degrees). Margins are the smallest distance "
    "to a balance-joint limit over the motion, and the smallest such distance as a fraction of "
    "the limit (the position range, the velocity, acceleration or effort limit). Colours: "
    '<span class="swatch" style="background:#ffcdd2"></span>broken (beyond the limit by more '
    f"than {LIMIT_TOLERANCE:g} in the limit's unit; efforts: {EFFORT_TOLERANCE:g} of the limit), "
    '<span class="swatch" style="background:#ffe082"></span>at the limit (within '
    f"{100 * AT_LIMIT_BAND:g} % of it), "
    '<span class="swatch" style="background:#dcedc8"></span>inside. Values below their '
    f"tolerance are shown as 0 (&lt; tolerance): attitudes {ANGLE_TOLERANCE:g} rad, base rates "
    f"{RATE_TOLERANCE:g} rad/s, relative momentum residuals {MOMENTUM_TOLERANCE:g}, limit "
    f"margins {LIMIT_TOLERANCE:g}, torques {TORQUE_TOLERANCE:g} N m, singular values "
    f"{SIGMA_TOLERANCE:g}. The plan rows are the "
    "kinematic motion each method produces (re-simulated on a fine grid), the effort margins "
    "its free-floating inverse dynamics; the simulation rows are the same plans tracked by "
    "joint controllers in forward dynamics. A FAILED column holds a solver's last iterate, not "
    "a plan.</p>"
)


def render_report(
    metrics: Mapping[str, Any],
    figures: Sequence[tuple[str, Path]] = (),
    description: str | None = None,
    extra_html: str = "",
    torques: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> str:
    """The report of ``metrics`` (the content of ``metrics.json``) as one HTML string, with the
    ``figures`` ``(caption, PNG file)`` embedded in that order, trusted ``extra_html`` at the end
    (the 3D scene) and, per method, ``torques`` ``(t, tau)`` (times [s], joint torques (T, n)
    [N m]) drawn over the motion in the torque tables (left out: peaks only)."""
    task, methods = metrics.get("task", {}), metrics.get("methods", {})
    failures = metrics.get("failures") or {}
    versions = ", ".join(f"{k} {v}" for k, v in metrics.get("versions", {}).items())
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>balance-opt: {html.escape(str(task.get('name', 'report')))}</title>",
        f"<style>\n{asset('report.css')}</style></head><body>",
        f"<h1>balance-opt report: {html.escape(str(task.get('name', '')))}</h1>",
        (
            f'<p class="meta">task file <code>{html.escape(str(task.get("file", "")))}</code>, sha256 '
            f"<code>{html.escape(str(task.get('sha256', ''))[:16])}</code>&hellip;; {stamp}; {html.escape(versions)}</p>"
        ),
    ]
    line = headline(metrics)
    if line:
        parts.append(f'<p class="headline">{html.escape(line)}</p>')
    if description:
        parts.append(f"<p>{html.escape(description)}</p>")
    parts.extend(
        f'<p class="failure">FAILED: {html.escape(method_label(k))}: {html.escape(v)}</p>'
        for k, v in failures.items()
    )
    parts.extend(
        f'<p class="failure">WARNING: {html.escape(method_label(k))}: {html.escape(w)}</p>'
        for k, m in methods.items()
        for w in m.get("warnings") or ()
    )
    parts.append("<h2>Comparison</h2>")
    parts.append(comparison_table(methods, failures))
    parts.append(_NOTES)
    parts.append("<h2>Limit violations</h2>")
    parts.append(_violations(methods))
    if any(m.get("effort") for m in methods.values()):
        parts.append("<h2>Joint torques</h2>")
        parts.append(
            '<p class="meta">Torques of the free-floating inverse dynamics of each plan\'s '
            "joint motion (nothing acts on the base): the peak |torque| of each joint, when it "
            "comes, and how it compares with the joint's effort limit (bars: peak over limit, "
            "the limit dashed, the at-the-limit band shaded). The whole time series is in each "
            "method's NPZ file (<code>joint_torque</code>).</p>"
        )
        parts.append(_torque_profiles(methods, failures, torques))
    parts.append(capture_table(metrics.get("capture")))  # "" without a capture
    if figures:
        parts.append("<h2>Figures</h2>")
        parts.extend(_figure(title, png) for title, png in figures)
    parts.append(extra_html)
    parts.append("</body></html>")
    return "\n".join(parts)
