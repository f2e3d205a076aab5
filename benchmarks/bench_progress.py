"""Cost of the live progress line (:mod:`balance_opt.progress`) on the optimal planner's solve.

On the capture task, for each N: the Ipopt solve time with progress off (the callback returns
at once), on to a terminal (the live line, refreshed at most every 0.1 s) and on to a file (one
summary line per solve), solves interleaved so that load drifts hit all three alike. Prints
the iterations, the median solve time of each mode, and the time spent in the progress code
itself per iteration (measured around it: the direct cost, which load does not blur as it
blurs the difference of two solve times) and its share of the solve.

Run: ``python benchmarks/bench_progress.py [--intervals 100 400] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import io
import statistics
import time

from balance_opt import progress
from balance_opt.app.scenarios import capture_task
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
    spent = [0.0]
    inner = progress.iteration

    def timed_iteration(*args):
        start = time.perf_counter()
        inner(*args)
        spent[0] += time.perf_counter() - start

    progress.iteration = timed_iteration  # the callback looks it up at each call
    scenario = capture_task()
    model = PlannerModel(scenario.robot)
    print(f"{'N':>5} {'iter':>5} " + " ".join(f"{m + ' [s]':>14}" for m in MODES), end="")
    print(f" {'in progress per iter [ms]':>26} {'share [%]':>10}")
    for n in args.intervals:
        options = PlannerOptions(intervals=n)
        nlp = build_balance_nlp(model, scenario.mission, scenario.q_B0, options)
        nlp.solve_once("analytic")  # warm: the structure built, the kernels loaded
        times = {m: [] for m in MODES}
        iterations, in_terminal, counted = 0, 0.0, 0
        for _ in range(args.repeat):
            for mode in MODES:
                stream = _Terminal() if mode == "terminal" else io.StringIO()
                progress.configure(mode != "off", stream)
                before = spent[0]
                result = nlp.solve_once("analytic")
                times[mode].append(result.solver.last.wall_time_s["solve"])
                iterations = result.solver.solves[-1].iterations
                if mode == "terminal":
                    in_terminal += spent[0] - before
                    counted += iterations + 1  # Ipopt calls back for iteration 0 too
        progress.configure(False)
        med = {m: statistics.median(v) for m, v in times.items()}
        per_iter = in_terminal / max(counted, 1)
        share = 100 * per_iter * (iterations + 1) / med["terminal"]
        row = " ".join(f"{med[m]:14.3f}" for m in MODES)
        print(f"{n:5d} {iterations:5d} {row} {per_iter * 1e3:26.3f} {share:10.3f}")


if __name__ == "__main__":
    main()
