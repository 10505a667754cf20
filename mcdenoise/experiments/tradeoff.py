"""Accuracy against time: the Pareto front and equal-time comparisons.

Every (method, spp) of a scene is a point ``(total seconds, relMSE)``, where total seconds =
render seconds of that spp level + the method's denoise seconds (0 for plain rendering). A
point is on the **Pareto front** when no other point is at least as fast *and* at least as
accurate (and strictly better in one); those are the only choices worth making. An
**equal-time** table answers "given this many seconds, what is the most accurate thing to
do?": for each budget, the lowest-error point whose total time fits, next to the best plain
rendering that fits (what denoising bought in that budget).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Point:
    """One (method, spp) of a scene (or of the mean over scenes): its total time and error."""

    method: str
    spp: int
    seconds: float
    error: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "spp": self.spp,
            "seconds": self.seconds,
            "error": self.error,
        }


def _usable(points: Iterable[Point]) -> list[Point]:
    return [
        p
        for p in points
        if math.isfinite(p.seconds) and math.isfinite(p.error) and p.seconds >= 0 and p.error >= 0
    ]


def pareto_front(points: Iterable[Point]) -> list[Point]:
    """The non-dominated points, fastest first (errors then strictly decrease).

    >>> pts = [Point("a", 1, 1.0, 0.5), Point("b", 1, 2.0, 0.6), Point("c", 2, 3.0, 0.1)]
    >>> [p.method for p in pareto_front(pts)]
    ['a', 'c']
    """
    ordered = sorted(_usable(points), key=lambda p: (p.seconds, p.error, p.method, p.spp))
    front: list[Point] = []
    for p in ordered:
        if not front or p.error < front[-1].error:
            if front and p.seconds == front[-1].seconds:
                front[-1] = p  # same time, lower error: it dominates
            else:
                front.append(p)
    return front


def log_budgets(seconds: Iterable[float], count: int = 8) -> tuple[float, ...]:
    """``count`` log-spaced budgets from the smallest to the largest positive time, rounded up
    to 3 significant digits (so the fastest point fits the first budget, every point the last).

    >>> log_budgets([1.0, 10.0, 100.0], count=3)
    (1.0, 10.0, 100.0)
    """
    vals = sorted(s for s in seconds if math.isfinite(s) and s > 0)
    if not vals:
        return ()
    lo, hi = vals[0], vals[-1]
    if count < 2 or hi <= lo:
        return (_round_up(hi),)
    raw = np.geomspace(lo, hi, count)
    return tuple(sorted({_round_up(float(v)) for v in raw}))


def _round3(v: float) -> float:
    return float(f"{v:.3g}")


def _round_up(v: float) -> float:
    r = _round3(v)
    if r < v:
        step = 10.0 ** (math.floor(math.log10(v)) - 2)
        r = float(f"{r + step:.3g}")
    return r


@dataclass(frozen=True)
class EqualTimeRow:
    """Best choices within one time budget.

    Attributes:
        budget: seconds available (render + denoise).
        best: the lowest-error point that fits, or ``None`` when nothing fits.
        runner_up: the best point of another method that fits, if any.
        noisy: the best plain rendering (method ``noisy_label``) that fits, if any.
        gain: ``noisy.error / best.error`` (how much lower the error is than plain rendering
            in the same budget), when both exist.
    """

    budget: float
    best: Point | None
    runner_up: Point | None = None
    noisy: Point | None = None
    gain: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "budget": self.budget,
            "best": None if self.best is None else self.best.to_dict(),
            "runner_up": None if self.runner_up is None else self.runner_up.to_dict(),
            "noisy": None if self.noisy is None else self.noisy.to_dict(),
            "gain": self.gain,
        }


def equal_time(
    points: Iterable[Point], budgets: Sequence[float], *, noisy_label: str = "noisy"
) -> list[EqualTimeRow]:
    """One :class:`EqualTimeRow` per budget (ascending).

    >>> pts = [Point("noisy", 4, 1.0, 0.4), Point("nlm", 1, 0.9, 0.1), Point("nlm", 4, 2.0, 0.05)]
    >>> [(r.budget, r.best.method, r.best.spp) for r in equal_time(pts, [1.0, 2.5])]
    [(1.0, 'nlm', 1), (2.5, 'nlm', 4)]
    >>> equal_time(pts, [1.0])[0].gain
    4.0
    """
    pts = _usable(points)
    rows = []
    for budget in sorted(budgets):
        fits = sorted(
            (p for p in pts if p.seconds <= budget), key=lambda p: (p.error, p.seconds, p.method)
        )
        best = fits[0] if fits else None
        runner = next((p for p in fits if best is not None and p.method != best.method), None)
        noisy = next((p for p in fits if p.method == noisy_label), None)
        gain = None
        if best is not None and noisy is not None and best.error > 0:
            gain = noisy.error / best.error
        rows.append(EqualTimeRow(float(budget), best, runner, noisy, gain))
    return rows
