"""Issue 36: guides shared by both halves bias the two-buffer estimate low; the renderer
halves them, a file that shares them is estimated with a warning and a measured check, and an
estimate below its own noise is an upper bound, never a silent 0."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.eval.estimate import (
    SHARED_WARNING,
    estimate_from_outputs,
    estimate_record,
    format_estimates,
    shown_value,
    upper_bound,
)
from mcdenoise.io import FeatureBuffers
from mcdenoise.io.buffers import shared_guides


def test_shared_noisy_guides_bias_the_estimate_and_halved_ones_do_not(bench) -> None:
    """A sub-pixel texture: the albedo is as noisy as the colour. Filters guided by the full
    buffer's albedo get estimates far below the truth (below zero here); guided by each
    half's own albedo, the estimate is unbiased."""
    r = bench.shared_guides_study(trials=16, size=48, spp=4, seed=3)
    for name, by in r.items():
        z_shared, q_shared = by["shared"]
        z_halved, q_halved = by["halved"]
        assert z_shared < -10 and q_shared < 0.5, (name, by)
        assert abs(z_halved) < 4 and 0.8 < q_halved < 1.25, (name, by)


def _textured_buffers(bench, halved: bool, seed: int = 0) -> FeatureBuffers:
    gen = torch.Generator().manual_seed(seed)
    _mu, a, b, ga, gb = bench.textured_samples(32, 4, 1, gen)
    a, b, ga, gb = (t[0].float() for t in (a, b, ga, gb))
    var = ((a - b) ** 2 / 2).clamp_min(1e-6)
    bufs = {
        "color": (a + b) / 2,
        "color_var": var / 2,
        "color_a": a,
        "color_b": b,
        "albedo": (ga + gb) / 2,
        "albedo_var": ((ga - gb) ** 2 / 4).clamp_min(1e-6),
        "depth": torch.ones(1, 32, 32),
        "depth_var": torch.zeros(1, 32, 32),
    }
    if halved:
        bufs |= {"albedo_a": ga, "albedo_b": gb}
    return FeatureBuffers(bufs, spp=4)


def test_shared_guides_are_the_noisy_features_not_halved(bench) -> None:
    shared = _textured_buffers(bench, halved=False)
    assert shared_guides(shared) == ["albedo"]  # depth has zero variance: noise-free
    assert shared_guides(shared, reads=("color", "normal")) == []
    assert shared_guides(_textured_buffers(bench, halved=True)) == []
    shared.buffers.pop("depth_var")  # noise unknown: counted as shared
    assert shared_guides(shared) == ["albedo", "depth"]
    shared.buffers.pop("color_b")
    shared.buffers.pop("color_a")
    assert shared_guides(shared) == []  # no colour halves: nothing is estimated from them


def test_estimate_record_warns_and_measures_shared_guides(bench) -> None:
    demodulate = bench.guided_filters()["demodulate"]

    def denoiser(fb: FeatureBuffers) -> torch.Tensor:
        return demodulate(fb["color"][None].double(), fb["albedo"][None].double())[0].float()

    fb = _textured_buffers(bench, halved=False)
    out = denoiser(fb)
    rec = estimate_record(denoiser, fb, out, method="demod", reads=("color", "albedo"))
    assert rec["estimate_warning"] == SHARED_WARNING.format("albedo")
    # the check: with the shared guide smoothed, less of the other half's noise reaches the
    # filter and the (low) estimate rises
    shown = rec["relmse_estimated"] or rec["relmse_estimated_upper"]
    assert rec["relmse_estimated_smoothed_guides"] > shown
    clean = estimate_record(denoiser, _textured_buffers(bench, halved=True), out)
    assert "estimate_warning" not in clean and "relmse_estimated_smoothed_guides" not in clean


def test_an_estimate_below_its_noise_is_an_upper_bound_never_zero() -> None:
    g = torch.Generator().manual_seed(5)
    a = 0.5 + 0.2 * torch.randn(3, 32, 32, generator=g)
    b = 0.5 + 0.2 * torch.randn(3, 32, 32, generator=g)
    fb = FeatureBuffers({"color": (a + b) / 2, "color_a": a, "color_b": b}, spp=4)
    # a "filter" that returns the other half: ê = −¾(A − B)², far below zero
    est = estimate_from_outputs(b, a, fb, block=8)
    assert est.relmse == 0.0 and est.upper is not None and est.upper > 0
    assert est.upper == pytest.approx(2 * est.relmse_se)
    d = est.to_dict()
    assert d["relmse_estimated"] is None and d["relmse_estimated_upper"] == est.upper
    row = {**d, "scene": "s", "method": "m", "spp": 4, "note": "", "normaliser": ""}
    assert shown_value(row) == f"< {est.upper:.3g}"
    table = format_estimates([row])
    assert f"< {est.upper:.3g}" in table and " 0 " not in table
    # a clear estimate stays a value (a flat grey of 0.3 where the truth is 0.5)
    flat = torch.full_like(a, 0.3)
    good = estimate_from_outputs(flat, flat, fb, block=8)
    assert good.upper is None and good.to_dict()["relmse_estimated"] == good.relmse > 0
    assert upper_bound(0.3, 0.1) is None and upper_bound(0.05, 0.1) == pytest.approx(0.25)
    assert upper_bound(-0.4, 0.1) == pytest.approx(0.2)
