"""The ``nfor`` method (mcdenoise/methods/nfor.py): refusals, the hard cases, the halves it reads."""

from __future__ import annotations

import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers, sanitize
from mcdenoise.methods.nfor import METHOD, denoise_nfor

H = W = 16
FAST = {"search_radius": 2, "prefilter_radius": 2, "patch_radius": 2}


def _halves(clean: torch.Tensor, spp: int = 4, seed: int = 0):
    """``(A, B, var_A, var_B)`` of ``clean`` ``(3, H, W)`` with exponential sample noise."""
    g = torch.Generator().manual_seed(seed)
    s = torch.empty(spp, 1, *clean.shape[1:]).exponential_(1.0, generator=g) * clean
    a, b = s[: spp // 2], s[spp // 2 :]
    n = spp // 2
    return a.mean(0), b.mean(0), a.var(0) / n, b.var(0) / n


def _buffers(clean: torch.Tensor, albedo: torch.Tensor, **extra: torch.Tensor) -> FeatureBuffers:
    a, b, va, vb = _halves(clean)
    normal = torch.zeros(3, H, W)
    normal[2] = 1.0
    bufs = {
        "color": (a + b) / 2,
        "color_var": (va + vb) / 4,
        "color_a": a,
        "color_b": b,
        "color_a_var": va,
        "color_b_var": vb,
        "albedo": albedo,
        "normal": normal,
        "depth": torch.full((1, H, W), 2.0),
    }
    bufs.update(extra)
    return FeatureBuffers(bufs, spp=4)


def _edge_albedo(dark: float = 0.05) -> torch.Tensor:
    a = torch.full((3, H, W), 0.8)
    a[:, :, W // 2 :] = dark
    return a


def _relmse(x: torch.Tensor, ref: torch.Tensor) -> float:
    return float(((x - ref) ** 2 / (ref**2 + 0.01)).mean())


def test_an_input_without_halves_is_refused_with_how_to_get_them() -> None:
    fb = FeatureBuffers({"color": torch.rand(3, 8, 8)})
    reason = METHOD.accepts(fb)
    assert reason is not None and "color_a, color_b" in reason and "render --halves" in reason
    with pytest.raises(InputError, match="render --halves"):
        denoise_nfor(fb)
    one = FeatureBuffers({"color": torch.rand(3, 8, 8), "color_a": torch.rand(3, 8, 8)})
    with pytest.raises(InputError, match="needs the half buffers color_b"):
        denoise_nfor(one)


def test_denoises_and_keeps_an_albedo_edge() -> None:
    albedo = _edge_albedo()
    fb = _buffers(albedo * 1.0, albedo)
    out = denoise_nfor(fb, **FAST)
    assert _relmse(out, albedo) < 0.2 * _relmse(fb["color"], albedo)
    # The dark side stays dark: the albedo feature separates the two sides.
    assert float(out[:, :, W // 2 + 1 :].mean()) < 0.1


@pytest.mark.parametrize("case", ["firefly", "zero albedo", "nan features"])
def test_hard_cases_stay_finite(case: str) -> None:
    albedo = _edge_albedo(0.0 if case == "zero albedo" else 0.05)
    clean = albedo * 1.0
    fb = _buffers(clean, albedo)
    if case == "firefly":  # one bright sample in half A only
        a = fb["color_a"].clone()
        a[:, 8, 4] = 1e4
        fb["color_a"] = a
        fb["color_a_var"] = (
            fb["color_a_var"]
            .clone()
            .index_put_((torch.arange(3), torch.tensor(8), torch.tensor(4)), torch.tensor(0.25e8))
        )
        fb["color"] = (fb["color_a"] + fb["color_b"]) / 2
    if case == "nan features":
        n = fb["normal"].clone()
        n[:, 3:6, 3:6] = float("nan")
        fb["normal"] = n
        d = fb["depth"].clone()
        d[:, 0, :] = float("inf")
        fb["depth"] = d
    clean_fb, _ = sanitize(fb)  # what the framework hands a method
    out = denoise_nfor(clean_fb, **FAST)
    assert bool(torch.isfinite(out).all()) and bool((out >= 0).all())
    if case == "firefly":  # the firefly is clamped in its half, not spread
        assert float(out.max()) < 50.0
        assert _relmse(out, clean) < 1e-3 * _relmse(fb["color"], clean)


def test_noisy_feature_halves_are_used() -> None:
    # Depth of field: the albedo comes as two noisy halves; they are cross-prefiltered.
    albedo = _edge_albedo()
    g = torch.Generator().manual_seed(4)
    aa = (albedo + 0.05 * torch.randn(3, H, W, generator=g)).clamp_min(0)
    ab = (albedo + 0.05 * torch.randn(3, H, W, generator=g)).clamp_min(0)
    fb = _buffers(albedo * 1.0, (aa + ab) / 2, albedo_a=aa, albedo_b=ab)
    out = denoise_nfor(fb, **FAST)
    assert bool(torch.isfinite(out).all())
    assert _relmse(out, albedo) < 0.35 * _relmse(fb["color"], albedo)


def test_parameters_are_checked() -> None:
    fb = _buffers(_edge_albedo(), _edge_albedo())
    with pytest.raises(InputError, match="unknown feature"):
        denoise_nfor(fb, features=("colour",))
    with pytest.raises(InputError, match="bandwidths"):
        denoise_nfor(fb, bandwidths=("x",))
    params = METHOD.resolve_params({"bandwidths": "0.5,1,2", "features": "albedo"})
    assert params["bandwidths"] == ("0.5", "1", "2")  # strings, converted by the adapter
    out = denoise_nfor(fb, **{**params, **FAST})
    assert out.shape == (3, H, W)
