"""Multi-scale kernel prediction: safe softmax, strip-wise kernel application, scale compositor."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from mcdenoise.models.multiscale import (
    LOGIT_LIMIT,
    apply_head,
    composite,
    downsample,
    head_logits,
    kernel_softmax,
    upsample,
)

#: one intra-op thread for this module (tests/conftest.py)
ONE_THREAD = True

#: float32 epsilon. A k x k kernel's softmax and its application sum k² terms; two float32
#: computations of such a sum by different paths (torch's softmax against ours, strips
#: against the whole image, another CPU's vector width) may differ by up to (k² - 1) *
#: EPS32 / 2 relative (Higham's bound for reordering a sum of non-negative terms), plus an
#: ulp or two of ``exp``. The comparisons of such results below allow k² * EPS32 (3e-6 for
#: k = 5) relative to the values compared, far below what a wrong tap, axis or
#: normalisation gives (1e-2 and more).
EPS32 = torch.finfo(torch.float32).eps


def _check_kernels(w: torch.Tensor) -> None:
    assert w.dtype == torch.float32
    assert bool(torch.isfinite(w).all())
    assert bool((w >= 0).all())
    torch.testing.assert_close(w.sum(1), torch.ones_like(w.sum(1)), atol=1e-5, rtol=0)


# --- kernel_softmax ----------------------------------------------------------------------


def _hostile_logits() -> torch.Tensor:
    """``(1, 9, 2, 4)`` logits; every pixel holds another kind of trouble (docs/hard-cases.md item 21)."""
    g = torch.Generator().manual_seed(0)
    z = torch.randn(1, 9, 2, 4, generator=g)
    z[0, 0, 0, 0] = 1e30  # one huge tap
    z[0, :, 0, 1] = 1e30  # every tap huge
    z[0, 3, 0, 2] = float("inf")  # one +Inf tap
    z[0, 5, 0, 2] = float("inf")  # ... and another
    z[0, 4, 0, 3] = float("-inf")  # one -Inf tap
    z[0, 2, 1, 0] = float("nan")  # one NaN tap
    z[0, :, 1, 1] = float("-inf")  # every tap -Inf
    z[0, :, 1, 2] = float("nan")  # every tap NaN
    z[0, :, 1, 3] = -1e30  # every tap hugely negative
    return z


@pytest.mark.parametrize("grad", [False, True], ids=["inference", "autograd"])
def test_softmax_is_a_finite_partition_of_unity_for_any_logits(grad: bool) -> None:
    z = _hostile_logits()
    before = z.clone()
    z.requires_grad_(grad)
    w = kernel_softmax(z)
    _check_kernels(w.detach())
    # the input is never modified in place (the inference path works on a copy)
    torch.testing.assert_close(z.detach(), before, equal_nan=True, atol=0, rtol=0)
    w = w.detach()[0]
    assert float(w[0, 0, 0]) == pytest.approx(1.0)  # a huge tap takes all the weight
    assert w[:, 0, 1].tolist() == pytest.approx([1 / 9] * 9)  # all equal: uniform
    # two +Inf taps share the weight; the -Inf tap gets none
    assert float(w[3, 0, 2]) == pytest.approx(0.5) and float(w[5, 0, 2]) == pytest.approx(0.5)
    assert float(w[4, 0, 3]) == 0.0
    for px in ((1, 1), (1, 2), (1, 3)):  # all -Inf / all NaN / all -1e30: uniform, never 0/0
        assert w[:, px[0], px[1]].tolist() == pytest.approx([1 / 9] * 9)
    if grad:
        kernel_softmax(z).square().sum().backward()
        assert bool(torch.isfinite(z.grad).all())


def test_softmax_matches_torch_on_ordinary_logits() -> None:
    z = torch.randn(2, 25, 3, 5) * 4
    torch.testing.assert_close(kernel_softmax(z), torch.softmax(z, 1), atol=1e-7, rtol=25 * EPS32)
    # NaN counts as 0, Inf as the limit
    z[0, 0, 0, 0] = float("nan")
    z[0, 1, 0, 0] = float("inf")
    want = torch.softmax(torch.nan_to_num(z, nan=0.0, posinf=LOGIT_LIMIT), 1)
    torch.testing.assert_close(kernel_softmax(z), want)


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
def test_softmax_is_float32_under_autocast(dtype: torch.dtype) -> None:
    z = (torch.randn(1, 9, 4, 4) * 30).to(dtype)
    z[0, 0, 0, 0] = float("inf")
    z[0, :, 1, 1] = torch.finfo(dtype).max  # the largest finite value of the low precision
    for requires_grad in (False, True):
        with torch.autocast("cpu", dtype=dtype):
            w = kernel_softmax(z.clone().requires_grad_(requires_grad))
        _check_kernels(w.detach())
        # computed from the float32 logits (the same values), not in the low precision
        torch.testing.assert_close(w.detach(), kernel_softmax(z.float()), atol=1e-7, rtol=9 * EPS32)


def test_in_image_softmax_is_the_softmax_renormalised_over_the_in_image_taps() -> None:
    k, h, w = 5, 6, 7
    r = k // 2
    z = torch.randn(2, k * k, h, w, generator=torch.Generator().manual_seed(3)) * 3
    inside = torch.zeros(1, k * k, h, w, dtype=torch.bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            ys, xs = torch.arange(h)[:, None] + dy, torch.arange(w)[None, :] + dx
            inside[0, (dy + r) * k + dx + r] = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
    full = torch.softmax(z, 1) * inside
    want = full / full.sum(1, keepdim=True)
    for grad in (False, True):
        got = kernel_softmax(z.clone().requires_grad_(grad), in_image=True).detach()
        torch.testing.assert_close(got, want, atol=1e-7, rtol=k * k * EPS32)
        assert bool((got[~inside.expand_as(got)] == 0).all())  # exactly 0 outside the image
        _check_kernels(got)


def test_border_kernels_pointing_out_of_the_image_keep_gradients_finite() -> None:
    """A border pixel whose kernel puts ~all its mass outside the image: renormalising by an
    in-image mass of ~1e-37 overflowed the backward pass (NaN gradients made 1 training step
    in 6 non-finite); the in-image softmax keeps it finite, also where the loss ignores the
    pixel (a zero upstream gradient must not become 0 * inf)."""
    k, h, w = 5, 8, 8
    # demodulated irradiance of a bright light: values ~1e4
    image = torch.rand(1, 3, h, w, generator=torch.Generator().manual_seed(0)) * 1e4
    feats = torch.ones(1, 1, h, w)
    head = nn.Conv2d(1, k * k, 1)
    with torch.no_grad():
        head.weight.zero_()
        head.bias.zero_()
        head.bias[0] = 86.0  # the (-2, -2) tap: outside the image in the top rows and columns
    out = apply_head(image, feats, head, k)
    mask = torch.zeros_like(out)
    mask[..., 2:-2, 2:-2] = 1  # the loss sees the centre only, as on training crops
    ((out - image) * mask).square().sum().backward()
    assert bool(torch.isfinite(out).all())
    assert all(bool(torch.isfinite(p.grad).all()) for p in head.parameters())
    assert float(head.bias.grad.abs().sum()) > 0


# --- head_logits / apply_head -------------------------------------------------------------


def test_head_logits_equals_the_convolution() -> None:
    head = nn.Conv2d(6, 9, 1)
    feats = torch.randn(3, 6, 5, 7)
    torch.testing.assert_close(head_logits(head, feats), head(feats), atol=1e-6, rtol=1e-5)
    # channels-last (what the encoder produces) and a non-contiguous slice give the same
    cl = feats.contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(head_logits(head, cl), head(feats), atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(
        head_logits(head, feats[..., 1:4, :]), head(feats[..., 1:4, :]), atol=1e-6, rtol=1e-5
    )
    other = nn.Conv2d(6, 9, 3, padding=1)  # not 1x1: the module itself is called
    assert torch.equal(head_logits(other, feats), other(feats))


@pytest.mark.parametrize("kernel", [3, 5])
def test_strips_give_the_unstripped_result(kernel: int) -> None:
    g = torch.Generator().manual_seed(1)
    h, w = 13, 9
    image = torch.rand(2, 3, h, w, generator=g)  # [0, 1]: k² * EPS32 absolute (EPS32 above)
    feats = torch.randn(2, 6, h, w, generator=g)
    head = nn.Conv2d(6, kernel * kernel, 1)
    with torch.no_grad():
        head.weight.mul_(5)  # peaked, varied kernels: a wrong neighbour would show
        whole = apply_head(image, feats, head, kernel)
        assert not torch.allclose(whole, image, atol=1e-2)  # the kernels do filter
        for strip in (1, 2, 3, 4, 5, 7, 12, 13, 100):
            part = apply_head(image, feats, head, kernel, strip=strip)
            torch.testing.assert_close(
                part, whole, atol=kernel * kernel * EPS32, rtol=0, msg=f"strip {strip}"
            )


def test_identity_head_returns_the_image() -> None:
    k = 5
    head = nn.Conv2d(4, k * k, 1)
    with torch.no_grad():
        head.weight.zero_()
        head.bias.zero_()
        head.bias[k * k // 2] = 1e6  # centre logit huge
    image = torch.rand(1, 3, 9, 11) * 1e4
    image[0, :, 4, 4] = 0.0
    feats = torch.randn(1, 4, 9, 11)
    with torch.no_grad():
        for strip in (None, 2):
            torch.testing.assert_close(
                apply_head(image, feats, head, k, strip=strip), image, atol=0, rtol=1e-6
            )


def test_a_constant_image_stays_constant_under_any_kernels() -> None:
    head = nn.Conv2d(4, 9, 1)
    with torch.no_grad():
        head.weight.mul_(10)
        out = apply_head(torch.full((1, 3, 8, 6), 2.5), torch.randn(1, 4, 8, 6), head, 3, strip=3)
    # 9 taps summing to 1 (to 9 * EPS32), each times 2.5 (EPS32 above)
    torch.testing.assert_close(out, torch.full_like(out, 2.5), atol=2.5 * 9 * EPS32, rtol=0)


def test_apply_head_output_is_float32_under_bf16_autocast() -> None:
    head = nn.Conv2d(4, 9, 1)
    image = (torch.rand(1, 3, 6, 6) * 1e5).bfloat16()  # HDR near 1e5 (docs/hard-cases.md item 22)
    feats = torch.randn(1, 4, 6, 6)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        for strip in (None, 2):
            out = apply_head(image, feats, head, 3, strip=strip)
            assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())


# --- down/upsampling and the compositor ------------------------------------------------------


def test_down_and_upsampling_shapes_and_constants() -> None:
    x = torch.full((2, 3, 8, 6), 0.7)
    d = downsample(x)
    assert d.shape == (2, 3, 4, 3)
    torch.testing.assert_close(upsample(d, (8, 6)), x)
    # the box mean of a 2x2 block
    y = torch.arange(16.0).view(1, 1, 4, 4)
    assert downsample(y)[0, 0].tolist() == [[2.5, 4.5], [10.5, 12.5]]


def test_composite_alpha_zero_keeps_the_fine_result() -> None:
    g = torch.Generator().manual_seed(2)
    fine = torch.rand(2, 3, 8, 10, generator=g)
    coarse = torch.rand(2, 3, 4, 5, generator=g) * 100
    assert torch.equal(composite(fine, coarse, torch.zeros(2, 1, 8, 10)), fine)


def test_composite_alpha_one_with_the_fines_own_coarse_version_is_the_fine_result() -> None:
    # fine + α·(U(coarse) - U(D(fine))) with coarse = D(fine): both upsamplings are the same
    # computation on the same values, so this holds bit for bit for ANY image, although
    # U∘D (bilinear after box) is a blur, not the identity:
    g = torch.Generator().manual_seed(3)
    fine = torch.rand(1, 3, 8, 8, generator=g)
    assert torch.equal(composite(fine, downsample(fine), torch.ones(1, 1, 8, 8)), fine)
    assert not torch.allclose(upsample(downsample(fine), (8, 8)), fine, atol=1e-2)


def test_composite_alpha_one_takes_low_frequencies_from_the_coarse_result() -> None:
    # With a constant coarse image b and a fine image a + checkerboard: D(fine) = a exactly
    # (each 2x2 block holds two +h and two -h), U of a constant is that constant, so the
    # result is b + checkerboard: mean from the coarse scale, detail from the fine one.
    a, b, h = 0.5, 2.0, 0.1
    yy, xx = torch.meshgrid(torch.arange(8), torch.arange(6), indexing="ij")
    checker = torch.where((yy + xx) % 2 == 0, h, -h).float()
    fine = (a + checker).expand(1, 3, 8, 6)
    coarse = torch.full((1, 3, 4, 3), b)
    out = composite(fine, coarse, torch.ones(1, 1, 8, 6))
    torch.testing.assert_close(out, (b + checker).expand(1, 3, 8, 6), atol=1e-6, rtol=0)
    # constant images: alpha = 1 returns the coarse constant
    out = composite(torch.full((1, 3, 8, 6), a), coarse, torch.ones(1, 1, 8, 6))
    torch.testing.assert_close(out, torch.full_like(out, b), atol=1e-6, rtol=0)


def test_composite_is_linear_in_alpha() -> None:
    g = torch.Generator().manual_seed(4)
    fine = torch.rand(1, 3, 8, 8, generator=g)
    coarse = torch.rand(1, 3, 4, 4, generator=g)
    alpha = torch.rand(1, 1, 8, 8, generator=g)
    lo = composite(fine, coarse, torch.zeros_like(alpha))
    hi = composite(fine, coarse, torch.ones_like(alpha))
    torch.testing.assert_close(composite(fine, coarse, alpha), lo + alpha * (hi - lo))


def test_composite_is_float32_under_bf16_autocast() -> None:
    fine = torch.rand(1, 3, 4, 4).bfloat16()
    coarse = torch.rand(1, 3, 2, 2).bfloat16()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = composite(fine, coarse, torch.full((1, 1, 4, 4), 0.5).bfloat16())
    assert out.dtype == torch.float32


# --- gradients (float64 gradcheck) -------------------------------------------------------------


def test_composite_gradcheck() -> None:
    g = torch.Generator().manual_seed(5)
    fine = torch.rand(1, 2, 4, 6, dtype=torch.float64, generator=g, requires_grad=True)
    coarse = torch.rand(1, 2, 2, 3, dtype=torch.float64, generator=g, requires_grad=True)
    alpha = torch.rand(1, 1, 4, 6, dtype=torch.float64, generator=g, requires_grad=True)
    assert torch.autograd.gradcheck(composite, (fine, coarse, alpha))


@pytest.mark.parametrize("strip", [None, 2])
def test_apply_head_gradcheck_through_image_features_and_head(strip: int | None) -> None:
    g = torch.Generator().manual_seed(6)
    k, n_feat = 3, 2
    head = nn.Conv2d(n_feat, k * k, 1).double()
    image = torch.rand(1, 2, 6, 6, dtype=torch.float64, generator=g, requires_grad=True)
    feats = torch.randn(1, n_feat, 6, 6, dtype=torch.float64, generator=g, requires_grad=True)
    weight = head.weight.detach().clone().requires_grad_(True)
    bias = head.bias.detach().clone().requires_grad_(True)
    del head.weight, head.bias  # plain tensors from here on: the predicted head parameters

    def fn(img, f, w, b):
        head.weight, head.bias = w, b  # apply_head still sees a 1x1 nn.Conv2d (addmm path)
        return apply_head(img, f, head, k, strip=strip)

    assert torch.autograd.gradcheck(fn, (image, feats, weight, bias))
