"""Display transforms for metrics and report images: sRGB encoding, exposure, false colour.

Everything here works on numpy arrays of layout ``(C, H, W)`` (``C = 3`` for RGB) and never
modifies its input. Two transforms are used by :mod:`mcdenoise.eval`, and every report states
which one a number or picture went through:

* **metric space** (:func:`to_srgb`): linear HDR RGB, clamped to ``[0, 1]``, then the sRGB
  transfer function (IEC 61966-2-1). No exposure is applied, so PSNR/SSIM do not depend on a
  choice made by the report. This is the space of PSNR and SSIM.
* **display space** (:func:`display`): the same, after multiplying by an exposure chosen once
  per scene from the *reference* (:func:`auto_exposure`), so the noisy input, every output and
  the reference of one scene are shown with the same tonemap.

:func:`false_color` maps scalar error values to RGB with a small built-in colour map (no
matplotlib needed).
"""

from __future__ import annotations

import numpy as np

#: Rec. 709 / sRGB luminance weights of linear RGB.
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)

#: Colour shown for non-finite (NaN/Inf) pixels in display and false-colour images (magenta).
NONFINITE_RGB = (1.0, 0.0, 1.0)

# 17 samples of matplotlib's "inferno" colour map (CC0), from 0 (black) to 1 (pale yellow);
# sampled with `matplotlib.colormaps["inferno"](np.linspace(0, 1, 17))`.
_INFERNO = np.array(
    [
        (0.0015, 0.0005, 0.0139),
        (0.0423, 0.0281, 0.1411),
        (0.1293, 0.0473, 0.2908),
        (0.2383, 0.0366, 0.3964),
        (0.3415, 0.0623, 0.4294),
        (0.4412, 0.0993, 0.4316),
        (0.5409, 0.1347, 0.4151),
        (0.6401, 0.1714, 0.3811),
        (0.7357, 0.2159, 0.3302),
        (0.8224, 0.2752, 0.2661),
        (0.8943, 0.3534, 0.1936),
        (0.9470, 0.4492, 0.1153),
        (0.9784, 0.5579, 0.0349),
        (0.9879, 0.6753, 0.0653),
        (0.9746, 0.7977, 0.2063),
        (0.9476, 0.9174, 0.4107),
        (0.9884, 0.9984, 0.6449),
    ],
    dtype=np.float64,
)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (OETF) applied elementwise to values in ``[0, 1]``.

    Args:
        linear: linear-light values, any shape; expected in ``[0, 1]`` (values outside are
            not clamped here, use :func:`to_srgb`).

    Returns:
        float64 array of the same shape, sRGB-encoded.

    >>> srgb_encode(np.array([0.0, 0.0031308, 0.5, 1.0])).round(6).tolist()
    [0.0, 0.04045, 0.735357, 1.0]
    """
    x = np.asarray(linear, dtype=np.float64)
    low = 12.92 * x
    high = 1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055
    return np.where(x <= 0.0031308, low, high)


def to_srgb(linear: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear HDR RGB -> sRGB in ``[0, 1]``: multiply by ``exposure``, clamp, encode.

    Args:
        linear: ``(C, H, W)`` linear HDR RGB (any range). NaN stays NaN; +Inf becomes 1.
        exposure: linear scale factor applied before clamping (1 = none).

    Returns:
        float64 ``(C, H, W)`` sRGB-encoded values in ``[0, 1]`` (NaN where the input was NaN).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        x = np.asarray(linear, dtype=np.float64) * float(exposure)
    return srgb_encode(np.clip(x, 0.0, 1.0))


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance ``(H, W)`` of linear RGB ``(3, H, W)``, in float64."""
    x = np.asarray(rgb, dtype=np.float64)
    if x.ndim != 3 or x.shape[0] != 3:
        raise ValueError(f"expected (3, H, W) RGB, got shape {x.shape}")
    w = LUMINANCE_WEIGHTS
    return w[0] * x[0] + w[1] * x[1] + w[2] * x[2]


def auto_exposure(reference: np.ndarray, *, key: float = 0.18) -> float:
    """Exposure factor that maps the reference's log-average luminance to ``key`` (middle grey).

    This is Reinhard's "key" exposure: ``key / exp(mean(log(max(L, 1e-4))))`` over the finite
    pixels of positive luminance ``L``. It is additionally limited so that at most 10 % of the
    pixels are pushed beyond 4x white (keeps mostly-dark scenes with large lit areas readable);
    a small very bright area (a lamp) does not darken the rest.
    A black or entirely non-finite reference gets exposure 1.

    Args:
        reference: ``(3, H, W)`` linear HDR RGB reference.

    Returns:
        A positive finite float.

    >>> auto_exposure(np.full((3, 4, 4), 0.36))
    0.5
    """
    lum = luminance(reference)
    lum = lum[np.isfinite(lum) & (lum > 0)]
    if lum.size == 0:
        return 1.0
    log_avg = float(np.exp(np.mean(np.log(np.maximum(lum, 1e-4)))))
    exposure = key / log_avg
    p90 = float(np.percentile(lum, 90))
    exposure = min(exposure, 4.0 / p90)
    if not np.isfinite(exposure) or exposure <= 0:
        return 1.0
    return float(round(exposure, 12))


def display(linear: np.ndarray, exposure: float) -> np.ndarray:
    """Display-ready sRGB ``(3, H, W)`` float64 in ``[0, 1]``; non-finite pixels in magenta.

    Args:
        linear: ``(3, H, W)`` linear HDR RGB.
        exposure: linear scale applied before clamping (see :func:`auto_exposure`).
    """
    x = np.asarray(linear, dtype=np.float64)
    out = to_srgb(np.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0), exposure)
    bad = ~np.isfinite(x).all(axis=0)
    if bad.any():
        for c in range(3):
            out[c][bad] = NONFINITE_RGB[c]
    return out


def false_color(values: np.ndarray, lo: float, hi: float, *, log: bool = True) -> np.ndarray:
    """Map scalar values ``(H, W)`` to RGB ``(3, H, W)`` in ``[0, 1]`` with the inferno map.

    Args:
        values: scalar field, e.g. per-pixel relMSE. Non-finite entries are drawn magenta.
        lo, hi: values mapped to the two ends of the colour map (clamped outside). With
            ``log=True`` (the default) the map is linear in ``log10(value)`` and both must be
            positive.
        log: use a logarithmic scale.

    Returns:
        float64 ``(3, H, W)`` RGB, already display-encoded (do not apply sRGB again).
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"expected (H, W) values, got shape {v.shape}")
    if not hi > lo:
        raise ValueError(f"false_color needs hi > lo, got lo={lo}, hi={hi}")
    finite = np.isfinite(v)
    safe = np.where(finite, v, lo)
    if log:
        if lo <= 0:
            raise ValueError(f"a log scale needs lo > 0, got lo={lo}")
        t = (np.log10(np.maximum(safe, lo)) - np.log10(lo)) / (np.log10(hi) - np.log10(lo))
    else:
        t = (safe - lo) / (hi - lo)
    t = np.clip(t, 0.0, 1.0) * (len(_INFERNO) - 1)
    i0 = np.floor(t).astype(np.int64)
    i1 = np.minimum(i0 + 1, len(_INFERNO) - 1)
    frac = (t - i0)[..., None]
    rgb = _INFERNO[i0] * (1.0 - frac) + _INFERNO[i1] * frac  # (H, W, 3)
    rgb[~finite] = NONFINITE_RGB
    return np.ascontiguousarray(np.moveaxis(rgb, -1, 0))


def colorbar(width: int = 256, height: int = 16) -> np.ndarray:
    """A horizontal legend strip ``(3, height, width)`` of the :func:`false_color` map, low->high."""
    ramp = np.tile(np.linspace(0.0, 1.0, width), (height, 1))
    return false_color(ramp, 0.0, 1.0, log=False)


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """Display-encoded ``(3, H, W)`` values in ``[0, 1]`` -> ``(H, W, 3)`` uint8 for PNG files."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float64), nan=0.0), 0.0, 1.0)
    return np.ascontiguousarray(np.moveaxis(np.round(x * 255.0).astype(np.uint8), 0, -1))
