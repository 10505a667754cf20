"""The ``select`` parameter of ``kalantari-xbf``/``-nlm`` (mcdenoise/methods/kalantari.py):
per-region selection by the half buffers when asked for (``auto``/``on``) and the input has
them; the model alone by default and otherwise."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.denoise import denoise
from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.methods.kalantari import NLM, XBF

H = W = 24
HALVES = ("color_a", "color_b", "color_a_var", "color_b_var")


def _buffers(seed: int = 0, spp: int = 16) -> FeatureBuffers:
    """A two-region image (albedo edge, shading ramp) with exponential sample noise in halves
    of ``spp / 2`` samples each, every guide the shipped models need, with variances."""
    g = torch.Generator().manual_seed(seed)
    albedo = torch.full((3, H, W), 0.7)
    albedo[:, :, W // 2 :] = 0.1
    clean = albedo * torch.linspace(0.5, 2.0, W)[None, None]
    n = spp // 2
    halves = []
    for _ in range(2):
        s = torch.empty(n, *clean.shape).exponential_(1.0, generator=g) * clean
        halves.append((s.mean(0), s.var(0) / n))
    (a, va), (b, vb) = halves
    normal = torch.zeros(3, H, W)
    normal[2] = 1.0
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, H), torch.linspace(-1, 1, W), indexing="ij")
    return FeatureBuffers(
        {
            "color": (a + b) / 2,
            "color_var": (va + vb) / 4,
            "color_a": a,
            "color_b": b,
            "color_a_var": va,
            "color_b_var": vb,
            "albedo": albedo,
            "albedo_var": torch.zeros(3, H, W),
            "normal": normal,
            "normal_var": torch.zeros(3, H, W),
            "depth": torch.full((1, H, W), 2.0),
            "depth_var": torch.zeros(1, H, W),
            "position": torch.stack([xx, yy, torch.zeros_like(xx)]),
            "position_var": torch.zeros(3, H, W),
        },
        spp=spp,
    )


def _without_halves(fb: FeatureBuffers) -> FeatureBuffers:
    return FeatureBuffers(
        {k: v for k, v in fb.buffers.items() if k not in HALVES}, spp=fb.spp, source=fb.source
    )


@pytest.mark.parametrize("method", ["kalantari-xbf", "kalantari-nlm"])
def test_by_default_without_halves_and_with_select_off_the_output_is_the_models(method) -> None:
    fb = _buffers()
    model_alone = denoise(_without_halves(fb), method, params={"select": "off"}, device="cpu")
    default = denoise(fb, method, device="cpu")  # halves present, default select=off
    auto = denoise(_without_halves(fb), method, params={"select": "auto"}, device="cpu")
    assert torch.equal(default.image, model_alone.image)  # to the bit
    assert torch.equal(auto.image, model_alone.image)  # auto without halves: the model alone


@pytest.mark.slow  # two selections of 42 filters each: about a minute on a loaded machine
def test_select_with_halves_changes_the_output_and_stays_finite() -> None:
    fb = _buffers(seed=1)
    off = denoise(fb, "kalantari-xbf", device="cpu").image
    on = denoise(fb, "kalantari-xbf", params={"select": "on"}, device="cpu").image
    auto = denoise(fb, "kalantari-xbf", params={"select": "auto"}, device="cpu").image
    assert on.shape == off.shape and bool(torch.isfinite(on).all()) and bool((on >= 0).all())
    assert not torch.equal(on, off) and torch.equal(auto, on)  # 16 spp: auto selects


@pytest.mark.parametrize("method", [XBF, NLM])
def test_the_select_parameter_is_checked(method) -> None:
    fb = _buffers()
    reason = method.accepts(fb, {"select": "sometimes"})
    assert reason is not None and "select" in reason and "auto, on, off" in reason
    reason = method.accepts(_without_halves(fb), {"select": "on"})
    assert reason is not None and "color_a and color_b" in reason
    assert method.accepts(_without_halves(fb), {"select": "auto"}) is None
    assert method.defaults["select"] == "off"
    with pytest.raises(InputError, match="select"):
        denoise(fb, method.name, params={"select": "sometimes"}, device="cpu")
