"""The reference-free error estimate (mcdenoise/eval/estimate.py) on synthetic halves whose
truth is known: unbiased for linear and nonlinear filters under Gaussian, log-normal and rare
bright-outlier noise; candidate filters ranked per block like the true error in most blocks;
the half inputs and the refusals.

The synthetic images and candidate filters are those of ``benchmarks/bench_estimate.py
synthetic`` (loaded from there), at a smaller size.
"""

from __future__ import annotations

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.eval.estimate import (
    block_means,
    cross_error,
    estimate_error,
    estimate_from_outputs,
    half_error,
    split_halves,
    squared_error,
)
from mcdenoise.io import FeatureBuffers


@pytest.mark.parametrize("noise", ["gaussian", "lognormal", "outliers"])
def test_unbiased_and_ranks_blocks_like_the_truth(bench, noise) -> None:
    r = bench.synthetic_study(noise, trials=32, size=48, spp=8, block=16, seed=1)
    for name, z in r["bias_in_se"].items():
        assert abs(z) < 4, (noise, name, z)
    # 5 candidates: a random pick agrees in 20 % of the blocks and orders half of the pairs
    assert r["argmin_agree"] > 0.45, r
    assert r["pair_agree"] > 0.8, r


def test_the_bias_check_catches_a_wrong_construction(bench) -> None:
    """Leaving out the −¼(D_A − D_B)² term (averaging NFOR's per-half errors) estimates the
    error of a half-sample output, not of the mean of both: the same check flags it."""
    gen = torch.Generator().manual_seed(2)
    mu = bench.synthetic_truth(48)
    a, b, va, vb = bench.synthetic_halves(mu, 8, "gaussian", 32, gen)
    f = bench.candidate_filters()["gauss0.75"]
    da, db = f(a), f(b)
    true = ((da + db) / 2 - mu).square().mean(dim=(1, 2, 3))
    right = cross_error(da, db, a, b, va, vb).mean(dim=(1, 2, 3))
    wrong = (0.5 * (half_error(da, b, vb) + half_error(db, a, va))).mean(dim=(1, 2, 3))
    z = lambda d: float(d.mean() / (d.std() / len(d) ** 0.5))  # noqa: E731
    assert abs(z(right - true)) < 4
    assert z(wrong - true) > 5  # 30 % too high here


def test_identity_estimates_the_variance_of_the_noisy_mean() -> None:
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(3, 4, 5, generator=g), torch.rand(3, 4, 5, generator=g)
    va, vb = torch.rand(3, 4, 5, generator=g), torch.rand(3, 4, 5, generator=g)
    e = cross_error(a, b, a, b, va, vb)
    torch.testing.assert_close(e, 0.75 * (a - b) ** 2 - 0.5 * (va + vb))
    torch.testing.assert_close(squared_error(a, b, a, b), 0.25 * (a - b) ** 2)
    # Differences between candidates do not need the variances.
    c = cross_error(a * 0.5, b * 0.5, a, b) - cross_error(a, b, a, b)
    torch.testing.assert_close(c, cross_error(a * 0.5, b * 0.5, a, b, va, vb) - e)


def test_block_means_weight_partial_blocks() -> None:
    t = torch.arange(3 * 5 * 7, dtype=torch.float64).reshape(3, 5, 7)
    means, counts = block_means(t, 4)
    assert means.shape == (2, 2) and counts.tolist() == [[16, 12], [4, 3]]
    assert float((means * counts).sum() / counts.sum()) == pytest.approx(float(t.mean()))


def _halved(h: int = 24, w: int = 24, seed: int = 0) -> FeatureBuffers:
    g = torch.Generator().manual_seed(seed)
    a, b = torch.rand(3, h, w, generator=g), torch.rand(3, h, w, generator=g)
    albedo = torch.rand(3, h, w, generator=g)
    return FeatureBuffers(
        {
            "color": (a + b) / 2,
            "color_var": torch.full((3, h, w), 0.01),
            "color_a": a,
            "color_b": b,
            "color_a_var": torch.full((3, h, w), 0.02),
            "color_b_var": torch.full((3, h, w), 0.02),
            "albedo": albedo,
            "albedo_var": torch.full((3, h, w), 0.001),
            "albedo_a": albedo * 0.9,
            "albedo_b": albedo * 1.1,
            "normal": torch.rand(3, h, w, generator=g),
        },
        spp=8,
        source="x.exr",
    )


def test_split_halves_gives_plain_half_inputs() -> None:
    fb = _halved()
    ha, hb = split_halves(fb)
    for half, tag in ((ha, "a"), (hb, "b")):
        assert torch.equal(half["color"], fb[f"color_{tag}"])
        assert torch.equal(half["color_var"], fb[f"color_{tag}_var"])
        assert torch.equal(half["albedo"], fb[f"albedo_{tag}"])
        assert torch.equal(half["albedo_var"], 2 * fb["albedo_var"])  # no half variance given
        assert torch.equal(half["normal"], fb["normal"])  # not halved: shared
        assert half.spp == 4 and not any(n.endswith(("_a", "_b", "_a_var", "_b_var")) for n in half)
    plain = fb.subset(["color", "color_var", "albedo"])
    with pytest.raises(InputError, match=r"x\.exr: no half buffers \(color_a, color_b\)"):
        split_halves(plain)
    del fb.buffers["color_b"]
    with pytest.raises(InputError, match="color_a without color_b"):
        split_halves(fb)


def test_estimate_error_runs_the_denoiser_on_each_half() -> None:
    fb = _halved()
    seen = []

    def denoiser(x: FeatureBuffers) -> torch.Tensor:
        seen.append(x.spp)
        return x["color"] * 0 + x["color"].mean()

    est = estimate_error(denoiser, fb, block=8)
    assert seen == [4, 4] and est.judged == "halves-mean"
    da = fb["color_a"] * 0 + fb["color_a"].mean()
    db = fb["color_b"] * 0 + fb["color_b"].mean()
    again = estimate_from_outputs(da, db, fb, block=8)
    assert est.relmse == pytest.approx(again.relmse) and est.relmse_se > 0
    sq = squared_error(da, db, fb["color_a"], fb["color_b"])
    rel = (sq / (((da + db) / 2) ** 2 + 0.01)).mean()
    assert est.relmse == pytest.approx(max(float(rel), 0.0), rel=1e-5)
    full = estimate_from_outputs(da, db, fb, output=fb["color"], block=8)
    assert full.judged == "full" and full.to_dict()["estimate_of"] == "full"


def test_pseudo_reference_is_the_pixelwise_median() -> None:
    from mcdenoise.eval.estimate import pseudo_reference

    x = torch.tensor([1.0, 5.0, 2.0])[:, None, None, None] * torch.ones(3, 3, 2, 2)
    assert torch.equal(pseudo_reference(list(x)), torch.full((3, 2, 2), 2.0, dtype=torch.float64))
    # an even count: the mean of the middle two (two outputs: their mean), not torch's lower
    pr = pseudo_reference([x[0], x[1]])
    assert torch.equal(pr, torch.full((3, 2, 2), 3.0, dtype=torch.float64))
    # one output far off does not move it
    far = pseudo_reference([x[0], x[2], x[2] * 100])
    assert torch.equal(far, torch.full((3, 2, 2), 2.0, dtype=torch.float64))


def test_matched_normaliser_puts_back_what_the_denoiser_removed() -> None:
    from mcdenoise.eval.estimate import matched_normaliser

    out = torch.full((3, 9, 9), 0.5)
    assert torch.allclose(matched_normaliser(out, out), out.double())
    noisy = out.clone()
    noisy[:, 4, 4] = 25.5  # a highlight bright in the input, gone from the output
    n = matched_normaliser(out, noisy)
    # spread over the 5x5 window around it, its energy kept; untouched farther away
    assert torch.allclose(n[:, 2:7, 2:7], torch.full((3, 5, 5), 1.5, dtype=torch.float64))
    assert torch.allclose(n[:, 0], torch.full((3, 9), 0.5, dtype=torch.float64))
    assert float(n.sum()) == pytest.approx(float(noisy.double().sum()))


def test_difference_form_is_spread_plus_product_of_residuals() -> None:
    """``ê = ¼(D_A − D_B)² + (A − D_A)(B − D_B)`` (the module docstring's decomposition)."""
    g = torch.Generator().manual_seed(3)
    a, b, da, db = (torch.rand(3, 5, 5, generator=g, dtype=torch.float64) for _ in range(4))
    want = 0.25 * (da - db).square() + (a - da) * (b - db)
    torch.testing.assert_close(squared_error(da, db, a, b), want)
