"""Result records of an evaluation, and their JSON-safe form.

An evaluation is a flat list of :class:`EvalRecord` (one per evaluated image: each denoised
output and each noisy input, grouped by ``scene``), not a fixed table, so later experiments
(error vs spp, equal time) can add records and fields without a new format.

A sequence (a folder of frames, see :func:`mcdenoise.eval.run.evaluate`) is one record per
method too: its ``metrics`` are the headline values of
:class:`mcdenoise.eval.temporal_metrics.SequenceValues` (frames past the warm-up), and its ``sequence``
(:class:`SequenceDetail`) holds the warm-up values, the values over all frames and one
:class:`FrameRecord` per frame.

JSON has no infinity and no NaN: :func:`jsonable` writes ``+inf`` as the string ``"inf"``
(``-inf`` as ``"-inf"``, NaN as ``"nan"``); missing values are ``null``. The same strings are
used in CSV cells (missing values are empty cells). PSNR of an output identical to its
reference is the main source of ``"inf"``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.eval.temporal_metrics import metric_spec

#: Version of the results.json layout; bump when fields change meaning.
SCHEMA = "mcdenoise.eval/1"

#: ``role`` of a record: a denoised output, or the noisy input it was made from.
ROLE_OUTPUT = "output"
ROLE_NOISY = "noisy"


@dataclass
class FrameRecord:
    """One frame of an evaluated sequence.

    Attributes:
        frame: the reference frame's stem (``frame_0003``).
        index: position in the sequence (0 = first).
        file: the evaluated file of this frame.
        warmup: one of the warm-up frames, reported apart.
        seconds: denoise wall time of this frame (``mcdenoise:seconds``), when known.
        metrics: still metrics of this frame and, from the second frame on, temporal metrics of
            the pair (previous frame, this frame); ``None`` where not computed.
        unavailable, failed, reason, bad_pixels: as in :class:`EvalRecord`.
    """

    frame: str
    index: int
    file: str
    warmup: bool = False
    seconds: float | None = None
    metrics: dict[str, float | None] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)
    failed: bool = False
    reason: str | None = None
    bad_pixels: int = 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict."""
        return jsonable(
            {
                "frame": self.frame,
                "index": self.index,
                "file": self.file,
                "warmup": self.warmup,
                "seconds": self.seconds,
                "metrics": self.metrics,
                "unavailable": self.unavailable,
                "failed": self.failed,
                "reason": self.reason,
                "bad_pixels": self.bad_pixels,
            }
        )


@dataclass
class SequenceDetail:
    """What an evaluated sequence adds to its record (see :mod:`mcdenoise.eval.temporal_metrics`).

    Attributes:
        warmup: number of first frames reported apart.
        frames: one :class:`FrameRecord` per frame, in order.
        warmup_metrics, warmup_unavailable: still metrics averaged over the warm-up frames,
            temporal ones over the pairs ending in frames 1 .. warmup.
        all_metrics, all_unavailable: averaged over every frame and every pair.
    """

    warmup: int
    frames: list[FrameRecord] = field(default_factory=list)
    warmup_metrics: dict[str, float | None] = field(default_factory=dict)
    warmup_unavailable: dict[str, str] = field(default_factory=dict)
    all_metrics: dict[str, float | None] = field(default_factory=dict)
    all_unavailable: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict."""
        return jsonable(
            {
                "frame_count": len(self.frames),
                "warmup": self.warmup,
                "first": self.frames[0].frame if self.frames else None,
                "last": self.frames[-1].frame if self.frames else None,
                "warmup_metrics": self.warmup_metrics,
                "warmup_unavailable": self.warmup_unavailable,
                "all_metrics": self.all_metrics,
                "all_unavailable": self.all_unavailable,
                "frames": [f.to_dict() for f in self.frames],
            }
        )


@dataclass
class EvalRecord:
    """One evaluated image of one scene.

    Attributes:
        scene: scene name (the reference file's stem).
        file: path of the evaluated EXR (or a label when arrays were evaluated).
        role: ``"output"`` or ``"noisy"`` (the noisy input, shown as method ``"noisy"``).
        method: denoising method (``mcdenoise:method``), ``"noisy"`` for noisy inputs.
        input: noisy input this output was made from, when known and evaluated.
        spp: samples per pixel of the (noisy) input, when known.
        seconds: denoise wall time (``mcdenoise:seconds``), when known.
        device: device the denoiser ran on (``mcdenoise:device``), when known.
        params: denoiser parameters as recorded (``mcdenoise:params``, JSON text), if any.
        metrics: metric name -> value (``None`` when failed or unavailable; PSNR may be inf).
        unavailable: metric name -> reason it could not be computed.
        relmse_ratio: relMSE of this image / relMSE of its noisy input (1 for noisy rows).
        failed: the image has NaN/Inf pixels (or its reference has): no metric computed.
        reason: one line explaining the failure.
        bad_pixels: number of pixels with a non-finite channel.
        notes: other remarks for the reader (e.g. noisy input named but not found).
        sequence: for a sequence (a folder of frames), its warm-up values, values over all
            frames and per-frame values; then ``metrics`` are the values past the warm-up,
            ``seconds`` the mean per frame and ``file`` the folder. ``None`` for a still.
    """

    scene: str
    file: str
    role: str = ROLE_OUTPUT
    method: str = ""
    input: str | None = None
    spp: int | None = None
    seconds: float | None = None
    device: str | None = None
    params: str | None = None
    metrics: dict[str, float | None] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)
    relmse_ratio: float | None = None
    failed: bool = False
    reason: str | None = None
    bad_pixels: int = 0
    notes: list[str] = field(default_factory=list)
    sequence: SequenceDetail | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict (see :func:`jsonable` for inf/NaN); ``sequence`` only for sequences."""
        extra = {} if self.sequence is None else {"sequence": self.sequence.to_dict()}
        return jsonable(
            {
                "scene": self.scene,
                "file": self.file,
                "role": self.role,
                "method": self.method,
                "input": self.input,
                "spp": self.spp,
                "seconds": self.seconds,
                "device": self.device,
                "params": self.params,
                "metrics": self.metrics,
                "unavailable": self.unavailable,
                "relmse_ratio": self.relmse_ratio,
                "failed": self.failed,
                "reason": self.reason,
                "bad_pixels": self.bad_pixels,
                "notes": self.notes,
                **extra,
            }
        )


@dataclass
class ScenePreview:
    """Small linear-HDR crops of one scene's images, for the report's image strip.

    Attributes:
        window: ``(y0, x0, h, w)`` of the crop in the full image (the whole image if small).
        full_shape: ``(H, W)`` of the full images.
        exposure: display exposure chosen from the reference (see ``tonemap.auto_exposure``).
        reference: ``(3, h, w)`` float32 linear HDR RGB crop of the reference.
        images: record ``file`` -> ``(3, h, w)`` float32 linear HDR RGB crop of that image.
        overview: ``(3, th, tw)`` float32 downscaled full reference (shows where the crop is),
            or ``None`` when the crop is the whole image.
        overview_factor: the integer downscale factor of ``overview``.
    """

    window: tuple[int, int, int, int]
    full_shape: tuple[int, int]
    exposure: float
    reference: np.ndarray
    images: dict[str, np.ndarray] = field(default_factory=dict)
    overview: np.ndarray | None = None
    overview_factor: int = 1


@dataclass
class EvalResult:
    """Everything an evaluation produced: records, references, metric list, previews.

    Attributes:
        records: one :class:`EvalRecord` per evaluated image, grouped by scene, noisy inputs
            first within a scene.
        references: scene -> reference file (or label).
        metrics: metric names evaluated, in column order.
        previews: scene -> :class:`ScenePreview` (not written to JSON).
        version: mcdenoise version that computed the numbers.
        created: ISO 8601 time of the evaluation.
        warmup: for an evaluation of sequences, the number of warm-up frames reported apart;
            ``None`` for stills.
    """

    records: list[EvalRecord] = field(default_factory=list)
    references: dict[str, str] = field(default_factory=dict)
    metrics: list[str] = field(default_factory=list)
    previews: dict[str, ScenePreview] = field(default_factory=dict)
    version: str = ""
    created: str = ""
    warmup: int | None = None
    # scene -> its records, and the state of ``records`` it was made from (scene_records)
    _by_scene: tuple[tuple[int, int, int], dict[str, list[EvalRecord]]] | None = field(
        default=None, init=False, repr=False, compare=False
    )

    def scenes(self) -> list[str]:
        """Scene names in first-seen order."""
        return list(dict.fromkeys([*self.references, *(r.scene for r in self.records)]))

    def scene_records(self, scene: str) -> list[EvalRecord]:
        """Records of ``scene``, in order. The records are grouped by scene once (again when
        ``records`` has grown or been replaced): a report asks this of every scene, and a scan
        of every record per scene made a report of n scenes O(n²)."""
        recs = self.records
        state = (id(recs), len(recs), id(recs[-1]) if recs else 0)
        if self._by_scene is None or self._by_scene[0] != state:
            groups: dict[str, list[EvalRecord]] = {}
            for r in recs:
                groups.setdefault(r.scene, []).append(r)
            self._by_scene = (state, groups)
        return list(self._by_scene[1].get(scene, ()))

    @property
    def any_failed(self) -> bool:
        """True when at least one record failed."""
        return any(r.failed for r in self.records)

    @property
    def has_sequences(self) -> bool:
        """True when the records are sequences (folders of frames)."""
        return any(r.sequence is not None for r in self.records)

    def format_table(self) -> str:
        """A plain-text summary table (one line per record) for terminals and logs; for
        sequences the values past the warm-up (see :meth:`format_frames`)."""

        # the parts of a summary metric (bias R, G, B) stay in the JSON and CSV
        shown = [
            m
            for m in self.metrics
            if any(r.metrics.get(m) is not None for r in self.records)
            and metric_spec(m).part_of not in self.metrics
        ]
        head = [
            "scene",
            "method",
            "spp",
            *(metric_spec(m).label for m in shown),
            "vs noisy",
            "status",
        ]
        rows = [head]
        # two outputs of one method (e.g. two trained models) are told apart by their file
        shared = Counter((r.scene, r.method, r.spp) for r in self.records)
        for r in self.records:
            name = r.method
            if shared[(r.scene, r.method, r.spp)] > 1:
                name += f" [{Path(r.file).name}]"
            cells = [r.scene, name, "" if r.spp is None else str(r.spp)]
            cells += [_short(r.metrics.get(m), signed=metric_spec(m).signed) for m in shown]
            cells.append("" if r.relmse_ratio is None else f"{r.relmse_ratio:.3g}x")
            cells.append(f"FAILED: {r.reason}" if r.failed else "ok")
            rows.append(cells)
        text = _align(rows)
        if self.warmup is not None and self.has_sequences:
            text += (
                f"\n(sequences: mean over the frames after the first {self.warmup} (warm-up); "
                "temporal metrics over the pairs of frames both past it)"
            )
        return text

    def format_frames(self, metrics: tuple[str, ...] = ("relmse", "trelmse")) -> str:
        """Per-frame values of every sequence: one line per frame, per record the columns
        ``metrics`` (those evaluated); warm-up frames are marked ``*``. Empty without
        sequences."""

        keys = [m for m in metrics if m in self.metrics]
        blocks = []
        for scene in self.scenes():
            recs = [r for r in self.scene_records(scene) if r.sequence is not None]
            if not recs or not keys:
                continue
            head = ["frame"] + [f"{r.method} {metric_spec(m).label}" for r in recs for m in keys]
            rows = [head]
            first = recs[0].sequence
            assert first is not None
            for i, fr in enumerate(first.frames):
                cells = [fr.frame + (" *" if fr.warmup else "")]
                for r in recs:
                    seq = r.sequence
                    assert seq is not None
                    f = seq.frames[i] if i < len(seq.frames) else None
                    for m in keys:
                        v = None if f is None else f.metrics.get(m)
                        cells.append(_short(v, signed=metric_spec(m).signed))
                rows.append(cells)
            blocks.append(f"{scene}: per frame (* = warm-up)\n" + _align(rows, last_free=False))
        return "\n\n".join(blocks)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dict: schema, version, metric definitions, references and records
        (and, for sequences, how the warm-up is reported)."""

        extra = {}
        if self.warmup is not None and self.has_sequences:
            extra["sequences"] = {
                "warmup": self.warmup,
                "how": (
                    "metrics: still metrics averaged over the frames t >= warmup, temporal "
                    "metrics over the frame pairs (t-1, t) with t-1 >= warmup; "
                    "sequence.warmup_metrics: frames t < warmup and pairs 1 <= t <= warmup; "
                    "sequence.all_metrics: every frame and every pair t >= 1; "
                    "sequence.frames[t].metrics: frame t, temporal ones for the pair (t-1, t)"
                ),
            }
        return jsonable(
            {
                "schema": SCHEMA,
                "mcdenoise_version": self.version,
                "created": self.created,
                "encoding": (
                    'Non-finite numbers are strings: "inf", "-inf", "nan" (PSNR of an output '
                    'identical to its reference is "inf"); missing values are null.'
                ),
                "metrics": {name: metric_spec(name).describe() for name in self.metrics},
                **extra,
                "references": self.references,
                "records": [r.to_dict() for r in self.records],
            }
        )


def printable(text: str) -> str:
    """``text`` for one line of a terminal table: control characters (a newline or an escape
    sequence a file's header may hold as its method or scene) as Python escapes."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _align(rows: list[list[str]], *, last_free: bool = True) -> str:
    """Rows of cells as left-aligned columns (the last column unpadded when ``last_free``)."""
    rows = [[printable(c) for c in row] for row in rows]
    n = len(rows[0]) - (1 if last_free else 0)
    widths = [max(len(row[i]) for row in rows) for i in range(n)]
    lines = []
    for row in rows:
        line = "  ".join(c.ljust(w) for c, w in zip(row[:n], widths))
        lines.append((line + "  " + row[-1]) if last_free else line.rstrip())
    return "\n".join(lines)


def _short(value: float | None, *, signed: bool = False) -> str:
    if value is None:
        return "-"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if signed and math.isfinite(value):  # a relative change (mean bias): in percent
        return f"{100.0 * value:+.2f}%"
    return f"{value:.4g}"


def encode_float(value: float) -> float | str:
    """A float for JSON/CSV: finite values unchanged, ``inf`` -> ``"inf"``, NaN -> ``"nan"``."""
    v = float(value)
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return v


def decode_float(value: Any) -> float | None:
    """Inverse of :func:`encode_float` (``None`` and ``""`` give ``None``)."""
    if value is None or value == "":
        return None
    return float(value)


def jsonable(obj: Any) -> Any:
    """Recursively convert to JSON-safe types: numpy scalars to Python, non-finite floats to
    strings (:func:`encode_float`), tuples to lists, paths to strings."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return encode_float(float(obj))
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)
