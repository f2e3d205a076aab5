"""The version of the Ipopt library the planner solves with, for the record of a run."""

from __future__ import annotations

import ctypes
import glob
import logging
import os

log = logging.getLogger(__name__)


def ipopt_version() -> str:
    """Version of the Ipopt library bundled with CasADi (e.g. ``"3.14.19"``), or ``"unknown"``."""
    import casadi

    folder = os.path.dirname(casadi.__file__)
    patterns = ("libipopt.so*", "libipopt*.dylib", "libipopt*.dll", "ipopt*.dll")
    candidates = sorted(
        {p for pat in patterns for p in glob.glob(os.path.join(folder, pat))}, key=len
    )
    for path in candidates:
        try:
            lib = ctypes.CDLL(path)
            getter = lib.GetIpoptVersion
        except (OSError, AttributeError):
            continue
        major, minor, release = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        getter(ctypes.byref(major), ctypes.byref(minor), ctypes.byref(release))
        return f"{major.value}.{minor.value}.{release.value}"
    log.debug("no Ipopt library with GetIpoptVersion in %s", folder)
    return "unknown"
