"""One unit of an experiment: one (scene, spp level, method), its fingerprint, how it is run,
timed and measured, and its record (``DIR/work/<scene>/spp<n>/<label>.json``). Sequence units
run through :mod:`mcdenoise.experiments.sequence_units`; the loop over units, resume and shards
are :mod:`mcdenoise.experiments.runner`.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import re
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise import __version__
from mcdenoise.denoise import denoise
from mcdenoise.denoise_files import ReadOptions, WriteOptions
from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.metrics import compute_metrics
from mcdenoise.eval.results import jsonable
from mcdenoise.experiments.dataset import (
    Level,
    SceneData,
)
from mcdenoise.experiments.entries import MethodEntry, run_device
from mcdenoise.experiments.sequence_units import run_sequence_unit as run
from mcdenoise.experiments.shards import (
    host_name,
)
from mcdenoise.experiments.timing import (
    cpu_model,
    time_runs,
    timing_clock,
)
from mcdenoise.io import load_buffers
from mcdenoise.models.weights import weights_digest
from mcdenoise.output import write_result
from mcdenoise.registry import get_method


def slug(label: str) -> str:
    """A file-name-safe form of a label; labels that need changing get a short hash suffix,
    so two labels never share a file.

    >>> slug("nlm"), slug("xbf[kernel_size=5]")
    ('nlm', 'xbf_kernel_size_5-e98a451a')
    """
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", label).strip("._") or "method"
    if safe == label:
        return safe
    return f"{safe}-{zlib.crc32(label.encode('utf-8')):08x}"


@dataclass(frozen=True)
class Unit:
    """One (scene, spp level, method) of the experiment."""

    scene: SceneData
    level: Level
    entry: MethodEntry

    @property
    def key(self) -> tuple[str, int, str]:
        return (self.scene.id, self.level.spp, self.entry.label)

    def path(self, out: Path) -> Path:
        """Where the unit's record is kept: ``DIR/work/<scene>/spp<n>/<label>.json``."""
        return (
            out
            / WORK
            / slug(self.scene.id)
            / f"spp{self.level.spp}"
            / f"{slug(self.entry.label)}.json"
        )

    def output_path(self, out: Path) -> Path:
        """The output file, or for a sequence the folder of its output frames."""
        name = f"{slug(self.scene.id)}_spp{self.level.spp}_{slug(self.entry.label)}"
        return out / OUTPUTS / (name if self.scene.is_sequence else f"{name}.exr")


@dataclass(frozen=True)
class RunSettings:
    """What, besides the unit itself, decides a unit's numbers (part of its fingerprint)."""

    metrics: tuple[str, ...]
    repetitions: int
    warmup: int
    device: str
    threads: int | None
    save_output: Callable[[int], bool]
    warmup_frames: int = 2  # sequences: first frames reported apart


def fingerprint(unit: Unit, settings: RunSettings) -> str:
    """Hash of everything that decides a unit's record; a cached record is reused only when
    it matches."""
    params = unit.entry.params()
    payload = {
        "schema": UNIT_SCHEMA,
        "version": __version__,
        "scene": unit.scene.fingerprint,
        "spp": unit.level.spp,
        "part": unit.level.part,
        "label": unit.entry.label,
        "method": unit.entry.method,
        "params": params,
        # the learned methods' weights by content: a retrained run folder or updated shipped
        # weights must not reuse records made with the old ones
        "weights": (
            weights_digest(unit.entry.method, str(params["model"])) if "model" in params else None
        ),
        "metrics": list(settings.metrics),
        "repetitions": settings.repetitions if not unit.entry.is_noisy else 0,
        "warmup": settings.warmup if not unit.entry.is_noisy else 0,
        "device": settings.device if not unit.entry.is_noisy else None,
        "threads": settings.threads if not unit.entry.is_noisy else None,
    }
    if unit.scene.is_sequence:  # a still unit's fingerprint is unchanged
        payload["frames"] = len(unit.scene.frames)
        payload["warmup_frames"] = settings.warmup_frames
    text = json.dumps(jsonable(payload), sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:20]


def read_unit(path: Path, expected: str | None = None) -> dict[str, Any] | None:
    """A unit record, or ``None`` when absent, unreadable, or of another fingerprint."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(data, dict) or data.get("schema") != UNIT_SCHEMA:
        return None
    if expected is not None and data.get("fingerprint") != expected:
        return None
    return data


def _relative(p: Path, out: Path) -> str:
    try:
        return p.resolve().relative_to(out.resolve()).as_posix()
    except ValueError:
        return str(p.resolve())


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds")


def _load_color(path: Path, part: str | None = None) -> tuple[np.ndarray, Any]:

    buffers = load_buffers(path, part=part)
    return buffers["color"].numpy(), buffers


def run_unit(
    unit: Unit,
    buffers: Any,
    reference: np.ndarray,
    out: Path,
    settings: RunSettings,
    device: Any,
) -> dict[str, Any]:
    """Run one unit on its already loaded input ``buffers`` (``FeatureBuffers`` of the level)
    against ``reference`` (``(3, H, W)`` float32 linear HDR RGB); return its record (not yet
    written)."""
    entry, level, scene = unit.entry, unit.level, unit.scene
    record = _base_record(unit, settings)
    ref_name = str(scene.reference)
    if entry.is_noisy:
        image = buffers["color"].numpy()
        name = str(level.file) if level.file is not None else f"{scene.noisy}#{level.part}"
    else:
        method = get_method(entry.method)
        dev = run_device(method, device, record["notes"], entry.method)

        def once() -> tuple[Any, float, str]:
            r = denoise(buffers, method, params=entry.overrides, device=dev)
            return r, r.seconds, r.device

        try:
            result, timing = time_runs(
                once, repetitions=settings.repetitions, warmup=settings.warmup
            )
        except McdenoiseError as err:
            return _failed(record, " ".join(str(err).split()), settings)
        record["denoise_seconds"] = timing.median
        record["timing"] = timing.to_dict()
        record["device"] = timing.device
        record["threads"] = timing.threads
        image = result.image.numpy()
        name = str(unit.output_path(out))
        if settings.save_output(level.spp):
            _write_output(unit, result, timing.median, buffers, out)
            record["output"] = _relative(unit.output_path(out), out)
    values = compute_metrics(
        image, reference, list(settings.metrics), output_name=name, reference_name=ref_name
    )
    # unknown render time (a folder without manifest): the total is unknown too
    record["total_seconds"] = (
        None
        if level.render_seconds is None
        else level.render_seconds + float(record["denoise_seconds"])
    )
    record["metrics"] = values.values
    record["unavailable"] = values.unavailable
    record["failed"] = values.failed
    record["reason"] = values.reason
    record["bad_pixels"] = values.bad_pixels
    record["finished"] = _now()
    return record


def _failed(record: dict[str, Any], error: str, settings: RunSettings) -> dict[str, Any]:
    """``record`` as a unit whose method refused its input with ``error``."""
    record["error"] = error
    record["total_seconds"] = None
    record["metrics"] = dict.fromkeys(settings.metrics)
    record["unavailable"] = {}
    record["failed"] = True
    record["reason"] = f"could not run: {error}"
    record["bad_pixels"] = 0
    record["finished"] = _now()
    return record


def _base_record(unit: Unit, settings: RunSettings) -> dict[str, Any]:
    """The fields every unit record starts with (what ran, on what, from which input)."""
    entry, level, scene = unit.entry, unit.level, unit.scene
    return {
        "schema": UNIT_SCHEMA,
        "fingerprint": fingerprint(unit, settings),
        "scene": scene.id,
        "spp": level.spp,
        "method": entry.label,
        "base_method": entry.method,
        "params": entry.params(),
        "input": {"file": str((level.file or scene.noisy).resolve()), "part": level.part},
        "render_seconds": level.render_seconds,
        "render_jit_seconds_excluded": level.jit_seconds,
        "denoise_seconds": 0.0,
        "timing": None,
        # what denoise_seconds measure: "process" (an external command, whole process),
        # "in-process" (the method's own work), None (noisy)
        "timing_clock": timing_clock(entry.method),
        "device": None,
        "threads": None,
        # where it ran (shards spread units over machines; the report says when times mix
        # machines) and the device the run asked for (part of the fingerprint)
        "host": host_name(),
        "cpu": _CPU,
        "run_device": settings.device,
        "output": None,
        "error": None,
        "notes": [],
    }


def run_sequence_unit(
    unit: Unit,
    frames: Sequence[Any],
    references: Sequence[np.ndarray],
    out: Path,
    settings: RunSettings,
    device: Any,
) -> dict[str, Any]:
    """:func:`run_unit` for a sequence (:func:`mcdenoise.experiments.sequence_units.run_sequence_unit`)."""

    record = run(
        unit,
        frames,
        references,
        out,
        settings,
        device,
        base=lambda: _base_record(unit, settings),
        fail=lambda rec, err: _failed(rec, err, settings),
        relative=_relative,
    )
    record["finished"] = _now()
    return record


def _write_output(unit: Unit, result: Any, median: float, buffers: Any, out: Path) -> None:
    """The unit's output (:func:`mcdenoise.output.write_result`), with the median seconds
    of the timed runs, the method's label and the level's spp and part."""

    path = unit.output_path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    extra = {
        "mcdenoise:seconds": float(median),  # the median of the timed runs
        "mcdenoise:label": unit.entry.label,
        "mcdenoise:spp": int(unit.level.spp),
    }
    write_result(
        unit.level.file or unit.scene.noisy,
        path,
        buffers,
        result,
        ReadOptions(part=unit.level.part or None),
        WriteOptions(),
        attributes=extra,
        source_profile=False,
    )


#: Version of the unit records in ``DIR/work``; bump when their fields change meaning.
UNIT_SCHEMA = "mcdenoise.experiment-unit/1"


_CPU = cpu_model()


WORK = "work"


OUTPUTS = "outputs"
