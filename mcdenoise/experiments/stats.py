"""Statistics over scenes: is a method's advantage real, or noise of the scene sample?

With several scenes, one mean hides how much the answer depends on which scenes were picked.
For every method and spp level this module reports, over the scenes where both the method
and the *baseline* have a relMSE:

* the arithmetic and geometric mean relMSE over scenes;
* the **ratio to the baseline**: the geometric mean over scenes of
  ``relMSE(method) / relMSE(baseline)`` (0.5 = half the baseline's error), with a percentile
  **bootstrap confidence interval** obtained by resampling the scenes with replacement
  (``resamples`` times, seeded, so a re-run gives the same interval);
* **wins**: in how many scenes it has the lowest relMSE of all methods at that level, and in
  how many it beats the baseline;
* a verdict: ``better`` when the whole interval is below 1, ``worse`` when above 1,
  ``no clear difference`` otherwise (so a 0.5 % difference on four scenes is not sold as an
  improvement). One scene gives no interval at all.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcdenoise.geomean import geometric_mean

#: Verdicts of :class:`RatioStats`.
BETTER = "better"
WORSE = "worse"
UNCLEAR = "no clear difference"
SINGLE = "one scene: no interval"
IS_BASELINE = "baseline"
NO_RESULT = "no result"


def bootstrap_geomean_ci(
    ratios: Sequence[float],
    *,
    resamples: int = 2000,
    confidence: float = 0.95,
    rng: np.random.Generator | None = None,
) -> tuple[float, float, float]:
    """Geometric mean of positive ``ratios`` and its percentile bootstrap interval.

    Resamples the ratios with replacement ``resamples`` times; the interval is the
    ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles of the resampled geometric
    means. One ratio gives the degenerate interval ``(r, r, r)``.

    Raises:
        ValueError: no ratio, or a ratio that is not finite and positive.

    >>> point, lo, hi = bootstrap_geomean_ci([0.5, 0.5, 0.5], rng=np.random.default_rng(0))
    >>> point, lo, hi
    (0.5, 0.5, 0.5)
    """
    r = np.asarray(ratios, dtype=np.float64)
    point = geometric_mean(r, invalid="raise")
    if r.size == 1:
        return point, point, point
    rng = rng or np.random.default_rng(0)
    idx = rng.integers(0, r.size, size=(int(resamples), r.size))
    means = np.log(r)[idx].mean(axis=1)
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(means, [alpha, 1.0 - alpha])
    return point, float(np.exp(lo)), float(np.exp(hi))


@dataclass(frozen=True)
class RatioStats:
    """One method at one spp level, over scenes (see the module docstring).

    ``ratio``/``ci_low``/``ci_high`` are ``None`` when no scene has both values.
    """

    method: str
    spp: int
    baseline: str
    scenes: int
    mean_relmse: float | None
    geomean_relmse: float | None
    ratio: float | None
    ci_low: float | None
    ci_high: float | None
    wins: int
    beats_baseline: int
    verdict: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "spp": self.spp,
            "baseline": self.baseline,
            "scenes": self.scenes,
            "mean_relmse": self.mean_relmse,
            "geomean_relmse": self.geomean_relmse,
            "ratio": self.ratio,
            "ci_low": self.ci_low,
            "ci_high": self.ci_high,
            "wins": self.wins,
            "beats_baseline": self.beats_baseline,
            "verdict": self.verdict,
        }


def _stream(seed: int, method: str, spp: int) -> np.random.Generator:
    """A generator seeded by (seed, method, spp): independent of the order of the methods."""
    return np.random.default_rng([seed, zlib.crc32(method.encode()), spp])


def wins(
    errors: Mapping[tuple[str, int, str], float], scenes: Sequence[str], spp: int
) -> dict[str, int]:
    """Method -> number of scenes where it has the lowest relMSE at ``spp`` (ties: each)."""
    counts: dict[str, int] = {}
    for scene in scenes:
        vals = {m: e for (s, n, m), e in errors.items() if s == scene and n == spp}
        vals = {m: e for m, e in vals.items() if e is not None and math.isfinite(e)}
        if not vals:
            continue
        best = min(vals.values())
        for m, e in vals.items():
            if e == best:
                counts[m] = counts.get(m, 0) + 1
    return counts


def compare_methods(
    errors: Mapping[tuple[str, int, str], float],
    *,
    scenes: Sequence[str],
    methods: Sequence[str],
    spps: Sequence[int],
    baseline: str,
    resamples: int = 2000,
    confidence: float = 0.95,
    seed: int = 0,
) -> list[RatioStats]:
    """:class:`RatioStats` for every method (in ``methods`` order) at every level.

    Args:
        errors: ``(scene, spp, method) -> relMSE``; missing or non-finite entries (a failed
            output) are left out of that method's statistics.
        scenes, methods, spps: what to report on.
        baseline: the method ratios are taken to.
        resamples, confidence, seed: of the bootstrap.
    """
    out: list[RatioStats] = []
    for spp in spps:
        won = wins(errors, scenes, spp)
        for method in methods:
            mine, ratios, beats = [], [], 0
            for scene in scenes:
                e = errors.get((scene, spp, method))
                if e is None or not math.isfinite(e):
                    continue
                mine.append(e)
                b = errors.get((scene, spp, baseline))
                if b is not None and math.isfinite(b) and b > 0 and e > 0:
                    ratios.append(e / b)
                    beats += e < b
            mean = float(np.mean(mine)) if mine else None
            geo = geometric_mean(mine, invalid="none")
            ratio = lo = hi = None
            if method == baseline:
                verdict = IS_BASELINE
            elif not mine:
                verdict = NO_RESULT
            elif not ratios:
                verdict = "no common scene with the baseline"
            else:
                ratio, lo, hi = bootstrap_geomean_ci(
                    ratios,
                    resamples=resamples,
                    confidence=confidence,
                    rng=_stream(seed, method, spp),
                )
                if len(ratios) == 1:
                    verdict = SINGLE
                elif hi < 1.0:
                    verdict = BETTER
                elif lo > 1.0:
                    verdict = WORSE
                else:
                    verdict = UNCLEAR
            out.append(
                RatioStats(
                    method=method,
                    spp=spp,
                    baseline=baseline,
                    scenes=len(mine),
                    mean_relmse=mean,
                    geomean_relmse=geo,
                    ratio=ratio,
                    ci_low=lo,
                    ci_high=hi,
                    wins=won.get(method, 0),
                    beats_baseline=int(beats),
                    verdict=verdict,
                )
            )
    return out
