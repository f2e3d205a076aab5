"""CasADi functions on disk: serialized (:class:`FunctionStore`), and compiled to C, with an
on-disk cache shared by processes."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import heapq
import logging
import os
import platform
import re
import shutil
import threading
import time
from collections.abc import Callable
from pathlib import Path

import casadi as cs

from balance_opt.cache import (
    MODELS_FOLDER,
    atomic_write_text,
    build_dir,
    check_record,
    clean_stale,
    default_cache_dir,
    enforce_limit,
    file_lock,
    load_checked,
    lock_path,
    record_path,
    run_commands,
    write_record,
)

log = logging.getLogger(__name__)

#: C compiler flags of the kernels: -Og runs them as fast as -O1 and -O2 (CasADi's straight-line
#: scalar code gains nothing from the passes it leaves out) and compiles in two thirds of -O1's
#: time; no
#: -march=native or -ffast-math, and no fused multiply-adds (which a machine with FMA would
#: otherwise form where it can), so that results do not depend on the machine and a kernel cut
#: into parts (:func:`split_functions`) computes the same bits as the whole one.
COMPILER_FLAGS = ("-Og", "-ffp-contract=off", "-shared", "-fPIC")
#: Niceness of the background compiler: the plan being solved meanwhile keeps the CPU (not for
#: a compilation the plan waits for, :func:`compile_functions`'s ``wait``).
BACKGROUND_NICENESS = 10
#: A failed background compilation is not started again before this time [s] has passed.
RETRY_SECONDS = 24 * 3600.0
#: How long the planning call that started a background compilation waits for it at its end
#: [s] before stopping it (the next run then starts it again).
COMPILE_WAIT = 300.0
#: Statements per C function of a split kernel (:func:`split_functions`): the compiler's
#: register allocation grows faster than linearly with a function's length, so a Hessian of
#: 10^5 statements in pieces of this size compiles in a fraction of the time, and runs as fast.
PART_STATEMENTS = 300
_SUFFIX = ".dll" if os.name == "nt" else ".so"


class FunctionStore:
    """Named lists of CasADi functions of one planner model, on disk."""

    def __init__(self, label: str, key: str, cache_dir: str | Path | None = None):
        root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.folder = root / MODELS_FOLDER
        self.prefix = f"{re.sub(r'[^A-Za-z0-9._-]+', '_', label)[:40]}_{key}"

    def path(self, name: str) -> Path:
        return self.folder / f"{self.prefix}_{name}.casadi"

    def get(self, name: str, make: Callable[[], list[cs.Function]]) -> list[cs.Function]:
        """The functions saved as ``name`` (a damaged file deleted), else ``make()``'s, saved (a
        failure to write is only logged: the cache only saves time)."""
        path = self.path(name)
        functions = load_checked(
            path,
            lambda p: list(cs.FileDeserializer(str(p)).unpack()),
            f"planner model {path}",
            "building it again",
        )
        if functions is not None:
            return functions
        functions = make()
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with file_lock(lock_path(path)), build_dir(self.folder, path.stem) as tmp:
                out = tmp / path.name
                serializer = cs.FileSerializer(str(out))
                serializer.pack(functions)
                del serializer  # closes the file
                os.replace(out, path)
                write_record(path)
        except (OSError, RuntimeError) as exc:
            log.warning("planner model not cached (%s): %s", path, exc)
        return functions


@dataclasses.dataclass(frozen=True)
class Compiled:
    functions: list[cs.Function]
    compiled: bool
    compile_time: float
    library: str
    background: bool = False
    process: Compilation | None = None


def find_compiler() -> str | None:
    """A C compiler on the PATH (``$CC``, ``cc``, ``gcc``, ``clang``), or ``None``."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def library_path(digest: str, compiler: str, cache_dir: Path | None = None) -> Path:
    """Where the library of content ``digest`` compiled by ``compiler`` is cached."""
    parts = [
        digest,
        compiler,
        " ".join(COMPILER_FLAGS),
        cs.__version__,
        platform.machine(),
        platform.system(),
    ]
    name = hashlib.sha256("\n".join(parts).encode()).hexdigest()[:20]
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return folder / f"balance_kernels_{name}{_SUFFIX}"


def load_cached(names: list[str], library: Path) -> list[cs.Function] | None:
    """The functions ``names`` of ``library`` if it is cached and intact, else ``None`` (a
    damaged library is deleted, so that it is rebuilt); BlockingIOError while another process
    compiles it."""
    # finite differences only let CasADi build (never evaluate) derivative graphs it asks for
    return load_checked(
        library,
        lambda path: [cs.external(name, str(path), {"enable_fd": True}) for name in names],
        f"balance kernels {library}",
        "deleting and rebuilding",
        blocking=False,
    )


def compile_functions(
    functions: list[cs.Function],
    cache_dir: Path | None = None,
    digest: str | None = None,
    background: bool = False,
    label: str = "",
    wait: bool = False,
) -> Compiled:
    """Compile CasADi functions to one shared library, cached on disk; in the ``background``:
    by a :class:`Compilation` (``process``) while the functions run on CasADi's VM; with
    ``wait`` as well, by a :class:`Compilation` at full priority that this call waits for (at
    most :data:`COMPILE_WAIT`): the library's functions, or the VM's if it failed or was
    stopped (a failure is not retried before :data:`RETRY_SECONDS`, as in the background)."""
    compiler = find_compiler()
    if compiler is None:
        raise OSError("no C compiler found (tried $CC, cc, gcc, clang)")
    source = _source(functions) if digest is None else None
    digest = digest or hashlib.sha256(source.encode()).hexdigest()
    library = library_path(digest, compiler, cache_dir)
    library.parent.mkdir(parents=True, exist_ok=True)
    names = [f.name() for f in functions]
    vm = Compiled(functions, False, 0.0, str(library), True)
    try:
        loaded = load_cached(names, library)
    except BlockingIOError:  # being compiled by another process
        if background:
            return vm
        loaded = None
    if loaded is not None:
        return Compiled(loaded, True, 0.0, str(library))
    clean_stale(library.parent)
    source = source or _source(functions)
    what = f"planner kernels for {label}" if label else "planner kernels"
    if background:
        failure = _recent_failure(library)
        if failure:
            log.warning(
                "%s: the background compilation failed (%s); using CasADi's virtual machine "
                "(`balance-opt cache --clear` to try again)",
                what,
                failure,
            )
            return vm
        try:
            process = Compilation(compiler, source, library, 0 if wait else BACKGROUND_NICENESS)
        except BlockingIOError:
            log.info("%s are being compiled by another process; not waiting", what)
            return vm
        if not wait:
            log.info("compiling %s (background) ...", what)
            return dataclasses.replace(vm, process=process)
        log.info("compiling %s (at most %.0f s) ...", what, COMPILE_WAIT)
        start = time.perf_counter()
        loaded = load_cached(names, library) if finish(process, announce=False) else None
        if loaded is None:  # failed (noted) or stopped: this plan runs on the VM
            log.warning("%s not compiled; using CasADi's virtual machine", what)
            return vm
        return Compiled(loaded, True, time.perf_counter() - start, str(library))
    log.info("compiling %s ...", what)
    with file_lock(lock_path(library)):  # one compiles, the others wait
        elapsed = 0.0 if check_record(library)[0] else _compile(compiler, source, library)
    externals = load_cached(names, library)
    if externals is None:
        raise OSError(f"the compiled library {library} does not match its record")
    return Compiled(externals, True, elapsed, str(library))


def _source(functions: list[cs.Function]) -> str:
    generator = cs.CodeGenerator("balance_kernels.c", {"with_header": False})
    for f in functions:
        generator.add(f)
    return split_functions(generator.dump())


# CasADi's C code of an SX function: a body of scalar assignments to work variables ``a<k>``
# (reused once dead) and writes of outputs, in one C function per CasADi function
_BODY_START = re.compile(
    r"^static int (casadi_f\d+)\(const casadi_real\*\* arg, casadi_real\*\* res, "
    r"casadi_int\* iw, casadi_real\* w, int mem\) \{$"
)
_VARIABLE = re.compile(r"\b(a\d+)\b")
_ASSIGN = re.compile(r"^  (a\d+)=(.*);$")
_OUTPUT = re.compile(r"^  if \(res\[\d+\]!=0\) res\[\d+\]\[\d+\]=a\d+;$")
# a part: never inlined back into its caller, not exported from the library
_PART_MACRO = """#if defined(__GNUC__)
#define BALANCE_PART __attribute__((noinline, visibility("hidden")))
#elif defined(_MSC_VER)
#define BALANCE_PART __declspec(noinline)
#else
#define BALANCE_PART
#endif
"""
_PART_START = re.compile(r"^BALANCE_PART void casadi_f\d+_part\d+\(.*\{$")
# CasADi's helpers (casadi_sq, casadi_fmax, ...) and where its preamble ends
_HELPER = re.compile(r"^(casadi_real|casadi_int|int|void) \**casadi_\w+\(")
_PREAMBLE_END = "/* Configuration this file was compiled with */"


def split_functions(source: str, statements: int = PART_STATEMENTS) -> str:
    """CasADi's C ``source`` with each function body longer than ``statements`` cut into
    parts of at most that many, each a C function of its own, called in order.

    The parts run the same operations in the same order, so the results are the same to the
    last bit; a value one part computes and a later one reads passes through an array on the
    stack (a body of another form is left whole)."""
    lines = source.split("\n")
    out, i, split = [], 0, False
    while i < len(lines):
        start = _BODY_START.match(lines[i])
        if start is None:
            out.append(lines[i])
            i += 1
            continue
        j = i + 1
        while lines[j].startswith("  casadi_real a"):
            j += 1
        end = next((k for k in range(j, len(lines) - 1) if lines[k] == "  return 0;"), None)
        if end is None:  # not of this form: the rest as it is
            out += lines[i:]
            break
        body = lines[j:end]
        if (
            len(body) > statements
            and lines[end + 1] == "}"
            and all(_ASSIGN.match(line) or _OUTPUT.match(line) for line in body)
        ):
            out += _parts(start.group(1), body, statements)
            split = True
        else:
            out += lines[i : end + 2]
        i = end + 2
    return _PART_MACRO + "\n".join(out) if split else source


def _parts(name: str, body: list[str], statements: int) -> list[str]:
    size = -(-len(body) // -(-len(body) // statements))  # parts of equal size
    # each assignment's value gets a number of its own (the body reuses variable names)
    current: dict[str, int] = {}
    first, last = [], []  # the part that computes a value, the last part that reads it
    code = []  # (value assigned or None, the text with the values read at odd places)
    for k, line in enumerate(body):
        part = k // size
        assign = _ASSIGN.match(line)
        pieces = _VARIABLE.split(assign.group(2) if assign else line)
        for i in range(1, len(pieces), 2):
            pieces[i] = value = current[pieces[i]]
            last[value] = part
        if assign:
            current[assign.group(1)] = len(first)
            code.append((len(first), pieces))
            first.append(part)
            last.append(part)
        else:
            code.append((None, pieces))
    # the values read by a later part: slots of the array, each reused once its value's
    # last reader has run
    slot, free, busy, n_slots = {}, [], [], 0
    for value, part in enumerate(first):
        if last[value] == part:
            continue
        while busy and busy[0][0] < part:
            free.append(heapq.heappop(busy)[1])
        if not free:
            free.append(n_slots)
            n_slots += 1
        slot[value] = free.pop()
        heapq.heappush(busy, (last[value], slot[value]))

    names = [f"s[{slot[v]}]" if v in slot else f"v{v}" for v in range(len(first))]

    def fill(pieces: list) -> str:
        pieces[1::2] = [names[v] for v in pieces[1::2]]
        return "".join(pieces)

    out, n_parts = [], -(-len(body) // size)
    for part in range(n_parts):
        lines = code[part * size : (part + 1) * size]
        out.append(
            f"BALANCE_PART void {name}_part{part}(const casadi_real** arg, "
            "casadi_real** res, casadi_real* s) {"
        )
        local = [f"v{v}" for v, _ in lines if v is not None and v not in slot]
        out += [f"  casadi_real {', '.join(local[a : a + 12])};" for a in range(0, len(local), 12)]
        out += [f"  {names[v]}={fill(t)};" if v is not None else fill(t) for v, t in lines]
        out += ["}", ""]
    out.append(
        f"static int {name}(const casadi_real** arg, casadi_real** res, casadi_int* iw, "
        "casadi_real* w, int mem) {"
    )
    out.append(f"  casadi_real s[{max(n_slots, 1)}];")
    out += [f"  {name}_part{part}(arg, res, s);" for part in range(n_parts)]
    return [*out, "  return 0;", "}"]


def c_files(source: str) -> list[str]:
    """The split ``source`` (:func:`split_functions`) as two C files to compile at once and
    link: ``source`` without its last parts, about half of its lines (declared instead), and
    those parts after CasADi's preamble (its helpers made local to the file, so the compiler can
    inline them there too)."""
    lines = source.split("\n")
    starts = [k for k, line in enumerate(lines) if _PART_START.match(line)]
    if len(starts) < 2 or _PREAMBLE_END not in lines:
        return [source]
    parts = [(k, lines.index("}", k)) for k in starts]
    half, size, moved = sum(e - k for k, e in parts) / 2, 0, []
    for k, e in reversed(parts):
        if size + e - k > half:
            break
        moved.append((k, e))
        size += e - k
    if not moved:
        return [source]
    preamble = [
        f"static {line}" if _HELPER.match(line) else line
        for line in lines[: lines.index(_PREAMBLE_END)]
    ]
    first, cut, body = list(lines), set(), []
    for k, e in sorted(moved):
        body += lines[k : e + 1]
        first[k] = lines[k][:-2] + ";"  # the declaration
        cut.update(range(k + 1, e + 1))
    second = "\n".join([*preamble, _PART_MACRO, *body, ""])
    return ["\n".join(line for k, line in enumerate(first) if k not in cut), second]


def _recent_failure(library: Path) -> str:
    """The error of a background compilation of ``library`` that failed within
    :data:`RETRY_SECONDS` (not retried before then), else ``""``."""
    note = library.with_suffix(".failed")  # a failed background compilation's message
    try:
        if time.time() - note.stat().st_mtime < RETRY_SECONDS:
            return note.read_text().strip()[:300] or "no message"
    except OSError:
        pass
    return ""


class Compilation(threading.Thread):
    """A background compilation: a thread of this process that runs the compilers (child
    processes, niced by ``niceness``) while it holds the library's lock, which it takes (without
    waiting) before the constructor returns: BlockingIOError when another holds it."""

    def __init__(
        self, compiler: str, source: str, library: Path, niceness: int = BACKGROUND_NICENESS
    ):
        super().__init__(daemon=True)
        self.compiler, self.source, self.library = compiler, source, library
        self.niceness = niceness
        self.stopped = threading.Event()
        self._locked = threading.Event()
        self._refused: OSError | None = None
        self.start()
        self._locked.wait()
        if self._refused is not None:
            raise self._refused

    def run(self) -> None:
        library = self.library
        held = contextlib.ExitStack()
        try:  # taken and released by this thread (filelock keeps its holds per thread)
            held.enter_context(file_lock(lock_path(library), blocking=False))
        except OSError as exc:
            self._refused = exc
            return
        finally:
            self._locked.set()
        try:
            with held:
                if check_record(library)[0] is None:
                    _compile(self.compiler, self.source, library, self.stopped, self.niceness)
            enforce_limit(library.parent, keep=[library, record_path(library)])
            library.with_suffix(".failed").unlink(missing_ok=True)
        except OSError as exc:  # the planner keeps the VM; noted, so that runs do not retry
            if not self.stopped.is_set():
                with contextlib.suppress(OSError):
                    atomic_write_text(library.with_suffix(".failed"), str(exc))

    def stop(self) -> None:
        self.stopped.set()
        self.join(10.0)


def finish(process: Compilation, timeout: float = COMPILE_WAIT, announce: bool = True) -> bool:
    """Wait up to ``timeout`` [s] for a background compilation this process started, then stop
    it if it still runs (the next run starts again). Returns whether it ended on its own."""
    if announce and process.is_alive():
        log.info(
            "waiting for the C compiler of the planner kernels (at most %.0f s; the next runs "
            "load the library) ...",
            timeout,
        )
    try:
        process.join(timeout)
    except BaseException:  # a second Ctrl-C while waiting: the compilers end with the command
        process.stop()
        raise
    if not process.is_alive():
        return True
    process.stop()
    log.warning("planner kernels: compilation stopped after %.0f s; not cached", timeout)
    return False


def wait_for_library(library: str | Path) -> dict | None:
    """Wait for the compilation of ``library`` under way in any process to end (for benchmarks
    and tests): its record (``compile_seconds``), or ``None`` (failed)."""
    with file_lock(lock_path(Path(library))):
        return check_record(Path(library))[0]


def _compile(
    compiler: str,
    source: str,
    library: Path,
    stop: threading.Event | None = None,
    niceness: int = 0,
) -> float:
    """Compile C ``source`` to the shared ``library`` and record it; returns the wall time [s].
    A split source is compiled as several files at once (:func:`c_files`), then linked. The
    caller holds the library's lock; a compilation in a :class:`Compilation` (``stop`` given)
    ends its compilers when ``stop`` is set, and runs them at ``niceness``."""
    for path in (library, record_path(library)):
        path.unlink(missing_ok=True)
    start = time.perf_counter()
    with build_dir(library.parent, library.stem) as tmp:
        out = tmp / library.name
        texts = c_files(source)
        try:
            _build(compiler, texts, out, stop, niceness)
        except OSError as exc:  # one file cannot depend on how CasADi's preamble is laid out
            if len(texts) == 1 or (stop is not None and stop.is_set()):
                raise
            log.warning("the kernels as %d C files did not build (%s); as one", len(texts), exc)
            _build(compiler, [source], out, stop, niceness)
        os.replace(out, library)  # atomic: a process never loads a partial library
    elapsed = time.perf_counter() - start
    write_record(library, compile_seconds=round(elapsed, 3))
    log.info("compiled balance kernels to %s in %.1f s", library, elapsed)
    return elapsed


def _build(
    compiler: str, texts: list[str], out: Path, stop: threading.Event | None, niceness: int
) -> None:
    names = ["balance_kernels.c"] + [f"balance_kernels_{k}.c" for k in range(1, len(texts))]
    files = [out.parent / name for name in names]
    for path, text in zip(files, texts):
        path.write_text(text)
    command = [compiler, *COMPILER_FLAGS]
    nice = shutil.which("nice") if niceness else None
    if nice:  # in the background: the plan being solved keeps the CPU
        command = [nice, "-n", str(niceness), *command]
    inputs = [str(f) for f in files]
    try:
        if len(files) > 1:
            inputs = [str(f.with_suffix(".o")) for f in files]
            run_commands([[*command, "-c", str(f), "-o", o] for f, o in zip(files, inputs)], stop)
        run_commands([[*command, *inputs, "-o", str(out), "-lm"]], stop)
    except OSError as exc:
        raise OSError(f"{compiler} failed on the balance kernels: {exc}") from exc
