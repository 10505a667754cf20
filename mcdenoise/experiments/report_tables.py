"""An experiment's tables: ``results.json``, ``results.csv`` (one row per unit) and ``frames.csv``
(one row per frame of a sequence unit), and the mark of times measured around a whole process.
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Mapping
from typing import Any

from mcdenoise.eval.eval_report import csv_cell
from mcdenoise.experiments.analysis import ExperimentResult
from mcdenoise.experiments.timing import PROCESS, timing_clock
from mcdenoise.io.atomic import write_text_atomic

#: Columns of results.csv before the metric columns.
CSV_HEAD = (
    "scene",
    "method",
    "base_method",
    "spp",
    "render_seconds",
    "denoise_seconds",
    "total_seconds",
    "denoise_runs",
    "device",
    "threads",
    "timing_clock",
    "host",
)


#: Columns of results.csv after the metric columns.
CSV_TAIL = (
    "relmse_vs_noisy",
    "limited_by_reference",
    "pareto",
    "equal_quality_spp",
    "equal_quality_seconds",
    "equal_quality_extrapolated",
    "speedup",
    "failed",
    "error",
    "reason",
    "output",
    "params",
)


#: Columns of results.csv added at its end when the scenes are sequences.
CSV_SEQUENCE = ("frames", "warmup_frames", "relmse_warmup", "trelmse_warmup")


#: Columns of frames.csv (sequences: one row per record and frame) before the metrics.
FRAMES_CSV_HEAD = ("scene", "method", "spp", "frame", "index", "warmup", "denoise_seconds")


def write_json(result: ExperimentResult, path: str | os.PathLike[str]) -> None:
    """``result.to_dict()`` as strict JSON (``allow_nan=False``), atomically."""
    text = json.dumps(result.to_dict(), indent=1, ensure_ascii=False, allow_nan=False)
    write_text_atomic(path, text + "\n")


def _cell(value: Any) -> str:
    """:func:`~mcdenoise.eval.eval_report.csv_cell`, with a dict or list as sorted JSON."""
    if isinstance(value, dict | list):
        return json.dumps(value, sort_keys=True)
    return csv_cell(value)


#: Marks a denoise time that is a whole process (an external command), not in-process work.
PROCESS_MARK = "‡"


PROCESS_NOTE = (
    f"{PROCESS_MARK}: an external command's time is the whole process (writing its input "
    "files, starting the program, its own loading and work, reading its output), not "
    "comparable on the same footing with the in-process methods' times."
)


def record_clock(r: Mapping[str, Any]) -> str | None:
    """What a record's denoise seconds measure (``process``, ``in-process``, ``None`` for
    noisy); records written before the field existed are judged by their method."""
    if "timing_clock" in r:
        return r["timing_clock"]

    return timing_clock(str(r.get("base_method") or r.get("method")))


def _process_mark(r: Mapping[str, Any]) -> str:

    return PROCESS_MARK if record_clock(r) == PROCESS else ""


def _process_methods(result: ExperimentResult) -> list[str]:
    """Labels of the methods whose times are whole processes (external commands)."""
    return sorted({str(r["method"]) for r in result.records if _process_mark(r)})


def _process_methods_note(result: ExperimentResult) -> str:
    return (
        f"{', '.join(_process_methods(result))}: external command(s), timed as whole "
        f"processes ({PROCESS_MARK}); " + PROCESS_NOTE.partition(": ")[2]
    )


def csv_columns(result: ExperimentResult) -> list[str]:
    """Header of results.csv."""
    extra = CSV_SEQUENCE if result.is_sequences else ()
    return [*CSV_HEAD, *result.metrics, *CSV_TAIL, *extra]


def write_csv(result: ExperimentResult, path: str | os.PathLike[str]) -> None:
    """One row per (scene, spp, method) record, atomically."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(csv_columns(result))
    for r in result.records:
        timing = r.get("timing") or {}
        eq = r.get("equal_quality") or {}
        row = [r["scene"], r["method"], r.get("base_method"), r["spp"]]
        row += [r.get("render_seconds"), r.get("denoise_seconds"), r.get("total_seconds")]
        row.append(";".join(_cell(v) for v in timing.get("runs", [])) or None)
        row += [r.get("device"), r.get("threads"), record_clock(r), r.get("host")]
        row += [(r.get("metrics") or {}).get(m) for m in result.metrics]
        row += [r.get("relmse_vs_noisy"), r.get("limited_by_reference"), r.get("pareto")]
        row += [eq.get("spp"), eq.get("seconds"), eq.get("extrapolated"), eq.get("speedup")]
        row += [r.get("failed"), r.get("error"), r.get("reason"), r.get("output")]
        row.append(r.get("params") or None)
        if result.is_sequences:
            warm = r.get("warmup_metrics") or {}
            row += [r.get("frames_count"), r.get("warmup_frames")]
            row += [warm.get("relmse"), warm.get("trelmse")]
        w.writerow([_cell(v) for v in row])
    write_text_atomic(path, buf.getvalue())


def write_frames_csv(result: ExperimentResult, path: str | os.PathLike[str]) -> None:
    """Sequences: one row per (scene, spp, method, frame) with the frame's denoise seconds
    (the last timed run) and metrics (temporal ones: the pair ending at that frame)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*FRAMES_CSV_HEAD, *result.metrics])
    for r in result.records:
        for f in r.get("frames") or []:
            row = [r["scene"], r["method"], r["spp"], f.get("frame"), f.get("index")]
            row += [f.get("warmup"), f.get("seconds")]
            row += [(f.get("metrics") or {}).get(m) for m in result.metrics]
            w.writerow([_cell(v) for v in row])
    write_text_atomic(path, buf.getvalue())
