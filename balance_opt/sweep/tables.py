"""The two tables of a sweep: ``results.csv`` and ``diagnostics.csv`` (columns: ``docs/sweeps.md``).

Floats are written in full precision (``repr``) so that two runs of the same sweep compare cell
by cell. Parquet is not written: pyarrow is about 100 MB for tables any tool reads as CSV."""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from balance_opt.report.output_dir import replaced_atomically
from balance_opt.sweep.spec import parameter_columns

#: Leading columns of both tables: they identify a case.
KEY_COLUMNS = ("index", "case_id", "method")
#: Prefixes of the parameter, baseline and time columns.
PARAM_PREFIX, BASELINE_PREFIX, TIMING_PREFIX = "param.", "mission_only.", "time."
#: The figures of merit in ``results.csv`` (flattened ``metrics.json`` names), in this order; a
#: column appears when at least one case has it (``solver.*``: optimal cases; ``simulation.*``:
#: sweeps with ``simulate: true``).
METRICS = (
    "duration_s",
    "max_drift_rad",
    "final_drift_rad",
    "max_base_rate_rad_s",
    "peak_balance_rate_rad_s",
    "min_sigma_min",
    "max_momentum_residual",
    "limit_violations",
    "min_limit_margin.position",
    "min_limit_margin.velocity",
    "min_limit_margin.acceleration",
    "balance_limit_margin.position",
    "balance_limit_margin.velocity",
    "balance_limit_margin.acceleration",
    "solver.status",
    "solver.iterations",
    "solver.objective",
    "solver.max_constraint_violation",
    "simulation.max_drift_rad",
    "simulation.final_drift_rad",
    "simulation.max_tracking_error_rad",
    "simulation.max_relative_momentum_residual",
)
#: The baseline's figures in ``results.csv`` (after :data:`BASELINE_PREFIX`).
BASELINE = ("max_drift_rad", "final_drift_rad", "max_base_rate_rad_s")
#: The times in ``results.csv`` (after :data:`TIMING_PREFIX`) [s]: the whole case in its worker,
#: the worker's CPU time meanwhile, the plan, the baseline replay.
TIMES = ("case_s", "cpu_s", "plan_s", "baseline_s")
#: Metric names that hold wall times (they differ from run to run, unlike everything else:
#: ``solver.solve_time_s``, ``details.wall_time_s.build``, ...; not
#: ``details.max_violation_at.time_s``, a time along the motion).
_TIMING_METRIC = re.compile(r"(^|[._])(wall_time|solve_time|build_time|elapsed)(_s)?($|[._])")


def is_timing_column(name: str) -> bool:
    """True for columns that depend on when and where a case ran (wall times, process ids)."""
    if name.startswith(TIMING_PREFIX):
        return True
    return not name.startswith(PARAM_PREFIX) and bool(_TIMING_METRIC.search(name))


def flatten(prefix: str, value: Any, out: dict) -> None:
    """Nested mappings into ``out`` with their keys joined by ``.``."""
    if isinstance(value, dict):
        for key, item in value.items():
            flatten(f"{prefix}.{key}" if prefix else str(key), item, out)
    else:
        out[prefix] = value


def _split(result: dict) -> tuple[dict[str, Any], dict[str, Any]]:
    """The cells of one case: ``(results row, diagnostics row)``."""
    keys = {key: result.get(key) for key in KEY_COLUMNS}
    tidy: dict[str, Any] = {**keys, "status": result.get("status")}
    extra: dict[str, Any] = dict(keys)
    for name, value in parameter_columns(result.get("parameters", {})).items():
        tidy[PARAM_PREFIX + name] = value
    metrics: dict[str, Any] = {}
    flatten("", result.get("metrics") or {}, metrics)
    metrics.pop("method", None)  # the key column
    for name in METRICS:
        if name in metrics:
            tidy[name] = metrics.pop(name)
    baseline = (result.get("info") or {}).get("mission_only") or {}
    for name in BASELINE:
        tidy[BASELINE_PREFIX + name] = baseline.get(name)
    error = result.get("error") or {}
    tidy["error_type"] = error.get("type")
    tidy["error_message"] = error.get("message")
    timing = dict(result.get("timing") or {})
    for name in TIMES:
        tidy[TIMING_PREFIX + name] = timing.pop(name, None)
    extra.update(metrics)
    extra["error_traceback"] = error.get("traceback")
    for name, value in timing.items():
        extra[TIMING_PREFIX + name] = value
    return tidy, extra


def _columns(rows: Sequence[dict], order: Sequence[str] | None = None) -> list[str]:
    """The columns of ``rows``: ``order`` first (those some row has), then the others in
    first-seen order, the timing columns last."""
    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    names = [c for c in order or () if c in seen] + [c for c in seen if c not in (order or ())]
    return [c for c in names if not is_timing_column(c)] + [c for c in names if is_timing_column(c)]


def results_table(results: Iterable[dict]) -> tuple[list[str], list[dict[str, Any]]]:
    """Columns and rows of ``results.csv`` (columns: ``docs/sweeps.md``), rows in case-index order."""
    rows = [_split(r)[0] for r in sorted(results, key=lambda r: r["index"])]
    if not rows:
        return [*KEY_COLUMNS, "status"], []
    params = [c for row in rows for c in row if c.startswith(PARAM_PREFIX)]
    order = [
        *KEY_COLUMNS,
        "status",
        *dict.fromkeys(params),
        *(m for m in METRICS if any(m in row for row in rows)),
        *(BASELINE_PREFIX + name for name in BASELINE),
        "error_type",
        "error_message",
        *(TIMING_PREFIX + name for name in TIMES),
    ]
    return [c for c in order if any(c in row for row in rows)], rows


def diagnostics_table(results: Iterable[dict]) -> tuple[list[str], list[dict[str, Any]]]:
    """Columns and rows of ``diagnostics.csv``: the key columns, then everything a case recorded
    that ``results.csv`` leaves out (first-seen order, timing columns last)."""
    rows = [_split(r)[1] for r in sorted(results, key=lambda r: r["index"])]
    return _columns(rows, KEY_COLUMNS), rows


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return json.dumps(value)
    return str(value)


def write_table_csv(path: str | Path, columns: Sequence[str], rows: Sequence[dict]) -> Path:
    """Write a table as CSV (floats as ``repr``: read back exactly; empty cell for missing),
    atomically."""
    path = Path(path)
    with replaced_atomically(path) as tmp, tmp.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_cell(row.get(c)) for c in columns])
    return path


def read_table_csv(path: str | Path) -> tuple[list[str], list[dict[str, str]]]:
    """Columns and rows (as text) of a table written by :func:`write_table_csv`."""
    with Path(path).open(newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


def write_tables(out_dir: str | Path, results: Sequence[dict]) -> dict[str, Path]:
    """Write ``results.csv`` and ``diagnostics.csv`` into ``out_dir``; name -> path."""
    out_dir = Path(out_dir)
    return {
        "table": write_table_csv(out_dir / "results.csv", *results_table(results)),
        "diagnostics": write_table_csv(out_dir / "diagnostics.csv", *diagnostics_table(results)),
    }
