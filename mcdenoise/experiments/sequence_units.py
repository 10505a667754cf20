"""Units of a sequence experiment: one method over one whole sequence at one spp level.

A sequence unit is what a still unit is (:mod:`mcdenoise.experiments.runner`), with a
sequence in place of an image:

* the frames of the level are read once (every frame's part ``spp<n>``, motion buffers
  included) and the method runs over them in order through
  :func:`mcdenoise.denoise.denoise_sequence`, i.e. :meth:`mcdenoise.method.Method.run_frames`:
  a temporal method (``svgf``) through its ``run_sequence``, carrying its history from frame
  to frame; a per-frame method (``nlm``, ``oidn``, ``kpcn``) on each frame alone;
* timing: the whole sequence is run ``warmup`` times untimed and ``repetitions`` times timed
  (:func:`~mcdenoise.experiments.timing.time_runs`); the seconds of one run are the *mean
  seconds per frame* of the method (``DenoiseResult.seconds`` summed over the frames, divided
  by their number: no reading, no sanitising), the median over runs is the unit's
  ``denoise_seconds``, and the last run's seconds of every frame are kept
  (``frame_seconds``). So ``total_seconds`` = render seconds per frame + denoise seconds per
  frame, and every curve and table of the report reads "per frame";
* metrics: :func:`mcdenoise.eval.temporal_metrics.sequence_metrics` of the last run's output frames
  against the reference frames (not reimplemented here): the headline ``metrics`` are the
  still metrics averaged over the frames past the warm-up and the temporal metrics over the
  frame pairs past it, ``warmup_metrics`` the warm-up frames' (reported apart), ``all_metrics``
  every frame's, and ``frames`` the value of every frame;
* the outputs (when kept) are ``DIR/outputs/<scene>_spp<n>_<label>/frame_0000.exr``, one file
  per frame, named as the input frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.denoise import denoise_sequence
from mcdenoise.denoise_files import ReadOptions, WriteOptions
from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.results import decode_float
from mcdenoise.eval.temporal_metrics import sequence_metrics
from mcdenoise.experiments.entries import run_device
from mcdenoise.experiments.timing import time_runs
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.output import write_result
from mcdenoise.registry import get_method


def load_frames(paths: Sequence[Path], part: str | None = None) -> list[Any]:
    """Every frame's ``FeatureBuffers`` (the level ``part``; ``None``: the only part)."""

    return [load_buffers(p, part=part) for p in paths]


def frame_name(index: int) -> str:
    """``frame_0003``: the layout's name of frame ``index`` (:mod:`mcdenoise.render.layout`)."""
    return f"frame_{index:04d}"


def run_sequence_unit(
    unit: Any,
    frames: Sequence[Any],
    references: Sequence[np.ndarray],
    out: Path,
    settings: Any,
    device: Any,
    *,
    base: Callable[[], dict[str, Any]],
    fail: Callable[[dict[str, Any], str], dict[str, Any]],
    relative: Callable[[Path, Path], str],
) -> dict[str, Any]:
    """Run one sequence unit (see the module docstring) on its loaded ``frames``
    (``FeatureBuffers`` of the level, in order) against ``references`` (``(3, H, W)`` per
    frame); return its record. ``base`` gives the record's common fields, ``fail`` turns it
    into a "could not run" record, ``relative`` names a path relative to ``out`` (the
    runner's helpers, so still and sequence records share one layout)."""

    entry, level = unit.entry, unit.level
    record = base()
    n = len(frames)
    record["frames_count"] = n
    record["warmup_frames"] = settings.warmup_frames
    if entry.is_noisy:
        images = [f["color"].numpy() for f in frames]
        frame_seconds: list[float] = [0.0] * n
    else:
        method = get_method(entry.method)
        dev = run_device(method, device, record["notes"], entry.method)

        def once() -> tuple[list[Any], float, str]:
            results = list(denoise_sequence(frames, method, params=entry.overrides, device=dev))
            per_frame = sum(r.seconds for r in results) / max(len(results), 1)
            return results, per_frame, results[0].device if results else str(dev)

        try:
            results, timing = time_runs(
                once, repetitions=settings.repetitions, warmup=settings.warmup
            )
        except McdenoiseError as err:
            return fail(record, " ".join(str(err).split()))
        record["denoise_seconds"] = timing.median
        record["timing"] = timing.to_dict()
        record["device"] = timing.device
        record["threads"] = timing.threads
        images = [r.image.numpy() for r in results]
        frame_seconds = [float(r.seconds) for r in results]
        if settings.save_output(level.spp):
            folder = unit.output_path(out)
            for t, (r, src) in enumerate(zip(results, frames)):
                _write_frame(folder / f"{frame_name(t)}.exr", unit, r, timing.median, src, t)
            record["output"] = relative(folder, out)
            record["output_frames"] = n
    values = sequence_metrics(
        images, list(references), list(settings.metrics), warmup=settings.warmup_frames
    )
    record["total_seconds"] = level.render_seconds + float(record["denoise_seconds"])
    record["metrics"] = values.values
    record["unavailable"] = values.unavailable
    record["warmup_metrics"] = values.warmup_values
    record["all_metrics"] = values.all_values
    record["failed"] = values.failed
    record["reason"] = values.reason
    record["bad_pixels"] = values.bad_pixels
    record["frames"] = [
        {
            "index": f.index,
            "frame": frame_name(f.index),
            "warmup": f.warmup,
            "seconds": frame_seconds[f.index],
            "metrics": f.values,
            "failed": f.failed,
        }
        for f in values.frames
    ]
    return record


def _write_frame(
    path: Path, unit: Any, result: Any, median: float, buffers: Any, index: int
) -> None:
    """One output frame with the attributes a still output has, plus its frame number
    (:func:`mcdenoise.output.write_result`)."""

    path.parent.mkdir(parents=True, exist_ok=True)
    extra = {
        "mcdenoise:seconds": float(result.seconds),  # this frame's own seconds
        "mcdenoise:seconds_per_frame_median": float(median),
        "mcdenoise:label": unit.entry.label,
        "mcdenoise:spp": int(unit.level.spp),
        "mcdenoise:frame": int(index),
    }
    write_result(
        unit.scene.frames[index].noisy,
        path,
        buffers,
        result,
        ReadOptions(part=unit.level.part),
        WriteOptions(),
        attributes=extra,
        source_profile=False,
    )


def outputs_present(record: Mapping[str, Any], out: Path) -> bool:
    """Every output frame of a sequence record is on disk (what resume trusts)."""
    folder = Path(str(record.get("output")))
    folder = folder if folder.is_absolute() else out / folder
    n = int(record.get("output_frames") or 0)
    return n > 0 and all((folder / f"{frame_name(t)}.exr").is_file() for t in range(n))


#: How the over-sequences temporal table is formed (results.json and the report state it).
TEMPORAL_OVERALL = (
    "Per method and spp, over the sequences where it succeeded in every one: relMSE and "
    "temporal relMSE (steady and warm-up) as geometric means over sequences, as the still "
    "tables; tPSNR (dB) and tRMAE as arithmetic means, as Noisebase averages them; seconds "
    "per frame as arithmetic means"
)
#: Columns of the temporal table: (key in the row, metric, group, how it is averaged).
TEMPORAL_COLUMNS = (
    ("relmse", "relmse", "metrics", "geometric"),
    ("relmse_warmup", "relmse", "warmup_metrics", "geometric"),
    ("trelmse", "trelmse", "metrics", "geometric"),
    ("trelmse_warmup", "trelmse", "warmup_metrics", "geometric"),
    ("tpsnr", "tpsnr", "metrics", "arithmetic"),
    ("trmae", "trmae", "metrics", "arithmetic"),
)


def number(value: Any) -> float | None:
    """A record value as a float (``"inf"`` strings decoded); ``None`` when missing (as
    :func:`mcdenoise.experiments.record_values.number`, which imports this module: no cycle)."""

    try:
        return decode_float(value)
    except (TypeError, ValueError):
        return None


def _value(record: Mapping[str, Any], group: str, metric: str) -> float | None:

    if record.get("failed"):
        return None
    v = number((record.get(group) or {}).get(metric))
    return v if v is not None and not math.isnan(v) else None


def temporal_rows(result: Any, scenes: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """One row per (method, spp) over the sequences ``scenes`` (default: all): see
    :data:`TEMPORAL_OVERALL`; a value is ``None`` unless every sequence has it."""

    ids = list(scenes) if scenes is not None else [s.id for s in result.scenes]
    by = {(r["scene"], int(r["spp"]), r["method"]): r for r in result.records}
    rows = []
    for label in result.labels:
        for spp in result.spps:
            recs = [by.get((s, spp, label)) for s in ids]
            ok = [r for r in recs if r is not None and not r.get("failed")]
            complete = bool(ids) and len(ok) == len(ids)
            row: dict[str, Any] = {"method": label, "spp": spp, "sequences": len(ok)}
            row["complete"] = complete
            for key in ("render_seconds", "denoise_seconds", "total_seconds"):
                vals = [number(r.get(key)) for r in ok]
                good = [v for v in vals if v is not None and math.isfinite(v)]
                row[key] = sum(good) / len(good) if complete and len(good) == len(ok) else None
            for key, metric, group, how in TEMPORAL_COLUMNS:
                vals = [_value(r, group, metric) for r in ok]
                if not complete or any(v is None for v in vals):
                    row[key] = None
                elif how == "geometric":
                    row[key] = geometric_mean(vals, invalid="none")
                else:
                    row[key] = math.fsum(vals) / len(vals)  # type: ignore[arg-type]
            rows.append(row)
    return rows
