"""The mixing-aware prefilter of auxiliary features (mcdenoise.prep.aux_prefilter): a surface
mixed with the background (the defocused horizon) is denoised although the colour shows no
noise there; an in-focus texture finer than the noise window is kept; a variance buffer is
used as it is."""

from __future__ import annotations

import torch

from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.prep.aux_prefilter import (
    aux_feature_variance,
    mixing_mask,
    prefilter_aux,
)
from mcdenoise.prep.inputs import PREFILTER_ESTIMATED, prefilter_feature, prepare_inputs
from mcdenoise.prep.kpcn import prepare_tensors

SPP = 4


def defocused_horizon(seed: int = 0, size: int = 48) -> tuple[FeatureBuffers, torch.Tensor]:
    """A grey floor (albedo 0.6, normal +y) seen through a wide defocus against a sky (albedo
    0, normal 0) of the same radiance: each pixel's 4 samples hit the floor with a probability
    that falls from 0.9 at the left to 0.1 at the right. The albedo and normal are the means of
    those samples; the colour is the same everywhere (floor and sky are equally bright), so it
    carries no sign of the mixing. Returns the buffers and the true (expected) albedo."""
    g = torch.Generator().manual_seed(seed)
    p = torch.linspace(0.9, 0.1, size).expand(size, size)
    hits = (torch.rand(SPP, size, size, generator=g) < p).float()  # (spp, H, W)
    frac = hits.mean(0)
    albedo = (0.6 * frac).expand(3, -1, -1).contiguous()
    normal = torch.stack([torch.zeros_like(frac), frac, torch.zeros_like(frac)])
    color = 0.5 + 0.005 * torch.randn(3, size, size, generator=g)
    bufs = FeatureBuffers({"color": color, "albedo": albedo, "normal": normal}, spp=SPP)
    return bufs, (0.6 * p).expand(3, -1, -1)


def fine_texture(seed: int = 0, size: int = 48) -> FeatureBuffers:
    """An in-focus, one-pixel checkerboard albedo (0.1 / 0.8) on a flat surface (unit normals),
    lit evenly: the colour is albedo × 1 plus 2 % noise, with its variance buffer. The albedo
    has no noise at all, but every 2×2 detail of it is large, so a neighbourhood estimate
    takes it for noise."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    chk = ((yy + xx) % 2).float()
    albedo = (0.1 + 0.7 * chk).expand(3, -1, -1).contiguous()
    normal = torch.stack([torch.zeros(size, size), torch.ones(size, size), torch.zeros(size, size)])
    color = albedo * (1.0 + 0.02 * torch.randn(3, size, size, generator=g))
    color_var = (0.02 * albedo).square()
    bufs = {"color": color, "color_var": color_var, "albedo": albedo, "normal": normal}
    return FeatureBuffers(bufs, spp=SPP)


def mse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).square().mean())


def test_mixing_mask_marks_short_normals_and_their_neighbours() -> None:
    n = torch.zeros(1, 3, 9, 9)
    n[:, 1] = 1.0  # unit normals: no mixing
    assert not mixing_mask(n).any()
    n[:, 1, 4, 4] = 0.5  # one pixel half on the background
    m = mixing_mask(n)[0, 0]
    assert m[3:6, 3:6].all()  # the pixel and its 8 neighbours
    assert int(m.sum()) == 9
    n[:, 1, 4, 4] = 0.97  # a deficit of 0.03: below the threshold
    assert not mixing_mask(n).any()


def test_a_surface_mixed_with_the_background_is_denoised_where_the_colour_shows_nothing() -> None:
    b, truth = defocused_horizon()
    noisy = mse(b["albedo"], truth)
    adaptive = prepare_tensors(b, "basic", "adaptive")["albedo"]
    capped = prepare_tensors(b, "basic", "all")["albedo"]
    # the colour's noise caps the old prefilter to almost nothing here
    assert mse(capped, truth) > 0.9 * noisy
    # without the cap the mixing noise is filtered: less than half the error is left
    assert mse(adaptive, truth) < 0.5 * noisy
    # and the result is unbiased where the floor fraction is known: the mean albedo of each
    # column stays with the truth
    cols = (adaptive - truth).mean(dim=(0, 1))
    assert float(cols[4:-4].abs().mean()) < 0.02


def test_an_in_focus_texture_finer_than_the_window_is_kept() -> None:
    b = fine_texture()
    out = prepare_tensors(b, "basic", "adaptive")["albedo"]
    assert float((out - b["albedo"]).abs().max()) < 0.01
    # what the cap protects it from: the uncapped neighbourhood estimate would blur it
    inp = prepare_inputs(b, features=["albedo", "normal"], prefilter=False)
    f = inp.features["albedo"]
    everywhere = torch.ones_like(f[:, :1], dtype=torch.bool)
    v = aux_feature_variance(f, inp.color, inp.color_var, everywhere)
    blurred = prefilter_feature(f, v, PREFILTER_ESTIMATED)
    assert float((blurred - f).abs().max()) > 0.1


def test_a_feature_with_a_variance_buffer_is_steered_by_it() -> None:
    b, _ = defocused_horizon(seed=1)
    f = b["albedo"][None]
    var = torch.full_like(f[:, :1], 0.01)
    out = prefilter_aux(
        {"albedo": f, "normal": b["normal"][None]},
        {"albedo": var},
        b["color"][None],
        torch.full_like(var, 1e-6),
    )
    torch.testing.assert_close(out["albedo"], prefilter_feature(f, var, PREFILTER_ESTIMATED))
    # the normal (no buffer) is prefiltered by its own estimate, and changes
    assert not torch.equal(out["normal"], b["normal"][None])


def test_without_a_normal_the_cap_holds_everywhere() -> None:
    b, _ = defocused_horizon(seed=2)
    inp = prepare_inputs(b, features=["albedo"], prefilter=False)
    f = inp.features["albedo"]
    out = prefilter_aux({"albedo": f}, {}, inp.color, inp.color_var)["albedo"]
    v = aux_feature_variance(f, inp.color, inp.color_var, None)
    torch.testing.assert_close(out, prefilter_feature(f, v, PREFILTER_ESTIMATED))
    assert mse(out, f) < 1e-4  # the colour allows no noise: (almost) untouched


def test_features_of_one_shape_are_filtered_together_bit_for_bit_as_alone() -> None:
    b, _ = defocused_horizon(seed=3)
    inp = prepare_inputs(b, features=["albedo", "normal"], prefilter=False)
    out = prefilter_aux(inp.features, {}, inp.color, inp.color_var)
    mixing = mixing_mask(inp.features["normal"])
    for name, f in inp.features.items():
        v = aux_feature_variance(f, inp.color, inp.color_var, mixing)
        assert torch.equal(out[name], prefilter_feature(f, v, PREFILTER_ESTIMATED)), name
    assert list(out) == ["albedo", "normal"]
