"""Tests of ``mcdenoise/experiments/tradeoff.py``: Pareto fronts and equal-time tables."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from mcdenoise.experiments.tradeoff import Point, equal_time, log_budgets, pareto_front


def random_points(seed: int, n: int = 40) -> list[Point]:
    rng = np.random.default_rng(seed)
    return [
        Point(f"m{rng.integers(4)}", int(2 ** rng.integers(6)), float(t), float(e))
        for t, e in zip(rng.random(n) * 10, rng.random(n))
    ]


def dominates(a: Point, b: Point) -> bool:
    return (
        a.seconds <= b.seconds
        and a.error <= b.error
        and (a.seconds, a.error) != (b.seconds, b.error)
    )


@pytest.mark.parametrize("seed", range(5))
def test_front_is_exactly_the_non_dominated_points(seed):
    pts = random_points(seed)
    front = pareto_front(pts)
    assert front, "a non-empty set has a non-empty front"
    for p in front:  # nothing dominates a front point
        assert not any(dominates(q, p) for q in pts)
    for p in pts:  # everything else is dominated by a front point (or equal to one)
        if p not in front:
            assert any(
                dominates(f, p) or (f.seconds, f.error) == (p.seconds, p.error) for f in front
            )
    assert [p.seconds for p in front] == sorted(p.seconds for p in front)
    assert all(b.error < a.error for a, b in itertools.pairwise(front))


def test_front_ignores_unusable_points_and_keeps_the_better_of_equal_times():
    pts = [
        Point("a", 1, 1.0, 0.5),
        Point("b", 1, 1.0, 0.4),
        Point("nan", 1, 0.5, math.nan),
        Point("inf", 1, math.inf, 0.01),
    ]
    assert [p.method for p in pareto_front(pts)] == ["b"]


@pytest.mark.parametrize("seed", range(3))
def test_equal_time_picks_the_most_accurate_point_that_fits(seed):
    pts = random_points(seed)
    budgets = [0.5, 2.0, 5.0, 20.0]
    rows = equal_time(pts, budgets, noisy_label="m0")
    assert [r.budget for r in rows] == budgets
    for row in rows:
        fits = [p for p in pts if p.seconds <= row.budget]
        if not fits:
            assert row.best is None
            continue
        assert row.best.seconds <= row.budget
        assert row.best.error == min(p.error for p in fits)
        if row.runner_up is not None:
            assert row.runner_up.method != row.best.method and row.runner_up.seconds <= row.budget
        noisy = [p for p in fits if p.method == "m0"]
        if noisy:
            assert row.noisy.error == min(p.error for p in noisy)
            assert row.gain == pytest.approx(row.noisy.error / row.best.error)
    # a larger budget never gives a worse best error
    errs = [r.best.error for r in rows if r.best is not None]
    assert errs == sorted(errs, reverse=True)


def test_nothing_fits_a_tiny_budget():
    (row,) = equal_time([Point("a", 1, 1.0, 0.1)], [0.1])
    assert row.best is None and row.noisy is None and row.gain is None


def test_log_budgets_cover_every_time():
    times = [0.013, 0.2, 1.7, 33.3]
    b = log_budgets(times, count=6)
    assert len(b) == 6 and list(b) == sorted(b)
    assert b[0] == pytest.approx(0.013) and b[-1] >= max(times)
    assert log_budgets([0.012345, 1.0], count=3)[0] >= 0.012345  # rounded up: the fastest fits
    ratios = np.diff(np.log(b))
    assert np.allclose(ratios, ratios.mean(), rtol=0.05)  # log-spaced (up to rounding)
    assert log_budgets([]) == ()
    assert log_budgets([2.0, 2.0]) == (2.0,)
