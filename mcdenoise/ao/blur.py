"""Depth-aware (bilateral) blurs that remove the interleaved-sampling pattern of screen-space AO.

Every screen-space AO method rotates its samples per pixel with a small repeating noise tile
(:func:`mcdenoise.ao.geometry.interleaved_noise`) and then blurs the raw AO over about the
tile's size, stopping at geometric edges so occlusion does not bleed across silhouettes. The
methods differ in the kernel they were published with:

* Crytek SSAO (Mittring 2007) and Chapman's hemisphere SSAO: a 4×4 box over the 4×4 rotation
  tile (:func:`box_offsets`);
* HBAO (Bavoil & Sainz 2008): a cross-bilateral Gaussian, depth weighted, run as an x and a
  y pass as NVIDIA's HBAO+ does (:func:`gaussian_line_offsets`);
* scalable AO (McGuire et al. 2012): a separable bilateral of radius 4 with stride 2 and the
  Gaussian weights 0.153, 0.144, 0.122, 0.092, 0.061 (:data:`SAO_WEIGHTS`), run as a
  horizontal then a vertical pass;
* XeGTAO: a 3×3 edge-aware pass, run one to three times ("sharp" to "soft").

The edge test is the same for all (:func:`bilateral`): a neighbour counts with its kernel
weight times a plane weight ``exp(-(n_i · (P_j - P_i) / (s r))²)`` — how far the neighbour
lies from the centre's tangent plane relative to ``s`` times the AO radius ``r`` — and a normal
weight ``max(0, n_i · n_j)^p``; empty pixels weigh 0 and an empty centre is left as it is.
The plane distance (rather than a depth difference) keeps slanted floors blurred along their
slope, where depth changes fast from pixel to pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.ao.geometry import ViewGBuffer

#: Kernel: (dy, dx, weight) per tap.
Taps = Sequence[tuple[int, int, float]]
#: McGuire et al. 2012 (SAO reference code, ``gaussian[]``): weights of taps 0..4.
SAO_WEIGHTS = (0.153170, 0.144893, 0.122649, 0.092902, 0.061009)


def box_offsets(size: int = 4) -> list[tuple[int, int, float]]:
    """A ``size`` × ``size`` box (taps ``-size//2 .. size - size//2 - 1``, the 4×4 blur of the
    4×4 rotation tile)."""
    lo = -(size // 2)
    return [(dy, dx, 1.0) for dy in range(lo, lo + size) for dx in range(lo, lo + size)]


def gaussian_offsets(radius: int, sigma: float | None = None) -> list[tuple[int, int, float]]:
    """A square Gaussian kernel of ``radius`` (σ = (radius + 1) / 2 by default, the
    HBAO sample's blur)."""
    s = sigma if sigma is not None else (radius + 1) / 2.0
    return [
        (dy, dx, math.exp(-(dx * dx + dy * dy) / (2.0 * s * s)))
        for dy in range(-radius, radius + 1)
        for dx in range(-radius, radius + 1)
    ]


def sao_offsets(horizontal: bool, stride: int = 2) -> list[tuple[int, int, float]]:
    """One pass of the scalable-AO separable blur: taps ``-4..4`` times ``stride``."""
    taps = []
    for k in range(-4, 5):
        w = SAO_WEIGHTS[abs(k)]
        taps.append((0, k * stride, w) if horizontal else (k * stride, 0, w))
    return taps


def gaussian_line_offsets(
    radius: int, horizontal: bool, sigma: float | None = None
) -> list[tuple[int, int, float]]:
    """One pass of a separable Gaussian of ``radius`` (σ = (radius + 1) / 2 by default): the
    horizontal or the vertical half of :func:`gaussian_offsets` (HBAO+'s blur runs as an x and
    a y pass)."""
    s = sigma if sigma is not None else (radius + 1) / 2.0
    taps = []
    for k in range(-radius, radius + 1):
        w = math.exp(-(k * k) / (2.0 * s * s))
        taps.append((0, k, w) if horizontal else (k, 0, w))
    return taps


def bilateral(
    ao: Tensor,
    g: ViewGBuffer,
    taps: Taps,
    radius: float,
    *,
    plane_sigma: float = 0.1,
    normal_power: float = 8.0,
) -> Tensor:
    """One depth- and normal-aware blur pass of ``ao`` ``(H, W)`` with kernel ``taps``.

    ``radius`` is the AO radius (scene units); ``plane_sigma`` the tangent-plane distance, as
    a fraction of it, at which a neighbour's weight has fallen to 1/e; ``normal_power`` the
    exponent of the normal weight. Returns ``(H, W)``.
    """
    h, w = ao.shape
    pad = max((max(abs(dy), abs(dx)) for dy, dx, _ in taps), default=0)
    # one padded stack (position, normal, valid, ao), sliced per tap: no copy per tap
    stack = torch.cat([g.position, g.normal, g.valid.float().unsqueeze(0), ao.unsqueeze(0)])
    padded = F.pad(stack.unsqueeze(0), (pad, pad, pad, pad)).squeeze(0)
    p, n = g.position, g.normal
    num = torch.zeros_like(ao)
    den = torch.zeros_like(ao)
    scale = 1.0 / max(plane_sigma * radius, 1e-12)
    for dy, dx, wt0 in taps:
        view = padded[:, pad + dy : pad + dy + h, pad + dx : pad + dx + w]
        d = view[:3] - p
        plane = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) * scale
        cos = (view[3] * n[0] + view[4] * n[1] + view[5] * n[2]).clamp_min(0.0)
        wt = wt0 * view[6] * torch.exp(-plane * plane) * cos.pow(normal_power)
        num = num + wt * view[7]
        den = den + wt
    out = torch.where(den > 0, num / den.clamp_min(1e-30), ao)
    return torch.where(g.valid, out, ao)


def blur_passes(
    ao: Tensor, g: ViewGBuffer, passes: Sequence[Taps], radius: float, **kwargs: float
) -> Tensor:
    """:func:`bilateral` once per kernel of ``passes`` (a separable blur is two passes)."""
    for taps in passes:
        ao = bilateral(ao, g, taps, radius, **kwargs)
    return ao


__all__ = [
    "SAO_WEIGHTS",
    "bilateral",
    "blur_passes",
    "box_offsets",
    "gaussian_line_offsets",
    "gaussian_offsets",
    "sao_offsets",
]
