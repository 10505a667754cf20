"""NFOR's tensor operators (mcdenoise/filters/nfor.py): the regression against a direct
weighted least-squares solve, tiling, the NL-means, and the whole filter on synthetic noise."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.filters.nfor import NforSettings, collaborative_regression, nfor
from mcdenoise.filters.nfor_weights import nl_means


def _weights_direct(guide, var, f, r, k, var_scale):
    """Tungsten's nlMeansWeights, pixel by pixel: ``w[i][j]`` for all pairs in the window."""
    _, c, h, w = guide.shape
    g, v = guide[0].double().numpy(), var[0].double().numpy() * var_scale
    out = {}
    for y in range(h):
        for x in range(w):
            for dy in range(-r, r + 1):
                for dx in range(-r, r + 1):
                    qy, qx = y + dy, x + dx
                    if not (0 <= qy < h and 0 <= qx < w):
                        continue
                    dists = np.zeros(c)
                    cnt = 0
                    for py in range(y - f, y + f + 1):
                        for px in range(x - f, x + f + 1):
                            ok = 0 <= py < h and 0 <= px < w
                            ok = ok and 0 <= py + dy < h and 0 <= px + dx < w
                            if not ok:
                                continue
                            vp, vq = v[:, py, px], v[:, py + dy, px + dx]
                            diff = (g[:, py, px] - g[:, py + dy, px + dx]) ** 2
                            t = (diff - (vp + np.minimum(vp, vq))) / ((vp + vq) * k * k + 1e-7)
                            dists += np.minimum(t, 1e4)
                            cnt += 1
                    out[(y, x, qy, qx)] = np.exp(-np.maximum(dists / cnt, 0)).min()
    return out


def test_regression_matches_a_direct_weighted_least_squares_solve() -> None:
    g = torch.Generator().manual_seed(0)
    h, w, r, f = 7, 8, 2, 1
    img = torch.rand(1, 3, h, w, generator=g)
    guide = img + 0.05 * torch.randn(1, 3, h, w, generator=g)
    var = torch.full((1, 3, h, w), 0.01)
    feats = torch.rand(1, 2, h, w, generator=g)
    out = collaborative_regression(
        img, guide, var, feats, k=0.7, patch_radius=f, search_radius=r, ridge=0.0, floor=0.0
    )
    wts = _weights_direct(guide, var, f, r, 0.7, 2.0)
    y_np, f_np = img[0].double().numpy(), feats[0].double().numpy()
    acc = np.zeros((3, h, w))
    wsum = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            nb = [(qy, qx) for (cy, cx, qy, qx) in wts if (cy, cx) == (y, x)]
            xm = np.array(
                [
                    [1, (qx - x) / r, (qy - y) / r, *(f_np[:, qy, qx] - f_np[:, y, x])]
                    for qy, qx in nb
                ]
            )
            wv = np.array([wts[(y, x, qy, qx)] for qy, qx in nb])
            ym = np.array([y_np[:, qy, qx] for qy, qx in nb])
            sw = np.sqrt(wv)[:, None]
            beta = np.linalg.lstsq(sw * xm, sw * ym, rcond=None)[0]
            pred = xm @ beta
            for (qy, qx), p, wi in zip(nb, pred, wv, strict=True):
                acc[:, qy, qx] += wi * p
                wsum[qy, qx] += wi
    ref = torch.from_numpy(acc / wsum).float()
    assert torch.allclose(out[0], ref, atol=2e-4), float((out[0] - ref).abs().max())


def test_tiles_do_not_change_the_result() -> None:
    g = torch.Generator().manual_seed(1)
    img = torch.rand(1, 3, 19, 17, generator=g)
    var = torch.full((1, 1, 19, 17), 0.02)
    feats = torch.rand(1, 2, 19, 17, generator=g)
    kw = dict(k=1.0, patch_radius=1, search_radius=2)
    whole = collaborative_regression(img, img, var, feats, **kw)
    tiled = collaborative_regression(img, img, var, feats, tile=9, **kw)
    assert torch.allclose(whole, tiled, atol=1e-5)
    nlm_kw = dict(patch_radius=2, search_radius=3, k=0.5)
    assert torch.allclose(
        nl_means(img, img, var, **nlm_kw), nl_means(img, img, var, tile=7, **nlm_kw)
    )


def test_kept_weights_equal_recomputed_weights(monkeypatch: pytest.MonkeyPatch) -> None:
    """The regression keeps each offset's weights for its reconstruction pass; with no room
    for them it recomputes them, and the result is the same to the bit."""
    import mcdenoise.filters.nfor as nfor_mod

    g = torch.Generator().manual_seed(2)
    img = torch.rand(1, 3, 15, 13, generator=g)
    guide = img + 0.05 * torch.randn(1, 3, 15, 13, generator=g)
    var = torch.full((1, 1, 15, 13), 0.02)
    feats = torch.rand(1, 2, 15, 13, generator=g)
    kw = dict(k=0.5, patch_radius=1, search_radius=3, var_scale=1.5)
    kept = collaborative_regression(img, guide, var, feats, **kw)
    monkeypatch.setattr(nfor_mod, "WEIGHT_CACHE_BYTES", 0)
    recomputed = collaborative_regression(img, guide, var, feats, **kw)
    assert torch.equal(kept, recomputed)


def test_nl_means_weights_come_from_the_guide() -> None:
    # A guide with an edge keeps the image's two sides apart; a flat guide blurs them.
    img = torch.zeros(1, 1, 12, 12)
    img[..., 6:] = 1.0
    var = torch.full((1, 1, 12, 12), 1e-4)
    edge = nl_means(img, img, var, patch_radius=1, search_radius=3, k=0.5)
    flat = nl_means(img, torch.zeros_like(img), var, patch_radius=1, search_radius=3, k=0.5)
    # to float32 rounding of a weighted mean of 7 x 7 taps on any CPU (49 * eps32, Higham's
    # reordering bound); the flat guide mixes the sides by 0.2 and more
    assert torch.allclose(edge, img, atol=49 * torch.finfo(torch.float32).eps)
    assert float(flat[0, 0, :, 5].mean()) > 0.2


def _scene(h: int = 20, w: int = 20):
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    albedo = torch.stack([0.2 + 0.6 * (xx > 0.5), 0.3 + 0.4 * (yy > 0.4), 0.5 + 0 * xx])[None]
    clean = albedo * (1.0 + xx)
    return clean, albedo


@pytest.mark.parametrize("noise", ["gaussian", "lognormal"])
def test_nfor_removes_most_of_the_noise(noise: str) -> None:
    clean, albedo = _scene()
    g = torch.Generator().manual_seed(2)
    halves = []
    for _ in range(2):
        if noise == "gaussian":
            s = 1 + 0.5 * torch.randn(2, 1, *clean.shape[2:], generator=g)
        else:  # heavy-tailed, mean 1
            s = torch.empty(2, 1, *clean.shape[2:]).log_normal_(0, 1.0, generator=g) / np.exp(0.5)
        samples = clean * s
        halves.append((samples.mean(0, keepdim=True), samples.var(0, keepdim=True) / 2))
    (a, va), (b, vb) = halves
    noisy = (a + b) / 2
    s = NforSettings(search_radius=3, prefilter_radius=2)
    out = nfor(a, b, va, vb, albedo, albedo, settings=s)
    err = float((out - clean).square().mean())
    assert bool(torch.isfinite(out).all())
    assert err < 0.2 * float((noisy - clean).square().mean())


def test_selection_is_close_to_the_better_bandwidth() -> None:
    clean, albedo = _scene()
    g = torch.Generator().manual_seed(3)
    a = clean + 0.15 * torch.randn(clean.shape, generator=g)
    b = clean + 0.15 * torch.randn(clean.shape, generator=g)
    v = torch.full((1, 1, *clean.shape[2:]), 0.15**2)
    base = dict(search_radius=3, prefilter_radius=2, second_pass=False)
    errs = {}
    for ks in ((0.5,), (1.0,), (0.5, 1.0)):
        out = nfor(a, b, v, v, albedo, albedo, settings=NforSettings(bandwidths=ks, **base))
        errs[ks] = float((out - clean).square().mean())
    # Per-pixel choices by a noisy estimate: between the two, near the better one.
    assert errs[(0.5, 1.0)] < max(errs[(0.5,)], errs[(1.0,)])
    assert errs[(0.5, 1.0)] <= 1.25 * min(errs[(0.5,)], errs[(1.0,)])


def test_bad_inputs_are_refused_by_name() -> None:
    a = torch.rand(1, 3, 8, 8)
    v = torch.full((1, 1, 8, 8), 0.01)
    with pytest.raises(InputError, match="color_b"):
        nfor(a, torch.rand(1, 3, 8, 9), v, v)
    with pytest.raises(InputError, match="features_a and features_b"):
        nfor(a, a, v, v, torch.rand(1, 1, 8, 8), None)
    with pytest.raises(InputError, match="bandwidth"):
        nfor(a, a, v, v, settings=NforSettings(bandwidths=()))
