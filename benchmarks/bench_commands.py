"""Whole-command times: ``balance-opt validate``, ``plan --method analytic``, ``plan --method
optimal`` and ``compare`` on each task file, each run as its own process (what a user waits for:
interpreter start, imports, model, planning, output files).

Every command runs once to warm the kernel cache (not counted), then ``--repeats`` times,
interleaved (validate, analytic, optimal, compare, validate, ...) so that a change of load on a
shared machine hits them alike. Prints per command the median wall time, the median CPU time of
the process (user + system: on a loaded machine wall time waits for a CPU, CPU time does not),
and the ratio of each median to validate's (targets in :data:`TARGETS`), then the stages of the
median run of each command from its ``-v`` log (``STAGE: done in X s`` lines; ``rest`` is the
time no stage accounts for: interpreter start, imports, task loading, writing the files), and
what the imports a planning command makes beyond validate's take (:data:`LATER_IMPORTS`: each
inside a stage above or in its rest). The tables also replace the ``commands`` section of
``docs/performance.md``.

    python benchmarks/bench_commands.py [TASK ...] [--repeats 3] [--cache DIR]
        [--source CHECKOUT] [--against OTHER_CHECKOUT] [--no-doc]
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from perf_doc import write_section

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TASK = ROOT / "examples" / "capture_task.yaml"
#: Targets of the whole-command time as a multiple of validate's.
TARGETS = {"plan analytic": 2.5, "plan optimal": 4.0, "compare": 6.0}
_STAGE = re.compile(r"INFO (.+?): done in ([0-9.]+) s")


def command_lines(task: Path, out: Path) -> dict[str, list[str]]:
    """The four commands, each with ``-v`` (for the stage log) and its own output folder."""
    cli = [sys.executable, "-m", "balance_opt.cli", "-v"]
    plan = [*cli, "plan", str(task), "-f", "--method"]
    return {
        "validate": [*cli, "validate", str(task)],
        "plan analytic": [*plan, "analytic", "-o", str(out / "analytic")],
        "plan optimal": [*plan, "optimal", "-o", str(out / "optimal")],
        "compare": [*cli, "compare", str(task), "-o", str(out / "compare"), "-f"],
    }


def run_once(argv: list[str], env: dict[str, str]) -> tuple[float, float, dict[str, float]]:
    """``(wall s, CPU s, {stage: s})`` of one process, run in the checkout on its PYTHONPATH
    (``python -m`` puts the working folder ahead of PYTHONPATH)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(
        argv, check=False, env=env, capture_output=True, text=True, cwd=env["PYTHONPATH"]
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    stages: dict[str, float] = {}
    for name, seconds in _STAGE.findall(proc.stderr + proc.stdout):
        name = re.sub(r"^\S+: ", "", name)  # drop the task-name prefix
        name = re.sub(r" \(.*\)$", "", name)  # drop "(N = 100, ...)"
        stages[name] = stages.get(name, 0.0) + float(seconds)
    return wall, cpu, stages


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", type=Path, default=[DEFAULT_TASK])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--cache", default=os.environ.get("BALANCE_OPT_CACHE"), help="BALANCE_OPT_CACHE to use"
    )
    parser.add_argument(
        "--source",
        type=Path,
        default=ROOT,
        help="checkout whose balance_opt to run (default: this one; another to compare)",
    )
    parser.add_argument(
        "--against",
        type=Path,
        help="a second checkout, run interleaved with --source (same load for both)",
    )
    parser.add_argument("--no-doc", action="store_true", help="do not write docs/performance.md")
    args = parser.parse_args(argv)
    sources = [args.source.resolve()] + ([args.against.resolve()] if args.against else [])
    envs = []
    for source in sources:
        envs.append(dict(os.environ, PYTHONPATH=str(source)))
        if args.cache:
            envs[-1]["BALANCE_OPT_CACHE"] = args.cache
    load = os.getloadavg()[0]
    print(
        f"balance_opt from {', '.join(map(str, sources))}, {args.repeats} interleaved runs per "
        f"command after one warm-up, {os.cpu_count()} CPUs, load average {load:.2f} before"
    )
    lines = []
    for task in args.tasks:
        runs: list[dict[str, list]] = [{} for _ in sources]
        with tempfile.TemporaryDirectory(prefix="bench_commands_") as tmp:
            commands = command_lines(task.resolve(), Path(tmp))
            for env in envs:  # warm the kernel cache and the OS file cache
                for argv_ in commands.values():
                    run_once(argv_, env)
            for _ in range(args.repeats):
                for name, argv_ in commands.items():
                    for k, env in enumerate(envs):
                        runs[k].setdefault(name, []).append(run_once(argv_, env))
        for source, source_runs in zip(sources, runs):
            where = f" ({source})" if len(sources) > 1 else ""
            lines += ["", f"**{task.name}**{where}", "", *_table(source_runs)]
    lines += _import_costs(envs[0], args.repeats)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print("\n".join(lines))
    if not args.no_doc and not args.against:
        tasks = " ".join(str(t) for t in args.tasks)
        command = f"python benchmarks/bench_commands.py {tasks} --repeats {args.repeats}"
        print(f"wrote {write_section('commands', command, lines, load)}")
    return 0


#: Imports a planning command makes beyond validate's, each timed in a fresh interpreter that
#: has imported validate's already (NumPy, Pinocchio, CasADi, balance_opt).
LATER_IMPORTS = {
    "scipy.integrate": "the attitude integration (DOP853) of the mission arm alone and the law",
    "matplotlib.figure, matplotlib.backends.backend_agg": "the figures",
    "meshcat.geometry": "the 3D scene",
}


def _import_costs(env: dict[str, str], repeats: int) -> list[str]:
    """The median time [s] of each of :data:`LATER_IMPORTS`, as table lines."""
    out = ["", "| import | for | median [s] |", "| --- | --- | --- |"]
    for modules, what in LATER_IMPORTS.items():
        code = (
            "import time, numpy, pinocchio, casadi, balance_opt.cli, balance_opt.tasks.task\n"
            f"t = time.perf_counter()\nimport {modules}\nprint(time.perf_counter() - t)"
        )
        times = [
            float(
                subprocess.run(
                    [sys.executable, "-c", code], env=env, capture_output=True, text=True,
                    check=True, cwd=env["PYTHONPATH"],
                ).stdout
            )
            for _ in range(repeats)
        ]  # fmt: skip
        out.append(f"| `{modules}` | {what} | {statistics.median(times):.2f} |")
    return out


def _table(runs: dict[str, list[tuple[float, float, dict[str, float]]]]) -> list[str]:
    base = statistics.median(w for w, _, _ in runs["validate"])
    base_cpu = statistics.median(c for _, c, _ in runs["validate"])
    out = [
        "| command | wall median [s] | runs [s] | x validate (wall) | CPU median [s] "
        "| x validate (CPU) | target |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, samples in runs.items():
        walls = [w for w, _, _ in samples]
        wall, cpu = statistics.median(walls), statistics.median(c for _, c, _ in samples)
        target = f"<= {TARGETS[name]}" if name in TARGETS else ""
        out.append(
            f"| {name} | {wall:.2f} | {', '.join(f'{w:.2f}' for w in walls)} | {wall / base:.2f} "
            f"| {cpu:.2f} | {cpu / base_cpu:.2f} | {target} |"
        )
    out += ["", "Stages of the median run [s] (from the -v log; 'rest': the process minus them):"]
    out.append("")
    for name, samples in runs.items():
        wall, _, stages = sorted(samples, key=lambda s: s[0])[len(samples) // 2]
        parts = [f"{stage} {sec:.2f}" for stage, sec in stages.items()]
        parts.append(f"rest {wall - sum(stages.values()):.2f}")
        out.append(f"- {name} ({wall:.2f}): " + ", ".join(parts))
    return out


if __name__ == "__main__":
    sys.exit(main())
