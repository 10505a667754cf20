"""Temporal metrics of a denoised sequence, and its per-frame metrics with the warm-up apart.

A denoiser that is good on every frame alone can still flicker: its error changes from frame
to frame although the scene does not. Temporal metrics judge the *frame differences*: the
output's ``Δo_t = o_t − o_{t−1}`` against the reference's ``Δr_t = r_t − r_{t−1}``, so a
stable bias costs nothing and independent noise per frame costs twice its variance.

==========  =====================================================  ==========================
name        value of one frame pair (t − 1, t), t ≥ 1                 colour space
==========  =====================================================  ==========================
trelmse     mean((Δo_t − Δr_t)² / (r_t² + ε)), ε = 0.01              linear HDR RGB
tpsnr       10 · log10(1 / mean((Δo_t − Δr_t)²)), in dB               Noisebase 8-bit display
trmae       mean(|Δo_t − Δr_t| / (|Δr_t| + 0.01)) / 3                 Noisebase 8-bit display
==========  =====================================================  ==========================

The sequence value of each is the arithmetic mean over its frame pairs (Noisebase's
``TemporalMetricAdapter.compute``: the sum over pairs divided by their number).

* ``trelmse`` (temporal relMSE) is the project's definition (``DESIGN.md``): the
  relMSE of the frame difference, normalised like relMSE by the *current* reference frame
  ``r_t² + ε`` (ε = :data:`mcdenoise.losses.RELMSE_EPS`, the relMSE ε), not by ``Δr_t``, which
  is 0 wherever the scene is still and would make every flicker there infinitely bad.
* ``tpsnr`` and ``trmae`` are Noisebase's (Balint et al. 2023), ported literally so numbers
  compare with that benchmark, on its 8-bit display values: see :mod:`mcdenoise.eval.noisebase`.

Warm-up. A temporal method has no history on the first frame (SVGF starts its moving average
there; a causal window has no past frame yet), so its first frames are worse than the rest
for a reason a long sequence outgrows. Noisebase therefore drops the first ``warmup`` frames
(16 in its test sets) before it forms any pair or per-frame mean. Here they are reported
apart, not dropped (:class:`SequenceValues`): the headline values average the frames
``t ≥ W`` (per-frame metrics) and the pairs whose two frames are both past the warm-up
(``t ≥ W + 1``, as Noisebase); the warm-up values average frames ``t < W`` and pairs
``1 ≤ t ≤ W``; the "all" values average every frame and every pair ``t ≥ 1`` (with ``W = 0``
the headline trelmse is the mean over all ``t ≥ 1`` of ``DESIGN.md``). The default
``W =`` :data:`WARMUP_FRAMES` ``= 2``: a 5-frame window (Vogels et al. 2018, two frames on
each side) has its whole past from frame 2 on, and the sequences
this project renders are short (6–16 frames), so a longer warm-up would leave few frames to
judge. SVGF's spatial variance estimate is used until its history holds 4 frames (Schied
et al. 2017): ``warmup = 4`` excludes that too; ``warmup = 16`` is Noisebase's setting.

Per-frame metrics are the still-image metrics of :mod:`mcdenoise.eval.metrics`
(relMSE, SSIM, FLIP, ...), computed by :func:`~mcdenoise.eval.metrics.compute_metrics`.

Undefined is never 0: a sequence of one frame has no pair, so its temporal metrics are
*unavailable* with that reason; so are headline values when every frame (or pair) is warm-up.
A frame with NaN/Inf pixels fails the whole sequence (no mean is taken over the others), as
a failed still gets no value.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.eval.images import ArrayLike, as_image, check_same_shape, nonfinite_pixels
from mcdenoise.eval.metrics import (
    LINEAR,
    METRICS,
    Metric,
    MetricUnavailable,
    compute_metrics,
    describe_metric,
    relative_squared_error,
    resolve_metrics,
)
from mcdenoise.eval.noisebase import (
    NOISEBASE_DISPLAY,
    NOISEBASE_RMAE_EPS,
    SOURCE_NOISEBASE,
    noisebase_display,
    tpsnr_pair,
    trmae_pair,
)
from mcdenoise.losses import RELMSE_EPS

#: Default number of warm-up frames reported apart (see the module docstring for why 2).
WARMUP_FRAMES = 2

_QUIET = {"invalid": "ignore", "over": "ignore", "divide": "ignore"}


# --- one frame pair ----------------------------------------------------------------------------


def _trelmse_pair(o0: np.ndarray, o1: np.ndarray, r0: np.ndarray, r1: np.ndarray) -> float:
    with np.errstate(**_QUIET):
        return float(np.mean(relative_squared_error(((o1 - o0) - (r1 - r0)) ** 2, r1)))


# --- registry --------------------------------------------------------------------------------


@dataclass(frozen=True)
class TemporalMetric:
    """One temporal metric: its value on a frame pair and how reports must describe it.

    The attributes reports read (``label``, ``definition``, ``space``, ``epsilon``,
    ``higher_is_better``, ``signed``, ``part_of``, ``optional``, :meth:`describe`,
    :meth:`better`) are those of :class:`~mcdenoise.eval.metrics.Metric`.

    Attributes:
        pair: ``(o_{t−1}, o_t, r_{t−1}, r_t) -> value``, arrays ``(3, H, W)`` float64 in
            ``space`` (linear HDR RGB, or :func:`noisebase_display` values when ``display``).
        display: the pair function takes Noisebase display values.
        source: where the definition comes from.
    """

    name: str
    label: str
    pair: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], float]
    space: str
    definition: str
    epsilon: float | None = None
    higher_is_better: bool = False
    display: bool = False
    source: str = ""
    optional: bool = False
    signed: bool = False
    part_of: str | None = None

    def describe(self) -> dict[str, Any]:
        """JSON-ready description, as :meth:`Metric.describe` plus ``temporal`` and ``source``."""
        return {**describe_metric(self), "temporal": True, "source": self.source}

    def better(self, a: float, b: float) -> bool:
        """True when value ``a`` is strictly better than ``b``."""
        return a > b if self.higher_is_better else a < b


_PAIRS = "mean over the frame pairs (t − 1, t) past the warm-up (both frames t − 1, t ≥ warm-up)"

#: Registered temporal metrics, in report column order.
TEMPORAL_METRICS: dict[str, TemporalMetric] = {
    m.name: m
    for m in (
        TemporalMetric(
            "trelmse",
            "temporal relMSE",
            _trelmse_pair,
            LINEAR,
            "mean((Δo − Δr)² / (r_t² + ε)), ε = "
            f"{RELMSE_EPS}, Δo = o_t − o_{{t−1}}, Δr = r_t − r_{{t−1}}; {_PAIRS}",
            RELMSE_EPS,
            source="DESIGN.md, issue 23 (relMSE of the frame difference)",
        ),
        TemporalMetric(
            "tpsnr",
            "tPSNR (dB)",
            tpsnr_pair,
            NOISEBASE_DISPLAY,
            "10·log10(1 / mean((Δo − Δr)²)) with peak 1, as Noisebase; +inf for an exact "
            f'difference (written as "inf"); {_PAIRS}',
            higher_is_better=True,
            display=True,
            source=SOURCE_NOISEBASE,
        ),
        TemporalMetric(
            "trmae",
            "tRMAE",
            trmae_pair,
            NOISEBASE_DISPLAY,
            f"mean(|Δo − Δr| / (|Δr| + {NOISEBASE_RMAE_EPS})) / 3, as Noisebase (its / 3 "
            f"included); {_PAIRS}",
            NOISEBASE_RMAE_EPS,
            display=True,
            source=SOURCE_NOISEBASE,
        ),
    )
}


def metric_spec(name: str) -> Metric | TemporalMetric:
    """The registered still (:data:`~mcdenoise.eval.metrics.METRICS`) or temporal
    (:data:`TEMPORAL_METRICS`) metric called ``name``."""
    return METRICS[name] if name in METRICS else TEMPORAL_METRICS[name]


def is_temporal(name: str) -> bool:
    """Whether ``name`` is a temporal metric (needs a sequence)."""
    return name in TEMPORAL_METRICS


def resolve_sequence_metrics(names: Sequence[str] | None) -> list[str]:
    """Metric names for a sequence: still metrics (as
    :func:`~mcdenoise.eval.metrics.resolve_metrics`, parts added) first, then temporal ones;
    ``None`` means every registered metric of both kinds.

    >>> resolve_sequence_metrics(["tpsnr", "relmse"])
    ['relmse', 'tpsnr']

    Raises:
        InputError: an unknown name (the message lists both kinds) or an empty list.
    """
    if names is None:
        return [*METRICS, *TEMPORAL_METRICS]
    keys = [str(n).strip().lower() for n in names]
    unknown = [n for n, k in zip(names, keys) if k not in METRICS and k not in TEMPORAL_METRICS]
    if unknown:
        raise InputError(
            f"unknown metric {unknown[0]!r}; known: {', '.join(METRICS)}; temporal (sequences): "
            f"{', '.join(TEMPORAL_METRICS)}"
        )
    still = [k for k in keys if k in METRICS]
    temporal = list(dict.fromkeys(k for k in keys if k in TEMPORAL_METRICS))
    if not still and not temporal:
        raise InputError("no metric requested")
    return [*(resolve_metrics(still) if still else []), *temporal]


# --- whole sequences, plain functions ------------------------------------------------------------


def _frames(frames: ArrayLike | Sequence[ArrayLike], what: str) -> list[np.ndarray]:
    """A ``(T, 3, H, W)`` array/tensor or a sequence of ``(3, H, W)`` frames, as float64 frames."""
    if hasattr(frames, "ndim") and frames.ndim == 4:
        seq = [frames[i] for i in range(frames.shape[0])]
    else:
        seq = list(frames)
    return [as_image(f, f"{what} frame {i}") for i, f in enumerate(seq)]


def _sequence_value(
    metric: TemporalMetric,
    outputs: ArrayLike | Sequence[ArrayLike],
    references: ArrayLike | Sequence[ArrayLike],
    warmup: int,
) -> float:
    xs, rs = _frames(outputs, "output"), _frames(references, "reference")
    if len(xs) != len(rs):
        raise InputError(f"{len(xs)} output frames but {len(rs)} reference frames")
    for i, (x, r) in enumerate(zip(xs, rs)):
        check_same_shape(x, r, output_name=f"output frame {i}", reference_name=f"frame {i}")
        check_same_shape(x, xs[0], output_name=f"output frame {i}", reference_name="frame 0")
    xs, rs = xs[warmup:], rs[warmup:]  # Noisebase: frames before the warm-up are not read
    if len(xs) < 2:
        raise MetricUnavailable(
            f"{metric.name} needs 2 frames past the warm-up of {warmup}, got {len(xs)}"
        )
    if metric.display:
        xs, rs = [noisebase_display(x) for x in xs], [noisebase_display(r) for r in rs]
    values = [metric.pair(xs[t - 1], xs[t], rs[t - 1], rs[t]) for t in range(1, len(xs))]
    return math.fsum(values) / len(values)


def temporal_relmse(
    outputs: ArrayLike | Sequence[ArrayLike], references: ArrayLike | Sequence[ArrayLike]
) -> float:
    """Temporal relMSE: the mean over ``t ≥ 1`` of
    ``mean((Δo_t − Δr_t)² / (r_t² + 0.01))``, with ``Δo_t = o_t − o_{t−1}`` and
    ``Δr_t = r_t − r_{t−1}``.

    Args:
        outputs, references: ``(T, 3, H, W)`` or ``T`` frames ``(3, H, W)``, linear HDR RGB.

    Raises:
        MetricUnavailable: fewer than 2 frames (no frame difference exists).
        InputError: frame counts or sizes differ.

    >>> r = np.ones((2, 3, 1, 1)); o = r.copy(); o[1] += 0.1  # output rises, reference not
    >>> round(temporal_relmse(o, r), 12)  # 0.1² / (1 + 0.01)
    0.009900990099
    """
    return _sequence_value(TEMPORAL_METRICS["trelmse"], outputs, references, 0)


def tpsnr(
    outputs: ArrayLike | Sequence[ArrayLike],
    references: ArrayLike | Sequence[ArrayLike],
    warmup: int = 0,
) -> float:
    """Noisebase's tPSNR (dB) of linear HDR frames; the first ``warmup`` frames are dropped
    before any pair is formed, as Noisebase does (its test sets use 16).

    Raises:
        MetricUnavailable: fewer than 2 frames past the warm-up.
    """
    return _sequence_value(TEMPORAL_METRICS["tpsnr"], outputs, references, warmup)


def trmae(
    outputs: ArrayLike | Sequence[ArrayLike],
    references: ArrayLike | Sequence[ArrayLike],
    warmup: int = 0,
) -> float:
    """Noisebase's tRMAE of linear HDR frames (its ``/ 3`` included); ``warmup`` as
    :func:`tpsnr`.

    Raises:
        MetricUnavailable: fewer than 2 frames past the warm-up.
    """
    return _sequence_value(TEMPORAL_METRICS["trmae"], outputs, references, warmup)


# --- streaming evaluation of one sequence ---------------------------------------------------


@dataclass
class FrameValues:
    """Metrics of one frame of a sequence.

    Attributes:
        index: position in the sequence (0 = first frame).
        frame: how the frame is named (its reference file's stem, e.g. ``frame_0003``).
        warmup: the frame is one of the warm-up frames (``index < warmup``).
        values: metric -> value: the still metrics of this frame, and for ``index ≥ 1`` the
            temporal metrics of the pair (index − 1, index); ``None`` when not computed.
        unavailable: metric -> why it could not be computed for this frame.
        failed, reason, bad_pixels: as :class:`~mcdenoise.eval.metrics.MetricValues`.
    """

    index: int
    frame: str
    warmup: bool
    values: dict[str, float | None] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)
    failed: bool = False
    reason: str | None = None
    bad_pixels: int = 0


@dataclass
class SequenceValues:
    """Metrics of a whole sequence (see the module docstring for the three groups).

    Attributes:
        values: headline values: still metrics averaged over frames ``t ≥ warmup``, temporal
            ones over pairs ``t ≥ warmup + 1``; ``None`` when unavailable or failed.
        unavailable: metric -> why its headline value is undefined.
        warmup_values, warmup_unavailable: the same over frames ``t < warmup`` and pairs
            ``1 ≤ t ≤ warmup``.
        all_values, all_unavailable: the same over every frame and every pair ``t ≥ 1``.
        frames: per-frame values.
        warmup: number of warm-up frames.
        failed, reason, bad_pixels: a frame has NaN/Inf pixels (or its reference has): no
            sequence value is given; ``bad_pixels`` sums over frames.
    """

    values: dict[str, float | None]
    unavailable: dict[str, str]
    warmup_values: dict[str, float | None]
    warmup_unavailable: dict[str, str]
    all_values: dict[str, float | None]
    all_unavailable: dict[str, str]
    frames: list[FrameValues]
    warmup: int
    failed: bool = False
    reason: str | None = None
    bad_pixels: int = 0


class SequenceEvaluator:
    """Metrics of one output sequence, fed frame by frame (two frames held in memory).

    Like Noisebase's ``TemporalMetricAdapter``: each :meth:`feed` computes the frame's still
    metrics and, from the second frame on, the temporal metrics of the pair it closes;
    :meth:`summary` averages them, the warm-up apart.

    Args:
        metrics: metric names, still and temporal (default: all; see
            :func:`resolve_sequence_metrics`).
        warmup: number of first frames reported apart (default :data:`WARMUP_FRAMES`).
        name: how messages name this sequence.

    >>> ev = SequenceEvaluator(["relmse", "trelmse"], warmup=0)
    >>> for t in range(3):
    ...     _ = ev.feed(np.full((3, 2, 2), 1.0 + 0.1 * (t % 2)), np.ones((3, 2, 2)))
    >>> s = ev.summary()
    >>> round(s.values["trelmse"], 12), round(s.values["relmse"], 12)  # 0.01/1.01, 0.01/1.01/3
    (0.009900990099, 0.003300330033)
    """

    def __init__(
        self,
        metrics: Sequence[str] | None = None,
        *,
        warmup: int = WARMUP_FRAMES,
        name: str = "output",
    ) -> None:
        if int(warmup) != warmup or warmup < 0:
            raise InputError(f"warm-up must be a whole number of frames >= 0, got {warmup}")
        self.metrics = resolve_sequence_metrics(metrics)
        self.still = [m for m in self.metrics if not is_temporal(m)]
        self.temporal = [m for m in self.metrics if is_temporal(m)]
        self.warmup = int(warmup)
        self.name = name
        self.frames: list[FrameValues] = []
        self._shape: tuple[int, ...] | None = None
        self._first: str = ""
        # previous frame, prepared: (linear output, linear reference, display output, display ref)
        self._prev: tuple[np.ndarray, ...] | None = None
        self._display = any(TEMPORAL_METRICS[m].display for m in self.temporal)

    def feed(
        self,
        output: ArrayLike,
        reference: ArrayLike,
        *,
        frame: str | None = None,
        output_name: str | None = None,
        reference_name: str | None = None,
    ) -> FrameValues:
        """Add the next frame: ``output`` and ``reference`` ``(3, H, W)`` linear HDR RGB.

        Raises:
            InputError: the two differ in size, or differ from the sequence's first frame.
        """
        index = len(self.frames)
        label = frame if frame is not None else f"frame {index}"
        out_name = output_name or f"{self.name} {label}"
        ref_name = reference_name or f"reference {label}"
        x, r = as_image(output, out_name), as_image(reference, ref_name)
        check_same_shape(x, r, output_name=out_name, reference_name=ref_name)
        if self._shape is None:
            self._shape, self._first = x.shape, label
        elif x.shape != self._shape:
            raise InputError(
                f"{ref_name} is {x.shape[2]}x{x.shape[1]} but {self._first} of the sequence is "
                f"{self._shape[2]}x{self._shape[1]}: the frames of a sequence must have one size"
            )
        fv = FrameValues(index=index, frame=label, warmup=index < self.warmup)
        if self.still:
            mv = compute_metrics(x, r, self.still, output_name=out_name, reference_name=ref_name)
            fv.values, fv.unavailable = dict(mv.values), dict(mv.unavailable)
            fv.failed, fv.reason, fv.bad_pixels = mv.failed, mv.reason, mv.bad_pixels
        else:
            fv.bad_pixels = nonfinite_pixels(x)
            ref_bad = nonfinite_pixels(r)
            if fv.bad_pixels or ref_bad:
                fv.failed = True
                fv.reason = (
                    f"{fv.bad_pixels} non-finite pixel(s) (NaN/Inf) in {out_name}"
                    if fv.bad_pixels
                    else f"reference {ref_name} has {ref_bad} non-finite pixel(s) (NaN/Inf)"
                )
        current = None
        if not fv.failed:
            shown = (noisebase_display(x), noisebase_display(r)) if self._display else (x, r)
            current = (x, r, *shown)
        for m in self.temporal:
            fv.values[m] = None
            if index == 0 or fv.failed:
                continue
            if self._prev is None:
                fv.unavailable[m] = "the previous frame failed"
                continue
            spec = TEMPORAL_METRICS[m]
            assert current is not None
            (o0, r0), (o1, r1) = (
                (self._prev[2:], current[2:]) if spec.display else (self._prev[:2], current[:2])
            )
            fv.values[m] = spec.pair(o0, o1, r0, r1)
        self._prev = current
        self.frames.append(fv)
        return fv

    def summary(self) -> SequenceValues:
        """The sequence's values: headline, warm-up and all (see :class:`SequenceValues`)."""
        n, w = len(self.frames), self.warmup
        failed = [f for f in self.frames if f.failed]
        groups: dict[str, tuple[dict[str, float | None], dict[str, str]]] = {}
        for group in ("steady", "warmup", "all"):
            values: dict[str, float | None] = {}
            why: dict[str, str] = {}
            for m in self.metrics:
                values[m] = None
                if failed:
                    continue
                try:
                    values[m] = self._mean(m, group)
                except MetricUnavailable as err:
                    why[m] = str(err)
            groups[group] = (values, why)
        result = SequenceValues(
            values=groups["steady"][0],
            unavailable=groups["steady"][1],
            warmup_values=groups["warmup"][0],
            warmup_unavailable=groups["warmup"][1],
            all_values=groups["all"][0],
            all_unavailable=groups["all"][1],
            frames=list(self.frames),
            warmup=w,
            bad_pixels=sum(f.bad_pixels for f in self.frames),
        )
        if not n:
            result.failed, result.reason = True, f"{self.name}: no frame"
        elif failed:
            result.failed = True
            result.reason = f"{len(failed)} of {n} frames failed; {failed[0].reason}"
        return result

    def _mean(self, metric: str, group: str) -> float:
        """Mean of ``metric`` over the frames (or pairs) of ``group``; MetricUnavailable when
        there are none or one of them lacks the value."""
        n, w = len(self.frames), self.warmup
        temporal = is_temporal(metric)
        if temporal:  # the pair (t − 1, t) is stored with frame t
            keep = {"steady": range(w + 1, n), "warmup": range(1, min(w, n - 1) + 1)}
            chosen = keep.get(group, range(1, n))
        else:
            keep = {"steady": range(w, n), "warmup": range(min(w, n))}
            chosen = keep.get(group, range(n))
        if not len(chosen):
            raise MetricUnavailable(_why_empty(temporal, group, n, w))
        values: list[float] = []
        for t in chosen:
            f = self.frames[t]
            if metric in f.unavailable:
                raise MetricUnavailable(f"{f.frame}: {f.unavailable[metric]}")
            v = f.values.get(metric)
            if v is None:
                raise MetricUnavailable(f"{f.frame}: not computed")
            values.append(v)
        return math.fsum(values) / len(values)  # +inf when a PSNR is (an exact pair)


def _why_empty(temporal: bool, group: str, n: int, w: int) -> str:
    if temporal and n < 2:
        return f"a sequence of {n} frame has no frame pair" if n == 1 else "no frame"
    if group == "warmup":
        return "no warm-up frame (warm-up 0)" if w == 0 else "no frame pair in the warm-up"
    if temporal:
        return f"no frame pair past the warm-up: {n} frames, the first {w} are warm-up"
    return f"every frame is warm-up: {n} frames, warm-up {w}"


def sequence_metrics(
    outputs: ArrayLike | Sequence[ArrayLike],
    references: ArrayLike | Sequence[ArrayLike],
    metrics: Sequence[str] | None = None,
    *,
    warmup: int = WARMUP_FRAMES,
) -> SequenceValues:
    """Per-frame and temporal metrics of one output sequence against its reference frames.

    Args:
        outputs, references: ``(T, 3, H, W)`` arrays/tensors or ``T`` frames ``(3, H, W)``,
            linear HDR RGB, the same number of frames of one size.
        metrics: still and temporal metric names (default: all).
        warmup: number of first frames reported apart (default :data:`WARMUP_FRAMES`).

    Raises:
        InputError: frame counts or sizes differ, or a metric name is unknown.
    """
    xs, rs = _frames(outputs, "output"), _frames(references, "reference")
    if len(xs) != len(rs):
        raise InputError(f"{len(xs)} output frames but {len(rs)} reference frames")
    ev = SequenceEvaluator(metrics, warmup=warmup)
    for x, r in zip(xs, rs):
        ev.feed(x, r)
    return ev.summary()
