"""What engineers ask of a capture, for ``metrics.json`` (its ``capture`` block) and the report:
the jump of the base's angular velocity, the impulse the base receives, and the attitude drift
before and after the capture (``docs/physics.md``, "Capture").
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from balance_opt.motion.so3 import relative_rotation, rotation_angle


def _norm(values) -> float:
    return float(np.linalg.norm(values))


def _drifts(t, quaternion, t_c: float) -> dict[str, float]:
    """Attitude drift before the capture (from the start) and after it (from the attitude at
    the capture) [rad]."""
    k = int(np.flatnonzero(t <= t_c + 1e-12)[-1])
    from_start = rotation_angle(relative_rotation(quaternion[:1], quaternion))
    after = rotation_angle(relative_rotation(quaternion[k : k + 1], quaternion[k:]))
    return {
        "drift_at_capture_rad": float(from_start[k]),
        "max_drift_before_rad": float(from_start[: k + 1].max()),
        "max_drift_after_rad": float(after.max()),
        "final_drift_since_capture_rad": float(after[-1]),
        "max_drift_rad": float(from_start.max()),
    }


def _block(info: Mapping[str, Any], t, quaternion, t_c: float) -> dict[str, Any]:
    jump = info["omega_jump"]
    return {
        **_drifts(np.asarray(t), np.asarray(quaternion), t_c),
        "omega_jump_rad_s": list(jump),
        "omega_jump_norm_rad_s": _norm(jump),
        "ee_impulse": list(info["ee_impulse"]),
        "base_impulse_coupling": list(info["base_impulse_coupling"]),
        "base_momentum_jump": list(info["base_momentum_jump"]),
        "momentum_before": list(info["momentum_before"]),
        "momentum_after": list(info["momentum_after"]),
    }


def capture_metrics(task, results: Mapping[str, Any], simulations=None) -> dict[str, Any] | None:
    """The ``capture`` block of ``metrics.json`` (``docs/outputs.md``); ``None`` for a task
    without a capture.
    """
    target = getattr(task, "target", None)
    if target is None:
        return None
    t_c = float(target.time)
    out: dict[str, Any] = {
        "time_s": t_c,
        "target": {
            "mass_kg": float(target.mass),
            "inertia_kg_m2": np.asarray(target.inertia).tolist(),
            "com_m": np.asarray(target.com).tolist(),
            "linear_velocity_m_s": np.asarray(target.linear_velocity).tolist(),
            "angular_velocity_rad_s": np.asarray(target.angular_velocity).tolist(),
        },
        "methods": {},
        "simulated": {},
    }
    for name, result in results.items():
        info = result.info.get("capture")
        if info is not None:
            out["methods"][name] = _block(info, result.t, result.quaternion, t_c)
    for name, sim in (simulations or {}).items():
        info = sim.info.get("capture")
        if info is not None:
            out["simulated"][name] = _block(info, sim.t, sim.quaternion, t_c)
    return out


def _pair(values) -> str:
    """``|linear| / |angular|`` of a 6-vector."""
    return f"{_norm(values[:3]):.3g} / {_norm(values[3:]):.3g}"


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
        f"{math.degrees(_norm(t['angular_velocity_rad_s'])):.3g} deg/s.</p>"
        "<table><tr><th>method</th><th>|&Delta;&omega;<sub>b</sub>| [deg/s]</th>"
        "<th>base momentum jump [N s / N m s]</th><th>N<sup>-T</sup> impulse [N s / N m s]</th>"
        "<th>max drift before [deg]</th><th>max drift after [deg]</th>"
        "<th>final drift since capture [deg]</th></tr>" + "".join(rows) + "</table>"
        '<p class="meta">The base momentum jump is the base body\'s own momentum change with the '
        "joints held through the impact; the N<sup>-T</sup> impulse is the end-effector impulse "
        "carried by the coupling factors (Eq. 25, Moore-Penrose form for an arm of fewer than "
        "six joints). Drift after the capture is measured from the attitude at the capture.</p>"
    )
