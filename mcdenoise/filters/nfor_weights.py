"""NFOR's NL-means weights (Bitterli et al. 2016, section 4.2, after Rousselle et al. 2012): the
patch distance of two pixels under a per-pixel variance, the weights of every offset in the
search window, and the tiling that keeps their memory bounded. The regression that uses them
is :mod:`mcdenoise.filters.nfor`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import torch
from torch import Tensor
from torch.nn import functional as F

from mcdenoise.errors import InputError
from mcdenoise.filters._common import check_image, check_same_size
from mcdenoise.filters.kernels import neg_exp
from mcdenoise.filters.parallel import parallel_map

#: Output tile edge of every operator here.
TILE = 256


#: Most bytes of regression weights kept between the two passes over the window offsets.
WEIGHT_CACHE_BYTES = 256 * 2**20


#: Largest per-pixel distance term before the patch average (Tungsten's ``DistanceClamp``).
DIST_CLAMP = 1e4


#: ε of Tungsten's NL-means distance (``nlMeansWeights``).
EPS = 1e-7


def _distance(
    guide: Tensor, var: Tensor, dy: int, dx: int, f: int, k: float, var_scale: float
) -> tuple[Tensor, slice, slice] | None:
    """Tungsten's ``nlMeansWeights`` distance of every centre ``i`` to ``j = i + (dy, dx)``.

    Per channel: ``t_p = ((g_p - g_q)² - (v_p + min(v_p, v_q))) / ((v_p + v_q) k² + ε)``
    (Rousselle et al. 2012 with α = 1), clamped at :data:`DIST_CLAMP`, averaged over the
    ``(2f+1)²`` patch pairs inside the image. Returns ``(d (B, C, h, w), ys, xs)`` over the
    centres whose neighbour is inside the image, or ``None`` when there are none.
    """
    h, w = guide.shape[-2:]
    y0, y1 = max(0, -dy), min(h, h - dy)
    x0, x1 = max(0, -dx), min(w, w - dx)
    if y1 <= y0 or x1 <= x0:
        return None
    ys, xs = slice(y0, y1), slice(x0, x1)
    gi, gj = guide[..., ys, xs], guide[..., y0 + dy : y1 + dy, x0 + dx : x1 + dx]
    vi, vj = var[..., ys, xs], var[..., y0 + dy : y1 + dy, x0 + dx : x1 + dx]
    if var_scale != 1.0:  # the crop functions scale var once, not per offset
        vi, vj = vi * var_scale, vj * var_scale
    t = (gi - gj).square_().sub_(vi + torch.minimum(vi, vj))
    t = t.div_((vi + vj).mul_(k * k).add_(EPS)).clamp_(max=DIST_CLAMP)
    if f > 0:  # mean over the patch pairs inside the valid rectangle (clipped counts)
        t = _box_mean(t, f)
    return t, ys, xs


def _box_mean(t: Tensor, f: int) -> Tensor:
    """Mean over the ``(2f+1)²`` window of each pixel, counting only pixels inside ``t``
    (separable running sums; ``avg_pool2d`` with ``count_include_pad=False`` gives the same and
    was 5x slower on these maps)."""
    n = 2 * f + 1
    h, w = t.shape[-2:]
    c = F.pad(t, (f + 1, f)).cumsum(dim=-1)
    t = c[..., n:] - c[..., :-n]
    c = F.pad(t, (0, 0, f + 1, f)).cumsum(dim=-2)
    t = c[..., n:, :] - c[..., :-n, :]
    return t.mul_(_inverse_counts(h, w, f, t))


def _inverse_counts(h: int, w: int, f: int, like: Tensor) -> Tensor:
    """``(h, w)``: 1 / the number of window pixels inside an ``h × w`` image (cached: the
    same few shapes recur for every window offset)."""
    return _inverse_counts_cached(h, w, f, like.dtype, like.device)


@functools.lru_cache(maxsize=64)
def _inverse_counts_cached(
    h: int, w: int, f: int, dtype: torch.dtype, device: torch.device
) -> Tensor:
    ky = [min(y + f, h - 1) - max(y - f, 0) + 1 for y in range(h)]
    kx = [min(x + f, w - 1) - max(x - f, 0) + 1 for x in range(w)]
    cy = torch.tensor(ky, dtype=dtype, device=device)
    cx = torch.tensor(kx, dtype=dtype, device=device)
    return 1.0 / (cy[:, None] * cx[None, :])


def _shifted(ys: slice, xs: slice, dy: int, dx: int) -> tuple[slice, slice]:
    return slice(ys.start + dy, ys.stop + dy), slice(xs.start + dx, xs.stop + dx)


def _offsets(r: int) -> list[tuple[int, int]]:
    return [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1)]


def _nlm_crop(
    image: Tensor, guide: Tensor, var: Tensor, f: int, r: int, k: float, var_scale: float
) -> Tensor:
    """Per-channel NL-means of ``image`` ``(B, G·C, H, W)`` with the weights of the ``C``
    guide channels, shared by the ``G`` groups (Tungsten's ``nlMeans`` on a ``Vec3f`` or a
    ``float`` pixmap)."""
    b, _, h, w = image.shape
    c = guide.shape[1]
    img = image.reshape(b, -1, c, h, w)
    acc = torch.zeros_like(img)
    wsum = guide.new_zeros((b, 1, c, h, w))
    var = var * var_scale
    for dy, dx in _offsets(r):
        got = _distance(guide, var, dy, dx, f, k, 1.0)
        if got is None:
            continue
        d, ys, xs = got
        wt = neg_exp(d.clamp_min_(0.0)).unsqueeze(1)  # (B, 1, C, h', w')
        yj, xj = _shifted(ys, xs, dy, dx)
        acc[..., ys, xs].addcmul_(img[..., yj, xj], wt)
        wsum[..., ys, xs].add_(wt)
    return (acc / wsum).reshape(image.shape)  # the centre's weight is 1: wsum >= 1


def nl_means(
    image: Tensor,
    guide: Tensor,
    var: Tensor,
    *,
    patch_radius: int,
    search_radius: int,
    k: float,
    var_scale: float = 1.0,
    tile: int = TILE,
) -> Tensor:
    """NL-means with per-channel weights from a separate guide (Tungsten's ``nlMeans``).

    Args:
        image: ``(B, G·C, H, W)`` values to average (any range); each group of ``C`` channels
            uses the weights of the matching guide channels.
        guide: ``(B, C, H, W)`` whose patches are compared (e.g. the other half buffer).
        var: ``(B, 1 or C, H, W)`` variance of the mean of ``guide``.
        patch_radius, search_radius: ``F`` and ``R``.
        k: bandwidth; ``var_scale`` multiplies ``var`` (Tungsten passes the full buffer's
            variance times 2 for a half).
        tile: output tile edge (no effect on the result).

    Returns:
        ``(B, G·C, H, W)``.

    Example:
        >>> g = torch.rand(1, 3, 12, 12)
        >>> out = nl_means(torch.ones(1, 6, 12, 12), g, torch.full((1, 1, 12, 12), 0.01),
        ...                patch_radius=1, search_radius=2, k=0.5)
        >>> torch.allclose(out, torch.ones(1, 6, 12, 12))
        True
    """
    image, guide, var = check_inputs(image, guide, var)
    if image.shape[1] % guide.shape[1]:
        raise InputError(
            f"image has {image.shape[1]} channels, not a multiple of the guide's {guide.shape[1]}"
        )
    var = var.expand(-1, guide.shape[1], -1, -1)

    def run(img: Tensor, g: Tensor, v: Tensor) -> Tensor:
        return _nlm_crop(img, g, v, patch_radius, search_radius, k, var_scale)

    return _tiled(run, [image, guide, var], search_radius + patch_radius, tile)


def _tiled(fn: Callable[..., Tensor], inputs: Sequence[Tensor], halo: int, tile: int) -> Tensor:
    """``fn(*inputs)`` computed on output tiles, each from a crop ``halo`` wider on every
    side (clipped to the image). Exact when ``fn``'s output at a pixel depends only on inputs
    within ``halo`` of it: a crop's edge then cannot reach the tile."""
    h, w = inputs[0].shape[-2:]
    if tile < 1:
        raise InputError(f"tile must be positive, got {tile}")
    if h <= tile and w <= tile:
        return fn(*inputs)
    boxes = [
        (y0, min(y0 + tile, h), x0, min(x0 + tile, w))
        for y0 in range(0, h, tile)
        for x0 in range(0, w, tile)
    ]

    def one(box: tuple[int, int, int, int]) -> Tensor:
        y0, y1, x0, x1 = box
        cy0, cy1, cx0, cx1 = (
            max(0, y0 - halo),
            min(h, y1 + halo),
            max(0, x0 - halo),
            min(w, x1 + halo),
        )
        res = fn(*[t[..., cy0:cy1, cx0:cx1] for t in inputs])
        return res[..., y0 - cy0 : y1 - cy0, x0 - cx0 : x1 - cx0]

    parts = parallel_map(one, boxes, inputs[0])
    out = parts[0].new_empty((*parts[0].shape[:-2], h, w))
    for (y0, y1, x0, x1), part in zip(boxes, parts, strict=True):
        out[..., y0:y1, x0:x1] = part
    return out


def check_inputs(image: Tensor, guide: Tensor, var: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``image``, ``guide`` and ``var`` checked as ``(B, C, H, W)`` of one size, the last two in
    ``image``'s dtype (NL-means and the regression take the same three)."""
    image = check_image(image, "image")
    guide = check_image(guide, "guide").to(image.dtype)
    var = check_image(var, "var").to(image.dtype)
    check_same_size(image, guide, "guide", "image")
    check_same_size(image, var, "var", "image")
    return image, guide, var
