"""The Pinocchio-CasADi bridge (balance_opt/model/bridge.py): the compiled program against
numeric Pinocchio, the 'pinocchio' backend's maps against adam's, its caches (corrupt files are
rebuilt, concurrent builds compile once) and the fallback of ``backend="auto"`` to adam.

The slow tests build the real program once per test session (about 1.5 min of CPU) in the
session's kernel cache (see conftest.py); the others use a stand-in compiler in a temporary
folder.
"""

import json
import re
import shutil
import stat
import threading
from pathlib import Path

import casadi as cs
import numpy as np
import pinocchio as pin
import pytest
from conftest import copy_programs

from balance_opt.errors import BalanceOptError
from balance_opt.model import bridge, symbolic
from balance_opt.model.symbolic import SymbolicMaps, available_backends, backend_description

ATOL = 1e-9
N_CONFIGS = 20
NO_COMPILER = "no C++ compiler found: tried $CXX, c++, g++, clang++"


def _random_q(robot, rng):
    """A configuration within the joint limits (continuous joints within one turn)."""
    return rng.uniform(
        np.maximum(robot.limits.lower, -np.pi), np.minimum(robot.limits.upper, np.pi)
    )


def _pinocchio_primitives(robot, q):
    """A_G and each end effector's LOCAL_WORLD_ALIGNED Jacobian from numeric Pinocchio, columns
    [base; arm joints in arm order]."""
    model, data = robot.model, robot.model.createData()
    cols = np.r_[0:6, robot.pin_v_indices]
    qp = robot.pin_q(q)
    A = pin.computeCentroidalMap(model, data, qp)[:, cols]
    pin.computeJointJacobians(model, data, qp)
    pin.updateFramePlacements(model, data)
    jac = [
        pin.getFrameJacobian(
            model, data, model.getFrameId(arm.ee_frame), pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )[:, cols]
        for arm in robot.arms
    ]
    return A, jac


@pytest.fixture(params=["paper", "baxter"])
def robot(request, paper, baxter):
    return {"paper": paper, "baxter": baxter}[request.param]


@pytest.fixture
def fake_compiler(tmp_path, monkeypatch):
    """A stand-in C++ compiler: logs each call to ``calls.txt``, takes half a second, and
    "builds" by copying ``/bin/true`` to its ``-o`` argument, or fails with ``error:`` lines
    when ``fail`` is written next to it."""
    script = tmp_path / "fake-c++"
    script.write_text(
        "#!/bin/sh\n"
        'if [ "$1" = "--version" ]; then echo "fake c++ 1.0"; exit 0; fi\n'
        f'if [ -e "{tmp_path}/fail" ]; then\n'
        '  echo "bridge.cpp: In function main:" >&2\n'
        '  echo "bridge.cpp:3:1: error: expected declaration" >&2\n'
        '  echo "bridge.cpp:9:1: error: another one" >&2\n'
        "  exit 1\n"
        "fi\n"
        'while [ $# -gt 0 ]; do [ "$1" = "-o" ] && out="$2"; shift; done\n'
        f'echo call >> "{tmp_path}/calls.txt"\n'
        "sleep 0.5\n"
        'cp /bin/true "$out"\n'
    )
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setattr(bridge, "find_cxx_compiler", lambda: str(script))
    return tmp_path


def _programs(folder):
    """The bridge programs in a cache folder (their records and locks have a suffix)."""
    return [p for p in folder.glob("pinocchio_casadi_bridge_*") if not p.suffix]


def _calls(folder):
    path = folder / "calls.txt"
    return len(path.read_text().splitlines()) if path.exists() else 0


# ----------------------------------------------------------------------------- real bridge
@pytest.mark.slow
def test_bridge_matches_numeric_pinocchio(robot):
    fun = bridge.bridge_function(robot)
    rng = np.random.default_rng(2024)
    for _ in range(N_CONFIGS):
        q = _random_q(robot, rng)
        A, *jac, oMi = (np.array(x) for x in fun(q))
        A_ref, jac_ref = _pinocchio_primitives(robot, q)
        np.testing.assert_allclose(A, A_ref, rtol=0, atol=ATOL)
        assert len(jac) == len(robot.arms)
        for J, J_ref in zip(jac, jac_ref):
            np.testing.assert_allclose(J, J_ref, rtol=0, atol=ATOL)
        data = robot.model.createData()
        pin.forwardKinematics(robot.model, data, robot.pin_q(q))
        placements = [np.r_[M.rotation.ravel(order="F"), M.translation] for M in data.oMi[1:]]
        np.testing.assert_allclose(oMi, np.array(placements).T, rtol=0, atol=ATOL)


@pytest.mark.slow
def test_pinocchio_backend_maps_equal_adam(robot):
    maps = SymbolicMaps(robot, backend="pinocchio")
    adam = SymbolicMaps(robot, backend="adam")
    assert maps.backend == "pinocchio"
    assert maps.backend_description.startswith("pinocchio (bridge, built once per machine: ")
    rng = np.random.default_rng(7)
    for _ in range(N_CONFIGS):
        q = _random_q(robot, rng)
        for f in ("centroidal_momentum_matrix_fun", "base_jacobian_fun"):
            ours, theirs = getattr(maps, f)()(q), getattr(adam, f)()(q)
            np.testing.assert_allclose(np.array(ours), np.array(theirs), rtol=0, atol=ATOL)


@pytest.mark.slow
def test_auto_prefers_the_bridge(paper):
    if "pinocchio" not in available_backends():
        pytest.skip("no C++ compiler or headers for the bridge here")
    maps = SymbolicMaps(paper)
    assert maps.backend == "pinocchio"
    record = bridge.ensure_bridge()
    assert record.path.is_file() and record.wall_seconds > 0 and record.cpu_seconds > 0
    assert backend_description() == f"pinocchio (bridge, built once per machine: {record.wall_seconds:.0f} s)"


@pytest.mark.slow
def test_truncated_program_is_rebuilt(paper, tmp_path, monkeypatch):
    """A cached program whose bytes no longer match its record is compiled again (here by a
    stand-in compiler command that copies the good program back), then runs."""
    record = bridge.ensure_bridge()
    good = tmp_path / "good"
    shutil.copy(record.path, good)
    record_file = record.path.with_suffix(".json")
    saved_record = record_file.read_text()
    key = record.path.name.rsplit("_", 1)[1]
    with open(record.path, "r+b") as fh:
        fh.truncate(1000)
    commands = []

    def copy_command(self, output):
        commands.append(output)
        return ["cp", str(good), str(output)]

    monkeypatch.setattr(bridge.Toolchain, "command", copy_command)
    monkeypatch.setattr(bridge, "_build_key", lambda toolchain: key)
    try:
        rebuilt = bridge.ensure_bridge()
        assert len(commands) == 1 and rebuilt.built_now and rebuilt.path == record.path
        assert record.path.read_bytes() == good.read_bytes()
        assert json.loads(record_file.read_text())["sha256"] == json.loads(saved_record)["sha256"]
        assert not bridge.ensure_bridge().built_now  # checked again, not rebuilt
        assert len(commands) == 1
        bridge.function_path(paper, record.path).unlink()  # the rebuilt program has to run
        A, _ = _pinocchio_primitives(paper, np.zeros(paper.n))
        np.testing.assert_allclose(
            np.array(bridge.bridge_function(paper)(np.zeros(paper.n))[0]), A, rtol=0, atol=ATOL
        )
    finally:
        record_file.write_text(saved_record)  # keep the real build time for later tests


@pytest.mark.slow
def test_truncated_function_file_is_generated_anew(paper):
    q = np.linspace(-1, 1, paper.n)
    expected = [np.array(x) for x in bridge.bridge_function(paper)(q)]
    path = bridge.function_path(paper, bridge.ensure_bridge().path)
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.truncate(size // 2)
    again = [np.array(x) for x in bridge.bridge_function(paper)(q)]
    assert path.stat().st_size == size
    for a, b in zip(again, expected):
        np.testing.assert_array_equal(a, b)
    assert isinstance(cs.Function.load(str(path)), cs.Function)


# ----------------------------------------------------------------------------- stand-ins
def test_concurrent_builds_compile_once(fake_compiler):
    cache = fake_compiler / "cache"
    records, errors = [], []

    def build():
        try:
            records.append(bridge.ensure_bridge(cache))
        except bridge.BridgeUnavailable as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=build) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert _calls(fake_compiler) == 1
    assert len({r.path for r in records}) == 1 and sum(r.built_now for r in records) == 1
    (program,) = _programs(cache)
    assert program.read_bytes() == Path("/bin/true").read_bytes()
    assert json.loads(program.with_suffix(".json").read_text())["wall_seconds"] >= 0.5


def test_build_failure_names_the_first_compiler_error(fake_compiler):
    (fake_compiler / "fail").touch()
    with pytest.raises(bridge.BridgeUnavailable) as err:
        bridge.ensure_bridge(fake_compiler / "cache")
    assert err.value.reason == "build failed: bridge.cpp:3:1: error: expected declaration"
    assert _programs(fake_compiler / "cache") == []


def test_unwritable_cache_folder_makes_the_bridge_unavailable(fake_compiler):
    blocker = fake_compiler / "not-a-folder"
    blocker.write_text("")
    with pytest.raises(bridge.BridgeUnavailable, match=r"build failed: .*not-a-folder"):
        bridge.ensure_bridge(blocker / "cache")


def test_build_progress_is_logged(fake_compiler, monkeypatch, caplog):
    monkeypatch.setattr(bridge, "PROGRESS_SECONDS", 0.1)
    with caplog.at_level("INFO", logger="balance_opt.model.bridge"):
        bridge.ensure_bridge(fake_compiler / "cache")
    messages = [r.getMessage() for r in caplog.records]
    # an honest estimate (the build's wall time depends on the load), and where it builds
    assert messages[0] == (
        "building the Pinocchio-CasADi bridge (once per machine: about 1.5 min of CPU, 1-6 min "
        f"of wall time depending on the load) in {fake_compiler / 'cache'}"
    )
    still = [m for m in messages[1:-1] if m.startswith("... still building the bridge (")]
    assert still and all(
        re.fullmatch(
            r"\.\.\. still building the bridge \(\d+ s so far, \d+ s of CPU of about 90\)", m
        )
        for m in still
    )
    assert messages[-1].startswith("built the Pinocchio-CasADi bridge in ")


@pytest.fixture
def no_pinocchio_casadi():
    if symbolic._imports("pinocchio.casadi"):
        pytest.skip("pinocchio.casadi imports here: auto never needs the bridge")


@pytest.mark.usefixtures("no_pinocchio_casadi")
def test_auto_falls_back_to_adam_without_a_compiler(paper, monkeypatch, caplog):
    monkeypatch.setattr(bridge, "find_cxx_compiler", lambda: None)
    assert available_backends() == ["adam"]
    with caplog.at_level("INFO", logger="balance_opt.model.symbolic"):
        maps = SymbolicMaps(paper)
        assert backend_description() == f"adam ({NO_COMPILER})"  # no notice of its own
    assert maps.backend == "adam"
    assert maps.backend_description == f"adam ({NO_COMPILER})"
    notices = [r.getMessage() for r in caplog.records if r.levelname == "INFO"]
    assert notices == [f"symbolic backend: adam ({NO_COMPILER}), not the Pinocchio-CasADi bridge"]
    with pytest.raises(
        BalanceOptError,
        match=r"backend 'pinocchio' cannot be used here: pinocchio.casadi does not import "
        r"\(PyPI's pin wheels lack it\) and the Pinocchio-CasADi bridge is unavailable: "
        r"no C\+\+ compiler found",
    ):
        SymbolicMaps(paper, backend="pinocchio")


@pytest.mark.usefixtures("no_pinocchio_casadi")
def test_auto_falls_back_to_adam_when_the_build_fails(paper, fake_compiler, monkeypatch):
    (fake_compiler / "fail").touch()
    monkeypatch.setenv("BALANCE_OPT_CACHE", str(fake_compiler / "cache"))
    maps = SymbolicMaps(paper)
    assert maps.backend_description == (
        "adam (build failed: bridge.cpp:3:1: error: expected declaration)"
    )


def test_built_programs_are_copied_into_another_cache_read_only(fake_compiler):
    """A test session's own cache is seeded with the user's bridge (issue 26): the programs
    whose bytes match their records are copied, the user's folder is left as it was, and the
    copy is a cached program there (no build)."""
    user, session = fake_compiler / "user", fake_compiler / "session"
    built = bridge.ensure_bridge(user / bridge.FOLDER).path
    broken = built.with_name("pinocchio_casadi_bridge_0000000000000000")
    broken.write_bytes(b"changed")
    broken.with_suffix(".json").write_text(built.with_suffix(".json").read_text())
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in (user / bridge.FOLDER).iterdir()}
    assert copy_programs(user, session) == [session / bridge.FOLDER / built.name]
    after = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in (user / bridge.FOLDER).iterdir()}
    assert after == before
    calls = (fake_compiler / "calls.txt").read_text().count("call")
    record = bridge.ensure_bridge(session / bridge.FOLDER)
    assert not record.built_now and record.path == session / bridge.FOLDER / built.name
    assert (fake_compiler / "calls.txt").read_text().count("call") == calls
    assert copy_programs(user, session) == []  # already there
