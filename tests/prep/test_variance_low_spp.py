"""The low-spp colour variance (mcdenoise/prep/variance.py) and its use by prepare_inputs."""

from __future__ import annotations

import torch

from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.prep.inputs import prepare_inputs
from mcdenoise.prep.variance import MAX_SPP, PRIOR_DOF, low_spp_variance, pooled_variance


def _two_sample_estimates(true_var: torch.Tensor, seed: int = 0) -> torch.Tensor:
    """Variance-of-the-mean estimates from 2 Gaussian samples per pixel: each is
    ``true_var · χ²₁`` (one degree of freedom), as noisy as a 2-spp render's."""
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(true_var.shape, generator=g, dtype=true_var.dtype)
    return true_var * z.square()


def test_at_two_spp_the_estimate_follows_the_noise_level_not_the_samples() -> None:
    true = torch.full((1, 1, 48, 48), 0.04)
    raw = _two_sample_estimates(true)
    out = low_spp_variance(raw, 2)
    # the raw estimate is off by a factor of 2 or more on most pixels; the shrunk one is not
    raw_far = float(((raw / true).log().abs() > 0.7).double().mean())
    out_far = float(((out / true).log().abs() > 0.7).double().mean())
    assert raw_far > 0.5
    assert out_far < 0.1
    # and it keeps the level on average (a mean is pooled, not a median, which would put
    # the chi-square's median, 0.45 of the mean, everywhere)
    assert abs(float(out.mean() / raw.mean()) - 1) < 0.01


def test_the_correction_fades_as_samples_grow() -> None:
    true = torch.full((1, 1, 32, 32), 0.04)
    raw = _two_sample_estimates(true, seed=1)
    pooled = pooled_variance(raw)
    prev = None
    for spp in (2, 3, 4, 6, 8):
        moved = float((low_spp_variance(raw, spp) - raw).abs().max())
        bound = PRIOR_DOF / (spp - 1 + PRIOR_DOF) * float((pooled - raw).abs().max())
        assert moved <= bound * 1.0001
        if prev is not None:
            assert moved < prev
        prev = moved
    for spp in (MAX_SPP + 1, 16, 64):  # enough samples: the pixel's own estimate
        assert torch.equal(low_spp_variance(raw, spp), raw)
    assert torch.equal(low_spp_variance(raw, None), raw)  # spp unknown: untouched
    assert torch.equal(low_spp_variance(raw, 2, prior_dof=0), raw)


def test_a_dark_pixel_beside_a_light_on_the_same_surface_borrows_nothing() -> None:
    """The light shares the ceiling's albedo and normal; its edge pixels are noisy. Pooled by
    relative variance and level, the dark ceiling keeps its own quiet level."""
    lum = torch.full((1, 1, 16, 16), 0.05)
    lum[..., :, 8:] = 20.0
    var = (0.1 * lum) ** 2
    var[..., :, 8] = 50.0  # the light's anti-aliased edge
    out = low_spp_variance(var, 2, luminance=lum)
    assert torch.allclose(out[..., :, :7], var[..., :, :7], rtol=1e-3)
    assert float(low_spp_variance(var, 2)[0, 0, 5, 6]) > 1.0  # without the luminance it would


def test_no_pooling_across_an_albedo_edge_and_excluded_pixels_lend_nothing() -> None:
    var = torch.full((1, 1, 16, 16), 1.0)
    var[..., 8:] = 100.0
    albedo = torch.full((1, 3, 16, 16), 0.2)
    albedo[..., 8:] = 0.8
    out = low_spp_variance(var, 2, {"albedo": albedo})
    # the quiet side stays quiet: its own 1.0 pooled over at most 7 x 7 taps, to float32
    # rounding of such a weighted mean on any CPU (49 * eps32, Higham's reordering bound); the
    # other side (100) lending with 1e-7 of the weight or more still fails it
    eps32 = torch.finfo(torch.float32).eps
    assert torch.allclose(out[..., :8], var[..., :8], rtol=49 * eps32)
    unguided = low_spp_variance(var, 2)
    assert float(unguided[0, 0, 0, 7]) > 10  # without the guide it would not
    # a clamped firefly's variance is not lent to its neighbours
    v = torch.full((1, 1, 9, 9), 1.0)
    v[..., 4, 4] = 1e6
    mask = torch.zeros_like(v, dtype=torch.bool)
    mask[..., 4, 4] = True
    lent = low_spp_variance(v, 2, exclude=mask)
    assert torch.allclose(lent[..., 4, 3], torch.tensor(1.0))
    assert float(lent[0, 0, 4, 4]) > 1e3  # its own estimate still counts
    assert float(low_spp_variance(v, 2)[0, 0, 4, 3]) > 1e3


def test_prepare_inputs_uses_it_only_when_asked_and_not_at_one_spp() -> None:
    true = torch.full((1, 1, 24, 24), 0.01)
    raw = _two_sample_estimates(true, seed=2)
    g = torch.Generator().manual_seed(5)
    color = 0.5 + 0.1 * torch.randn(3, 24, 24, generator=g)
    for spp in (2, 1):
        fb = FeatureBuffers(
            {"color": color.clamp_min(0), "color_var": raw[0].expand(3, 24, 24).clone()}, spp=spp
        )
        off = prepare_inputs(fb)
        on = prepare_inputs(fb, variance_prior=PRIOR_DOF)
        if spp == 1:  # the estimate from the colour, as before
            assert on.estimated_variance and torch.equal(on.color_var, off.color_var)
        else:
            assert not torch.equal(on.color_var, off.color_var)
            spread_on = float(on.color_var.log().std())
            spread_off = float(off.color_var.clamp_min(1e-12).log().std())
            assert spread_on < 0.5 * spread_off
