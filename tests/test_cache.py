"""The on-disk cache cannot hurt: damaged kernel libraries are rebuilt (never loaded), killed
builds are cleaned, the size is bounded, and ``balance-opt cache`` shows and clears it."""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from balance_opt import cache
from balance_opt.solvers import codegen

ROOT = Path(__file__).resolve().parents[1]
needs_cc = pytest.mark.skipif(codegen.find_compiler() is None, reason="no C compiler")

# Compiles a small kernel in the cache folder argv[1] and prints "<compile seconds> <value>";
# run in a child process, because loading a damaged library can kill the process that loads it.
_CHILD = """
import logging, sys
import casadi as cs
from balance_opt.solvers.codegen import compile_functions
logging.basicConfig(level=logging.WARNING, format="%(message)s")
x = cs.SX.sym("x", 2)
fun = cs.Function("cache_test_kernel", [x], [cs.sin(x[0]) * x[1] + cs.cos(x[1])])
out = compile_functions([fun], sys.argv[1])
print(out.compile_time, float(out.functions[0]([0.5, 2.0])))
"""


def _compile_in_child(folder: Path) -> tuple[float, float, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, str(folder)],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    assert proc.returncode == 0, f"exit {proc.returncode}: {proc.stderr}"
    elapsed, value = proc.stdout.split()
    return float(elapsed), float(value), proc.stderr


EXPECTED = float(__import__("math").sin(0.5) * 2.0 + __import__("math").cos(2.0))


def _library(folder: Path) -> Path:
    (library,) = folder.glob("balance_kernels_*.so")
    return library


@needs_cc
@pytest.mark.slow
@pytest.mark.parametrize(
    "damage, why",
    [
        ("truncate", "size"),
        ("zero", "size"),
        ("garbage", "SHA-256 differs"),
        ("no record", "no record of its SHA-256"),
    ],
)
def test_damaged_kernel_library_is_rebuilt_not_loaded(tmp_path, damage, why):
    elapsed, value, _ = _compile_in_child(tmp_path)
    library = _library(tmp_path)
    record = json.loads(cache.record_path(library).read_text())
    assert elapsed > 0 and value == pytest.approx(EXPECTED, abs=1e-15)
    assert record["size"] == library.stat().st_size
    assert record["sha256"] == cache.sha256_of(library)
    data = library.read_bytes()
    if damage == "truncate":  # the case that used to end in a bus error (exit 135)
        library.write_bytes(data[: len(data) // 2])
    elif damage == "zero":
        library.write_bytes(b"")
    elif damage == "garbage":  # same size, other bytes
        library.write_bytes(os.urandom(len(data)))
    else:
        cache.record_path(library).unlink()
    elapsed, value, stderr = _compile_in_child(tmp_path)
    assert elapsed > 0 and value == pytest.approx(EXPECTED, abs=1e-15)
    assert f"cached balance kernels {library}: " in stderr and why in stderr
    assert "deleting and rebuilding" in stderr
    assert library.read_bytes() == data  # the same bytes again (deterministic build)
    elapsed, value, stderr = _compile_in_child(tmp_path)  # now intact: loaded as is
    assert elapsed == 0.0 and "rebuilding" not in stderr


def test_stale_temporary_builds_are_removed_live_ones_kept(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = __import__("socket").gethostname()
    killed = tmp_path / f"balance_kernels_abc.tmp-{host}-{dead.pid}-x1y2z3w4"
    live = tmp_path / f"balance_kernels_abc.tmp-{host}-{os.getpid()}-a1b2c3d4"
    other_host_old = tmp_path / "balance_kernels_def.tmp-elsewhere-12-q1w2e3r4"
    other_host_new = tmp_path / "balance_kernels_ghi.tmp-elsewhere-13-q1w2e3r4"
    legacy_old = tmp_path / "pinocchio-bridge" / "tmpu8xrz8b8"
    record_tmp = tmp_path / f"balance_kernels_abc.json.tmp-{host}-{dead.pid}-zzzz1111"
    for folder in (killed, live, other_host_old, other_host_new, legacy_old):
        folder.mkdir(parents=True)
        (folder / "balance_kernels.c").write_text("int x;")
    record_tmp.write_text("{")
    old = time.time() - cache.STALE_SECONDS - 60
    for path in (other_host_old, legacy_old):
        os.utime(path, (old, old))
    removed = cache.clean_stale(tmp_path)
    assert set(removed) == {killed, other_host_old, legacy_old, record_tmp}
    assert live.is_dir() and other_host_new.is_dir() and not killed.exists()


@needs_cc
@pytest.mark.slow
def test_killed_compile_leaves_a_folder_the_next_build_removes(tmp_path):
    # a compile killed part-way (SIGKILL while the compiler runs) leaves its temporary folder
    env = {**os.environ, "PYTHONPATH": str(ROOT), "CC": "sleep-cc"}
    bindir = tmp_path / "bin"
    bindir.mkdir()
    (bindir / "sleep-cc").write_text("#!/bin/sh\nsleep 60\n")
    (bindir / "sleep-cc").chmod(0o755)
    env["PATH"] = f"{bindir}{os.pathsep}{env['PATH']}"
    folder = tmp_path / "cache"
    child = subprocess.Popen([sys.executable, "-c", _CHILD, str(folder)], env=env)
    deadline = time.time() + 60
    while not list(folder.glob("*.tmp-*")) and time.time() < deadline:
        time.sleep(0.1)
    child.kill()
    child.wait()
    (leftover,) = folder.glob("*.tmp-*")
    assert (leftover / "balance_kernels.c").is_file()
    _compile_in_child(folder)
    assert not leftover.exists() and _library(folder).is_file()


def _fake_entry(folder: Path, name: str, size: int, age: float) -> Path:
    library = folder / f"balance_kernels_{name}.so"
    library.write_bytes(b"\0" * size)
    cache.write_record(library)
    stamp = time.time() - age
    for path in (library, cache.record_path(library)):
        os.utime(path, (stamp, stamp))
    return library


def test_size_bound_evicts_least_recently_used_kernels(tmp_path, monkeypatch):
    old = _fake_entry(tmp_path, "old", 4000, 300)
    middle = _fake_entry(tmp_path, "middle", 4000, 200)
    new = _fake_entry(tmp_path, "new", 4000, 100)
    bridge = tmp_path / "pinocchio-bridge" / "pinocchio_casadi_bridge_0123"
    bridge.parent.mkdir()
    bridge.write_bytes(b"\0" * 5000)  # never evicted, however old
    os.utime(bridge, (0, 0))
    monkeypatch.setenv(cache.LIMIT_ENV, "14K")
    assert cache.size_limit() == 14 * 1024
    evicted = cache.enforce_limit(tmp_path, keep=[old])
    assert [e.name for e in evicted] == [middle.name]
    assert old.exists() and new.exists() and bridge.exists()
    assert not middle.exists() and not cache.record_path(middle).exists()
    assert cache.enforce_limit(tmp_path) == []  # 13 kB + records: under the bound


@pytest.mark.parametrize(
    "text, size", [("", 2 * 1024**3), ("500M", 500 * 1024**2), ("1.5G", 1.5 * 1024**3)]
)
def test_size_limit_from_the_environment(monkeypatch, text, size):
    monkeypatch.setenv(cache.LIMIT_ENV, text)
    assert cache.size_limit() == int(size)


def test_inventory_groups_by_kind_and_clear_deletes_all(tmp_path):
    _fake_entry(tmp_path, "aaa", 1000, 10)
    (tmp_path / "balance_kernels_aaa.so.lock").touch()
    functions = tmp_path / "pinocchio-bridge" / "functions"
    functions.mkdir(parents=True)
    (functions / "paper_robot_0123.casadi").write_text("x" * 300)
    (tmp_path / "pinocchio-bridge" / "pinocchio_casadi_bridge_0123").write_bytes(b"\1" * 700)
    (tmp_path / "pinocchio-bridge" / "pinocchio_casadi_bridge_0123.json").write_text("{}")
    (tmp_path / "ipopt-options-casadi-3.8.2.json").write_text("{}")
    live = tmp_path / f"balance_kernels_b.tmp-{__import__('socket').gethostname()}-{os.getpid()}-q"
    live.mkdir()
    found = {(e.kind, e.name): e for e in cache.entries(tmp_path)}
    assert set(found) == {
        ("planner kernels", "balance_kernels_aaa.so"),
        ("bridge", "pinocchio-bridge/pinocchio_casadi_bridge_0123"),
        ("bridge", "pinocchio-bridge/functions/paper_robot_0123.casadi"),
        ("Ipopt options", "ipopt-options-casadi-3.8.2.json"),
        ("temporary", live.name),
    }
    kernels = found[("planner kernels", "balance_kernels_aaa.so")]
    assert kernels.size == 1000 + cache.record_path(tmp_path / kernels.name).stat().st_size
    deleted, kept = cache.clear(tmp_path)
    assert len(deleted) == 4 and [e.name for e in kept] == [live.name]
    assert sorted(p.name for p in tmp_path.rglob("*")) == [live.name]


@needs_cc
@pytest.mark.slow
def test_optimal_plan_after_its_cached_kernels_were_truncated(tmp_path):
    """The reported failure: a half-truncated kernel library made every later optimal plan die
    with a bus error (exit 135). Now the plan deletes it and has it rebuilt."""
    private = tmp_path / "cache"
    private.mkdir()
    session = Path(os.environ["BALANCE_OPT_CACHE"])
    if (session / "pinocchio-bridge").is_dir():  # not the subject here: no rebuild wanted
        shutil.copytree(session / "pinocchio-bridge", private / "pinocchio-bridge")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "BALANCE_OPT_CACHE": str(private)}
    task = str(ROOT / "examples" / "capture_task.yaml")

    def plan(out: str) -> subprocess.CompletedProcess:
        args = [sys.executable, "-m", "balance_opt.cli", "plan", task, "-m", "optimal"]
        proc = subprocess.run(
            [*args, "-o", str(tmp_path / out)], capture_output=True, text=True, env=env, check=False
        )
        assert proc.returncode == 0, proc.stderr
        return proc

    first = plan("first")  # cold: the kernels compiled before the plan
    assert "compiling planner kernels for paper_robot (at most 300 s) ..." in first.stderr
    # the C code waiting for the compiler, or the library if it is done already
    found = private.glob("balance_kernels_*")
    (library,) = {p.with_suffix(".so") for p in found if p.suffix in (".c", ".so")}
    assert codegen.wait_for_library(library) is not None
    data = library.read_bytes()
    library.write_bytes(data[: len(data) // 2])
    again = plan("again")
    assert f"cached balance kernels {library}: " in again.stderr
    assert "deleting and rebuilding" in again.stderr
    assert "compiling planner kernels for paper_robot (at most 300 s) ..." in again.stderr
    assert codegen.wait_for_library(library) is not None
    assert library.read_bytes() == data  # rebuilt, the same bytes (deterministic build)
    plans = [(tmp_path / d / "optimal.csv").read_text() for d in ("first", "again")]
    assert plans[0] == plans[1]  # both on the library built again
