"""Cold and warm first optimal plans: the time a user waits for the first plan of a robot.

For each task (the paper robot, Baxter 7+7 and Talos 7+7 arm joints), in a fresh temporary
cache folder that holds only the Pinocchio-CasADi bridge program (built once per machine, like
a compiled wheel: not part of a robot's cold start):

* **cold**: a new process loads the task and plans with the optimal method. It builds the
  robot's symbolic model, saves it to the cache, compiles the point kernels (the C files at
  once, one compiler per file) and solves with the compiled kernels;
* **warm**: a new process plans the same task again: the model comes from the cache, the
  kernels from the compiled library.

Wall and CPU times are those of the whole process, imports and the compiler child included
(its wall time is read from the library's record). With ``--background`` more columns time
the cold plan as it was made before (``compile: "background"``): it solves on CasADi's
virtual machine while the compilers run (niced) and waits for them at its end; run right after
the cold one, in the same conditions. The load average is printed: on a loaded machine wall
times grow, CPU times much less.

The table also replaces the ``coldstart`` section of ``docs/performance.md``.

Run: ``python benchmarks/bench_coldstart.py [TASK ...] [--background] [--repeat N] [--no-doc]``
(default: the three example tasks; ``--repeat``: each task N times, interleaved).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from perf_doc import write_section

from balance_opt.model.bridge import BridgeUnavailable, ensure_bridge
from balance_opt.solvers.codegen import wait_for_library

ROOT = Path(__file__).resolve().parent.parent
TASKS = (
    ROOT / "examples" / "capture_task.yaml",
    ROOT / "examples" / "baxter_floating.yaml",
    ROOT / "examples" / "talos_arms.yaml",
)
#: The child process: load the task, plan it with the optimal method, print what happened.
CHILD = """
import json, sys, time
start = time.perf_counter()
from balance_opt.app.pipeline import plan_optimal
from balance_opt.tasks.task import load_task
from balance_opt.app.models import ModelCache
task = load_task(sys.argv[1])
# "auto": compile the kernels, then solve; "background": solve on the VM while they compile
models = ModelCache(compile=sys.argv[2])
result = plan_optimal(task, models=models)
info = result.details()
print(json.dumps({
    "plan_wall": time.perf_counter() - start,
    "iterations": info.get("total_iterations", info["iterations"]),
    "kernels": info["kernels"],
    "final_drift": result.final_drift,
    "robot_joints": int(task.robot.n),
}))
"""


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_plan(task: Path, cache: Path, mode: str) -> dict:
    """One planning process; its wall and CPU time [s] and what it printed."""
    env = dict(os.environ, BALANCE_OPT_CACHE=str(cache))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    start, cpu0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(task), mode],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    wall, cpu = time.perf_counter() - start, _children_cpu() - cpu0
    if proc.returncode != 0:
        raise RuntimeError(f"planning {task.name} failed:\n{proc.stderr[-2000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"wall": wall, "cpu": cpu, **out}


def fresh_cache(bridge_program: Path | None) -> Path:
    """A temporary cache folder holding only the bridge program (a per-machine installation)."""
    folder = Path(tempfile.mkdtemp(prefix="balance-opt-coldstart-"))
    if bridge_program is not None:
        target = folder / "pinocchio-bridge"
        target.mkdir()
        for path in (bridge_program, bridge_program.with_suffix(".json")):
            shutil.copy2(path, target / path.name)
    return folder


def bench(name: str, task: Path, bridge_program: Path | None, background: bool) -> dict:
    row = {"load": os.getloadavg()[0]}
    cache = fresh_cache(bridge_program)
    try:
        row["cold"] = run_plan(task, cache, "auto")
        library = row["cold"]["kernels"]["library"]
        record = wait_for_library(library) if library else None
        row["compile"] = float(record["compile_seconds"]) if record else float("nan")
        row["warm"] = run_plan(task, cache, "auto")
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    if background:
        cache = fresh_cache(bridge_program)
        try:
            row["background"] = run_plan(task, cache, "background")
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    return row


def _kernels(run: dict) -> str:
    return "C" if run["kernels"]["compiled"] else "VM"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", type=Path, default=list(TASKS))
    parser.add_argument(
        "--background",
        action="store_true",
        help="also time a cold plan on the VM while the kernels compile (as before)",
    )
    parser.add_argument("--repeat", type=int, default=1, help="runs of each task, interleaved")
    parser.add_argument("--no-doc", action="store_true", help="do not write docs/performance.md")
    args = parser.parse_args()
    try:
        bridge_program = ensure_bridge().path
    except BridgeUnavailable:
        bridge_program = None  # the adam backend
    load = os.getloadavg()[0]
    print(f"CPU cores: {os.cpu_count()}; times of whole processes [s]; load = 1-min load average")
    header = (
        "| task | robot joints | load | cold wall | cold CPU | kernels | Ipopt iter | "
        "compile wall | warm wall | warm CPU | kernels | cold/warm wall |"
    )
    if args.background:
        header += " cold, VM while compiling: wall | CPU | Ipopt iter |"
    lines = [header, "|" + " --- |" * (header.count("|") - 1)]
    print("\n".join(lines))
    for task in [t for _ in range(args.repeat) for t in args.tasks]:
        r = bench(task.stem, task.resolve(), bridge_program, args.background)
        cold, warm = r["cold"], r["warm"]
        line = (
            f"| {task.stem} | {cold['robot_joints']} | {r['load']:.1f} | {cold['wall']:.1f} | "
            f"{cold['cpu']:.1f} | {_kernels(cold)} | {cold['iterations']} | {r['compile']:.1f} | "
            f"{warm['wall']:.1f} | {warm['cpu']:.1f} | {_kernels(warm)} | "
            f"{cold['wall'] / warm['wall']:.2f} |"
        )
        if args.background:
            vm = r["background"]
            line += f" {vm['wall']:.1f} | {vm['cpu']:.1f} | {vm['iterations']} |"
        lines.append(line)
        print(line, flush=True)
    if not args.no_doc:
        command = " ".join(["python benchmarks/bench_coldstart.py", *sys.argv[1:]])
        print(f"wrote {write_section('coldstart', command, lines, load)}")


if __name__ == "__main__":
    main()
