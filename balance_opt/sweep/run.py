"""Running a sweep: its locked output folder, the manifest of its cases (``sweep.json``), the
cases on an engine, then the table, summary and plots."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from balance_opt.interrupts import handling_signals
from balance_opt.report.output_dir import FolderLock, OutputFolderError, make_parent
from balance_opt.sweep.engine import (
    CASES_DIR,
    make_engine,
    read_result,
    run_cases,
    write_json_atomic,
)
from balance_opt.sweep.report import write_report
from balance_opt.sweep.spec import Sweep

logger = logging.getLogger(__name__)

#: The case function of task sweeps (see :mod:`balance_opt.sweep.runner`).
TASK_RUNNER = "balance_opt.sweep.runner:run_task_case"
#: Files a sweep writes in its output folder (besides ``cases/``).
MANIFEST = "sweep.json"


@dataclass
class SweepOutcome:
    """What :func:`run_sweep` did: the run, the files written and the summary."""

    run: Any
    files: dict[str, Path]
    summary: dict[str, Any]


def _prepared(out_dir: Path, resume: bool, force: bool) -> None:
    """``out_dir`` created; a folder with files only with ``resume`` (its finished cases kept)
    or ``force`` (a previous sweep's results deleted first)."""
    if out_dir.is_dir() and any(out_dir.iterdir()) and not resume:
        if not force:
            raise OutputFolderError(
                f"output directory {out_dir} exists and is not empty; nothing was run. "
                "Use --resume to finish the sweep in it, --force to start it over, "
                "or choose another --output"
            )
        for old in [
            *(out_dir / CASES_DIR).glob("*.json"),
            *(out_dir / "plots").glob("*.png"),
            out_dir / "results.csv",
            out_dir / "summary.json",
            out_dir / MANIFEST,
        ]:
            old.unlink(missing_ok=True)
    try:
        out_dir.mkdir(exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(
            f"cannot create output folder {out_dir}: {exc.strerror or exc}"
        ) from None


def _manifest(sweep: Sweep) -> dict:
    """The sweep's manifest: its name, source, setup hash, what varies and every case."""
    return {
        "name": sweep.name,
        "source": sweep.source,
        "setup_hash": sweep.setup_hash,
        "varied": list(sweep.varied),
        "methods": list(sweep.spec.methods),
        "cases": [
            {k: c[k] for k in ("index", "case_id", "method", "parameters")} for c in sweep.cases
        ],
    }


def run_sweep(
    sweep: Sweep,
    out_dir: str | Path,
    jobs: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    force: bool = False,
    retry_failed: bool = False,
    plots: bool = True,
    runner: str = TASK_RUNNER,
    on_result=None,
    engine=None,
) -> SweepOutcome:
    """Run every case of a sweep and write its results, table, summary and plots into
    ``out_dir`` (``docs/sweeps.md``), even when cases failed or on an interruption.

    Args:
        jobs: worker processes (0: in this process); with ``scheduler="local"``, Dask workers.
        scheduler: None (local process pool), ``"local"`` (a Dask cluster on the loopback
            interface) or a Dask scheduler address.
        resume, retry_failed, on_result: see :func:`balance_opt.sweep.engine.run_cases`.
        engine: an engine to use instead of the one ``jobs`` and ``scheduler`` describe.

    Raises:
        OutputFolderError: the folder cannot be used, or another sweep is writing to it.
    """
    out_dir = Path(out_dir)
    make_parent(out_dir.absolute())
    with handling_signals(), FolderLock(out_dir):
        _prepared(out_dir, resume, force)
        manifest = _manifest(sweep)
        write_json_atomic(out_dir / MANIFEST, manifest)
        engine = engine if engine is not None else make_engine(jobs, scheduler)
        extra = {"name": sweep.name, "source": sweep.source, "engine": engine.describe()}
        try:
            run = run_cases(
                sweep.cases,
                runner,
                out_dir,
                engine,
                resume=resume,
                retry_failed=retry_failed,
                on_result=on_result,
            )
        except KeyboardInterrupt:  # the table and summary of the cases finished (no plots)
            done = [r for c in sweep.cases if (r := read_result(out_dir, c["case_id"])) is not None]
            extra["interrupted"] = True
            write_report(out_dir, done, sweep.varied, plots=False, extra_summary=extra)
            logger.warning(
                "interrupted: %d of %d case(s) finished; run again with --resume to go on",
                len(done),
                len(sweep.cases),
            )
            raise
        extra.update(
            workers=run.workers, elapsed_s=run.elapsed_s, ran=len(run.ran), skipped=len(run.skipped)
        )
        files, summary = write_report(out_dir, run.results, sweep.varied, plots, extra)
    return SweepOutcome(run, files, summary)
