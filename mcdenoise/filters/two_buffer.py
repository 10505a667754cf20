"""The two-buffer error of a filter (Rousselle et al. 2012; NFOR, Bitterli et al. 2016): tensor
operators on two independent half buffers ``A``, ``B`` and a filter's outputs ``D_A``, ``D_B``
on them. The derivation, the choice of the common term and the validation are in
:mod:`mcdenoise.eval.estimate`, which builds the reference-free error estimate on these; the
filters that select per region by this error (``methods/selection.py``, ``filters/nfor.py``)
import them from here (a leaf module: torch only).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

#: Default side of the blocks of :func:`block_means`.
BLOCK = 16


def half_error(out_a: Tensor, color_b: Tensor, var_b: Tensor | None = None) -> Tensor:
    """Per-pixel estimate of the squared error of ``out_a`` = D(A) (NFOR's selection term):
    ``(D_A − B)² − v_B``, unbiased; without ``var_b`` the term common to every candidate
    filter is left in (``(D_A − B)²``, enough to compare candidates)."""
    e = (out_a - color_b).square()
    return e if var_b is None else e - var_b


def cross_error(
    out_a: Tensor,
    out_b: Tensor,
    color_a: Tensor,
    color_b: Tensor,
    var_a: Tensor | None = None,
    var_b: Tensor | None = None,
) -> Tensor:
    """Per-pixel unbiased estimate of the squared error of ``(out_a + out_b) / 2``:
    ``½[(D_A − B)² − v_B + (D_B − A)² − v_A] − ¼(D_A − D_B)²`` (:mod:`mcdenoise.eval.estimate`).

    Without the variances the common term ``½(v_A + v_B)`` is left out: the result then
    ranks candidate filters (its differences are unbiased) but is not an error.
    All tensors broadcast together, e.g. ``(3, H, W)`` or ``(N, 3, H, W)``.
    """
    e = 0.5 * ((out_a - color_b).square() + (out_b - color_a).square())
    e = e - 0.25 * (out_a - out_b).square()
    if var_a is not None and var_b is not None:
        e = e - 0.5 * (var_a + var_b)
    return e


def squared_error(out_a: Tensor, out_b: Tensor, color_a: Tensor, color_b: Tensor) -> Tensor:
    """Per-pixel unbiased estimate of the squared error of ``(out_a + out_b) / 2`` that needs
    no variance buffer: :func:`cross_error` with ``½(A − B)²`` as the estimate of the common
    term ``½(Var A + Var B)``; what
    :func:`mcdenoise.eval.estimate.estimate_from_outputs` uses."""
    return cross_error(out_a, out_b, color_a, color_b) - 0.5 * (color_a - color_b).square()


def block_means(t: Tensor, block: int = BLOCK) -> tuple[Tensor, Tensor]:
    """Means of ``t`` ``(..., H, W)`` over the channels (all leading dims but the last two
    are averaged) and ``block × block`` blocks; partial blocks at the right and bottom edges
    are weighted by their pixel count. Returns ``(nby, nbx)`` means and the pixel counts."""
    x = t.reshape(-1, *t.shape[-2:]).double().mean(0)[None, None]
    h, w = x.shape[-2:]
    ones = torch.ones_like(x)
    pad = (0, (-w) % block, 0, (-h) % block)
    sums = F.avg_pool2d(F.pad(x, pad), block, divisor_override=1)[0, 0]
    counts = F.avg_pool2d(F.pad(ones, pad), block, divisor_override=1)[0, 0]
    return sums / counts, counts
