"""One BLAS thread for Ipopt's linear algebra."""

from __future__ import annotations

import ctypes
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

#: The environment variables OpenBLAS reads its number of threads from: one set overrides
#: the choice.
THREADS_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")

def casadi_openblas() -> ctypes.CDLL | None:
    """The OpenBLAS that CasADi's Ipopt plugin loaded, or ``None`` when none is loaded (before
    the first ``nlpsol``, or another build of CasADi). The wheel holds several copies of the
    file under different names: opening one by its path could load a second, unused instance,
    so it is looked up by name among the loaded libraries only (``RTLD_NOLOAD``)."""
    import casadi

    if not hasattr(os, "RTLD_NOLOAD"):
        return None  # no way to find the loaded one without loading another
    mode = os.RTLD_NOLOAD | os.RTLD_LAZY
    for path in sorted(Path(casadi.__file__).parent.glob("libcasadi-tp-openblas*")):
        try:
            lib = ctypes.CDLL(path.name, mode=mode)
            lib.openblas_get_num_threads  # noqa: B018 (raises AttributeError without it)
        except (OSError, AttributeError):
            continue
        return lib
    return None


def one_thread_for_ipopt() -> None:
    """Set CasADi's OpenBLAS to one thread (each time an NLP is built: cheap), unless one of
    :data:`THREADS_VARIABLES` is set (see the module docstring)."""
    if any(os.environ.get(name) for name in THREADS_VARIABLES):
        return
    lib = casadi_openblas()
    if lib is None:
        log.debug("CasADi's Ipopt loaded no OpenBLAS of its own: its threads are left alone")
        return
    lib.openblas_set_num_threads(ctypes.c_int(1))
