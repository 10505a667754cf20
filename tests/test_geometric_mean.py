"""Tests of ``mcdenoise/geomean.py`` (named apart from tests/experiments/test_stats.py): the one
geometric mean, its values, and each ``invalid`` policy on empty, zero, negative, NaN/None and
infinite inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcdenoise.geomean import geometric_mean

NAN, INF = math.nan, math.inf


def test_values() -> None:
    assert geometric_mean([0.5, 2.0, 1.0]) == 1.0
    assert geometric_mean([4.0]) == 4.0
    assert geometric_mean([1e-3, 1e-1]) == pytest.approx(1e-2, rel=1e-15)
    # exp(mean(log v)) in float64 numpy, the same float as the formula written out
    rng = np.random.default_rng(0)
    v = np.exp(rng.normal(-5, 2, 37))
    assert geometric_mean(v) == float(np.exp(np.mean(np.log(v))))
    assert geometric_mean(list(v)) == geometric_mean(iter(v)) == geometric_mean(tuple(v))
    # at most the arithmetic mean, at least the minimum
    assert v.min() <= geometric_mean(v) <= v.mean()
    for policy in ("limit", "none", "raise"):
        assert geometric_mean([0.5, 2.0, 1.0], invalid=policy) == 1.0


def test_scale_and_ratio_properties() -> None:
    a, b = [0.2, 0.01, 3.0], [0.1, 0.04, 1.5]
    assert geometric_mean([10 * x for x in a]) == pytest.approx(10 * geometric_mean(a), rel=1e-14)
    ratios = [x / y for x, y in zip(a, b, strict=True)]
    assert geometric_mean(ratios) == pytest.approx(geometric_mean(a) / geometric_mean(b), rel=1e-14)


@pytest.mark.parametrize(
    ("values", "want"),
    [
        ([], NAN),  # no value: unknown
        ([0.3, NAN], NAN),
        ([NAN, 0.3], NAN),
        ([0.3, None], NAN),  # None is a missing value
        ([0.0, NAN], NAN),  # unknown wins over the exact match, in either order
        ([NAN, 0.0], NAN),
        ([0.3, 0.0], 0.0),  # one exact match: the limit of exp(mean(log v)) is 0
        ([0.3, -1.0], 0.0),  # below 0 (never a relMSE): counted like 0
        ([0.0, INF], 0.0),
        ([0.3, INF], INF),
        ([0.3, -INF], 0.0),
    ],
)
def test_limit_policy(values: list[float | None], want: float) -> None:
    got = geometric_mean(values)
    assert isinstance(got, float)
    assert (math.isnan(got) and math.isnan(want)) or got == want


@pytest.mark.parametrize(
    "values", [[], [0.3, NAN], [0.3, None], [0.3, 0.0], [0.3, -1.0], [0.3, INF], [None]]
)
def test_none_and_raise_policies_refuse_any_value_not_finite_and_positive(values) -> None:
    assert geometric_mean(values, invalid="none") is None
    with pytest.raises(ValueError, match="finite values > 0"):
        geometric_mean(values, invalid="raise")


def test_unknown_policy_is_refused() -> None:
    with pytest.raises(ValueError, match="invalid must be"):
        geometric_mean([1.0], invalid="skip")  # type: ignore[call-overload]
