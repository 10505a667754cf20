"""Per-region selection by the two-buffer estimate (mcdenoise/methods/selection.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from torch.nn import functional as F

from mcdenoise.errors import InputError
from mcdenoise.filters.two_buffer import cross_error
from mcdenoise.io.buffers import FeatureBuffers, sanitize
from mcdenoise.methods.kalantari import denoise_kalantari, model_for
from mcdenoise.methods.selection import (
    FIXED_BEST,
    RULES,
    blend,
    choose,
    fixed_candidates,
    half_buffers,
    pick,
    select_filtered,
    select_kalantari,
    weights,
)

REPO = Path(__file__).resolve().parents[2]


def _blur(x: torch.Tensor, r: int) -> torch.Tensor:
    if r == 0:
        return x
    return F.avg_pool2d(x, 2 * r + 1, stride=1, padding=r, count_include_pad=False)


def _noisy_halves(clean: torch.Tensor, noise: str, seed: int, n: int = 2):
    """Halves of ``n`` samples each: Gaussian, or log-normal (heavy-tailed, mean 1)."""
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(2):
        if noise == "gaussian":
            s = 1 + 0.5 * torch.randn(n, *clean.shape, generator=g)
        else:
            s = torch.empty(n, *clean.shape).log_normal_(0.0, 1.2, generator=g) / math.exp(0.72)
        x = clean * s
        out.append((x.mean(0), x.var(0) / n))
    return out


@pytest.mark.parametrize("noise", ["gaussian", "lognormal"])
def test_the_two_buffer_estimate_is_unbiased(noise: str) -> None:
    # Averaged over many pixels and repetitions, the estimate of a blur's squared error
    # matches the true one, for Gaussian and for heavy-tailed noise.
    clean = torch.full((1, 3, 32, 32), 0.5)
    clean[..., 16:] = 2.0
    est, true = [], []
    for seed in range(12):
        (a, va), (b, vb) = _noisy_halves(clean, noise, seed)
        oa, ob = _blur(a, 2), _blur(b, 2)
        est.append(float(cross_error(oa, ob, a, b, va, vb).mean()))
        true.append(float(((oa + ob) / 2 - clean).square().mean()))
    e, t = sum(est) / len(est), sum(true) / len(true)
    assert abs(e - t) < 0.15 * t, (e, t)


def _buffers(clean: torch.Tensor, albedo: torch.Tensor, noise: str = "gaussian", seed: int = 0):
    (a, va), (b, vb) = _noisy_halves(clean[None], noise, seed)
    h, w = clean.shape[-2:]
    normal = torch.zeros(3, h, w)
    normal[2] = 1.0
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    zeros = {f"{n}_var": torch.zeros(c, h, w) for n, c in (("albedo", 3), ("normal", 3))}
    zeros |= {"depth_var": torch.zeros(1, h, w), "position_var": torch.zeros(3, h, w)}
    return FeatureBuffers(
        {
            "color": (a[0] + b[0]) / 2,
            "color_var": (va[0] + vb[0]) / 4,
            "color_a": a[0],
            "color_b": b[0],
            "color_a_var": va[0],
            "color_b_var": vb[0],
            "albedo": albedo,
            "normal": normal,
            "depth": torch.full((1, h, w), 2.0),
            "position": torch.stack([xx, yy, torch.zeros_like(xx)]),
            **zeros,
        },
        spp=4,
    )


def test_half_buffers_take_the_halves_and_twice_the_full_variance() -> None:
    clean = torch.full((3, 8, 8), 0.5)
    fb = _buffers(clean, clean)
    ha = half_buffers(fb, "a")
    assert torch.equal(ha["color"], fb["color_a"]) and torch.equal(
        ha["color_var"], fb["color_a_var"]
    )
    assert ha.spp == 2 and torch.equal(ha["albedo"], fb["albedo"])
    del fb.buffers["color_b_var"]
    hb = half_buffers(fb, "b")
    assert torch.allclose(hb["color_var"], 2 * fb["color_var"])


def test_selection_among_blurs_follows_the_image() -> None:
    # Constant left half (the widest blur wins), a fine checkerboard right half (no blur wins).
    clean = torch.full((1, 3, 32, 32), 1.0)
    checker = (torch.arange(32)[:, None] + torch.arange(32)[None]) % 2
    clean[..., 16:] = (0.2 + 1.6 * checker)[:, 16:].float()
    (a, va), (b, vb) = _noisy_halves(clean[0], "gaussian", 1)
    fb = FeatureBuffers(
        {"color": (a + b) / 2, "color_a": a, "color_b": b, "color_a_var": va, "color_b_var": vb}
    )
    radii = (0, 1, 3)

    def filter_fn(buf: FeatureBuffers, k: int) -> torch.Tensor:
        return _blur(buf["color"][None], radii[k])

    _, w = select_filtered(fb, filter_fn, 3, base=1, radius=3)
    index = w.argmax(dim=0, keepdim=True)
    assert float((index[:, 4:28, 2:12] == 2).float().mean()) > 0.9
    assert float((index[:, 4:28, 20:30] == 0).float().mean()) > 0.9


def test_weights_sum_to_one_and_argmin_is_the_choice() -> None:
    g = torch.Generator().manual_seed(0)
    errors = torch.rand(1, 5, 20, 20, generator=g)
    errors[:, 3, :, 10:] -= 0.5  # candidate 3 wins on the right
    outputs = torch.rand(1, 5, 3, 20, 20, generator=g)
    for rule in RULES:
        w = weights(errors, 2, rule, 0.3)
        assert w.shape == errors.shape and bool((w >= 0).all())
        assert torch.allclose(w.sum(dim=1), torch.ones(1, 20, 20))
    one_hot = weights(errors, 2, "argmin")
    assert torch.equal(blend(outputs, one_hot), pick(outputs, choose(errors, 2)))
    # a vanishing temperature is the argmin; a large one spreads the weight
    assert torch.allclose(weights(errors, 2, "soft", 1e-6), one_hot, atol=1e-4)
    assert float(weights(errors, 2, "soft", 100.0).amax()) < 0.3
    # smoothing blends the choices only near where they change (column 10)
    smooth = weights(errors, 2, "smooth")
    assert bool((smooth[:, 3, :, 15:] == 1).all())
    assert bool(((smooth[:, 3, :, 10] > 0) & (smooth[:, 3, :, 10] < 1)).any())
    with pytest.raises(InputError, match="rule"):
        weights(errors, 2, "vote")


def test_the_fixed_candidates_are_the_training_grids_best_and_neighbours() -> None:
    grid = json.loads((REPO / "benchmarks/results/kalantari_grid_xbf2.json").read_text())
    for spp, best in grid["best"].items():
        assert FIXED_BEST[int(spp)] == best
    assert fixed_candidates(5)[0] == FIXED_BEST[4] and fixed_candidates(12)[0] == FIXED_BEST[16]
    sets = fixed_candidates(4)
    assert len(sets) == 5 and len({tuple(sorted(d.items())) for d in sets}) == 5
    assert {d["sigma_spatial"] for d in sets} == {2.0, 4.0, 8.0}


@pytest.fixture(scope="module")
def xbf_model():
    clean = torch.full((3, 8, 8), 0.5)
    return model_for("xbf", _buffers(clean, clean), "shipped")


@pytest.mark.slow  # 27 runs of the shipped model: about 8 s idle, minutes on a loaded machine
@pytest.mark.parametrize("noise", ["gaussian", "lognormal"])
def test_selection_is_not_worse_than_the_model_on_a_constant_image(xbf_model, noise) -> None:
    albedo = torch.full((3, 24, 24), 0.6)
    clean = albedo * 1.0
    errs_sel, errs_base = [], []
    for seed in range(2):
        fb = _buffers(clean, albedo, noise, seed)
        base = denoise_kalantari(xbf_model, fb)
        sel = select_kalantari(xbf_model, fb)
        errs_base.append(float((base - clean).square().mean()))
        errs_sel.append(float((sel - clean).square().mean()))
    # "by more than noise": 10 % of the model's own error
    assert sum(errs_sel) <= 1.1 * sum(errs_base), (errs_sel, errs_base)


@pytest.mark.slow  # as above
@pytest.mark.parametrize("case", ["firefly", "zero albedo", "nan features"])
def test_selection_is_finite_on_the_hard_cases(xbf_model, case: str) -> None:
    albedo = torch.full((3, 16, 16), 0.8)
    albedo[:, :, 8:] = 0.0 if case == "zero albedo" else 0.05
    fb = _buffers(albedo * 1.0, albedo, "lognormal", 3)
    if case == "firefly":
        a = fb["color_a"].clone()
        a[:, 6, 5] = 1e4
        fb["color_a"] = a
        fb["color_a_var"] = (
            fb["color_a_var"]
            .clone()
            .index_put_((torch.arange(3), torch.tensor(6), torch.tensor(5)), torch.tensor(2.5e7))
        )
        fb["color"] = (fb["color_a"] + fb["color_b"]) / 2
        # as a renderer writes it: the full buffer's variance holds the firefly's too (else
        # the fixed candidates' clamp takes it for a precise highlight and keeps it)
        fb["color_var"] = (fb["color_a_var"] + fb["color_b_var"]) / 4
    if case == "nan features":
        n = fb["normal"].clone()
        n[:, 2:5, 2:5] = float("nan")
        fb["normal"] = n
    clean_fb, _ = sanitize(fb)
    out = select_kalantari(xbf_model, clean_fb)
    assert bool(torch.isfinite(out).all()) and bool((out >= 0).all())
    if case == "firefly":
        assert float(out.max()) < 100.0
