"""Tests of ``mcdenoise/experiments/stats.py``: bootstrap intervals, verdicts and wins."""

from __future__ import annotations

import numpy as np
import pytest

from mcdenoise.experiments.stats import (
    BETTER,
    IS_BASELINE,
    SINGLE,
    UNCLEAR,
    WORSE,
    bootstrap_geomean_ci,
    compare_methods,
    wins,
)
from mcdenoise.geomean import geometric_mean

SCENES = [f"s{i}" for i in range(8)]


def table(ratios: dict[str, list[float]], base: list[float]) -> dict:
    errors = {}
    for i, scene in enumerate(SCENES):
        errors[(scene, 4, "base")] = base[i]
        for method, r in ratios.items():
            errors[(scene, 4, method)] = base[i] * r[i]
    return errors


def stats_by_method(errors, seed=0, resamples=2000):
    rows = compare_methods(
        errors,
        scenes=SCENES,
        methods=["base", *sorted({m for (_, _, m) in errors} - {"base"})],
        spps=[4],
        baseline="base",
        resamples=resamples,
        seed=seed,
    )
    return {r.method: r for r in rows}


def test_bootstrap_interval_contains_the_geometric_mean_and_is_seeded():
    r = [0.5, 0.7, 0.6, 0.9, 0.55]
    point, lo, hi = bootstrap_geomean_ci(r, rng=np.random.default_rng(1))
    assert point == pytest.approx(float(np.exp(np.mean(np.log(r)))))
    assert min(r) <= lo <= point <= hi <= max(r)
    again = bootstrap_geomean_ci(r, rng=np.random.default_rng(1))
    assert again == (point, lo, hi)
    wider = bootstrap_geomean_ci(r, confidence=0.99, rng=np.random.default_rng(1))
    assert wider[1] <= lo and wider[2] >= hi
    with pytest.raises(ValueError):
        bootstrap_geomean_ci([0.5, 0.0])
    with pytest.raises(ValueError):
        bootstrap_geomean_ci([])
    for bad in ([0.5, float("nan")], [0.5, float("inf")], [-0.5]):
        with pytest.raises(ValueError):
            bootstrap_geomean_ci(bad)
    assert bootstrap_geomean_ci([0.5, 2.0])[0] == geometric_mean([0.5, 2.0]) == 1.0


def test_mean_and_geometric_mean_over_scenes():
    errors = {("s0", 4, "base"): 0.2, ("s1", 4, "base"): 0.3, ("s0", 4, "m"): 0.1}
    errors[("s1", 4, "m")] = 0.4
    (m,) = compare_methods(errors, scenes=["s0", "s1"], methods=["m"], spps=[4], baseline="base")
    assert m.mean_relmse == pytest.approx(0.25) and m.geomean_relmse == pytest.approx(0.2)
    # an exact match (error 0): the mean counts it, the geometric mean has none (not 0)
    errors[("s1", 4, "m")] = 0.0
    (m,) = compare_methods(errors, scenes=["s0", "s1"], methods=["m"], spps=[4], baseline="base")
    assert m.scenes == 2 and m.mean_relmse == pytest.approx(0.05) and m.geomean_relmse is None


def test_a_consistent_halving_is_better_and_a_doubling_worse():
    rng = np.random.default_rng(0)
    base = list(0.01 + rng.random(8))
    s = stats_by_method(
        table(
            {
                "half": [0.5 * (1 + 0.05 * rng.standard_normal()) for _ in SCENES],
                "double": [2.0] * 8,
            },
            base,
        )
    )
    assert s["half"].verdict == BETTER and s["half"].ci_high < 1
    assert s["half"].ratio == pytest.approx(0.5, rel=0.1)
    assert s["double"].verdict == WORSE and s["double"].ci_low > 1
    assert s["base"].verdict == IS_BASELINE and s["base"].ratio is None
    assert s["half"].wins == 8 and s["half"].beats_baseline == 8
    assert s["double"].wins == 0 and s["double"].beats_baseline == 0


def test_a_half_percent_difference_with_scatter_is_not_an_improvement():
    rng = np.random.default_rng(2)
    base = list(0.01 + rng.random(8))
    # 0.5 % better on average, but scene-to-scene scatter of 10 %
    r = list(0.995 * np.exp(0.1 * rng.standard_normal(8)))
    s = stats_by_method(table({"tiny": r}, base))["tiny"]
    assert s.verdict == UNCLEAR and s.ci_low < 1 < s.ci_high


def test_results_do_not_depend_on_the_order_of_the_methods():
    rng = np.random.default_rng(4)
    base = list(0.01 + rng.random(8))
    errors = table({"a": list(rng.random(8) + 0.5), "b": list(rng.random(8) + 0.5)}, base)
    one = compare_methods(errors, scenes=SCENES, methods=["a", "b"], spps=[4], baseline="base")
    two = compare_methods(errors, scenes=SCENES, methods=["b", "a"], spps=[4], baseline="base")
    assert {r.method: r for r in one} == {r.method: r for r in two}


def test_missing_and_single_scenes():
    errors = {("s0", 4, "base"): 0.2, ("s0", 4, "m"): 0.1, ("s1", 4, "base"): 0.3}
    rows = compare_methods(errors, scenes=["s0", "s1"], methods=["m"], spps=[4], baseline="base")
    (m,) = rows
    assert m.scenes == 1 and m.verdict == SINGLE and m.ratio == m.ci_low == m.ci_high == 0.5
    errors[("s0", 4, "m")] = float("nan")  # a failed output is left out, never averaged
    (m,) = compare_methods(errors, scenes=["s0", "s1"], methods=["m"], spps=[4], baseline="base")
    assert m.scenes == 0 and m.ratio is None and m.mean_relmse is None


def test_wins_count_ties_for_each():
    errors = {("a", 1, "x"): 0.1, ("a", 1, "y"): 0.1, ("b", 1, "x"): 0.3, ("b", 1, "y"): 0.2}
    assert wins(errors, ["a", "b"], 1) == {"x": 1, "y": 2}
