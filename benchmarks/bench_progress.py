"""Cost of the live progress line (:mod:`balance_opt.progress`) on the optimal planner's solve.

On the capture task, for each N: the Ipopt solve time with progress off (the callback returns
at once), on to a terminal (the live line, refreshed at most every 0.1 s) and on to a file (one
summary line per solve), solves interleaved so that load drifts hit all three alike. Prints
the iterations, the median solve time of each mode and the overhead per iteration against
"off" (noise on a loaded machine can make it negative).

Run: ``python benchmarks/bench_progress.py [--intervals 100 400] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import io
import statistics

from balance_opt import progress
from balance_opt.app.scenarios import paper_capture
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp

MODES = ("off", "terminal", "file")


class _Terminal(io.StringIO):
    """A stream that says it is a terminal (the live-line path), kept in memory."""

    def isatty(self) -> bool:
        return True


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", type=int, nargs="+", default=[100, 400])
    parser.add_argument("--repeat", type=int, default=5, help="solves per mode (median kept)")
    args = parser.parse_args(argv)
    scenario = paper_capture()
    model = PlannerModel(scenario.robot)
    print(f"{'N':>5} {'iter':>5} " + " ".join(f"{m + ' [s]':>14}" for m in MODES), end="")
    print(f" {'terminal-off per iter [ms]':>27}")
    for n in args.intervals:
        options = PlannerOptions(intervals=n)
        nlp = build_balance_nlp(model, scenario.mission, scenario.q_B0, options)
        nlp.solve_once("analytic")  # warm: the structure built, the kernels loaded
        times = {m: [] for m in MODES}
        iterations = 0
        for _ in range(args.repeat):
            for mode in MODES:
                stream = _Terminal() if mode == "terminal" else io.StringIO()
                progress.configure(mode != "off", stream)
                result = nlp.solve_once("analytic")
                times[mode].append(result.info["wall_time_s"]["solve"])
                iterations = result.info["iterations"]
        progress.configure(False)
        med = {m: statistics.median(v) for m, v in times.items()}
        per_iter = (med["terminal"] - med["off"]) / max(iterations, 1) * 1e3
        row = " ".join(f"{med[m]:14.3f}" for m in MODES)
        print(f"{n:5d} {iterations:5d} {row} {per_iter:27.3f}")


if __name__ == "__main__":
    main()
