"""Tests of mcdenoise.filters.kernels (docs/hard-cases.md items 13-15, 17, 18, 20; gradcheck)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from mcdenoise.errors import InputError
from mcdenoise.filters.kernels import Window, accumulate_weighted, apply_kernels


def reference_kernels(image: torch.Tensor, weights: torch.Tensor, normalize: bool) -> torch.Tensor:
    """Unfold-based reference: in-image taps only, renormalised (small images only)."""
    b, c, h, w = image.shape
    k = round(weights.shape[1] ** 0.5)
    u = F.unfold(image, k, padding=k // 2).view(b, c, k * k, h, w)
    inside = F.unfold(torch.ones_like(image[:, :1]), k, padding=k // 2).view(b, 1, k * k, h, w)
    wi = weights.unsqueeze(1) * inside
    out = (u * wi).sum(2) / wi.sum(2)
    if not normalize:
        out = out * weights.sum(1, keepdim=True)
    return out


def softmax_kernels(b: int, k: int, h: int, w: int, dtype=torch.float64, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return torch.softmax(torch.randn(b, k * k, h, w, generator=g, dtype=dtype), dim=1)


@pytest.mark.parametrize("normalize", [True, False])
@pytest.mark.parametrize("k,h,w", [(3, 7, 5), (5, 9, 11), (7, 4, 13)])
def test_matches_unfold_reference(normalize: bool, k: int, h: int, w: int) -> None:
    g = torch.Generator().manual_seed(1)
    x = torch.rand(2, 3, h, w, generator=g, dtype=torch.float64)
    wt = torch.rand(2, k * k, h, w, generator=g, dtype=torch.float64)
    out = apply_kernels(x, wt, normalize=normalize, tile=4)
    torch.testing.assert_close(out, reference_kernels(x, wt, normalize), rtol=1e-12, atol=1e-12)


def test_identity_kernel_is_exact() -> None:
    x = torch.rand(1, 3, 10, 9)
    wt = torch.zeros(1, 25, 10, 9)
    wt[:, 12] = 1.0
    assert torch.equal(apply_kernels(x, wt), x)
    assert torch.equal(apply_kernels(x, wt, normalize=True), x)


@pytest.mark.parametrize("value", [0.0, 0.7, 123.0])
def test_constant_image_unchanged_including_borders(value: float) -> None:
    # docs/hard-cases.md items 13 and 17: a zero-padded filter would darken the border of a positive image.
    x = torch.full((1, 3, 12, 10), value, dtype=torch.float64)
    out = apply_kernels(x, softmax_kernels(1, 7, 12, 10))
    torch.testing.assert_close(out, x, rtol=1e-12, atol=0.0)
    wt = torch.rand(1, 49, 12, 10, dtype=torch.float64)
    torch.testing.assert_close(apply_kernels(x, wt, normalize=True), x, rtol=1e-12, atol=0.0)


def test_zero_padding_would_have_darkened() -> None:
    # Guard that the border test above can fail: a zero-padded sum does darken the corner.
    x = torch.ones(1, 1, 6, 6, dtype=torch.float64)
    wt = softmax_kernels(1, 5, 6, 6)
    zero_padded = (F.unfold(x, 5, padding=2).view(1, 1, 25, 6, 6) * wt.unsqueeze(1)).sum(2)
    assert float(zero_padded[0, 0, 0, 0]) < 0.7
    assert float(apply_kernels(x, wt)[0, 0, 0, 0]) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("h,w", [(1, 1), (1, 2), (2, 1), (2, 2), (3, 3)])
@pytest.mark.parametrize("normalize", [True, False])
def test_images_smaller_than_kernel(h: int, w: int, normalize: bool) -> None:
    # docs/hard-cases.md items 14
    g = torch.Generator().manual_seed(3)
    x = torch.rand(1, 3, h, w, generator=g, dtype=torch.float64)
    wt = torch.rand(1, 21 * 21, h, w, generator=g, dtype=torch.float64)
    out = apply_kernels(x, wt, normalize=normalize)
    assert out.shape == x.shape and bool(torch.isfinite(out).all())
    torch.testing.assert_close(out, reference_kernels(x, wt, normalize))


def test_all_zero_weights_fall_back_to_centre() -> None:
    # docs/hard-cases.md item 15: never 0/0.
    x = torch.rand(1, 3, 6, 7)
    wt = torch.zeros(1, 9, 6, 7)
    out = apply_kernels(x, wt, normalize=True)
    assert torch.equal(out, x)
    # Without normalisation the kernel's mass (0) is kept: Σ w x = 0.
    assert torch.equal(apply_kernels(x, wt, normalize=False), torch.zeros_like(x))


def test_underflowing_weights_fall_back_to_centre() -> None:
    x = torch.rand(1, 2, 5, 5)
    wt = torch.full((1, 9, 5, 5), 1e-45)  # denormal: sums stay below the smallest normal
    assert torch.equal(apply_kernels(x, wt, normalize=True), x)


def test_mass_only_outside_the_image_falls_back_to_centre() -> None:
    x = torch.rand(1, 1, 4, 4, dtype=torch.float64)
    wt = torch.zeros(1, 9, 4, 4, dtype=torch.float64)
    wt[:, 0] = 1.0  # tap (-1, -1): outside the image for the top row and left column
    out = apply_kernels(x, wt, normalize=False)
    torch.testing.assert_close(out[..., 0, :], x[..., 0, :])
    torch.testing.assert_close(out[..., 1:, 0], x[..., 1:, 0])
    torch.testing.assert_close(out[..., 1:, 1:], x[..., :-1, :-1])


@pytest.mark.parametrize("tile,h,w", [(1, 9, 7), (5, 37, 29), ((3, 8), 37, 29), (64, 37, 29)])
def test_tiled_equals_untiled(tile, h: int, w: int) -> None:
    # docs/hard-cases.md items 20
    g = torch.Generator().manual_seed(4)
    x = torch.rand(2, 3, h, w, generator=g)
    wt = torch.softmax(torch.randn(2, 81, h, w, generator=g), dim=1)
    full = apply_kernels(x, wt, tile=10_000)
    out = apply_kernels(x, wt, tile=tile)
    assert (out - full).abs().max() <= 1e-6


def test_callback_never_sees_more_than_a_tile() -> None:
    # Memory bound: one offset's weights never exceed one output tile.
    x = torch.rand(1, 3, 40, 33)
    seen: list[tuple[int, int]] = []

    def fn(win: Window) -> torch.Tensor:
        c = win.centre(x[:, :1])
        seen.append((c.shape[-2], c.shape[-1]))
        return torch.ones_like(c)

    accumulate_weighted(x, fn, 21, tile=(8, 16))
    assert max(h for h, _ in seen) <= 8 and max(w for _, w in seen) <= 16
    assert len(seen) > 441  # several tiles, every offset


def test_accumulate_weighted_box_is_clipped_mean() -> None:
    x = torch.rand(2, 3, 11, 8, dtype=torch.float64)

    def ones(win: Window) -> torch.Tensor:
        return torch.ones_like(win.centre(x[:, :1]))

    out = accumulate_weighted(x, ones, 5, tile=3)
    ref = F.avg_pool2d(x, 5, stride=1, padding=2, count_include_pad=False)
    torch.testing.assert_close(out, ref)


def test_accumulate_weighted_skips_none() -> None:
    x = torch.rand(1, 1, 6, 6)

    def centre_only(win: Window) -> torch.Tensor | None:
        if win.dy or win.dx:
            return None
        return torch.ones_like(win.centre(x))

    assert torch.equal(accumulate_weighted(x, centre_only, 7), x)


def test_dtype_preserved_and_precisions_agree() -> None:
    # docs/hard-cases.md items 18
    x64 = torch.rand(1, 3, 16, 16, dtype=torch.float64) * 10
    w64 = softmax_kernels(1, 5, 16, 16)
    o64 = apply_kernels(x64, w64)
    o32 = apply_kernels(x64.float(), w64.float())
    assert o64.dtype == torch.float64 and o32.dtype == torch.float32
    torch.testing.assert_close(o32.double(), o64, rtol=1e-5, atol=1e-5)
    o16 = apply_kernels(x64.half(), w64.half())
    assert o16.dtype == torch.float32  # half is computed and returned in float32 (documented)


@pytest.mark.parametrize("normalize", [True, False])
def test_gradcheck(normalize: bool) -> None:
    # docs/hard-cases.md item 19: gradients w.r.t. the image and the (predicted) weights.
    g = torch.Generator().manual_seed(5)
    x = torch.rand(1, 2, 3, 4, generator=g, dtype=torch.float64, requires_grad=True)
    logits = torch.randn(1, 9, 3, 4, generator=g, dtype=torch.float64)
    logits[:, :, 0, 0] = -60.0  # near-zero weights at one pixel
    logits.requires_grad_(True)

    def f(x: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
        return apply_kernels(x, torch.softmax(logits, dim=1), normalize=normalize, tile=3)

    assert torch.autograd.gradcheck(f, (x, logits))


def test_gradcheck_callback_parameters() -> None:
    g = torch.Generator().manual_seed(6)
    x = torch.rand(1, 2, 5, 4, generator=g, dtype=torch.float64)
    s = (torch.rand(1, 1, 5, 4, generator=g, dtype=torch.float64) + 0.5).requires_grad_(True)

    def f(s: torch.Tensor) -> torch.Tensor:
        def fn(win: Window) -> torch.Tensor:
            return torch.exp(-(win.dy**2 + win.dx**2) * win.centre(s)) * torch.ones_like(
                win.centre(x[:, :1])
            )

        return accumulate_weighted(x, fn, 3, tile=2)

    assert torch.autograd.gradcheck(f, (s,))


@pytest.mark.parametrize("tile", [2, 100])
def test_centre_max_equals_explicit_kernels_with_the_centre_replaced(tile: int) -> None:
    # Buades 2005's rule: the centre's weight is the largest of the other in-image weights.
    g = torch.Generator().manual_seed(8)
    x = torch.rand(2, 3, 6, 5, generator=g, dtype=torch.float64)
    w = torch.rand(2, 25, 6, 5, generator=g, dtype=torch.float64)
    inside = F.unfold(torch.ones(2, 1, 6, 5, dtype=torch.float64), 5, padding=2).view(2, 25, 6, 5)
    others = (w * inside).clone()
    others[:, 12] = 0
    replaced = w.clone()
    replaced[:, 12] = others.max(dim=1).values
    called = []

    def fn(win: Window) -> torch.Tensor:
        called.append((win.dy, win.dx))
        return w[:, win.index : win.index + 1, win.yi, win.xi]

    out = accumulate_weighted(x, fn, 5, centre="max", tile=tile)
    torch.testing.assert_close(out, reference_kernels(x, replaced, True), rtol=1e-12, atol=1e-12)
    assert (0, 0) not in called


def test_centre_max_with_no_other_weight_keeps_the_pixel() -> None:
    x = torch.rand(1, 3, 4, 4, dtype=torch.float64)
    zero = accumulate_weighted(
        x, lambda win: torch.zeros_like(win.centre(x[:, :1])), 3, centre="max"
    )
    assert torch.equal(zero, x)
    assert torch.equal(accumulate_weighted(x, lambda win: None, 1, centre="max"), x)


def test_gradcheck_centre_max() -> None:
    g = torch.Generator().manual_seed(9)
    x = torch.rand(1, 2, 5, 4, generator=g, dtype=torch.float64).requires_grad_(True)
    s = (torch.rand(1, 1, 5, 4, generator=g, dtype=torch.float64) + 0.5).requires_grad_(True)

    def f(x: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        def fn(win: Window) -> torch.Tensor:
            d = (win.neighbour(x) - win.centre(x)).square().sum(1, keepdim=True)
            return torch.exp(-(win.dy**2 + 2 * win.dx**2) * win.centre(s) - d)

        return accumulate_weighted(x, fn, 3, centre="max", tile=3)

    assert torch.autograd.gradcheck(f, (x, s))


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: apply_kernels(torch.rand(1, 3, 4, 4), torch.rand(1, 8, 4, 4)), "k\\*k"),
        (lambda: apply_kernels(torch.rand(1, 3, 4, 4), torch.rand(1, 4, 4, 4)), "k odd"),
        (lambda: apply_kernels(torch.rand(1, 3, 4, 4), torch.rand(1, 9, 4, 5)), "must match"),
        (lambda: apply_kernels(torch.rand(1, 3, 4, 4), torch.rand(2, 9, 4, 4)), "must match"),
        (lambda: apply_kernels(torch.rand(3, 4, 4), torch.rand(1, 9, 4, 4)), "B, C, H, W"),
        (lambda: apply_kernels(torch.rand(1, 3, 4, 4), torch.rand(1, 9, 4, 4), tile=0), "tile"),
        (
            lambda: apply_kernels(torch.rand(1, 3, 4, 4), torch.full((1, 9, 4, 4), float("nan"))),
            "NaN",
        ),
        (lambda: accumulate_weighted(torch.rand(1, 1, 4, 4), lambda w: None, 4), "odd"),
        (lambda: accumulate_weighted(torch.rand(1, 1, 4, 4), lambda w: None, -3), "odd"),
        (
            lambda: accumulate_weighted(torch.rand(1, 1, 4, 4), lambda w: None, 3, centre="min"),
            "centre must be",
        ),
    ],
)
def test_bad_input_is_a_one_line_input_error(make, match) -> None:
    with pytest.raises(InputError, match=match) as err:
        make()
    assert "\n" not in str(err.value)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_matches_cpu() -> None:
    x = torch.rand(1, 3, 33, 47)
    wt = torch.softmax(torch.randn(1, 121, 33, 47), dim=1)
    cpu = apply_kernels(x, wt)
    gpu = apply_kernels(x.cuda(), wt.cuda(), tile=16)
    assert gpu.device.type == "cuda"
    # each value is a weighted mean of 121 values in [0, 1] with weights summing to 1: summed
    # in another order on the GPU it may move by up to 121 * eps32 (Higham's reordering
    # bound), 1.4e-5; one wrong tap (weight ~1/121) moves it by about 1e-3
    atol = wt.shape[1] * torch.finfo(torch.float32).eps
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-5, atol=atol)
