"""Tests of ``mcdenoise/experiments/quality.py``: equal quality against a known 1/N law, and
the reference's noise floor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mcdenoise.eval.metrics import relative_squared_error, relmse
from mcdenoise.experiments.quality import (
    ABOVE_LADDER,
    BELOW_LADDER,
    NoisyCurve,
    equal_quality,
    equal_quality_spp,
    limited_by_reference,
    loglog_slope,
    reference_noise_floor,
)

LADDER = (1, 2, 4, 8, 16)
C = 0.8  # relMSE of 1 spp
RATE = 0.05  # seconds per spp


def exact_curve(c: float = C, ladder=LADDER) -> NoisyCurve:
    return NoisyCurve(ladder, tuple(c / n for n in ladder), tuple(RATE * n for n in ladder))


@pytest.mark.parametrize("n", [1, 1.5, 3, 5.5, 8, 11, 16])
def test_inside_the_ladder_the_exact_spp_is_recovered(n):
    got, flag = equal_quality_spp(exact_curve(), C / n)
    assert flag is None
    assert got == pytest.approx(n, rel=1e-12)


@pytest.mark.parametrize("n", [17, 32, 100, 1e4])
def test_beyond_the_ladder_the_one_over_n_law_is_used_and_flagged(n):
    got, flag = equal_quality_spp(exact_curve(), C / n)
    assert flag == ABOVE_LADDER
    assert got == pytest.approx(n, rel=1e-12)


def test_worse_than_the_lowest_level_is_flagged_below_the_ladder():
    got, flag = equal_quality_spp(exact_curve(), 2 * C)
    assert flag == BELOW_LADDER and got == pytest.approx(0.5)


def test_seconds_and_speedup_use_the_measured_rate_of_plain_rendering():
    curve = exact_curve()
    assert curve.seconds_per_spp == pytest.approx(RATE)
    eq = equal_quality(curve, C / 64, total_seconds=0.4)
    assert eq.spp == pytest.approx(64) and eq.extrapolated == ABOVE_LADDER
    assert eq.seconds == pytest.approx(64 * RATE)
    assert eq.speedup == pytest.approx(64 * RATE / 0.4)
    # a method exactly as good as plain rendering at its own spp and cost has speed-up 1
    same = equal_quality(curve, C / 8, total_seconds=8 * RATE)
    assert same.speedup == pytest.approx(1.0) and same.extrapolated is None


def test_zero_error_needs_infinitely_many_samples():
    eq = equal_quality(exact_curve(), 0.0, total_seconds=1.0)
    assert math.isinf(eq.spp) and eq.speedup == math.inf and eq.extrapolated == ABOVE_LADDER
    with pytest.raises(ValueError):
        equal_quality_spp(exact_curve(), -1.0)


def test_a_wiggling_curve_uses_the_first_bracketing_segment():
    # the error rises again at 16 spp (e.g. the reference's noise): 0.06 is first reached
    # between 4 and 8 spp, not between 8 and 16
    curve = NoisyCurve((4, 8, 16), (0.08, 0.05, 0.07), (1.0, 2.0, 4.0))
    got, flag = equal_quality_spp(curve, 0.06)
    assert flag is None and 4 < got < 8
    # below the lowest measured error: anchored at the *highest* level, as documented
    got, flag = equal_quality_spp(curve, 0.035)
    assert flag == ABOVE_LADDER and got == pytest.approx(16 * 0.07 / 0.035)


def test_slope_and_fit_of_the_noisy_curve():
    curve = exact_curve()
    assert curve.slope() == pytest.approx(-1.0)
    assert curve.one_over_n() == pytest.approx(C)
    # c is the geometric mean of e·N: the best fit of e = c / N in log space
    rough = NoisyCurve((1, 4), (0.8, 0.05), (1.0, 4.0))
    assert rough.one_over_n() == pytest.approx(math.sqrt(0.8 * 0.2), rel=1e-14)
    assert loglog_slope([4], [0.1]) is None
    with pytest.raises(ValueError):
        NoisyCurve((1, 2), (0.1, 0.0), (1.0, 2.0))
    with pytest.raises(ValueError):
        NoisyCurve((2, 1), (0.1, 0.2), (1.0, 2.0))


def test_monte_carlo_images_follow_the_law_and_a_halved_variance_is_worth_twice_the_spp():
    """Simulated pixels: level n has noise variance s²/n. A 'denoiser' that halves the noise
    variance at n spp must be worth about 2n spp of plain rendering."""
    rng = np.random.default_rng(3)
    h, w, s = 96, 96, 0.4
    clean = 0.5 + 0.3 * rng.random((3, h, w))
    ladder = (1, 2, 4, 8, 16, 32)
    errs = [relmse(clean + rng.normal(0, s / math.sqrt(n), clean.shape), clean) for n in ladder]
    curve = NoisyCurve(ladder, tuple(errs), tuple(0.01 * n for n in ladder))
    assert curve.slope() == pytest.approx(-1.0, abs=0.03)
    for n in (2, 4, 8):
        halved = clean + rng.normal(0, s / math.sqrt(2 * n), clean.shape)
        got, flag = equal_quality_spp(curve, relmse(halved, clean))
        assert flag is None
        assert got == pytest.approx(2 * n, rel=0.06)


def test_noise_floor_of_a_known_variance():
    ref = np.full((3, 4, 5), 2.0)
    var = np.full((3, 4, 5), 0.0404)
    assert reference_noise_floor(ref, var) == pytest.approx(0.0404 / 4.01)
    # a luminance variance (one channel) applies to every channel
    assert reference_noise_floor(ref, var[:1]) == pytest.approx(0.0404 / 4.01)
    # black pixels: ε keeps the floor finite
    assert reference_noise_floor(np.zeros((3, 2, 2)), np.full((1, 2, 2), 1e-4)) == pytest.approx(
        1e-2
    )
    with pytest.raises(ValueError):
        reference_noise_floor(ref, var[:, :2])


def test_noise_floor_ignores_nonfinite_terms_and_clamps_negative_variances():
    ref = np.full((1, 2, 2), 1.0).repeat(3, axis=0)
    var = np.full((1, 2, 2), 0.0101)
    var[0, 0, 0] = np.nan  # a NaN variance: its terms are left out of the mean
    var[0, 0, 1] = -1.0  # a negative variance (a bad estimate) counts as 0
    assert reference_noise_floor(ref, var) == pytest.approx((0.0 + 0.01 + 0.01) / 3)
    # it is the metrics' relMSE normalisation applied to the variance
    ref2, var2 = np.full((3, 2, 2), 0.5), np.full((3, 2, 2), 0.02)
    assert reference_noise_floor(ref2, var2) == float(np.mean(relative_squared_error(var2, ref2)))
    assert math.isnan(reference_noise_floor(ref, np.full((1, 2, 2), np.nan)))


def test_noise_floor_predicts_the_error_of_a_noisy_reference():
    """The floor is the relMSE the reference has against the truth: check it by simulation."""
    rng = np.random.default_rng(5)
    truth = 0.2 + rng.random((3, 128, 128))
    var = np.full_like(truth, 0.01)
    ref = truth + rng.normal(0, 0.1, truth.shape)
    assert relmse(ref, truth) == pytest.approx(reference_noise_floor(truth, var), rel=0.05)


def test_limited_by_reference():
    assert limited_by_reference(0.019, 0.01) and not limited_by_reference(0.021, 0.01)
    assert not limited_by_reference(None, 0.01) and not limited_by_reference(0.001, None)


def test_noisy_rises_find_the_firefly_jump_of_the_issue():
    from mcdenoise.experiments.quality import noisy_rises

    # caustics_glass in the demo: 177 -> 44.7 -> 119 relMSE from 1 to 4 spp, then falling
    c = NoisyCurve((1, 2, 4, 8, 16), (177.0, 44.7, 119.0, 30.2, 22.1), (0.1, 0.2, 0.4, 0.8, 1.6))
    assert noisy_rises(c) == [(2, 44.7, 4, 119.0)]
    # a monotone curve, and a wiggle within 2x the reference's noise floor, are not flagged
    assert noisy_rises(NoisyCurve((1, 2, 4), (0.8, 0.4, 0.2), (1.0, 2.0, 4.0))) == []
    wiggle = NoisyCurve((1, 2, 4), (0.8, 0.010, 0.011), (1.0, 2.0, 4.0))
    assert noisy_rises(wiggle, floor=0.006) == []
    assert noisy_rises(wiggle, floor=0.001) == [(2, 0.010, 4, 0.011)]
