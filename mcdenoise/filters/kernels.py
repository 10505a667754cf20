"""Per-pixel k×k weighted sums, memory-bounded: the engine under every filter of this package.

For each pixel ``i`` and a ``k × k`` window ``N(i)`` centred on it::

    out_i = Σ_{j ∈ N(i)} w_ij x_j / Σ_{j ∈ N(i)} w_ij

The window is never materialised as a ``k² × C × H × W`` tensor (``unfold`` at 21×21 on a
1080p frame needs more than 22 GB). Instead the image is cut into output tiles and, inside a
tile, the sum loops over the ``k²`` offsets ``(dy, dx)`` with in-place ``addcmul_`` on views:
no padding and no halo copy are needed because every neighbour is read straight from the input
image. Peak extra memory is one accumulator tile plus whatever one offset's weights need.

Two entry points share one private loop (``_accumulate``):

* :func:`apply_kernels` -- explicit per-pixel weights ``(B, k*k, H, W)``, e.g. the softmax
  kernels of a kernel-predicting CNN;
* :func:`accumulate_weighted` -- weights computed per offset by a callback from per-pixel
  parameters and guide features (the cross-bilateral and NLM filters), so no ``k²`` weight
  tensor exists at all.

Policies (docs/hard-cases.md items 15, 17, 20):

* **Borders**: only in-image neighbours count; the sum is renormalised over them. A positive
  image is never darkened near the border and no padding value leaks in.
* **Underflow**: a pixel whose in-image weights sum to less than the dtype's smallest normal
  number falls back to its own (centre) value, never 0/0.
* **Tiling**: every pixel sums its offsets in the same order whatever the tile size, so tiled
  and untiled results agree to rounding (bit-identical for :func:`apply_kernels`).
* **Centre weight** (:func:`accumulate_weighted`, ``centre="max"``): the pixel's own weight is
  replaced by the largest weight of its other neighbours (Buades, Coll, Morel 2005, "A review
  of image denoising algorithms", SIAM MMS 4(2), section 5.1). A distance-based weight gives
  the centre the best possible score, 1; a pixel whose neighbourhood matches nothing -- a
  firefly above all -- then keeps its own value whatever its noise. With the rule it is
  averaged with its best matches instead; where everything matches (flat regions) the
  largest weight is about 1 and nothing changes.

Everything is plain differentiable torch: gradients flow to the image, the weights and every
tensor the callback uses. Under autograd each offset's weights are kept for the backward pass
(``k²`` weight tiles), so use ``torch.no_grad()`` for inference on large images.

Strategies measured for :func:`apply_kernels` (float32, 1024×1024, 21×21, C = 3, 2 cores,
seconds): offset loop with ``addcmul_`` on channel-first views 0.45 untiled, 0.42 with 512²
tiles, 0.56 / 1.06 / 3.1 with 256² / 128² / 64² tiles (per-op overhead wins over cache
locality); the same loop with the weight sum as an extra ones-channel 0.58; channel-last
1.46; ``unfold`` of 64²/128² tiles + ``einsum`` 16-19. Weights that underflow to denormal
numbers make ``exp`` and the products 20x slower, hence :func:`neg_exp`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters._common import check_image, check_kernel_size
from mcdenoise.filters.parallel import parallel_map

#: Default output tile edge of :func:`apply_kernels` (measured fastest on 2 cores, see
#: ``benchmarks/bench_filters.py``: its per-offset work is two streaming ops).
KERNEL_TILE = 512
#: Default output tile edge of :func:`accumulate_weighted` (weight callbacks make ~15 small
#: temporaries per offset; 256×256 keeps them in cache).
CALLBACK_TILE = 256


@dataclass(frozen=True)
class Window:
    """One offset ``(dy, dx)`` of the window, restricted to one output tile.

    The slices select the rectangle of centre pixels ``i`` of the tile whose neighbour
    ``j = i + (dy, dx)`` lies inside the image (out-of-image neighbours are skipped).

    Attributes:
        dy, dx: offset of the neighbour, in ``[-r, r]`` with ``r = k // 2``.
        index: row-major tap index ``(dy + r) * k + (dx + r)``: the channel of this offset in
            an explicit ``(B, k*k, H, W)`` weight tensor.
        yi, xi: rows / columns of the centre pixels, in image coordinates.
        yj, xj: rows / columns of their neighbours, in image coordinates.
        ty, tx: the same centre pixels in tile-local coordinates.
        height, width: size ``(H, W)`` of the whole image.
    """

    dy: int
    dx: int
    index: int
    yi: slice
    xi: slice
    yj: slice
    xj: slice
    ty: slice
    tx: slice
    height: int
    width: int

    def centre(self, t: Tensor) -> Tensor:
        """View of ``t[..., yi, xi]`` (per-pixel values at the centre pixels)."""
        return t[..., self.yi, self.xi]

    def neighbour(self, t: Tensor) -> Tensor:
        """View of ``t[..., yj, xj]`` (values at the neighbours)."""
        return t[..., self.yj, self.xj]

    def param(self, p: float | Tensor) -> float | Tensor:
        """A parameter at the centre pixels: floats, 0-d and ``(B, 1, 1, 1)`` tensors as they
        are (they broadcast), per-pixel ``(B, 1, H, W)`` tensors sliced."""
        if isinstance(p, Tensor) and p.ndim >= 2 and (p.shape[-2] > 1 or p.shape[-1] > 1):
            return p[..., self.yi, self.xi]
        return p


#: Callback returning the weights ``(B, 1, h, w)`` (non-negative) of one :class:`Window`, or
#: ``None`` when they are all exactly zero (the offset is then skipped).
WeightFn = Callable[[Window], Tensor | None]


def _tile_size(tile: int | tuple[int, int] | None, default: int, h: int, w: int) -> tuple[int, int]:
    if tile is None:
        th = tw = default
    elif isinstance(tile, int) and not isinstance(tile, bool):
        th = tw = tile
    elif (
        isinstance(tile, tuple)
        and len(tile) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) for v in tile)
    ):
        th, tw = tile
    else:
        raise InputError(f"tile must be an int or a (height, width) pair, got {tile!r}")
    if th < 1 or tw < 1:
        raise InputError(f"tile must be positive, got {tile!r}")
    return min(th, h), min(tw, w)


def _tiles(h: int, w: int, th: int, tw: int) -> Iterator[tuple[int, int, int, int]]:
    for y0 in range(0, h, th):
        for x0 in range(0, w, tw):
            yield y0, min(y0 + th, h), x0, min(x0 + tw, w)


def _windows(k: int, h: int, w: int, ty0: int, ty1: int, tx0: int, tx1: int) -> Iterator[Window]:
    """Offsets of a k×k window over one tile, row-major, skipping fully out-of-image ones."""
    r = k // 2
    for dy in range(-r, r + 1):
        y0, y1 = max(ty0, -dy), min(ty1, h - dy)
        if y1 <= y0:
            continue
        for dx in range(-r, r + 1):
            x0, x1 = max(tx0, -dx), min(tx1, w - dx)
            if x1 <= x0:
                continue
            yield Window(
                dy=dy,
                dx=dx,
                index=(dy + r) * k + (dx + r),
                yi=slice(y0, y1),
                xi=slice(x0, x1),
                yj=slice(y0 + dy, y1 + dy),
                xj=slice(x0 + dx, x1 + dx),
                ty=slice(y0 - ty0, y1 - ty0),
                tx=slice(x0 - tx0, x1 - tx0),
                height=h,
                width=w,
            )


def _strips(
    ty0: int, ty1: int, tx0: int, tx1: int, y0: int, y1: int, x0: int, x1: int
) -> Iterator[tuple[slice, slice]]:
    """The part of tile ``[ty0,ty1)×[tx0,tx1)`` outside the rectangle ``[y0,y1)×[x0,x1)``."""
    y0, y1 = min(max(y0, ty0), ty1), max(min(y1, ty1), ty0)
    if y1 <= y0:  # nothing valid: the whole tile
        yield slice(ty0, ty1), slice(tx0, tx1)
        return
    x0, x1 = min(max(x0, tx0), tx1), max(min(x1, tx1), tx0)
    if ty0 < y0:
        yield slice(ty0, y0), slice(tx0, tx1)
    if y1 < ty1:
        yield slice(y1, ty1), slice(tx0, tx1)
    if tx0 < x0:
        yield slice(y0, y1), slice(tx0, x0)
    if x1 < tx1:
        yield slice(y0, y1), slice(max(x1, x0), tx1)


def _accumulate(
    image: Tensor,
    weight_fn: WeightFn,
    k: int,
    tile: tuple[int, int],
    tap_fn: Callable[[int, slice, slice], Tensor] | None = None,
    centre_max: bool = False,
) -> Tensor:
    """The shared loop.

    With ``centre_max`` the weight of offset ``(0, 0)`` is not asked for: the centre gets the
    largest weight of the other offsets, added after them (a pixel with no other weight keeps
    its own value through the underflow rule).

    With ``tap_fn(index, ys, xs)`` (weights of one tap over an image region), the kernels are
    taken as already normalised: each pixel keeps its total mass ``Σ_all w`` (in- and
    out-of-image taps) and the out-of-image share is redistributed over the in-image taps
    (see :func:`apply_kernels` with ``normalize=False``). Only the thin border strips where a
    tap falls outside the image are read for that.

    Tiles run in parallel (:func:`_run_tiles`).
    """
    b, c, h, w = image.shape
    r = k // 2
    tiny = torch.finfo(image.dtype).tiny
    out = torch.empty_like(image)

    def one_tile(ty0: int, ty1: int, tx0: int, tx1: int) -> None:
        shape = (ty1 - ty0, tx1 - tx0)
        acc = image.new_zeros((b, c, *shape))  # Σ w x over in-image taps   (B, C, th, tw)
        wsum = image.new_zeros((b, 1, *shape))  # Σ w over in-image taps    (B, 1, th, tw)
        wmax = image.new_zeros((b, 1, *shape)) if centre_max else None  # max w, off-centre
        grad = torch.is_grad_enabled()
        for win in _windows(k, h, w, ty0, ty1, tx0, tx1):
            if wmax is not None and win.dy == 0 and win.dx == 0:
                continue
            wt = weight_fn(win)  # (B, 1, h', w')
            if wt is None:
                continue
            acc[:, :, win.ty, win.tx].addcmul_(win.neighbour(image), wt)
            wsum[:, :, win.ty, win.tx].add_(wt)
            if wmax is not None:
                if grad:  # out of place: autograd keeps the maximum's inputs
                    ty, tx = win.ty, win.tx
                    pad = (tx.start, shape[1] - tx.stop, ty.start, shape[0] - ty.stop)
                    wmax = torch.maximum(wmax, F.pad(wt, pad))  # weights >= 0: 0 is neutral
                else:
                    view = wmax[:, :, win.ty, win.tx]
                    torch.maximum(view, wt, out=view)
        centre = image[:, :, ty0:ty1, tx0:tx1]
        if wmax is not None:
            acc.addcmul_(centre, wmax)
            wsum.add_(wmax)
        if tap_fn is not None:
            mass = wsum.clone()  # + Σ w over out-of-image taps, border strips only
            for dy in range(-r, r + 1):
                for dx in range(-r, r + 1):
                    index = (dy + r) * k + (dx + r)
                    rect = (max(0, -dy), min(h, h - dy), max(0, -dx), min(w, w - dx))
                    for ys, xs in _strips(ty0, ty1, tx0, tx1, *rect):
                        if ys.stop > ys.start and xs.stop > xs.start:
                            region = (
                                slice(ys.start - ty0, ys.stop - ty0),
                                slice(xs.start - tx0, xs.stop - tx0),
                            )
                            mass[:, :, region[0], region[1]] += tap_fn(index, ys, xs)
        total = wsum if tap_fn is None else mass
        if not bool(torch.isfinite(total).all()):
            raise InputError("the kernel weights hold NaN/Inf values (or overflow when summed)")
        ok = wsum > tiny
        safe = torch.where(ok, wsum, torch.ones_like(wsum))  # no 0/0, finite gradients
        if tap_fn is None:
            res = torch.where(ok, acc / safe, centre)
        else:
            res = torch.where(ok, acc * (mass / safe), centre * mass)
        out[:, :, ty0:ty1, tx0:tx1] = res

    _run_tiles(one_tile, h, w, tile, image)
    return out


def _run_tiles(
    fn: Callable[[int, int, int, int], None], h: int, w: int, tile: tuple[int, int], like: Tensor
) -> None:
    """Call ``fn(ty0, ty1, tx0, tx1)`` for every output tile, the tiles shared by the worker
    threads of :func:`~mcdenoise.filters.parallel.parallel_map` (on the CPU, without autograd).
    The tiles are the same whatever the thread count (NLM's patch sums start at a tile's edge,
    so its rounding depends on the tiling) and each computes what it computes alone: the
    result does not depend on the number of threads, bit for bit."""
    parallel_map(lambda t: fn(*t), _tiles(h, w, *tile), like)


def apply_kernels(
    image: Tensor,
    weights: Tensor,
    *,
    normalize: bool = False,
    tile: int | tuple[int, int] | None = None,
) -> Tensor:
    """Apply a different k×k kernel at every pixel.

    Args:
        image: ``(B, C, H, W)``, any range and colour space (the sum is linear), float32 or
            float64; half/bfloat16 inputs are computed and returned in float32 (HDR values
            overflow half precision).
        weights: ``(B, k*k, H, W)`` non-negative kernel weights, ``k`` odd; channel
            ``(dy + r) * k + (dx + r)`` weighs the neighbour at offset ``(dy, dx)``,
            ``r = k // 2`` (the layout of ``torch.nn.functional.unfold``).
        normalize: if True, every pixel gets the weighted mean ``Σ w x / Σ w``. If False (for
            kernels that are already normalised, e.g. a softmax), the kernel's total mass is
            kept: ``out = Σ w x`` in the interior; at the border the weights of out-of-image
            taps are redistributed proportionally over the in-image taps, so a softmax kernel
            never darkens the border.
        tile: output tile edge (or ``(th, tw)``) bounding the extra memory; default
            :data:`KERNEL_TILE`. The result does not depend on it.

    Returns:
        ``(B, C, H, W)`` tensor of the input's dtype (float32 for half inputs). Pixels whose
        in-image weights sum to 0 get their centre value (times the kernel mass if
        ``normalize=False``).

    Example:
        >>> x = torch.rand(1, 3, 8, 8)
        >>> w = torch.softmax(torch.randn(1, 9, 8, 8), dim=1)
        >>> apply_kernels(x, w).shape
        torch.Size([1, 3, 8, 8])
        >>> identity = torch.zeros(1, 9, 8, 8); identity[:, 4] = 1
        >>> torch.equal(apply_kernels(x, identity), x)
        True
    """
    image = _compute_dtype(check_image(image, "image"))
    # Weights are not scanned for NaN/Inf up front (a pass over k² planes); a non-finite
    # weight makes its pixel's weight sum non-finite, which the loop reports.
    weights = check_image(weights, "weights", finite=False).to(image.dtype)
    if weights.shape[0] != image.shape[0] or weights.shape[2:] != image.shape[2:]:
        raise InputError(
            f"weights have shape {tuple(weights.shape)} but image has shape "
            f"{tuple(image.shape)}: batch, height and width must match"
        )
    if weights.device != image.device:
        raise InputError(f"weights are on {weights.device} but image is on {image.device}")
    kk = weights.shape[1]
    k = round(kk**0.5)
    if k * k != kk or k % 2 == 0:
        raise InputError(
            f"weights must have k*k channels with k odd (e.g. 441 for 21x21), got {kk}"
        )
    check_kernel_size(k)
    _, _, h, w = image.shape

    def weight_fn(win: Window) -> Tensor:
        return weights[:, win.index : win.index + 1, win.yi, win.xi]

    def tap_fn(index: int, ys: slice, xs: slice) -> Tensor:
        return weights[:, index : index + 1, ys, xs]

    return _accumulate(
        image,
        weight_fn,
        k,
        _tile_size(tile, KERNEL_TILE, h, w),
        tap_fn=None if normalize else tap_fn,
    )


def accumulate_weighted(
    image: Tensor,
    weight_fn: WeightFn,
    kernel_size: int,
    *,
    centre: Literal["one", "max"] = "one",
    tile: int | tuple[int, int] | None = None,
) -> Tensor:
    """Weighted mean over a k×k window with weights computed per offset by ``weight_fn``.

    ``out_i = Σ_j w_ij x_j / Σ_j w_ij`` over in-image neighbours ``j``. For every
    :class:`Window` (one offset restricted to one tile) ``weight_fn`` returns the weights
    ``(B, 1, h, w)`` of the window's centre pixels (``win.centre(t)`` / ``win.neighbour(t)``
    slice per-pixel parameters and guides), or ``None`` if they are all zero. Only one
    offset's weights exist at a time, so memory is bounded by the tile.

    Args:
        image: ``(B, C, H, W)`` values to average (linear, any range), float32/float64.
        weight_fn: the weight callback; must be differentiable if gradients are wanted.
        kernel_size: odd window edge ``k``.
        centre: ``"one"``: the centre's weight is what ``weight_fn`` gives for offset
            ``(0, 0)``; ``"max"``: the largest weight of the other offsets (Buades 2005; see
            the module docstring), ``weight_fn`` is then not called for ``(0, 0)``.
        tile: output tile edge (or ``(th, tw)``); default :data:`CALLBACK_TILE`.

    Returns:
        ``(B, C, H, W)`` in the dtype of ``image``; pixels whose weights all underflow keep
        their centre value.

    Example:
        >>> x = torch.rand(1, 1, 5, 5)
        >>> box = accumulate_weighted(x, lambda win: torch.ones_like(win.centre(x)), 3)
        >>> bool(torch.isclose(box[0, 0, 2, 2], x[0, 0, 1:4, 1:4].mean()))
        True
    """
    image = check_image(image, "image")
    k = check_kernel_size(kernel_size)
    if centre not in ("one", "max"):
        raise InputError(f"centre must be 'one' or 'max', got {centre!r}")
    _, _, h, w = image.shape
    return _accumulate(
        image, weight_fn, k, _tile_size(tile, CALLBACK_TILE, h, w), centre_max=centre == "max"
    )


def neg_exp(e: Tensor) -> Tensor:
    """``exp(-e)`` for an exponent ``e >= 0``, exactly 0 where it is negligible.

    Weights below ``exp(-L)`` (``L`` = 80 in float32, 700 in float64; ≈ 1.8e-35 / 1e-304,
    against the centre's weight of 1) are set to 0 instead of being computed as denormal
    numbers: denormal ``exp`` results and products are 20x slower on x86 and would dominate
    the filters' run time. All other weights are shifted by ``exp(-L)``, far below rounding.
    """
    cut = exp_cut(e.dtype)
    if torch.is_grad_enabled() and e.requires_grad:
        return (torch.exp(-e.clamp(max=cut)) - math.exp(-cut)).clamp_min(0.0)
    w = e.clamp(max=cut).neg_().exp_()  # no autograd: reuse one buffer
    return w.sub_(math.exp(-cut)).clamp_min_(0.0)


def exp_cut(dtype: torch.dtype) -> float:
    """Exponent beyond which :func:`neg_exp` returns 0 (80 for float32, 700 for float64)."""
    return 700.0 if dtype == torch.float64 else 80.0


def _compute_dtype(t: Tensor) -> Tensor:
    """float16/bfloat16 -> float32 (sums of HDR values overflow half); others unchanged."""
    if t.dtype in (torch.float16, torch.bfloat16):
        return t.float()
    return t
