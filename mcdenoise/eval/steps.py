"""The steps an evaluation of stills and one of sequences share.

Both run match → check → measure: :mod:`mcdenoise.eval.matching` pairs every output with its
reference and noisy input; :func:`check_scene` refuses (or, with ``force``, notes) an output
made from another scene; the rows are put in report order (:func:`noisy_then_outputs`: each
noisy input followed by what was made from it); the measured values fill the records
(:func:`fill_record`) and every output gets its error relative to its noisy input
(:func:`set_ratios`). How to evaluate is one :class:`EvalOptions`, built once from the command
line or the caller's keyword arguments and handed down unchanged.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

from mcdenoise import __version__
from mcdenoise.errors import InputError
from mcdenoise.eval.matching import PathLike, as_float, as_int, default_warn
from mcdenoise.eval.preview import choose_crop, crop, overview
from mcdenoise.eval.results import ROLE_NOISY, EvalRecord, EvalResult, ScenePreview
from mcdenoise.eval.temporal_metrics import WARMUP_FRAMES
from mcdenoise.eval.tonemap import auto_exposure


@dataclass(frozen=True)
class EvalOptions:
    """How to evaluate, for stills and sequences alike.

    Attributes:
        inputs: noisy input EXR files/folders, used for outputs whose ``mcdenoise:source`` is
            absent or missing on disk (matched by longest stem prefix); each is evaluated as a
            ``"noisy"`` row of the scene it matches.
        metrics: metric names (default: every registered metric; FLIP is reported as
            unavailable, with the reason, when ``flip_evaluator`` is not installed).
        progress: report progress on stderr (:func:`mcdenoise.progress.progress_bar`).
        force: evaluate outputs whose source shows another scene than the reference; the
            message goes to ``warn`` and into the record's notes.
        warn: receives the warning lines of ``force`` (default: ``warnings.warn``).
        warmup: first frames of a sequence reported apart (sequences only).
    """

    inputs: Sequence[PathLike] = ()
    metrics: Sequence[str] | None = None
    progress: bool | str = False
    force: bool = False
    warn: Callable[[str], None] | None = None
    warmup: int = WARMUP_FRAMES


#: The defaults (frozen: safe to share).
DEFAULT_OPTIONS = EvalOptions()


def check_scene(problem: str | None, options: EvalOptions, notes: list[str], what: str) -> None:
    """The scene check of one output (or sequence): nothing when ``problem`` is ``None``;
    else refused (``InputError``), or with ``options.force`` noted and warned.

    ``what`` names what the user should give instead (``"scene"``, ``"sequence"``).
    """
    if problem is None:
        return
    if not options.force:
        raise InputError(f"{problem}; give the reference of that {what}, or --force")
    notes.append(problem)
    (options.warn or default_warn)(f"{problem} (evaluated anyway: --force)")


def new_result(metrics: list[str], warmup: int | None = None) -> EvalResult:
    """An empty result measuring ``metrics`` (resolved names), stamped with version and time."""
    return EvalResult(
        metrics=metrics,
        version=__version__,
        created=_dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds"),
        **({} if warmup is None else {"warmup": warmup}),
    )


K = TypeVar("K")
T = TypeVar("T")


def noisy_then_outputs(
    noisy: Iterable[K], outputs: Sequence[T], input_of: Callable[[T], K | None]
) -> Iterator[tuple[K | None, T | None]]:
    """The rows of one scene in report order: each noisy input (``(key, None)``) followed by
    the outputs made from it (``(key, output)``), then the outputs of no listed input
    (``(None, output)``), each group in the order given."""
    by_input: dict[K, list[T]] = {}
    for o in outputs:
        k = input_of(o)
        if k is not None:
            by_input.setdefault(k, []).append(o)
    placed: set[int] = set()
    for k in noisy:
        yield k, None
        for o in by_input.get(k, ()):
            placed.add(id(o))
            yield k, o
    for o in outputs:
        if id(o) not in placed:
            yield None, o


class _Measured(Protocol):
    values: dict[str, float]
    unavailable: dict[str, str]
    failed: bool
    reason: str | None
    bad_pixels: Any


def fill_record(rec: EvalRecord, measured: _Measured) -> None:
    """Copy what was measured of one image or sequence into its record."""
    rec.metrics, rec.unavailable = measured.values, measured.unavailable
    rec.failed, rec.reason, rec.bad_pixels = measured.failed, measured.reason, measured.bad_pixels


class _Row(Protocol):
    record: EvalRecord
    input_key: str | None


def set_ratios(jobs: Iterable[_Row], records: Mapping[str, EvalRecord]) -> None:
    """Every row's relMSE over its noisy input's (a noisy row's own: 1)."""
    for job in jobs:
        rec = job.record
        noisy = rec if rec.role == ROLE_NOISY else records.get(job.input_key or "")
        rec.relmse_ratio = relmse_ratio(rec, noisy)


def relmse_ratio(rec: EvalRecord, noisy: EvalRecord | None) -> float | None:
    """``rec``'s relMSE over ``noisy``'s, where both were measured."""
    if noisy is None or rec.failed or noisy.failed:
        return None
    a, b = rec.metrics.get("relmse"), noisy.metrics.get("relmse")
    if a is None or b is None or b <= 0:
        return None
    return float(a) / float(b)


def scene_preview(ref: np.ndarray) -> ScenePreview:
    """The preview of a scene: its crop window, exposure and overview, from the reference."""
    exposure = auto_exposure(ref)
    window = choose_crop(ref, exposure)
    full = (ref.shape[1], ref.shape[2])
    preview = ScenePreview(
        window=window, full_shape=full, exposure=exposure, reference=crop(ref, window)
    )
    if window != (0, 0, *full):
        preview.overview, preview.overview_factor = overview(ref)
    return preview


def array_records(
    scene: str,
    labels: Iterable[str],
    info: Mapping[str, Mapping[str, Any]],
    *,
    noisy: bool,
    seconds: bool = True,
) -> Iterator[EvalRecord]:
    """The records of in-memory images or sequences (``evaluate_arrays`` and its sequence
    twin): the noisy row first when there is one, then one per label, described by ``info``
    (label -> ``{"method", "spp", "seconds", "device", "params"}``)."""
    noisy_spp = as_int(info.get("noisy", {}).get("spp"))
    if noisy:
        yield EvalRecord(scene=scene, file="noisy", role=ROLE_NOISY, method="noisy", spp=noisy_spp)
    for label in labels:
        meta = dict(info.get(label, {}))
        yield EvalRecord(
            scene=scene,
            file=str(label),
            method=str(meta.get("method", label)),
            input="noisy" if noisy else None,
            spp=as_int(meta.get("spp")) or noisy_spp,
            seconds=as_float(meta.get("seconds")) if seconds else None,
            device=meta.get("device"),
            params=None if meta.get("params") is None else str(meta.get("params")),
        )
