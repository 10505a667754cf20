"""Equal quality: how many samples (and seconds) plain rendering needs to match an error.

Monte Carlo rendering converges as ``1/N``: the variance of a pixel mean, hence its expected
relMSE, falls as ``c / N`` with the sample count ``N``. The *measured* noisy curve of one
scene (relMSE of the noisy image at each level of the spp ladder) is the reference for
"what accuracy costs": a method that reaches error ``e`` after ``n`` spp plus ``t`` seconds of
denoising is worth the ``N(e)`` spp plain rendering would need for the same ``e``.

:func:`equal_quality_spp` inverts the measured curve:

* between two measured levels it interpolates linearly in log-log (``log N`` against
  ``log e``), scanning from the lowest level and taking the first segment that brackets ``e``
  (the measured curve can wiggle where the reference's own noise dominates);
* below the error of the highest measured level it extrapolates with the ``1/N`` law anchored
  at that level: ``N = N_max · e_max / e`` (flag ``"extrapolated"``);
* above the error of the lowest level (a method *worse* than 1-spp plain rendering) it
  extrapolates the same way from the lowest level (flag ``"below ladder"``).

The seconds plain rendering needs are ``N(e)`` times the measured seconds per spp of plain
rendering, taken from the highest level (cumulative render seconds, JIT compilation
excluded, divided by its spp; the fixed cost per render call makes lower levels relatively
dearer, so this is the cheap, conservative rate).

:func:`reference_noise_floor` is the relMSE the reference itself is expected to have against
the (unknown) converged image: ``mean(var / (ref² + ε))``, with ``var`` the reference's
variance of the mean (``color_var``). No measured error can be trusted far below it, so
records within :data:`FLOOR_FACTOR` × of it are flagged "limited by the reference".
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcdenoise.eval.metrics import relative_squared_error
from mcdenoise.geomean import geometric_mean
from mcdenoise.losses import RELMSE_EPS

#: Errors below this multiple of the reference's noise floor are "limited by the reference".
FLOOR_FACTOR = 2.0

#: ``extrapolated`` values of :class:`EqualQuality`.
ABOVE_LADDER = "extrapolated"
BELOW_LADDER = "below ladder"


@dataclass(frozen=True)
class NoisyCurve:
    """The measured relMSE of plain rendering at each level of one scene's spp ladder.

    Attributes:
        spp: the levels, strictly increasing.
        error: relMSE of the noisy image at each level (> 0).
        seconds: cumulative render seconds of each level (JIT compilation excluded).
    """

    spp: tuple[int, ...]
    error: tuple[float, ...]
    seconds: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (len(self.spp) == len(self.error) == len(self.seconds)) or not self.spp:
            raise ValueError("NoisyCurve needs as many errors and seconds as levels (>= 1)")
        if any(b <= a for a, b in itertools.pairwise(self.spp)):
            raise ValueError(f"spp must be strictly increasing, got {self.spp}")
        if not all(math.isfinite(e) and e > 0 for e in self.error):
            raise ValueError(f"noisy errors must be finite and > 0, got {self.error}")

    @property
    def seconds_per_spp(self) -> float:
        """Seconds per spp of plain rendering: the highest level's seconds / its spp."""
        return float(self.seconds[-1]) / float(self.spp[-1])

    def slope(self) -> float | None:
        """Least-squares slope of ``log e`` against ``log N`` (about -1 for Monte Carlo noise;
        flatter where the reference's noise floor is reached). ``None`` with one level."""
        return loglog_slope(self.spp, self.error)

    def one_over_n(self) -> float:
        """``c`` of the best ``e = c / N`` fit in log space (the geometric mean of ``e·N``)."""
        return geometric_mean(np.asarray(self.error) * np.asarray(self.spp))


@dataclass(frozen=True)
class EqualQuality:
    """Plain rendering's cost for the error of one (method, spp).

    Attributes:
        spp: samples per pixel plain rendering needs for the same relMSE (may be fractional;
            ``inf`` for an error of 0).
        seconds: the render seconds of that many spp (``spp × seconds_per_spp``).
        extrapolated: ``None`` when interpolated between measured levels, else
            :data:`ABOVE_LADDER` or :data:`BELOW_LADDER` (the ``1/N`` law was used).
        speedup: ``seconds`` / the method's total seconds (render + denoise), when known.
    """

    spp: float
    seconds: float
    extrapolated: str | None = None
    speedup: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "spp": self.spp,
            "seconds": self.seconds,
            "extrapolated": self.extrapolated,
            "speedup": self.speedup,
        }


def loglog_slope(spp: Sequence[float], error: Sequence[float]) -> float | None:
    """Least-squares slope of ``log(error)`` vs ``log(spp)``; ``None`` for fewer than 2 points.

    >>> round(loglog_slope([1, 2, 4, 8], [1.0, 0.5, 0.25, 0.125]), 6)
    -1.0
    """
    x = np.log(np.asarray(spp, dtype=np.float64))
    y = np.log(np.asarray(error, dtype=np.float64))
    if x.size < 2:
        return None
    return float(np.polyfit(x, y, 1)[0])


def equal_quality_spp(curve: NoisyCurve, error: float) -> tuple[float, str | None]:
    """spp plain rendering needs to reach relMSE ``error`` (see the module docstring).

    Returns:
        ``(spp, flag)``; ``flag`` is ``None`` (interpolated), :data:`ABOVE_LADDER` or
        :data:`BELOW_LADDER`. An ``error`` of 0 gives ``(inf, ABOVE_LADDER)``.

    Raises:
        ValueError: ``error`` is negative or not finite.

    >>> c = NoisyCurve((1, 4, 16), (0.8, 0.2, 0.05), (1.0, 4.0, 16.0))
    >>> n, flag = equal_quality_spp(c, 0.1)
    >>> round(n, 9), flag
    (8.0, None)
    >>> equal_quality_spp(c, 0.01)
    (80.0, 'extrapolated')
    """
    if not math.isfinite(error) or error < 0:
        raise ValueError(f"error must be finite and >= 0, got {error}")
    spp = np.asarray(curve.spp, dtype=np.float64)
    err = np.asarray(curve.error, dtype=np.float64)
    if error == 0:
        return math.inf, ABOVE_LADDER
    for i in range(len(spp) - 1):
        hi, lo = err[i], err[i + 1]
        if min(hi, lo) <= error <= max(hi, lo) and hi != lo:
            t = (math.log(error) - math.log(hi)) / (math.log(lo) - math.log(hi))
            log_n = math.log(spp[i]) + t * (math.log(spp[i + 1]) - math.log(spp[i]))
            return float(math.exp(log_n)), None
    if error in err:  # a flat segment hit exactly, or a single level
        return float(spp[int(np.flatnonzero(err == error)[0])]), None
    # no segment brackets ``error``: it lies outside the measured range
    if error < err.min():
        return float(spp[-1] * err[-1] / error), ABOVE_LADDER
    return float(spp[0] * err[0] / error), BELOW_LADDER


def equal_quality(
    curve: NoisyCurve, error: float, total_seconds: float | None = None
) -> EqualQuality:
    """:func:`equal_quality_spp` plus the seconds plain rendering needs and the speed-up over a
    method that took ``total_seconds`` (render + denoise) to reach ``error``.

    >>> c = NoisyCurve((1, 4, 16), (0.8, 0.2, 0.05), (1.0, 4.0, 16.0))
    >>> eq = equal_quality(c, 0.1, total_seconds=2.0)
    >>> round(eq.spp, 9), round(eq.seconds, 9), eq.extrapolated, round(eq.speedup, 9)
    (8.0, 8.0, None, 4.0)
    """
    n, flag = equal_quality_spp(curve, error)
    seconds = n * curve.seconds_per_spp
    speedup = None
    if total_seconds is not None and total_seconds > 0 and math.isfinite(seconds):
        speedup = seconds / total_seconds
    elif total_seconds is not None and total_seconds > 0:
        speedup = math.inf
    return EqualQuality(spp=n, seconds=seconds, extrapolated=flag, speedup=speedup)


def reference_noise_floor(
    reference: np.ndarray, variance: np.ndarray, eps: float = RELMSE_EPS
) -> float:
    """Expected relMSE of a reference against the converged image: ``mean(var / (ref² + ε))``.

    The variance is the expected squared error, put in relMSE units by
    :func:`mcdenoise.eval.metrics.relative_squared_error`.

    Args:
        reference: ``(3, H, W)`` linear HDR RGB reference colour.
        variance: its variance of the mean, ``(3, H, W)`` or ``(1, H, W)`` (a luminance
            variance, applied to every channel).
        eps: relMSE's ε (0.01).

    Returns:
        The mean over pixels and channels (non-finite terms ignored).

    >>> round(reference_noise_floor(np.ones((3, 2, 2)), np.full((1, 2, 2), 0.0101)), 6)
    0.01
    """
    ref = np.asarray(reference, dtype=np.float64)
    var = np.asarray(variance, dtype=np.float64)
    if ref.ndim != 3 or var.ndim != 3 or var.shape[1:] != ref.shape[1:]:
        raise ValueError(f"reference {ref.shape} and variance {var.shape} do not match")
    with np.errstate(invalid="ignore"):  # NaN variances become NaN terms, ignored below
        var = np.broadcast_to(np.maximum(var, 0.0), ref.shape)
    terms = relative_squared_error(var, ref, eps)
    finite = terms[np.isfinite(terms)]
    return float(finite.mean()) if finite.size else math.nan


def noisy_rises(
    curve: NoisyCurve, floor: float | None = None
) -> list[tuple[int, float, int, float]]:
    """Where the measured noisy curve *rises* with spp: ``(spp_a, e_a, spp_b, e_b)`` for each
    pair of consecutive levels with ``e_b > e_a``.

    The expected relMSE of plain rendering falls as ``1/N``; a measured rise means a few
    pixels of huge value (fireflies: rare light paths of high contribution, e.g. caustics
    seen through glass) dominate the mean, so that scene's errors, and every mean over scenes
    that includes it, depend on where those few samples landed. Rises at levels whose error
    is within :data:`FLOOR_FACTOR` × the reference's noise floor are left out: there the
    reference's own noise decides the wiggle.

    >>> c = NoisyCurve((1, 2, 4, 8), (177.0, 44.7, 119.0, 30.0), (1.0, 2.0, 4.0, 8.0))
    >>> noisy_rises(c)
    [(2, 44.7, 4, 119.0)]
    >>> noisy_rises(NoisyCurve((1, 2), (0.02, 0.021), (1.0, 2.0)), floor=0.015)
    []
    """
    out = []
    for i in range(len(curve.spp) - 1):
        a, b = curve.error[i], curve.error[i + 1]
        if b > a and not limited_by_reference(b, floor):
            out.append((curve.spp[i], float(a), curve.spp[i + 1], float(b)))
    return out


def limited_by_reference(error: float | None, floor: float | None) -> bool:
    """True when ``error`` is within :data:`FLOOR_FACTOR` × the reference's noise floor."""
    if error is None or floor is None or not math.isfinite(floor) or floor <= 0:
        return False
    return error < FLOOR_FACTOR * floor
