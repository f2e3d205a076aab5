"""The duration-vs-peak trade-off of the capture task at the given and at a free mission timing,
drawn from the results of ``examples/sweep_capture_timing.yaml`` (docs/mission-timing.md):

    balance-opt sweep examples/sweep_capture_timing.yaml -o results/sweep_capture_timing -j 2
    python examples/sweep_capture_timing_figure.py results/sweep_capture_timing \
        docs/mission_timing_tradeoff

prints the table (peak and final drift per duration, timing and problem) and writes the figure
(PNG at 300 dpi).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from balance_opt.report import plots, style

#: The sweep's two problems, by their collision-avoidance switch.
PROBLEMS = {False: "avoidance and jerk term off", True: "defaults"}
LINES = {"given": (0, (1.2, 1.4)), "free": "-"}


def main(folder: str, stem: str) -> None:
    table = pd.read_csv(Path(folder) / "results.csv")
    table = table[table["status"] == "ok"]
    avoid = table["param.optimal.collision.avoid"].astype(str).str.lower() == "true"
    table = table.assign(avoid=avoid)
    print("| duration [s] | problem | given: peak / final [rad] | free: peak / final [rad] |")
    print("| --- | --- | --- | --- |")
    for (duration, a), rows in table.groupby(["param.mission.duration", "avoid"]):
        cells = []
        for timing in ("given", "free"):
            row = rows[rows["param.mission.timing"] == timing].iloc[0]
            cells.append(f"{row['max_drift_rad']:.4f} / {row['final_drift_rad']:.4f}")
        print(f"| {duration:g} | {PROBLEMS[a]} | {cells[0]} | {cells[1]} |")
    with style.styled("column"):
        fig = style.figure("column", 2.6)
        ax = fig.subplots(1, 1)
        for a, colour in ((False, "#0072B2"), (True, "#E69F00")):
            for timing, dashes in LINES.items():
                rows = table[(table["avoid"] == a) & (table["param.mission.timing"] == timing)]
                rows = rows.sort_values("param.mission.duration")
                ax.plot(
                    rows["param.mission.duration"],
                    np.asarray(rows["max_drift_rad"]),
                    color=colour,
                    linestyle=dashes,
                    marker="o" if timing == "free" else "D",
                    label=f"{timing} timing, {PROBLEMS[a]}",
                )
        ax.set_xlabel("mission duration [s]")
        ax.set_ylabel("peak drift [rad]")
        ax.set_ylim(bottom=0.0)
        plots.layout(fig, np.array([[ax]]), ax.get_lines(), "column")
        style.save(fig, stem, ("png",))


if __name__ == "__main__":
    main(*sys.argv[1:3])
