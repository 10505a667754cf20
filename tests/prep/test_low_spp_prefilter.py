"""The features' prefilter at a few samples per pixel (prep/inputs.py's
low_spp_prefilter_variance) and the Kalantari methods' low-spp variance (issue 22)."""

from __future__ import annotations

import torch

from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.prep.inputs import (
    PREFILTER,
    low_spp_prefilter_variance,
    prefilter_feature,
    prepare_inputs,
)
from mcdenoise.prep.variance import MAX_SPP, low_spp_variance


def _two_sample_albedo(scene, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A defocused albedo from 2 samples per pixel: in the right half each sample lands on a
    random one of the four surfaces (a region blurred by defocus: its converged albedo is
    their mean), elsewhere on the pixel's own. Returns the albedo (mean of the 2), its
    variance of the mean ``(a1 - a2)² / 4`` -- 0 wherever the two samples happened to agree,
    as a 2-spp render's buffer is -- and the converged albedo."""
    g = torch.Generator().manual_seed(seed)
    palette = scene.albedo[0].reshape(3, -1).unique(dim=1)  # (3, 4) the surfaces' albedos
    h, w = scene.albedo.shape[-2:]
    mixing = torch.zeros(h, w, dtype=torch.bool)
    mixing[:, w // 2 :] = True
    samples = []
    for _ in range(2):
        pick = palette[:, torch.randint(0, palette.shape[1], (h, w), generator=g)]
        samples.append(torch.where(mixing, pick, scene.albedo[0]))
    mean = (samples[0] + samples[1]) / 2
    var = (samples[0] - samples[1]).square() / 4
    truth = torch.where(mixing, palette.mean(1)[:, None, None], scene.albedo[0])
    return mean, var, truth[None].float()


def _buffers(
    scene, albedo: torch.Tensor, albedo_var: torch.Tensor, spp: int | None
) -> FeatureBuffers:
    return FeatureBuffers(
        buffers={
            "color": scene.noisy[0].float(),
            "color_var": scene.var[0].float(),
            "albedo": albedo.float(),
            "albedo_var": albedo_var.float(),
        },
        spp=spp,
    )


def test_a_two_sample_albedo_is_prefiltered_where_its_buffer_missed_the_noise(scene) -> None:
    albedo, var, truth = _two_sample_albedo(scene)
    fb = _buffers(scene, albedo, var, spp=2)
    inp = prepare_inputs(fb, variance_prior=3.0)
    # what the buffer alone (pooled by the prior, as before) steers the prefilter to
    f = albedo[None].float()
    pooled = low_spp_variance(var[None].float(), 2, {"albedo": f}, prior_dof=3.0)
    by_buffer = prefilter_feature(f, pooled, PREFILTER)
    right = (..., slice(16, None))
    err_buffer = float((by_buffer - truth)[right].square().mean())
    err_new = float((inp.features["albedo"] - truth)[right].square().mean())
    err_raw = float((f - truth)[right].square().mean())
    # the pixels whose samples agreed (variance 0) are kept as they were written: measured
    # 0.23 of the raw error left by the buffer alone, 0.013 with the estimate
    assert err_buffer > 0.1 * err_raw
    assert err_new < 0.2 * err_buffer
    # the demodulation divides by the same prefiltered albedo
    assert torch.equal(inp.albedo, inp.features["albedo"])
    # the converged left half (variance 0, no noise) keeps its albedo and its edge
    torch.testing.assert_close(inp.features["albedo"][..., :, :10], truth[..., :, :10])


def test_only_at_low_spp_and_only_with_the_low_spp_variance(scene) -> None:
    albedo, var, _ = _two_sample_albedo(scene, seed=1)
    f, v = albedo[None].float(), var[None].float()
    for spp in (MAX_SPP + 1, 16, 64, None):
        assert low_spp_prefilter_variance(f, v, spp) is v
        fb = _buffers(scene, albedo, var, spp=spp)
        a = prepare_inputs(fb, variance_prior=3.0).features["albedo"]
        b = prepare_inputs(fb, variance_prior=0.0).features["albedo"]
        assert torch.equal(a, b)
    # without the low-spp variance (the learned models' training inputs, kpcn) nothing moves
    fb = _buffers(scene, albedo, var, spp=2)
    f0 = prepare_inputs(fb, variance_prior=0.0).features["albedo"]
    torch.testing.assert_close(f0, prefilter_feature(f, v, PREFILTER))


def test_an_in_focus_texture_is_not_taken_for_noise(scene) -> None:
    """A 4×4-texel checkerboard with an exact buffer (variance 0) at 2 spp: the estimate's
    median sees its edges as lines, not as noise, and the texture stays."""
    h, w = scene.albedo.shape[-2:]
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    checker = ((yy // 4 + xx // 4) % 2).float()
    albedo = (0.2 + 0.6 * checker).expand(3, h, w).clone()
    fb = _buffers(scene, albedo, torch.zeros(3, h, w), spp=2)
    out = prepare_inputs(fb, variance_prior=3.0).features["albedo"][0]
    assert float((out - albedo).abs().max()) < 0.02


def test_kalantari_methods_pool_the_two_sample_variance() -> None:
    """A flat grey surface at 2 spp whose light arrives through sparse bright samples (one
    sample in 10 is 25× the others): where the two samples agreed the variance is 0, and the
    learned filters leave such pixels alone; the methods' default low-spp variance
    (ν₀ = 0.1) lets them average."""
    from mcdenoise.denoise import denoise

    g = torch.Generator().manual_seed(3)
    h = w = 40
    hit = torch.rand(2, 1, h, w, generator=g) < 0.1
    samples = torch.where(hit, torch.tensor(0.5), torch.tensor(0.02)).expand(2, 3, h, w)
    truth = 0.02 + 0.48 * 0.1
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    buffers = {
        "color": samples.mean(0),
        "color_var": (samples[0] - samples[1]).square().mean(0, keepdim=True) / 4,
        "albedo": torch.full((3, h, w), 0.5),
        "normal": torch.tensor([0.0, 0.0, 1.0])[:, None, None].expand(3, h, w).clone(),
        "depth": torch.ones(1, h, w),
        "position": torch.stack([xx, yy, torch.zeros_like(xx)]),
        "depth_var": torch.zeros(1, h, w),
    }
    for name in ("albedo", "normal", "position"):
        buffers[name + "_var"] = torch.zeros(3, h, w)
    fb = FeatureBuffers(buffers=buffers, spp=2)

    def err(img: torch.Tensor) -> float:
        return float(((img - truth).square() / (truth**2 + 0.01)).mean())

    for name in ("kalantari-nlm", "kalantari-xbf"):
        default = err(denoise(fb, name, device="cpu").image)
        raw = err(denoise(fb, name, params={"variance_prior": 0.0}, device="cpu").image)
        assert default < 0.7 * raw, (name, default, raw)
