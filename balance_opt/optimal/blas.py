"""One BLAS thread for Ipopt's linear algebra.

CasADi's Ipopt plugin loads its own OpenBLAS (``libcasadi-tp-openblas``), which starts a thread
per core. MUMPS's dense blocks on the planner's KKT matrices are too small for a second thread
to pay: with 7 + 7 joints (Baxter, peak objective, N = 100 and 200) two threads took the same
wall time as one and twice the CPU (``OPENBLAS_NUM_THREADS=1`` against ``2`` with
``benchmarks/bench_scaling.py``), and the second core is where the figures' worker process and
a multi-start's workers run. So once the plugin is loaded (the first ``nlpsol``), its OpenBLAS
is set to one thread, unless ``OPENBLAS_NUM_THREADS`` says otherwise.
"""

from __future__ import annotations

import ctypes
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

#: The environment variable that overrides the choice (OpenBLAS's own).
THREADS_VARIABLE = "OPENBLAS_NUM_THREADS"

_done = False


def casadi_openblas() -> ctypes.CDLL | None:
    """CasADi's bundled OpenBLAS (the library the Ipopt plugin loaded), or ``None`` when the
    wheel has none (another build of CasADi)."""
    import casadi

    for path in sorted(Path(casadi.__file__).parent.glob("libcasadi-tp-openblas*")):
        try:
            lib = ctypes.CDLL(str(path))
            lib.openblas_get_num_threads  # noqa: B018 (raises AttributeError without it)
        except (OSError, AttributeError):
            continue
        return lib
    return None


def one_thread_for_ipopt() -> None:
    """Set CasADi's OpenBLAS to one thread, once per process, unless
    :data:`THREADS_VARIABLE` is set (see the module docstring)."""
    global _done
    if _done:
        return
    _done = True
    if os.environ.get(THREADS_VARIABLE):
        return
    lib = casadi_openblas()
    if lib is None:
        log.debug("no OpenBLAS in CasADi's folder: its threads are left alone")
        return
    lib.openblas_set_num_threads(ctypes.c_int(1))
