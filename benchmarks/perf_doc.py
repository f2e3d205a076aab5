"""The sections of ``docs/performance.md`` that the benchmark scripts write.

Each script prints its tables and rewrites its own section of the page, the text between
``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->`` (the rest of the page is left as it is),
headed by the machine it ran on: CPU model, cores, load average, date and the versions of
Python and of the libraries the figures depend on.
"""

from __future__ import annotations

import datetime
import os
import platform
import re
from importlib import metadata
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
#: Distributions whose versions the figures depend on.
VERSIONS = ("balance-opt", "casadi", "pin", "numpy", "scipy", "matplotlib")


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``; else what ``platform`` knows)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_line(load_before: float) -> str:
    """One line naming the machine, its load, the date and the versions."""
    versions = []
    for name in VERSIONS:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            pass
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"*{cpu_model()}, {os.cpu_count()} cores; load average {load_before:.2f} before, "
        f"{os.getloadavg()[0]:.2f} after; {now}; Python {platform.python_version()}, "
        f"{', '.join(versions)}.*"
    )


def write_section(name: str, command: str, lines: list[str], load_before: float) -> Path:
    """Replace section ``name`` of :data:`DOC` (appended when missing) with ``lines``, under
    the command that wrote it and :func:`machine_line`."""
    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    while lines and not lines[0]:
        lines = lines[1:]
    body = "\n".join(
        [start, f"`{command}`", "", machine_line(load_before), "", *lines, end]
    )
    text = DOC.read_text() if DOC.exists() else "# Performance\n"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: body, text)
    else:
        text = text.rstrip("\n") + "\n\n" + body + "\n"
    DOC.write_text(text)
    return DOC
