"""Image error metrics of a denoised output against a reference, and their registry.

Every function takes ``output`` and ``reference`` of layout ``(3, H, W)`` (numpy arrays or torch
tensors, any float dtype), **linear HDR RGB** as rendered, and computes in float64. Where a
metric needs display values it says so; the registry :data:`METRICS` records for each metric
its definition, its ε and the colour space it is computed in, so reports can state them:

=======  ==========================================  ======================================
name     definition                                  colour space
=======  ==========================================  ======================================
relmse   mean((x − r)² / (r² + ε)), ε = 0.01          linear HDR RGB
smape    mean(|x − r| / (|x| + |r| + ε)), ε = 0.01    linear HDR RGB
mse      mean((x − r)²)                              linear HDR RGB
psnr     10 · log10(1 / MSE), in dB                  sRGB, clamped to [0, 1] (no exposure)
ssim     SSIM, data_range = 1, mean over channels    sRGB, clamped to [0, 1] (no exposure)
flip     mean HDR-FLIP error (``flip_evaluator``)    linear HDR RGB (negatives clamped to 0)
bias     mean(x) / mean(r) − 1 over all channels     linear HDR RGB
bias_r   the same on R only (``bias_g``, ``bias_b``)  linear HDR RGB
=======  ==========================================  ======================================

The mean bias is signed (−0.03: the output is 3 % darker than the reference, energy lost;
0 is best): it is computed as ``(mean(x) − mean(r)) / |mean(r)|`` with the means over pixels
(and channels for ``bias``), so no ε shifts it. A reference whose mean is exactly 0 gives 0
when the output's mean is 0 too, else the metric is unavailable (:class:`MetricUnavailable`:
no relative change of a zero mean exists). Asking for ``bias`` also computes its channels.

The ε of relMSE and SMAPE are the training losses' (:data:`mcdenoise.losses.RELMSE_EPS`,
:data:`mcdenoise.losses.SMAPE_EPS`), imported from there. :func:`relative_squared_error` is the
relMSE normalisation ``(·) / (r² + ε)`` every numpy relMSE of the package goes through; the
torch one is :func:`mcdenoise.losses.relative_squared_error`. Errors are averaged over images
with :func:`mcdenoise.geomean.geometric_mean`.

Edge cases, by policy:

* identical images: relMSE = SMAPE = MSE = 0, PSNR = ``math.inf`` (reports write the string
  ``"inf"``, because JSON has no infinity), SSIM = 1, FLIP = 0;
* zero reference pixels: relMSE and SMAPE stay finite thanks to ε (SMAPE of 0 vs 0 is 0);
* NaN/Inf in an output: the plain metric functions return NaN or Inf (PSNR and SSIM return
  NaN rather than clamping Inf away), never a silently better number; :func:`compute_metrics` instead marks the output
  *failed*, counts its bad pixels and computes nothing;
* output and reference of different sizes: :class:`~mcdenoise.errors.InputError` naming both
  (never broadcasting);
* a black reference: see the mean bias above;
* FLIP needs the optional ``flip_evaluator`` package and a reference that is not black; when
  it cannot be computed, :class:`MetricUnavailable` carries the reason.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.eval.images import ArrayLike, as_image, check_same_shape, nonfinite_pixels
from mcdenoise.eval.tonemap import to_srgb
from mcdenoise.losses import RELMSE_EPS, SMAPE_EPS  # one ε for a loss and its metric

#: SSIM window side for images at least this large (skimage's default uniform window).
SSIM_WINDOW = 7

#: Colour space names used in the registry and in reports.
LINEAR = "linear HDR RGB"
SRGB_CLAMPED = "sRGB, clamped to [0, 1] (no exposure)"

# FLIP (flip_evaluator <= 1.7) computes its exposure range from the reference as
# [log2(x/Ymax), log2(x/max(Ymedian, FLT_EPSILON))] and calls C++ exit(-1) -- which kills the
# Python interpreter, SystemExit cannot catch it -- when the range is reversed, i.e. when the
# reference's maximum luminance is below FLT_EPSILON. We refuse such references first, with a
# safety factor.
_FLIP_MIN_LUMINANCE = 4.0 * float(np.finfo(np.float32).eps)


class MetricUnavailable(Exception):
    """A metric cannot be computed for this pair of images; ``str(err)`` is the reason."""


def _pair(output: ArrayLike, reference: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    x = as_image(output, "output")
    r = as_image(reference, "reference")
    check_same_shape(x, r)
    return x, r


# --- the metrics (private versions take validated float64 arrays) ----------------------------


# Non-finite inputs give NaN/Inf results by design (documented): no warnings for them.
_QUIET = {"invalid": "ignore", "over": "ignore", "divide": "ignore"}


def relative_squared_error(
    squared_error: np.ndarray, reference: np.ndarray, eps: float = RELMSE_EPS
) -> np.ndarray:
    """A squared error in relMSE units: ``squared_error / (r² + ε)``, elementwise, float64.

    The one place the relMSE normalisation is written for arrays (the torch twin is
    :func:`mcdenoise.losses.relative_squared_error`): :func:`relmse` and :func:`relmse_map`
    give it ``(x − r)²``; an expected squared error (a variance) can be given instead.
    Non-finite inputs give non-finite terms, without warnings.

    Args:
        squared_error: any shape broadcastable with ``reference``.
        reference: linear HDR RGB, e.g. ``(3, H, W)``.
        eps: relMSE's ε.

    >>> relative_squared_error(np.array([0.25, 1.0]), np.array([1.0, 0.0]))
    array([  0.24752475, 100.        ])
    """
    with np.errstate(**_QUIET):
        return squared_error / (reference**2 + eps)


def _relmse_map(x: np.ndarray, r: np.ndarray, eps: float = RELMSE_EPS) -> np.ndarray:
    with np.errstate(**_QUIET):
        return np.mean(relative_squared_error((x - r) ** 2, r, eps), axis=0)


def _relmse(x: np.ndarray, r: np.ndarray) -> float:
    with np.errstate(**_QUIET):
        return float(np.mean(relative_squared_error((x - r) ** 2, r)))


def _smape(x: np.ndarray, r: np.ndarray) -> float:
    with np.errstate(**_QUIET):
        return float(np.mean(np.abs(x - r) / (np.abs(x) + np.abs(r) + SMAPE_EPS)))


def _mse(x: np.ndarray, r: np.ndarray) -> float:
    with np.errstate(**_QUIET):
        return float(np.mean((x - r) ** 2))


def _psnr(x: np.ndarray, r: np.ndarray) -> float:
    if not (np.isfinite(x).all() and np.isfinite(r).all()):
        return math.nan  # clamping would hide Inf pixels
    err = float(np.mean((to_srgb(x) - to_srgb(r)) ** 2))
    if err == 0.0:
        return math.inf
    return 10.0 * math.log10(1.0 / err)


def ssim_window(height: int, width: int) -> int:
    """SSIM window side: 7, or the largest odd size that fits an image smaller than 7 px."""
    side = min(SSIM_WINDOW, height, width)
    return side if side % 2 == 1 else side - 1


def _ssim(x: np.ndarray, r: np.ndarray) -> float:
    from skimage.metrics import structural_similarity  # lazy: scikit-image is slow to import

    if not (np.isfinite(x).all() and np.isfinite(r).all()):
        return math.nan
    win = ssim_window(x.shape[1], x.shape[2])
    return float(
        structural_similarity(
            np.moveaxis(to_srgb(x), 0, -1),
            np.moveaxis(to_srgb(r), 0, -1),
            data_range=1.0,
            channel_axis=-1,
            win_size=win,
            # a 1x1 window has no sample covariance (N - 1 = 0): use the population one
            use_sample_covariance=win > 1,
        )
    )


def _import_flip() -> Any:
    """Import ``flip_evaluator`` (ImportError if absent)."""
    import flip_evaluator  # lazy: flip-evaluator is optional

    return flip_evaluator


def flip_status() -> str | None:
    """``None`` when FLIP can be computed here, else the reason it cannot (package missing)."""
    try:
        _import_flip()
    except ImportError:
        return "flip_evaluator is not installed (pip install 'mcdenoise[flip]')"
    return None


def _flip(x: np.ndarray, r: np.ndarray) -> float:
    reason = flip_status()
    if reason is not None:
        raise MetricUnavailable(reason)
    flip_evaluator = _import_flip()

    if not (np.isfinite(x).all() and np.isfinite(r).all()):
        raise MetricUnavailable("FLIP needs finite images")
    with np.errstate(over="ignore"):
        ref = np.ascontiguousarray(np.moveaxis(np.maximum(r, 0.0), 0, -1), dtype=np.float32)
        test = np.ascontiguousarray(np.moveaxis(np.maximum(x, 0.0), 0, -1), dtype=np.float32)
    if not (np.isfinite(ref).all() and np.isfinite(test).all()):
        raise MetricUnavailable("FLIP computes in float32: values beyond its range (3.4e38)")
    y_max = float((ref @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)).max())
    if y_max < _FLIP_MIN_LUMINANCE:
        raise MetricUnavailable(
            f"reference is black (max luminance {y_max:.3g}): FLIP's exposure range is undefined"
        )
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter):
            _, mean_error, _ = flip_evaluator.evaluate(ref, test, "HDR")
    except SystemExit:
        msg = " ".join(chatter.getvalue().split()) or "no message"
        raise MetricUnavailable(f"flip_evaluator refused the input: {msg}") from None
    except (RuntimeError, ValueError, TypeError) as err:
        raise MetricUnavailable(f"flip_evaluator failed: {' '.join(str(err).split())}") from None
    value = float(mean_error)
    if not math.isfinite(value):
        raise MetricUnavailable(f"flip_evaluator returned {value}")
    return value


def _relative_change(mean_x: float, mean_r: float, what: str) -> float:
    """``(mean_x − mean_r) / |mean_r|``; 0 for two zero means; unavailable for a zero
    reference mean only; NaN/Inf means give NaN/Inf (no error)."""
    if mean_r == 0.0:
        if mean_x == 0.0:
            return 0.0
        raise MetricUnavailable(f"the reference's mean{what} is 0: a relative bias is undefined")
    with np.errstate(**_QUIET):
        return float((mean_x - mean_r) / abs(mean_r))


def _bias(x: np.ndarray, r: np.ndarray) -> float:
    with np.errstate(**_QUIET):
        return _relative_change(float(np.mean(x)), float(np.mean(r)), "")


def _bias_channel(channel: int) -> Callable[[np.ndarray, np.ndarray], float]:
    name = "RGB"[channel]

    def fn(x: np.ndarray, r: np.ndarray) -> float:
        with np.errstate(**_QUIET):
            return _relative_change(
                float(np.mean(x[channel])), float(np.mean(r[channel])), f" in {name}"
            )

    return fn


# --- public functions -------------------------------------------------------------------------


def relmse(output: ArrayLike, reference: ArrayLike) -> float:
    """Relative MSE ``mean((x − r)² / (r² + 0.01))`` over all pixels and channels.

    Args:
        output: ``(3, H, W)`` linear HDR RGB, the image judged.
        reference: ``(3, H, W)`` linear HDR RGB, the ground truth.

    >>> round(relmse(np.full((3, 2, 2), 1.5), np.ones((3, 2, 2))), 12)  # 0.25 / 1.01
    0.247524752475
    """
    return _relmse(*_pair(output, reference))


def relmse_map(output: ArrayLike, reference: ArrayLike, eps: float = RELMSE_EPS) -> np.ndarray:
    """Per-pixel relMSE ``(H, W)``: ``(x − r)² / (r² + ε)`` averaged over the channels.

    Its mean is :func:`relmse`. Inputs are ``(3, H, W)`` linear HDR RGB.
    """
    return _relmse_map(*_pair(output, reference), eps)


def smape(output: ArrayLike, reference: ArrayLike) -> float:
    """SMAPE ``mean(|x − r| / (|x| + |r| + 0.01))`` on ``(3, H, W)`` linear HDR RGB.

    >>> smape(np.zeros((3, 1, 1)), np.zeros((3, 1, 1)))
    0.0
    """
    return _smape(*_pair(output, reference))


def mse(output: ArrayLike, reference: ArrayLike) -> float:
    """Mean squared error on ``(3, H, W)`` linear HDR RGB."""
    return _mse(*_pair(output, reference))


def psnr(output: ArrayLike, reference: ArrayLike) -> float:
    """PSNR in dB (peak 1) on sRGB clamped to ``[0, 1]``; ``math.inf`` when identical there.

    Inputs are ``(3, H, W)`` linear HDR RGB; both go through :func:`~.tonemap.to_srgb`
    (clamp, then the sRGB transfer function, no exposure) before the MSE.
    """
    return _psnr(*_pair(output, reference))


def ssim(output: ArrayLike, reference: ArrayLike) -> float:
    """SSIM on sRGB clamped to ``[0, 1]`` (``data_range=1``), averaged over the 3 channels.

    Uses skimage's uniform 7×7 window; images smaller than 7 px use the largest odd window
    that fits (see :func:`ssim_window`). Inputs are ``(3, H, W)`` linear HDR RGB.
    """
    return _ssim(*_pair(output, reference))


def flip(output: ArrayLike, reference: ArrayLike) -> float:
    """Mean HDR-FLIP error (``flip_evaluator.evaluate(ref, test, "HDR")``), in ``[0, 1]``.

    Inputs are ``(3, H, W)`` linear HDR RGB (negative values are clamped to 0, as HDR-FLIP
    requires). Default viewing conditions (67 pixels per degree), ACES tonemapper, exposure
    range chosen by FLIP from the reference.

    Raises:
        MetricUnavailable: ``flip_evaluator`` is not installed, an image has NaN/Inf, the
            reference is black, or ``flip_evaluator`` rejected the input (its ``sys.exit`` is
            caught and its printed message becomes the reason).
    """
    return _flip(*_pair(output, reference))


def mean_bias(output: ArrayLike, reference: ArrayLike) -> float:
    """Mean bias ``mean(x) / mean(r) − 1`` over all pixels and channels (signed; 0 is best).

    Computed as ``(mean(x) − mean(r)) / |mean(r)|`` in float64 on ``(3, H, W)`` linear HDR RGB:
    −0.03 means the output holds 3 % less energy than the reference (darker). NaN/Inf in an
    input give NaN/Inf.

    Raises:
        MetricUnavailable: the reference's mean is 0 and the output's is not (two zero means
            give 0).

    >>> round(mean_bias(np.full((3, 2, 2), 0.97), np.ones((3, 2, 2))), 12)
    -0.03
    """
    return _bias(*_pair(output, reference))


def channel_bias(output: ArrayLike, reference: ArrayLike) -> tuple[float, float, float]:
    """Mean bias of R, G and B separately (see :func:`mean_bias`); raises like it when one
    channel's reference mean is 0.

    >>> x = np.ones((3, 1, 2)); x[0] = 1.1
    >>> [round(v, 12) for v in channel_bias(x, np.ones((3, 1, 2)))]
    [0.1, 0.0, 0.0]
    """
    x, r = _pair(output, reference)
    return _bias_channel(0)(x, r), _bias_channel(1)(x, r), _bias_channel(2)(x, r)


# --- registry ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Metric:
    """One registered metric: how it is computed and how reports must describe it."""

    name: str
    label: str
    fn: Callable[[np.ndarray, np.ndarray], float]
    space: str
    definition: str
    epsilon: float | None = None
    higher_is_better: bool = False
    optional: bool = False
    #: signed, best at 0: the best value is the one of smallest magnitude
    signed: bool = False
    #: the summary metric this one details (e.g. ``bias_r`` of ``bias``), shown under it
    part_of: str | None = None

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (name, label, definition, ε, colour space, direction)."""
        return describe_metric(self)

    def better(self, a: float, b: float) -> bool:
        """True when value ``a`` is strictly better than ``b`` for this metric."""
        if self.signed:
            return abs(a) < abs(b)
        return a > b if self.higher_is_better else a < b


def describe_metric(m: Any) -> dict[str, Any]:
    """The JSON-ready description of a metric (:class:`Metric`, or a temporal one of
    :mod:`mcdenoise.eval.temporal_metrics`): label, definition, ε, colour space, direction."""
    return {
        "label": m.label,
        "definition": m.definition,
        "epsilon": m.epsilon,
        "space": m.space,
        "higher_is_better": m.higher_is_better,
        "best": "closest to 0" if m.signed else ("highest" if m.higher_is_better else "lowest"),
    }


#: Registered metrics, in report column order.
METRICS: dict[str, Metric] = {
    m.name: m
    for m in (
        Metric(
            "relmse",
            "relMSE",
            _relmse,
            LINEAR,
            f"mean((x − r)² / (r² + ε)), ε = {RELMSE_EPS}",
            RELMSE_EPS,
        ),
        Metric(
            "smape",
            "SMAPE",
            _smape,
            LINEAR,
            f"mean(|x − r| / (|x| + |r| + ε)), ε = {SMAPE_EPS}",
            SMAPE_EPS,
        ),
        Metric("mse", "MSE", _mse, LINEAR, "mean((x − r)²)"),
        Metric(
            "psnr",
            "PSNR (dB)",
            _psnr,
            SRGB_CLAMPED,
            '10·log10(1 / MSE) with peak 1; +inf for identical images (written as "inf")',
            higher_is_better=True,
        ),
        Metric(
            "ssim",
            "SSIM",
            _ssim,
            SRGB_CLAMPED,
            "SSIM (scikit-image), data_range = 1, uniform 7×7 window (smaller odd window for "
            "images under 7 px), mean over R, G, B",
            higher_is_better=True,
        ),
        Metric(
            "flip",
            "FLIP",
            _flip,
            LINEAR + " (negatives clamped to 0)",
            "mean HDR-FLIP error (flip_evaluator, 67 pixels per degree, ACES, automatic "
            "exposure range from the reference)",
            optional=True,
        ),
        Metric(
            "bias",
            "mean bias",
            _bias,
            LINEAR,
            "mean(x) / mean(r) − 1, means over pixels and channels (signed: −0.03 = 3 % darker "
            "than the reference; 0 when both means are 0, unavailable when only the "
            "reference's is)",
            signed=True,
        ),
        *(
            Metric(
                f"bias_{c.lower()}",
                f"bias {c}",
                _bias_channel(i),
                LINEAR,
                f"mean bias of the {c} channel: mean(x_{c}) / mean(r_{c}) − 1",
                signed=True,
                part_of="bias",
            )
            for i, c in enumerate("RGB")
        ),
    )
}

#: Summary metric -> the metrics that detail it (``bias`` -> its channels).
PARTS: dict[str, tuple[str, ...]] = {
    name: tuple(m.name for m in METRICS.values() if m.part_of == name)
    for name in METRICS
    if any(m.part_of == name for m in METRICS.values())
}


def resolve_metrics(names: Sequence[str] | None) -> list[str]:
    """Validate metric names (case-insensitive); ``None`` means every registered metric.

    A summary metric brings the metrics that detail it (``bias`` its channels ``bias_r``,
    ``bias_g``, ``bias_b``), right after it.

    >>> resolve_metrics(["relmse", "bias"])
    ['relmse', 'bias', 'bias_r', 'bias_g', 'bias_b']
    """
    if names is None:
        return list(METRICS)
    out: list[str] = []
    for n in names:
        key = str(n).strip().lower()
        if key not in METRICS:
            raise InputError(f"unknown metric {n!r}; known: {', '.join(METRICS)}")
        for k in (key, *PARTS.get(key, ())):
            if k not in out:
                out.append(k)
    if not out:
        raise InputError("no metric requested")
    return out


@dataclass
class MetricValues:
    """Metrics of one output against its reference.

    Attributes:
        values: metric name -> value; ``None`` when failed or unavailable. PSNR may be
            ``math.inf``.
        unavailable: metric name -> reason it could not be computed (e.g. FLIP missing).
        failed: the output (or its reference) has NaN/Inf pixels; no metric was computed.
        reason: one line explaining the failure, else ``None``.
        bad_pixels: count of pixels of the output with any non-finite channel.
    """

    values: dict[str, float | None] = field(default_factory=dict)
    unavailable: dict[str, str] = field(default_factory=dict)
    failed: bool = False
    reason: str | None = None
    bad_pixels: int = 0


def compute_metrics(
    output: ArrayLike,
    reference: ArrayLike,
    names: Sequence[str] | None = None,
    *,
    output_name: str = "output",
    reference_name: str = "reference",
) -> MetricValues:
    """Compute the metrics ``names`` (default: all registered) of ``output`` vs ``reference``.

    Args:
        output: ``(3, H, W)`` linear HDR RGB.
        reference: ``(3, H, W)`` linear HDR RGB of the same size.
        names: metric names from :data:`METRICS`.
        output_name, reference_name: how errors and failure reasons name the two images
            (file paths when evaluating files).

    Returns:
        :class:`MetricValues`. An output with any NaN/Inf pixel is ``failed`` with its bad-pixel
        count and no values; so is every output of a reference that has NaN/Inf pixels.

    Raises:
        InputError: shapes differ (the message names both images and sizes) or a metric name
            is unknown.
    """
    keys = resolve_metrics(names)
    x = as_image(output, output_name)
    r = as_image(reference, reference_name)
    check_same_shape(x, r, output_name=output_name, reference_name=reference_name)
    result = MetricValues(values=dict.fromkeys(keys))
    result.bad_pixels = nonfinite_pixels(x)
    ref_bad = nonfinite_pixels(r)
    if result.bad_pixels:
        result.failed = True
        result.reason = f"{result.bad_pixels} non-finite pixel(s) (NaN/Inf) in {output_name}"
    elif ref_bad:
        result.failed = True
        result.reason = f"reference {reference_name} has {ref_bad} non-finite pixel(s) (NaN/Inf)"
    if result.failed:
        return result
    for key in keys:
        try:
            result.values[key] = METRICS[key].fn(x, r)
        except MetricUnavailable as err:
            result.unavailable[key] = str(err)
    return result
