"""Tests of mcdenoise.prep.inputs: filter inputs from FeatureBuffers (extent, prefilter,
robust and estimated variance, demodulation)."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.filters.albedo import demodulate, demodulated_variance
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.prep.inputs import (
    FilterInputs,
    demodulate_inputs,
    estimate_feature_variance,
    estimate_variance,
    prefilter_feature,
    prepare_inputs,
    robust_variance,
)


def test_depth_and_position_are_divided_by_the_scene_extent() -> None:
    h, w = 20, 30
    ys, xs = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 2, w), indexing="ij")
    position = torch.stack([xs, ys, torch.zeros_like(xs)])  # a 2 x 1 plane
    depth = (1.0 + xs).unsqueeze(0)
    normal = torch.nn.functional.normalize(torch.rand(3, h, w), dim=0)
    albedo = torch.rand(3, h, w)
    fb = FeatureBuffers(
        buffers={
            "color": torch.rand(3, h, w),
            "position": position,
            "depth": depth,
            "normal": normal,
            "albedo": albedo,
        }
    )
    inp = prepare_inputs(fb)
    assert isinstance(inp, FilterInputs)
    assert inp.extent == pytest.approx(5**0.5, rel=0.03)  # diagonal of the 1st-99th pct box
    torch.testing.assert_close(inp.features["position"][0], position / inp.extent)
    torch.testing.assert_close(inp.features["depth"][0], depth / inp.extent)
    assert torch.equal(inp.features["normal"][0], normal)  # as they are
    assert torch.equal(inp.features["albedo"][0], albedo)  # no variance: not prefiltered
    assert list(inp.features) == ["albedo", "normal", "depth", "position"]
    assert inp.estimated_variance and inp.color_var.shape == (1, 1, h, w)


def test_feature_with_variance_is_prefiltered(scene) -> None:
    g = torch.Generator().manual_seed(1)
    noisy_albedo = scene.albedo + 0.05 * torch.randn(
        scene.albedo.shape, generator=g, dtype=torch.float64
    )
    fb = FeatureBuffers(
        buffers={
            "color": scene.noisy[0].float(),
            "color_var": scene.var[0].float(),
            "albedo": noisy_albedo[0].float(),
            "albedo_var": torch.full((1, 32, 32), 0.05**2),
        }
    )
    inp = prepare_inputs(fb)
    err_raw = float((noisy_albedo - scene.albedo).square().mean())
    err_pre = float((inp.features["albedo"].double() - scene.albedo).square().mean())
    assert err_pre < 0.5 * err_raw
    assert torch.equal(inp.albedo, inp.features["albedo"])  # demodulation uses the same
    raw = prepare_inputs(fb, prefilter=False)
    torch.testing.assert_close(raw.features["albedo"][0], noisy_albedo[0].float())


def test_feature_variance_estimate_is_local_and_ignores_sharp_edges() -> None:
    g = torch.Generator().manual_seed(3)
    h, w = 48, 64
    # a sharp step (vertical edge), a diagonal edge and a corner: noise-free
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    clean = ((xs > 20).double() * 0.6 + (xs + ys > 50).double() * 0.3 + 0.05)[None, None]
    clean = clean.expand(1, 3, h, w).clone()
    sigma = 0.1
    noisy = clean.clone()
    noisy[..., :, 40:] += sigma * torch.randn((1, 3, h, w - 40), generator=g, dtype=torch.float64)
    v = estimate_feature_variance(noisy)
    assert v.shape == (1, 1, h, w) and v.dtype == torch.float64
    # per channel the details have variance sigma^2; their channel mean has sigma^2 too
    inside = float(v[..., 4:-4, 44:-4].mean())
    assert 0.6 * sigma**2 < inside < 1.5 * sigma**2
    # the noise-free part, edges and corner included, reads (nearly) as noise-free
    assert float(v[..., :, :36].max()) < 0.05 * sigma**2
    v_clean = estimate_feature_variance(clean)
    assert float(v_clean.max()) < 1e-12
    torch.testing.assert_close(prefilter_feature(clean, v_clean), clean)  # edges kept


def test_feature_without_variance_is_prefiltered_only_when_asked(scene) -> None:
    g = torch.Generator().manual_seed(2)
    noisy_albedo = scene.albedo.clone()
    noise = 0.08 * torch.randn(scene.albedo.shape, generator=g, dtype=torch.float64)
    noisy_albedo[..., :, 16:] += noise[..., :, 16:]  # the right half is noisy (defocused)
    noisy_albedo = noisy_albedo.clamp(0, 1)  # as a renderer writes it (sanitising clamps at 0)
    normal = torch.nn.functional.normalize(torch.rand(3, 32, 32, generator=g), dim=0)
    fb = FeatureBuffers(
        buffers={
            "color": scene.noisy[0].float(),
            "albedo": noisy_albedo[0].float(),
            "normal": normal,
        }
    )
    raw = prepare_inputs(fb, prefilter=True)  # no variance buffer: as it is
    assert torch.equal(raw.features["albedo"][0], noisy_albedo[0].float())
    assert raw.estimated_features == ()
    inp = prepare_inputs(fb, estimate_missing=True)
    assert inp.estimated_features == ("albedo", "normal")
    assert "albedo" not in inp.feature_vars  # the estimate is not a renderer's variance
    assert torch.equal(inp.albedo, inp.features["albedo"])  # demodulation uses the same
    err = (inp.features["albedo"].double() - scene.albedo).square()
    err_raw = (noisy_albedo - scene.albedo).square()
    assert float(err[..., 18:].mean()) < 0.5 * float(err_raw[..., 18:].mean())
    # the noise-free half keeps its values (far from the noisy half)
    torch.testing.assert_close(
        inp.features["albedo"][..., :, :10], noisy_albedo[..., :, :10].float(), atol=2e-3, rtol=0
    )


def test_robust_variance_lifts_dropouts_and_keeps_outliers_local() -> None:
    v = torch.full((1, 3, 9, 9), 0.01)
    v[..., 4, 4] = 0.0  # an estimate that came out 0
    v[..., 2, 6] = 5.0  # a firefly's variance
    out = robust_variance(v)
    assert out.shape == (1, 1, 9, 9)
    assert float(out[0, 0, 4, 4]) == pytest.approx(0.01)
    assert float(out[0, 0, 2, 6]) == pytest.approx(5.0)
    neighbours = out[0, 0, 1:4, 5:8].flatten().tolist()
    assert sorted(neighbours)[-2] == pytest.approx(0.01)  # not spread to its neighbours


def test_estimate_variance_tracks_heteroscedastic_noise() -> None:
    g = torch.Generator().manual_seed(2)
    h, w = 64, 64
    mean = torch.full((1, 3, h, w), 0.2)
    mean[..., :, w // 2 :] = 2.0
    sigma = torch.full((1, 1, h, w), 0.02)
    sigma[..., :, w // 2 :] = 0.2  # brighter -> noisier
    noisy = (mean + sigma * torch.randn(1, 3, h, w, generator=g)).clamp_min(0)
    est = estimate_variance(noisy)
    assert est.shape == (1, 1, h, w)
    dark = float(est[..., :, 4 : w // 2 - 4].median())
    bright = float(est[..., :, w // 2 + 4 : -4].median())
    assert dark == pytest.approx(0.02**2, rel=0.35)
    assert bright == pytest.approx(0.2**2, rel=0.35)


def test_estimate_variance_flags_fireflies() -> None:
    g = torch.Generator().manual_seed(3)
    noisy = 0.5 + 0.02 * torch.randn(1, 3, 32, 32, generator=g)
    noisy[..., 10, 20] = 50.0
    est = estimate_variance(noisy)
    assert float(est[0, 0, 10, 20]) > 1000 * float(est.median())
    assert float(est[0, 0, 10, 21]) < 10 * float(est.median())


def test_demodulation_divides_by_albedo_plus_eps_and_is_off_without_albedo(scene) -> None:
    fb = FeatureBuffers(
        {
            "color": scene.noisy[0].float(),
            "color_var": scene.var[0].float(),
            "albedo": scene.albedo[0].float(),
        },
        spp=16,
    )
    inp = prepare_inputs(fb, prefilter=False)
    irr, var, factor = demodulate_inputs(inp, eps=0.01)
    assert factor is not None
    torch.testing.assert_close(irr * factor, inp.color)
    torch.testing.assert_close(factor, inp.albedo + 0.01)
    torch.testing.assert_close(var, inp.color_var / factor.square().mean(1, keepdim=True))
    # the same function the kpcn network uses on its prepared tensors
    irr2, factor2 = demodulate(inp.color, inp.albedo)
    assert torch.equal(irr2, irr) and torch.equal(factor2, factor)
    assert torch.equal(demodulated_variance(inp.color_var, factor2), var)
    # disabled, or no albedo: the colour itself, no remodulation
    for off in (
        demodulate_inputs(inp, enabled=False),
        demodulate_inputs(FilterInputs(inp.color, inp.color_var)),
    ):
        assert off[0] is inp.color and off[1] is inp.color_var and off[2] is None
    ones_irr, ones = demodulate(inp.color, None)
    assert torch.equal(ones_irr, inp.color) and bool((ones == 1).all())
