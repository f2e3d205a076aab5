"""Time of drawing a run's figures (the report's PNGs) and the paper's Figs. 2-5.

Plans and simulates a task once, then draws its figures several times in one process and
prints a table of CPU times (``time.process_time``: steady on a loaded machine): the first drawing (matplotlib imports, font cache, first text) and the median
of the next ones, for the figures of ``plan`` (plans only) and of ``compare`` (plans and
simulations), and for Figs. 2-5 as PNG + PDF. Run it with another checkout first on
``PYTHONPATH`` to compare two versions of the figure code on the same machine.

    python benchmarks/bench_figures.py [--task examples/capture_task.yaml] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path


def _timed(function) -> float:
    start = time.process_time()
    function()
    return time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="examples/capture_task.yaml")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    from balance_opt.app.pipeline import run_task
    from balance_opt.app.run_files import write_figures
    from balance_opt.tasks.task import load_task

    run = run_task(load_task(args.task), methods=("analytic", "optimal"), simulate=True)
    plan_run = replace(run, simulations={})
    paper = None
    try:
        from balance_opt.report.plots import paper_figure_set

        def paper(out: Path) -> None:
            sims = run.simulations  # Fig. 3 drawn from the balanced runs: timing only
            balanced = {k: v for k, v in sims.items() if k != "mission-only"}
            stems = {k: k for k in ("fig2", "fig3", "fig4", "fig5")}
            paper_figure_set(
                out,
                stems,
                ("png", "pdf"),
                sims["mission-only"],
                run.results["mission-only"],
                balanced,
                balanced,
            )
    except ImportError:  # an older checkout: no paper figure set
        pass

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        cases = [("plan (2 figures)", lambda: write_figures(plan_run, out))]
        cases.append(("compare (4 figures)", lambda: write_figures(run, out)))
        if paper is not None:
            cases.append(("paper Figs. 2-5, PNG + PDF", lambda: paper(out)))
        first = {name: _timed(f) for name, f in cases}
        times = {name: [] for name, _ in cases}
        for _ in range(args.repeat):
            for name, f in cases:  # interleaved
                times[name].append(_timed(f))
        for name, _ in cases:
            rows.append((name, first[name], statistics.median(times[name])))
    print(f"| figures | first drawing, CPU [s] | median of {args.repeat}, CPU [s] |")
    print("| --- | --- | --- |")
    for name, first_s, median_s in rows:
        print(f"| {name} | {first_s:.2f} | {median_s:.2f} |")


if __name__ == "__main__":
    main()
