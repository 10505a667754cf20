"""Kernel prediction at several scales and Vogels' scale compositor (float32 throughout).

A kernel-predicting network outputs, per pixel and per scale ``s`` (full, 1/2, 1/4 ...),
``k²`` logits. This module turns them into an image:

1. :func:`kernel_softmax`: logits -> kernel weights, a softmax over the ``k²`` taps computed in
   float32 with autocast disabled. NaN/±Inf/huge logits are sanitised first (NaN -> 0,
   clamped to ±:data:`LOGIT_LIMIT`), so the weights are always finite, non-negative and sum to 1.
   With ``in_image=True`` the softmax runs over each pixel's *in-image* taps only (taps that
   fall outside the image get weight exactly 0). That is the same function as a softmax over
   all taps renormalised over the in-image ones, but its gradient stays finite: renormalising
   by an in-image mass near 1e-38 (a border pixel whose kernel points out of the image) divides
   by its square in the backward pass, which underflows to 0 and made 1 training step in 6
   non-finite before this was changed.
2. :func:`apply_head`: runs a 1×1 head (features -> logits), the softmax and
   :func:`~mcdenoise.filters.kernels.apply_kernels` in strips of rows, so the ``k² × H × W``
   weight tensor never exists for the whole image (441 planes of a 4K frame are 14.6 GB). The
   result does not depend on the strip height: each strip filters the rows of the image it
   covers plus ``k // 2`` rows of context on both sides (whose own results are dropped), so
   every kept pixel sees all its in-image neighbours.
3. :func:`composite`: Vogels et al. 2018's scale compositor, coarse to fine::

       fine' = fine - α · U(D(fine)) + α · U(coarse)

   with ``D`` the 2×2 box downsampling, ``U`` bilinear upsampling and ``α ∈ [0, 1]`` a per-pixel
   weight predicted by the network: ``α = 1`` takes the low frequencies from the (less noisy)
   coarse result and keeps the high frequencies of the fine one; ``α = 0`` keeps the fine result.

Everything is differentiable; images are linear HDR ``(B, C, H, W)``, ``H`` and ``W`` divisible by
``2^(scales - 1)`` (the caller pads).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from mcdenoise.filters.kernels import apply_kernels

#: Logits are clamped to ±LOGIT_LIMIT before the softmax (exp of differences stays finite).
LOGIT_LIMIT = 1e4


def _f32(t: Tensor) -> Tensor:
    """float32 unless float64 (kept for gradcheck)."""
    return t if t.dtype in (torch.float32, torch.float64) else t.float()


def _mask_out_of_image(z: Tensor) -> None:
    """Set, in place, the logits of taps that fall outside the image to -inf.

    Channel ``(dy + r) * k + (dx + r)`` is the tap at offset ``(dy, dx)``: the taps of one ``dy``
    are a block of ``k`` channels, those of one ``dx`` every ``k``-th channel, so ``4 r`` slice
    assignments on the border bands do it.
    """
    k = round(z.shape[1] ** 0.5)
    r = k // 2
    h, w = z.shape[-2:]
    for d in range(1, r + 1):
        lo, hi = (r - d) * k, (r + d) * k  # first channel of the dy = -d and dy = +d blocks
        z[:, lo : lo + k, : min(d, h)] = -math.inf
        z[:, hi : hi + k, max(0, h - d) :] = -math.inf
        z[:, r - d :: k, :, : min(d, w)] = -math.inf
        z[:, r + d :: k, :, max(0, w - d) :] = -math.inf


def kernel_softmax(logits: Tensor, *, in_image: bool = False) -> Tensor:
    """Softmax over dim 1 of ``(B, k*k, H, W)`` logits, in float32, finite for any input.

    NaN logits count as 0 and ±Inf as ±:data:`LOGIT_LIMIT`; huge finite logits are harmless
    (the maximum is subtracted first, so ``exp`` sees values <= 0 and the sum is >= 1). Without
    autograd the softmax runs in place on a float32 copy (half the memory traffic).

    ``in_image=True``: the softmax is over the taps inside the ``H × W`` image only (the
    others get weight 0; the centre tap is always inside, so every pixel's weights sum to 1).
    """
    with torch.autocast(logits.device.type, enabled=False):
        z = _f32(logits)
        if torch.is_grad_enabled() and z.requires_grad:
            z = torch.nan_to_num(z, nan=0.0, posinf=LOGIT_LIMIT, neginf=-LOGIT_LIMIT)
            if in_image:
                _mask_out_of_image(z)
            return torch.softmax(z, dim=1)
        z = z.clone() if z is logits else z
        z.nan_to_num_(nan=0.0, posinf=LOGIT_LIMIT, neginf=-LOGIT_LIMIT)
        if in_image:
            _mask_out_of_image(z)
        z.sub_(z.amax(dim=1, keepdim=True)).exp_()
        return z.div_(z.sum(dim=1, keepdim=True))


def downsample(x: Tensor) -> Tensor:
    """2×2 box mean: ``(B, C, H, W)`` -> ``(B, C, H/2, W/2)`` (H, W even)."""
    return F.avg_pool2d(x, 2)


def upsample(x: Tensor, size: tuple[int, int]) -> Tensor:
    """Bilinear upsampling to ``size`` (half-pixel centres, matching :func:`downsample`)."""
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


def head_logits(head: Callable[[Tensor], Tensor], features: Tensor) -> Tensor:
    """``head(features)``; a 1×1 :class:`~torch.nn.Conv2d` runs as one matrix product on
    contiguous NCHW features (2.4× faster than the convolution for 24 -> 441 channels on CPU)."""
    if isinstance(head, nn.Conv2d) and head.kernel_size == (1, 1) and head.groups == 1:
        b, c, h, w = features.shape
        x = features.contiguous().view(b, c, h * w)
        weight = head.weight.view(head.out_channels, c).to(x.dtype)
        bias = (
            head.bias.to(x.dtype)[:, None]
            if head.bias is not None
            else x.new_zeros((head.out_channels, 1))
        )
        # one 2-D addmm per image: the batched matmul with a broadcast weight is 4x slower
        out = torch.stack([torch.addmm(bias, weight, x[i]) for i in range(b)])
        return out.view(b, head.out_channels, h, w)
    return head(features)


def apply_head(
    image: Tensor,
    features: Tensor,
    head: Callable[[Tensor], Tensor],
    kernel_size: int,
    *,
    strip: int | None = None,
) -> Tensor:
    """Predict per-pixel kernels from ``features`` with ``head`` and apply them to ``image``.

    Args:
        image: ``(B, C, H, W)`` what the kernels average (float32).
        features: ``(B, F, H, W)`` network features at the same resolution.
        head: maps ``(B, F, h, W)`` features to ``(B, k*k, h, W)`` logits, pixel-wise (a 1×1
            convolution: strips then give exactly the same logits as the whole image).
        kernel_size: ``k`` (odd).
        strip: rows per strip (``None``: the whole image at once, e.g. for training crops).

    Returns:
        ``(B, C, H, W)`` float32: every pixel the softmax-weighted mean of its ``k × k``
        neighbours (in-image neighbours only; see :func:`~mcdenoise.filters.kernels.apply_kernels`).
    """
    h = image.shape[-2]
    image = _f32(image)
    if strip is None or strip >= h:
        with torch.autocast(image.device.type, enabled=False):
            w = kernel_softmax(head_logits(head, features), in_image=True)
            return apply_kernels(image, w, normalize=True)
    r = kernel_size // 2
    out = torch.empty_like(image)
    for y0 in range(0, h, strip):
        y1 = min(h, y0 + strip)
        # the strip's rows plus r rows of context each side (their own results are dropped)
        a, b = max(0, y0 - r), min(h, y1 + r)
        w = kernel_softmax(head_logits(head, features[..., a:b, :]), in_image=True)
        with torch.autocast(image.device.type, enabled=False):
            res = apply_kernels(image[..., a:b, :], w, normalize=True)
        out[..., y0:y1, :] = res[..., y0 - a : y1 - a, :]
    return out


def composite(fine: Tensor, coarse: Tensor, alpha: Tensor) -> Tensor:
    """Vogels' scale compositor (see the module docstring).

    Args:
        fine: ``(B, C, H, W)`` result at the finer scale.
        coarse: ``(B, C, H/2, W/2)`` result at the next coarser scale.
        alpha: ``(B, 1, H, W)`` blend weights in [0, 1] (low frequencies from ``coarse``).
    """
    with torch.autocast(fine.device.type, enabled=False):
        fine, coarse, alpha = (_f32(t) for t in (fine, coarse, alpha))
        size = (fine.shape[-2], fine.shape[-1])
        low_fine = upsample(downsample(fine), size)
        return fine + alpha * (upsample(coarse, size) - low_fine)


__all__ = [
    "LOGIT_LIMIT",
    "apply_head",
    "composite",
    "downsample",
    "head_logits",
    "kernel_softmax",
    "upsample",
]
