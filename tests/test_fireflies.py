"""Every available method under a firefly and at 1 spp (issue 22, "Tests").

Synthetic inputs, made here (32×32, irradiance 1, so the clean colour is the albedo):

* a constant grey with one pixel 1e4× brighter, its variance that of one bright sample among
  4 (the other three equal to the grey), every other variance 0;
* the same firefly next to an edge between two albedos (0.8 | 0.05), on either side;
* a 1-spp render of the edge (exponential sample noise, mean 1) whose variance buffer is 0
  everywhere, as a renderer writes it for one sample.

Every registered method that can run here is tried (``registry.available_methods()``: ``oidn``
only where pyoidn is installed, the learned methods with their shipped models).

The bounds, and why:

* **Firefly error**: below the noisy input's (the issue's wording) and, more strictly, at most
  :data:`FIREFLY_ERROR_SHARE` of it. The noisy error is the firefly's own, ``(1e4 - 1)²`` at one
  pixel; a method that keeps 3 % of the firefly's excess at that pixel leaves 1e-3 of it. Before
  the firefly work (commit d14d2cb) ``nlm`` kept 17-51 % of it (error share 0.11-0.51),
  ``cross-bilateral`` 0.6-1.6 % and ``kalantari-nlm`` 3-5 % next to the edge (share 3e-3); the
  same three failed on the demo's ``caustics_glass``.
* **Energy**: ``mean(out) / mean(clean) - 1`` between :data:`DARKEN_TOLERANCE` below 0 and the
  noisy input's own bias. Whether the firefly is noise (the truth is the grey: bias 0) or a
  legitimate rare sample (the truth is the input's mean), the output's energy lies between the
  two; below means the grey itself was darkened (issue 20 allows 2 % at 4 spp), above means
  energy was made.
* **Edge**: the firefly's share of energy that lands across the edge, ``Σ (out - out_0)⁺`` over
  the other side (``out_0``: the same input without the firefly) over its excess, is at most
  :data:`BLEED_SHARE`. A filter blind to the edge puts about half of it there (the firefly
  touches the edge, its footprint is half across); OIDN, the strongest, puts 4 % there when the
  firefly is on the dark side. :func:`test_the_bleed_check_catches_an_edge_blind_blur` shows
  the check failing on such a blur.
* **1 spp, zero variance**: finite, non-negative, a lower relMSE than the noisy input (a zero
  variance must not read as "noise-free, keep every pixel"), and the mean within
  :data:`ONE_SPP_BIAS` of the clean mean. The input's own mean is 3.5 % high (one exponential
  sample per pixel: σ of the mean ≈ 3 % over 1024 pixels), and the variance-steered filters
  darken skewed noise through their asymmetric variance pair (``docs/results/bias.md``):
  measured at 4320ca7, out / clean = 0.913 (``cross-bilateral``) to 1.044 (``oidn``); 10 %
  catches a method that drops or makes energy wholesale.
"""

from __future__ import annotations

import pytest
import torch

from mcdenoise.denoise import denoise
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.methods import ao, nnao
from mcdenoise.registry import available_methods, get_method

H = W = 32
FIREFLY = 1e4
#: The firefly's error left by the output, as a share of the noisy input's (see the docstring).
FIREFLY_ERROR_SHARE = 1e-3
#: How far below the clean mean an output's mean may fall (issue 20's bound at 4 spp).
DARKEN_TOLERANCE = 0.02
#: Share of a firefly's excess energy allowed across an albedo edge (an edge-blind filter: ~0.5).
BLEED_SHARE = 0.1
#: |mean(out) / mean(clean) - 1| at 1 spp with a zero variance buffer.
ONE_SPP_BIAS = 0.1

#: The AO estimators read depth, normal and the camera only: a firefly in the colour never
#: reaches them (their hard cases, empty pixels and depth jumps, are in tests/ao).
AO_ESTIMATORS = {m.name for m in ao.METHODS} | {nnao.METHOD.name}
METHODS = [m.name for m in available_methods() if m.name not in AO_ESTIMATORS]
#: svgf (issue 23) returns a 1-spp frame unchanged (relMSE = the input's); reported to its
#: author. strict: once it denoises 1-spp frames this fails, and the mark must go.
SVGF_ONE_SPP = pytest.mark.xfail(
    reason="svgf passes 1-spp frames through unchanged", strict=True, raises=AssertionError
)


def _relmse(x: torch.Tensor, ref: torch.Tensor) -> float:
    return float(((x - ref) ** 2 / (ref**2 + 0.01)).mean())


def _buffers(
    color: torch.Tensor,
    var: torch.Tensor,
    albedo: torch.Tensor,
    spp: int,
    halves: dict[str, torch.Tensor] | None = None,
):
    """Float32 ``(C, H, W)`` buffers of a flat, camera-facing plane with ``albedo``; ``halves``
    (``color_a``, ``color_b`` and their variances) where the construction can split its samples
    (``nfor`` needs them; the other methods never see them)."""
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, H), torch.linspace(-1, 1, W), indexing="ij")
    normal = torch.zeros(3, H, W)
    normal[2] = 1.0
    zeros = {f"{n}_var": torch.zeros(c, H, W) for n, c in (("albedo", 3), ("normal", 3))}
    zeros |= {"depth_var": torch.zeros(1, H, W), "position_var": torch.zeros(3, H, W)}
    return FeatureBuffers(
        {
            "color": color,
            "color_var": var,
            "albedo": albedo,
            "normal": normal,
            "depth": torch.full((1, H, W), 2.0),
            "position": torch.stack([xx, yy, torch.zeros_like(xx)]),
            **zeros,
            **(halves or {}),
        },
        spp=spp,
    )


def _albedo(left: float, right: float, edge: int = W // 2) -> torch.Tensor:
    a = torch.full((3, H, W), right)
    a[:, :, :edge] = left
    return a


def firefly_input(albedo: torch.Tensor, at: tuple[int, int], spp: int = 4):
    """``(buffers, clean)``: the clean image ``albedo`` with one pixel ``FIREFLY``× brighter,
    the mean of one bright sample ``X`` and ``spp - 1`` samples equal to the clean value; its
    variance of the mean is the sample variance of those ``spp`` values over ``spp``."""
    clean = albedo.clone()
    color = clean.clone()
    var = torch.zeros(3, H, W)
    y, x = at
    c = clean[:, y, x]
    mean = FIREFLY * c
    bright = spp * mean - (spp - 1) * c
    sample_var = ((bright - mean) ** 2 + (spp - 1) * (c - mean) ** 2) / (spp - 1)
    color[:, y, x] = mean
    var[:, y, x] = sample_var / spp
    # Halves of spp/2 samples each: A holds the bright sample, B only clean ones.
    n = spp // 2
    color_a, var_a = clean.clone(), torch.zeros(3, H, W)
    half_mean = (bright + (n - 1) * c) / n
    color_a[:, y, x] = half_mean
    var_a[:, y, x] = ((bright - half_mean) ** 2 + (n - 1) * (c - half_mean) ** 2) / (n - 1) / n
    halves = {"color_a": color_a, "color_b": clean.clone(), "color_a_var": var_a}
    halves["color_b_var"] = torch.zeros(3, H, W)
    return _buffers(color, var, albedo, spp, halves), clean


def _run(buffers: FeatureBuffers, method: str) -> torch.Tensor:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return denoise(buffers, method, device="cpu").image
    finally:
        torch.set_num_threads(threads)


SCENES = {
    "constant": (0.5, 0.5, (16, 16)),
    "edge, bright side": (0.8, 0.05, (16, 15)),
    "edge, dark side": (0.8, 0.05, (16, 16)),
}


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("method", METHODS)
def test_one_firefly_is_removed_and_energy_is_bounded(method: str, scene: str) -> None:
    left, right, at = SCENES[scene]
    buffers, clean = firefly_input(_albedo(left, right), at)
    noisy = buffers.color
    out = _run(buffers, method)
    assert out.shape == clean.shape and bool(torch.isfinite(out).all())
    err, err_noisy = _relmse(out, clean), _relmse(noisy, clean)
    assert err < err_noisy
    assert err <= FIREFLY_ERROR_SHARE * err_noisy, (
        f"{method} keeps the firefly: relMSE {err:.4g}, {err / err_noisy:.2e} of the input's"
    )
    bias = float(out.mean() / clean.mean()) - 1
    noisy_bias = float(noisy.mean() / clean.mean()) - 1
    assert -DARKEN_TOLERANCE <= bias <= noisy_bias, f"{method}: energy bias {bias:+.4f}"


@pytest.mark.parametrize("side", ["bright", "dark"])
@pytest.mark.parametrize("method", METHODS)
def test_a_firefly_on_an_edge_does_not_bleed_across(method: str, side: str) -> None:
    albedo = _albedo(0.8, 0.05)
    at, across = ((16, 15), slice(16, None)) if side == "bright" else ((16, 16), slice(None, 16))
    buffers, clean = firefly_input(albedo, at)
    zero = torch.zeros(3, H, W)
    plain = {"color_a": clean.clone(), "color_b": clean.clone(), "color_a_var": zero}
    without = _buffers(clean.clone(), zero, albedo, 4, {**plain, "color_b_var": zero})
    share = _bleed_share(_run(buffers, method), _run(without, method), buffers.color, clean, across)
    assert share <= BLEED_SHARE, f"{method}: {share:.2%} of the firefly's excess crossed the edge"


def _bleed_share(out, out_0, noisy, clean, across: slice) -> float:
    """Share of the firefly's excess energy found across the edge (see the docstring)."""
    gained = (out - out_0)[:, :, across].clamp_min(0.0).sum()
    return float(gained / (noisy - clean).sum())


def test_the_bleed_check_catches_an_edge_blind_blur() -> None:
    # The check above must be able to fail: a 5×5 box blur (blind to the edge) fails it.
    albedo = _albedo(0.8, 0.05)
    buffers, clean = firefly_input(albedo, (16, 16))

    def blur(x: torch.Tensor) -> torch.Tensor:
        k = torch.ones(3, 1, 5, 5) / 25
        return torch.nn.functional.conv2d(x[None], k, padding=2, groups=3)[0]

    share = _bleed_share(blur(buffers.color), blur(clean), buffers.color, clean, slice(None, 16))
    assert share > BLEED_SHARE


@pytest.mark.parametrize(
    "method", [pytest.param(m, marks=SVGF_ONE_SPP) if m == "svgf" else m for m in METHODS]
)
def test_one_spp_with_zero_variance_is_denoised(method: str) -> None:
    # One sample per pixel: exponential noise (mean 1) on the edge image; the renderer's
    # variance of one sample is 0 everywhere.
    albedo = _albedo(0.8, 0.05)
    g = torch.Generator().manual_seed(5)
    noise = torch.empty(1, H, W).exponential_(1.0, generator=g)
    noisy = albedo * noise
    buffers = _buffers(noisy, torch.zeros(3, H, W), albedo, 1)
    reason = get_method(method).accepts(buffers)
    if reason is not None:  # nfor: one sample cannot be split into two halves
        assert "half buffers" in reason, reason
        return
    out = _run(buffers, method)
    assert bool(torch.isfinite(out).all()) and bool((out >= 0).all())
    assert _relmse(out, albedo) < _relmse(noisy, albedo)
    assert abs(float(out.mean() / albedo.mean()) - 1) <= ONE_SPP_BIAS
