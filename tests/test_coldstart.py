"""Cold start: the planner's symbolic model cached on disk, kernels compiled in the background
while the first plan runs on CasADi's virtual machine, and the next run loading the library."""

import logging
import os
from pathlib import Path

import casadi as cs
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from balance_opt import cache
from balance_opt.model.maps import NumericMaps, base_angular_velocity
from balance_opt.motion.trajectories import PointToPoint
from balance_opt.optimal.model import PlannerModel, model_key
from balance_opt.optimal.nlp import point_kernels
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.solvers import codegen
from balance_opt.solvers.codegen import FunctionStore

ROOT = Path(__file__).resolve().parents[1]
needs_cc = pytest.mark.skipif(codegen.find_compiler() is None, reason="no C compiler")


def _random_inputs(fun: cs.Function, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1, 1, fun.size_in(i)) for i in range(fun.n_in())]


def _same_kernels(a, b, tol: float) -> None:
    for fa, fb in zip(
        (a.value, a.jacobian, a.gradient, a.hessian), (b.value, b.jacobian, b.gradient, b.hessian)
    ):
        args = _random_inputs(fa)
        for ya, yb in zip(
            fa(*args) if fa.n_out() > 1 else [fa(*args)],
            fb(*args) if fb.n_out() > 1 else [fb(*args)],
        ):
            assert np.abs(np.array(ya) - np.array(yb)).max() <= tol, fa.name()


def test_stored_model_round_trips_and_matches_numeric_pinocchio(paper, tmp_path):
    fresh = PlannerModel(paper, compile=False, cache_dir=tmp_path)
    k1, dyn1 = point_kernels(fresh), fresh.dynamics_fun()
    stored = sorted(p.name for p in (tmp_path / "planner-models").glob("*.casadi"))
    assert [n.split(fresh.key)[1] for n in stored] == [
        "_dynamics_acceleration.casadi",  # built for the kernels (no momentum)
        "_dynamics_acceleration_h.casadi",  # with the momentum terms (the default)
        "_kernels_acceleration.casadi",
    ]
    warm = PlannerModel(paper, compile=False, cache_dir=tmp_path)
    k2, dyn2 = point_kernels(warm), warm.dynamics_fun()
    assert warm._maps is None  # loaded: no momentum map was built
    _same_kernels(k1, k2, 0.0)  # the same expression graph: bit for bit
    # the loaded dynamics against numeric Pinocchio: omega_b = I_G^{-1} (R^T L0 - A q_dot)
    rng = np.random.default_rng(3)
    q_M, q_B, qd_M, qd_B = (rng.uniform(-1, 1, 3) for _ in range(4))
    phi, h0 = np.array([0.1, -0.2, 0.05]), rng.uniform(-5, 5, 6)
    x, m = np.r_[phi, q_B, qd_B], np.r_[q_M, qd_M, np.zeros(3), h0]
    _, omega = dyn2(x, rng.uniform(-1, 1, 3), m)
    assert np.array_equal(np.array(dyn1(x, 0.5, m)[1]), np.array(omega))
    I_G, A = NumericMaps(paper).angular_maps(np.r_[q_M, q_B])
    R = Rotation.from_rotvec(phi).as_matrix()
    expected = base_angular_velocity(I_G, A, np.r_[qd_M, qd_B], ell=R.T @ h0[3:])
    assert np.abs(np.array(omega).ravel() - expected).max() < 1e-12
    assert np.abs(expected).max() > 1e-3  # not a trivially zero case
    kinds = {e.kind for e in cache.entries(tmp_path)}
    assert "planner models" in kinds
    assert all(e.evictable for e in cache.entries(tmp_path) if e.kind == "planner models")


@pytest.mark.parametrize("damage", ["truncate", "garbage", "no record"])
def test_damaged_stored_model_is_built_again(paper, tmp_path, caplog, damage):
    model = PlannerModel(paper, compile=False, cache_dir=tmp_path)
    reference = point_kernels(model)
    path = model.store.path("kernels_acceleration")
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(b"\0" * len(data))
    else:
        cache.record_path(path).unlink()
    with caplog.at_level(logging.WARNING, logger="balance_opt"):
        again = point_kernels(PlannerModel(paper, compile=False, cache_dir=tmp_path))
    assert f"cached planner model {path}" in caplog.text and "building it again" in caplog.text
    _same_kernels(reference, again, 0.0)
    assert cache.check_record(path)[0] is not None  # saved again, intact


def test_model_key_follows_robot_and_backend(paper, baxter):
    assert model_key(paper, "bridge x") != model_key(paper, "adam-robotics 0.5.0")
    assert model_key(paper, "bridge x") != model_key(baxter, "bridge x")
    adam = PlannerModel(paper, compile=False, backend="adam")
    auto = PlannerModel(paper, compile=False, backend="pinocchio")
    assert adam.key != auto.key
    assert FunctionStore("a/b c", "k").prefix == "a_b_c_k"


@needs_cc
def test_compilation_under_way_is_not_waited_for(tmp_path):
    x = cs.SX.sym("x", 2)
    fun = cs.Function("coldstart_test_kernel", [x], [cs.sin(x[0]) * x[1]])
    library = codegen.library_path("digest", codegen.find_compiler(), tmp_path)
    with cache.file_lock(tmp_path / f"{library.name}.lock"):  # as a compiling process does
        out = codegen.compile_functions([fun], tmp_path, "digest", background=True, label="t")
    assert out.background and not out.compiled and out.functions == [fun]
    assert out.library == str(library)
    assert not list(tmp_path.glob("*.c"))  # no second compilation started


@needs_cc
def test_a_kernel_cut_into_c_functions_computes_the_same_bits(tmp_path):
    """A long body cut into parts (split_functions) runs the same operations in the same order:
    its library gives the whole body's results to the last bit, and CasADi's VM's."""
    z = cs.SX.sym("z", 6)
    y = z
    for k in range(4):  # values read far from where they are computed, names reused
        y = cs.sin(y * cs.DM(np.arange(1.0, 7.0)) + cs.cos(y[::-1]) * z[k])
    hessian, _ = cs.hessian(cs.sumsqr(y), z)
    fun = cs.Function("split_test_kernel", [z], [cs.tril(hessian), y], {"cse": True})
    generator = cs.CodeGenerator("split_test.c", {"with_header": False})
    generator.add(fun)
    whole = generator.dump()
    assert codegen.split_functions(whole, 10**6) == whole  # short enough: left as it is
    cut = codegen.split_functions(whole, 40)
    assert cut.count("casadi_f0_part") >= 2 * 5  # at least 5 parts, each defined and called
    assert len(codegen.c_files(cut)) == 2  # compiled at once, linked
    compiler = codegen.find_compiler()
    libraries = []
    for name, source in (("whole", whole), ("cut", cut)):
        codegen._compile(compiler, source, tmp_path / f"{name}.so")
        libraries.append(cs.external("split_test_kernel", str(tmp_path / f"{name}.so")))
    rng = np.random.default_rng(7)
    for _ in range(5):
        arg = rng.uniform(-2, 2, 6)
        (h_whole, y_whole), (h_cut, y_cut) = (lib(arg) for lib in libraries)
        assert np.array(h_cut).tobytes() == np.array(h_whole).tobytes()
        assert np.array(y_cut).tobytes() == np.array(y_whole).tobytes()
        h_vm, _ = fun(arg)
        np.testing.assert_allclose(np.array(h_cut), np.array(h_vm), rtol=0, atol=1e-12)


@needs_cc
def test_kernels_that_do_not_build_as_several_files_build_as_one(tmp_path, monkeypatch, caplog):
    x = cs.SX.sym("x", 2)
    fun = cs.Function("coldstart_fallback_kernel", [x], [cs.sin(x[0]) * x[1]])
    monkeypatch.setattr(codegen, "c_files", lambda source: [source, "not C;"])
    with caplog.at_level(logging.WARNING, logger="balance_opt"):
        out = codegen.compile_functions([fun], tmp_path, "digest")
    assert out.compiled and "the kernels as 2 C files did not build" in caplog.text
    value = float(out.functions[0]([0.5, 2.0]))
    np.testing.assert_allclose(value, np.sin(0.5) * 2.0, rtol=0, atol=1e-15)


@needs_cc
@pytest.mark.slow
def test_background_library_is_picked_up_and_plans_the_same(paper, tmp_path, caplog):
    mission = PointToPoint([0.0, 0.3, -0.6], [1.2, 0.9, -1.6], 10.0)
    q_B0, options = np.array([0.0, 0.5, -1.0]), PlannerOptions(intervals=30)
    first = PlannerModel(paper, compile="background", cache_dir=tmp_path)
    with caplog.at_level(logging.INFO, logger="balance_opt"):
        vm = point_kernels(first)
    assert "compiling planner kernels for paper_robot (background) ..." in caplog.text
    assert vm.background and not vm.compiled and vm.library
    plan_vm = build_balance_nlp(first, mission, q_B0, options).solve()
    record = codegen.wait_for_library(vm.library)
    assert record is not None and record["compile_seconds"] > 0
    assert not list(tmp_path.glob("*.c")) and not list(tmp_path.glob("*.tmp-*"))
    # the next run (a new model, as a new process would build) loads the library
    second = PlannerModel(paper, compile="auto", cache_dir=tmp_path)
    compiled = point_kernels(second)
    assert compiled.compiled and compiled.library == vm.library and second._maps is None
    _same_kernels(vm, compiled, 1e-9)
    plan_c = build_balance_nlp(second, mission, q_B0, options).solve()
    assert plan_c.solver.last.kernels["compiled"] and not plan_vm.solver.last.kernels["compiled"]
    w_vm, w_c = (
        np.hstack([np.ravel(a) for a in vars(p.solver.solution).values() if a is not None])
        for p in (plan_vm, plan_c)
    )
    assert np.abs(w_vm - w_c).max() < 1e-7
    assert abs(plan_vm.final_drift - plan_c.final_drift) < 1e-9
    # a process that keeps the first model swaps the library in for its next plans
    assert first.upgrade_kernels() >= 1 and point_kernels(first).compiled and not first.nlp_cache


@needs_cc
def test_auto_compiles_the_kernels_before_the_first_plan(paper, tmp_path, caplog):
    """``compile="auto"`` (the default): a new robot's kernels are compiled before its first
    plan, which runs on them (nothing left running); they compute the VM's bits."""
    with caplog.at_level(logging.INFO, logger="balance_opt"):
        kernels = point_kernels(PlannerModel(paper, compile="auto", cache_dir=tmp_path))
    assert "compiling planner kernels for paper_robot (at most 300 s) ..." in caplog.text
    assert kernels.compiled and not kernels.background and kernels.compile_time > 0
    assert cache.check_record(Path(kernels.library))[0]["compile_seconds"] > 0
    vm = point_kernels(PlannerModel(paper, compile=False, cache_dir=tmp_path))
    _same_kernels(vm, kernels, 0.0)


def _broken_compiler(tmp_path, monkeypatch, message: str, name: str) -> cs.Function:
    """``$CC`` a compiler that fails with ``message``; a small function to compile."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    (bindir / "broken-cc").write_text(f"#!/bin/sh\necho 'broken-cc: {message}' >&2\nexit 1\n")
    (bindir / "broken-cc").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("CC", "broken-cc")
    x = cs.SX.sym("x", 2)
    return cs.Function(name, [x], [cs.cos(x[0]) * x[1]])


def test_auto_falls_back_to_the_vm_when_the_compiler_fails(tmp_path, monkeypatch, caplog):
    fun = _broken_compiler(tmp_path, monkeypatch, "no space", "coldstart_auto_failing_kernel")
    with caplog.at_level(logging.WARNING, logger="balance_opt"):
        out = codegen.compile_functions([fun], tmp_path, "digest", background=True, wait=True)
    assert not out.compiled and out.process is None and out.functions == [fun]
    assert "planner kernels not compiled; using CasADi's virtual machine" in caplog.text
    assert "no space" in Path(out.library).with_suffix(".failed").read_text()


def test_talos_example_has_fourteen_arm_joints():
    from balance_opt.tasks.task import load_task

    task = load_task(ROOT / "examples" / "talos_arms.yaml")
    assert task.robot.n == 14 and task.robot.mission.dof == 7
    assert all(j.startswith("arm_") for j in task.robot.joint_names)


def test_failed_background_compilation_is_reported_not_retried(tmp_path, monkeypatch, caplog):
    fun = _broken_compiler(tmp_path, monkeypatch, "out of memory", "coldstart_failing_kernel")
    folder = tmp_path / "cache"
    import psutil

    children = {p.pid for p in psutil.Process().children(recursive=True)}
    first = codegen.compile_functions([fun], folder, "digest", background=True, label="t")
    assert first.background and not first.compiled
    assert codegen.wait_for_library(first.library) is None
    # the compiler ran as this process's child: ended, and reaped by finish() (no zombie)
    assert codegen.finish(first.process, timeout=10)
    assert {p.pid for p in psutil.Process().children(recursive=True)} <= children
    note = Path(first.library).with_suffix(".failed")
    assert "out of memory" in note.read_text()
    assert not list(folder.glob("*.tmp-*")) and not list(folder.glob("*.c"))
    caplog.clear()  # the first call's own notice (recorded when an earlier test set INFO)
    with caplog.at_level(logging.INFO, logger="balance_opt"):
        again = codegen.compile_functions([fun], folder, "digest", background=True, label="t")
    assert again.background and not again.compiled
    assert "the background compilation failed" in caplog.text and "out of memory" in caplog.text
    assert "(background) ..." not in caplog.text  # not started again


def test_a_background_compilation_not_done_in_time_is_stopped(tmp_path, monkeypatch):
    """The planning call that started a compilation ends it: a compiler still running after
    the wait is stopped with everything it started, and its C code removed."""
    import psutil

    bindir = tmp_path / "bin"
    bindir.mkdir()
    (bindir / "slow-cc").write_text("#!/bin/sh\nsleep 60\nexit 1\n")
    (bindir / "slow-cc").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("CC", "slow-cc")
    x = cs.SX.sym("x", 2)
    fun = cs.Function("coldstart_slow_kernel", [x], [cs.sin(x[0]) * x[1]])
    children = {p.pid for p in psutil.Process().children(recursive=True)}
    out = codegen.compile_functions([fun], tmp_path / "cache", "digest", background=True)
    assert out.background and out.process is not None
    assert not codegen.finish(out.process, timeout=0.5)
    assert (
        psutil.wait_procs(
            [p for p in psutil.Process().children(recursive=True) if p.pid not in children], 5
        )[1]
        == []
    )
    assert not Path(out.library).exists() and not list((tmp_path / "cache").glob("*.c"))


@pytest.mark.skipif(os.name != "posix", reason="process groups")
def test_an_interrupted_compilation_leaves_no_compiler_running(tmp_path):
    """A compilation in the foreground interrupted while its compilers run: what each compiler
    started (cc1, as) ends with it, not only the compiler driver."""
    import signal
    import threading
    import time

    pids = tmp_path / "pids"
    bindir = tmp_path / "bin"
    bindir.mkdir()
    # a driver that works through a child of its own, as cc does through cc1
    (bindir / "driver-cc").write_text(f'#!/bin/sh\nsleep 60 &\necho $! >> "{pids}"\nwait\n')
    (bindir / "driver-cc").chmod(0o755)

    def interrupt() -> None:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and (
            not pids.exists() or len(pids.read_text().split()) < 2
        ):
            time.sleep(0.05)
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    timer = threading.Thread(target=interrupt)
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        cache.run_commands([[str(bindir / "driver-cc"), c] for c in ("a.c", "b.c")])
    timer.join()
    children = [int(p) for p in pids.read_text().split()]
    assert len(children) == 2

    assert not _still_running(children)


@pytest.mark.skipif(os.name != "posix", reason="process groups")
def test_an_interrupt_while_waiting_for_the_compiler_ends_it(tmp_path):
    """The end of a plan waits for its background compilation; an interrupt during that wait
    (a second Ctrl-C) ends the compilers too, rather than leaving them to the daemon thread that
    dies with the process."""
    import signal
    import threading
    import time

    pids = tmp_path / "pids"
    driver = tmp_path / "driver-cc"
    driver.write_text(f'#!/bin/sh\nsleep 60 &\necho $! >> "{pids}"\nwait\n')
    driver.chmod(0o755)
    compilation = codegen.Compilation(str(driver), "int x;\n", tmp_path / "k.so")

    def interrupt() -> None:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not pids.exists():
            time.sleep(0.05)
        time.sleep(0.2)  # inside finish()'s wait
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    timer = threading.Thread(target=interrupt)
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        codegen.finish(compilation, timeout=60)
    timer.join()
    assert not compilation.is_alive()
    assert not _still_running([int(p) for p in pids.read_text().split()])


@pytest.mark.skipif(os.name != "posix", reason="process groups")
def test_a_command_past_its_timeout_is_ended(tmp_path):
    """A child that does not answer in time (a compiler wrapper that hangs) is an error, and
    ends with everything it started."""
    pids = tmp_path / "pids"
    command = ["sh", "-c", f'sleep 60 & echo $! > "{pids}"; wait']
    with pytest.raises(OSError, match=r"^no answer in 0\.5 s$"):
        cache.run_commands([command], timeout=0.5)
    assert not _still_running([int(pids.read_text())])


def _still_running(pids: list[int], wait: float = 5.0) -> list[int]:
    """The processes of ``pids`` still running (not ended, nor zombies) after up to ``wait`` s."""
    import time

    import psutil

    def running(pid: int) -> bool:
        try:
            return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return False

    deadline = time.monotonic() + wait
    while any(running(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return [pid for pid in pids if running(pid)]
