"""The capture figure: the base's angular velocity and its attitude drift around a capture, per
method, with the capture time marked (``docs/physics.md``, "Capture")."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from balance_opt.motion.so3 import relative_rotation, rotation_angle
from balance_opt.report.style import SCREEN_DPI, figure, method_style, save, styled

#: Caption of the figure in the report.
CAPTION = (
    "Base angular velocity |omega_b| and attitude drift through the capture (dotted line); the "
    "drift after the capture is measured from the attitude at the capture (thin lines)"
)


def capture_figure(
    results: Mapping[str, object], t_c: float, path: str | Path, dpi: int = SCREEN_DPI
) -> Path:
    """Draw, for each result (a plan or a simulation), ``|omega_b|`` [deg/s] and the drift
    [deg] from the start (thick) and from the attitude at the capture (thin, after it), and
    write it as a PNG at ``path``. Returns the file."""
    with styled("column"):
        fig = figure("column", 4.2, layout="constrained")
        ax_w, ax_a = fig.subplots(2, 1, sharex=True)
        for name, r in results.items():
            style = method_style(name)
            t, quat = np.asarray(r.t), np.asarray(r.quaternion)
            ax_w.plot(t, np.degrees(np.linalg.norm(r.omega, axis=1)), **style)
            ax_a.plot(t, np.degrees(rotation_angle(relative_rotation(quat[:1], quat))), **style)
            k = int(np.flatnonzero(t <= t_c + 1e-12)[-1])
            since = rotation_angle(relative_rotation(quat[k : k + 1], quat[k:]))
            thin = {**style, "linewidth": 0.6, "marker": "", "label": None}
            ax_a.plot(t[k:], np.degrees(since), **thin)
        for ax in (ax_w, ax_a):
            ax.axvline(t_c, color="0.4", linestyle=":", linewidth=0.8)
        ax_w.set_ylabel("|ω_b| [deg/s]")
        ax_a.set_ylabel("drift [deg]")
        ax_a.set_xlabel("time [s]")
        ax_w.legend(loc="best")
        ax_w.set_ylim(bottom=0.0)
        ax_a.set_ylim(bottom=0.0)
    stem = Path(path).with_suffix("")
    return save(fig, stem, formats=("png",), dpi=dpi)[0]
