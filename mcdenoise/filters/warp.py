"""Backward warping of an image by per-pixel motion vectors, with a validity mask.

Convention (the ``motion`` buffer, :mod:`mcdenoise.io.buffers`): ``motion`` of frame ``t`` is
in pixels, x right, y down, and the surface seen through the centre of pixel ``p`` was at
``p + motion(p)`` on the film of frame ``t - 1`` (continuous film coordinates, pixel
``(i, j)`` spans ``[j, j + 1] × [i, i + 1]``, so its centre is ``(j + 0.5, i + 0.5)``).
Warping an image ``prev`` of frame ``t - 1`` to frame ``t`` samples it bilinearly there:
in pixel-index coordinates (pixel ``j`` at ``x = j``) the sample sits at
``x = j + motion_x``, ``y = i + motion_y``, between the four taps
``(floor(x) + {0, 1}, floor(y) + {0, 1})``. This is the tap pattern of Falcor's
``SVGFReproject.ps.slang`` (``posPrev = floor(posH) + motion * imageDim``, the four
``offset`` taps with bilinear weights from ``frac(posPrev)``) and of
``torch.nn.functional.grid_sample(..., align_corners=False)`` at ``p + 0.5 + motion``.

Invalid taps are **never read**: a tap outside the film, a tap on a pixel whose
``source_valid`` is 0, a tap that ``tap_valid`` rejects (e.g. SVGF's depth/normal
consistency tests), and every tap of an output pixel whose ``valid`` (the frame's
``motion_valid``) is 0 are masked with ``torch.where`` before anything is multiplied, so a
NaN or a huge value there cannot leak into the result or its gradient. The weights of the
remaining taps are renormalised (Falcor: "redistribute weights in case not all taps were
used"); an output pixel whose valid taps carry less than ``min_weight`` of the bilinear
weight (Falcor: ``sumw >= 0.01``) is invalid: value 0, mask 0.

Everything is plain vectorised torch (``gather`` on the flattened image), on the CPU or
CUDA, and differentiable with respect to the image (and, through the bilinear weights,
to the motion away from integer positions). The temporal methods (``svgf``, the temporal
KPCN) use it; :func:`mcdenoise.render.animation.warp_previous` is the renderer's own
``grid_sample`` check of its motion vectors, with border clamping and no mask.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mcdenoise.errors import InputError

#: Offsets ``(dx, dy)`` of the four bilinear taps, in Falcor's order.
TAP_OFFSETS: tuple[tuple[int, int], ...] = ((0, 0), (1, 0), (0, 1), (1, 1))
#: An output pixel needs valid taps with at least this much bilinear weight (Falcor 0.01).
MIN_WEIGHT = 0.01


@dataclass(frozen=True)
class BilinearTaps:
    """The four bilinear taps of every output pixel (see the module doc).

    Attributes:
        index: ``(B, 4, H, W)`` int64 flat index ``y * W + x`` of each tap in the source
            image, clamped onto the film (read only where ``inside``).
        weight: ``(B, 4, H, W)`` bilinear weight of each tap (sums to 1 per pixel).
        inside: ``(B, 4, H, W)`` bool, the tap lies on the source film (and the motion is
            finite).
        x, y: ``(B, 4, H, W)`` int64 tap column and row (unclamped, for callers that look
            at neighbourhoods of a tap).
    """

    index: Tensor
    weight: Tensor
    inside: Tensor
    x: Tensor
    y: Tensor


def _check(image: Tensor, motion: Tensor) -> None:
    if not isinstance(image, Tensor) or image.ndim != 4 or not image.is_floating_point():
        got = tuple(image.shape) if isinstance(image, Tensor) else type(image).__name__
        raise InputError(f"warp: image must be a floating (B, C, H, W) tensor, got {got}")
    if not isinstance(motion, Tensor) or motion.ndim != 4 or motion.shape[1] != 2:
        got = tuple(motion.shape) if isinstance(motion, Tensor) else type(motion).__name__
        raise InputError(f"warp: motion must be a (B, 2, H, W) tensor, got {got}")
    if motion.shape[0] != image.shape[0] or motion.shape[2:] != image.shape[2:]:
        raise InputError(
            f"warp: motion {tuple(motion.shape)} does not fit image {tuple(image.shape)} "
            "(batch, height and width must match)"
        )
    if motion.device != image.device:
        raise InputError(f"warp: motion is on {motion.device} but the image on {image.device}")


def _check_mask(mask: Tensor | None, image: Tensor, name: str, channels: int = 1) -> None:
    if mask is None:
        return
    b, _, h, w = image.shape
    if not isinstance(mask, Tensor) or tuple(mask.shape) != (b, channels, h, w):
        got = tuple(mask.shape) if isinstance(mask, Tensor) else type(mask).__name__
        raise InputError(f"warp: {name} must have shape {(b, channels, h, w)}, got {got}")


def bilinear_taps(motion: Tensor, dtype: torch.dtype | None = None) -> BilinearTaps:
    """The bilinear taps of ``motion`` ``(B, 2, H, W)`` (source and output are H×W).

    A non-finite motion makes every tap of its pixel fall outside (never read).
    """
    dtype = dtype or (motion.dtype if motion.is_floating_point() else torch.float32)
    h, w = motion.shape[2:]
    m = motion.to(dtype)
    finite = torch.isfinite(m).all(dim=1)
    # Clamp far-away samples to just outside the film: their taps stay outside, and the
    # float -> int conversion below never overflows.
    xs = torch.arange(w, dtype=dtype, device=m.device).view(1, 1, w) + m[:, 0]
    ys = torch.arange(h, dtype=dtype, device=m.device).view(1, h, 1) + m[:, 1]
    xs = torch.where(finite, xs, torch.full_like(xs, -4.0)).clamp(-4.0, w + 4.0)
    ys = torch.where(finite, ys, torch.full_like(ys, -4.0)).clamp(-4.0, h + 4.0)
    x0, y0 = torch.floor(xs), torch.floor(ys)
    fx, fy = xs - x0, ys - y0
    x0i, y0i = x0.long(), y0.long()
    weights, indices, insides, tx, ty = [], [], [], [], []
    for dx, dy in TAP_OFFSETS:
        ix, iy = x0i + dx, y0i + dy
        wx = fx if dx else 1.0 - fx
        wy = fy if dy else 1.0 - fy
        weights.append(wx * wy)
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h) & finite
        insides.append(inside)
        indices.append(iy.clamp(0, h - 1) * w + ix.clamp(0, w - 1))
        tx.append(ix)
        ty.append(iy)
    return BilinearTaps(
        index=torch.stack(indices, dim=1),
        weight=torch.stack(weights, dim=1),
        inside=torch.stack(insides, dim=1),
        x=torch.stack(tx, dim=1),
        y=torch.stack(ty, dim=1),
    )


def gather_flat(image: Tensor, index: Tensor) -> Tensor:
    """``image`` ``(B, C, H, W)`` read at flat indices ``index`` ``(B, H', W')`` (each in
    ``[0, H·W)``): ``(B, C, H', W')``."""
    b, c, h, w = image.shape
    flat = image.reshape(b, c, h * w)
    idx = index.reshape(b, 1, -1).expand(b, c, index.shape[1] * index.shape[2])
    return flat.gather(2, idx).reshape(b, c, index.shape[1], index.shape[2])


def gather_taps(image: Tensor, taps: BilinearTaps) -> list[Tensor]:
    """The four taps of ``image`` ``(B, C, H, W)``: a list of ``(B, C, H, W)``, in
    :data:`TAP_OFFSETS` order (clamped reads: mask them with ``taps.inside``)."""
    return [gather_flat(image, taps.index[:, k]) for k in range(len(TAP_OFFSETS))]


def warp(
    image: Tensor,
    motion: Tensor,
    *,
    valid: Tensor | None = None,
    source_valid: Tensor | None = None,
    tap_valid: Tensor | None = None,
    taps: BilinearTaps | None = None,
    min_weight: float = MIN_WEIGHT,
) -> tuple[Tensor, Tensor]:
    """Backward-warp ``image`` (frame ``t - 1``) to frame ``t`` along ``motion``.

    Args:
        image: ``(B, C, H, W)`` floating data of the source frame; may hold NaN/Inf where it
            is never read (invalid taps).
        motion: ``(B, 2, H, W)`` motion of frame ``t`` to frame ``t - 1``, pixels, x right,
            y down (the ``motion`` buffer).
        valid: ``(B, 1, H, W)`` on the output grid (the ``motion_valid`` buffer of frame
            ``t``); where it is <= 0.5 nothing is read and the output is invalid.
        source_valid: ``(B, 1, H, W)`` on the source grid; a tap on a pixel where it is
            <= 0.5 is not read (e.g. pixels that hold no history).
        tap_valid: ``(B, 4, H, W)`` bool, per output pixel and tap (in :data:`TAP_OFFSETS`
            order): further tap tests of the caller (SVGF's depth/normal consistency).
        taps: the :func:`bilinear_taps` of ``motion`` when the caller already has them.
        min_weight: an output pixel is valid when its valid taps carry at least this much
            bilinear weight (Falcor's 0.01).

    Returns:
        ``(warped, mask)``: ``(B, C, H, W)`` in ``image``'s dtype (0 where invalid) and the
        ``(B, 1, H, W)`` validity mask (1.0 / 0.0, same dtype).

    Raises:
        InputError: shapes or devices that do not fit.

    Example:
        >>> img = torch.arange(12.0).view(1, 1, 3, 4)
        >>> out, mask = warp(img, torch.zeros(1, 2, 3, 4))
        >>> bool(torch.equal(out, img)), bool(mask.all())
        (True, True)
    """
    _check(image, motion)
    _check_mask(valid, image, "valid")
    _check_mask(source_valid, image, "source_valid")
    _check_mask(tap_valid, image, "tap_valid", len(TAP_OFFSETS))
    if taps is None:
        taps = bilinear_taps(motion, image.dtype)
    ok = taps.inside
    if tap_valid is not None:
        ok = ok & tap_valid.to(torch.bool)
    if valid is not None:
        ok = ok & (valid > 0.5)
    if source_valid is not None:
        src = (source_valid > 0.5).to(image.dtype)
        ok = ok & torch.cat([gather_flat(src, taps.index[:, k]) for k in range(4)], 1).bool()
    weight = torch.where(ok, taps.weight.to(image.dtype), torch.zeros((), dtype=image.dtype))
    total = weight.sum(dim=1, keepdim=True)
    mask = total >= min_weight
    out = torch.zeros_like(image)
    zero = torch.zeros((), dtype=image.dtype, device=image.device)
    for k, tap in enumerate(gather_taps(image, taps)):
        read = torch.where(ok[:, k : k + 1], tap, zero)  # never multiply an unread value
        out = out + weight[:, k : k + 1] * read
    safe = torch.where(mask, total, torch.ones_like(total))
    out = torch.where(mask, out / safe, zero)
    return out, mask.to(image.dtype)


__all__ = [
    "MIN_WEIGHT",
    "TAP_OFFSETS",
    "BilinearTaps",
    "bilinear_taps",
    "gather_flat",
    "gather_taps",
    "warp",
]
