"""Per-region choice among shifted bandwidths of a learned filter, judged by the half buffers.

A Kalantari model predicts the filter bandwidths of every pixel from local statistics; it is
often right about where to blur and wrong about how much, and a better choice per region was
measured to be worth 18-35 % of its error (``benchmarks/headroom_kalantari.py``, the oracle
rows). Choosing needs an estimate of the error without the reference. SURE from the variance
buffer picked worse than no choice at all, because Monte Carlo noise is heavy-tailed and a
bright sample raises both the pixel and its variance estimate. Two independent half buffers
``A`` and ``B`` need no assumption on the noise (Rousselle, Knaus, Zwicker 2012; Bitterli et
al. 2016): run candidate ``k`` on each half and judge each result by the other half.

``D_k(A)`` does not depend on ``B``'s noise, so ``E[(D_k(A) - B)²] = E[(D_k(A) - μ)²] +
Var(B)``. With the same for ``D_k(B)`` and the identity
``((a + b)/2 - μ)² = ((a - μ)² + (b - μ)²)/2 - (a - b)²/4``, the per-pixel estimate
(:func:`~mcdenoise.filters.two_buffer.cross_error`, shared with ``mcdenoise eval``'s
reference-free estimate)::

    e_k = ((D_k(A) - B)² - Var B + (D_k(B) - A)² - Var A) / 2 - (D_k(A) - D_k(B))² / 4

is unbiased for the squared error of ``(D_k(A) + D_k(B)) / 2`` (NFOR's section 5.3). The
variance terms are the same for every candidate, so they do not change a ranking. Divided by
``pilot² + 0.01`` (``pilot``: the unshifted model's output on the full buffer, box-filtered,
the same for every candidate) it is in relMSE units; averaged over a ``(2R+1)²`` block around
each pixel, the candidate with the lowest estimate is chosen there (:func:`choose`).

**Which output.** The estimate judges filters run on *half* the samples; the user's output is
the candidate filter run on all of them, ``D_k(A ∪ B)``. The candidates are shifts of the
model's own prediction, and the model sees the noise level of what it filters (its features
include the colour's relative variance and the sample count), so a shift that helps on the
halves is taken to help on the full buffer; ``output="halves"`` gives NFOR's choice instead,
``(D_k(A) + D_k(B)) / 2``, for which the estimate is exactly unbiased. Both are measured in
``benchmarks/headroom_kalantari.py`` (``halves-block`` and ``halves-mean-block``).

Everything here is model-agnostic: :func:`select_filtered` takes a callable that filters a
:class:`~mcdenoise.io.buffers.FeatureBuffers` with candidate ``k``; the Kalantari methods pass
their model (:func:`select_kalantari`).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.box import box_mean
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.two_buffer import cross_error
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.prep.kalantari import item_features, prepare_for_model

#: Block radius ``R`` of the choice (17×17 blocks, the headroom benchmark's).
RADIUS = 8
#: Log-bandwidth shift ``s`` of the candidates (the headroom benchmark's).
SHIFT = 0.7
#: Radius of the box filter that makes the relMSE pilot (as the headroom benchmark's SURE).
PILOT_RADIUS = 3
#: ε of relMSE.
EPS = 0.01
#: Guides whose halves a half buffer takes when the renderer wrote them.
_GUIDES = ("albedo", "normal", "depth", "position")


def has_halves(buffers: FeatureBuffers) -> bool:
    """True when ``buffers`` hold both colour halves."""
    return "color_a" in buffers and "color_b" in buffers


def half_buffers(buffers: FeatureBuffers, half: str) -> FeatureBuffers:
    """The buffers of half ``"a"`` or ``"b"`` as an image of its own (``spp / 2`` samples).

    Colour: ``color_<h>`` with ``color_<h>_var`` (else twice ``color_var``, the variance of a
    mean of half the samples). Guides: their halves where the renderer wrote them (depth of
    field), with the halves' variances (else twice the full one), else the full guide.
    """
    if half not in ("a", "b"):
        raise InputError(f"half must be 'a' or 'b', got {half!r}")
    if not has_halves(buffers):
        raise InputError("half buffers color_a and color_b are needed")
    h = f"_{half}"
    out: dict[str, Tensor] = {"color": buffers[f"color{h}"]}

    def var(name: str) -> Tensor | None:
        v = buffers.get(f"{name}{h}_var")
        if v is None and f"{name}_var" in buffers:
            v = buffers[f"{name}_var"] * 2.0
        return v

    v = var("color")
    if v is not None:
        out["color_var"] = v
    for g in _GUIDES:
        if f"{g}{h}" in buffers:
            out[g] = buffers[f"{g}{h}"]
            gv = var(g)
        elif g in buffers:
            out[g] = buffers[g]
            gv = buffers.get(f"{g}_var")
        else:
            continue
        if gv is not None:
            out[f"{g}_var"] = gv
    spp = buffers.spp
    half_spp = None if spp is None else max(1, (spp + (1 if half == "a" else 0)) // 2)
    return FeatureBuffers(out, spp=half_spp, source=buffers.source)


def choose(errors: Tensor, radius: int) -> Tensor:
    """Index ``(B, 1, H, W)`` of the candidate with the lowest block-averaged estimate.

    ``errors``: ``(B, K, H, W)`` per-pixel estimates of ``K`` candidates (same units).
    """
    return box_mean(errors, radius).argmin(dim=1, keepdim=True)


def pick(outputs: Tensor, index: Tensor) -> Tensor:
    """``(B, C, H, W)`` from ``outputs`` ``(B, K, C, H, W)`` by ``index`` ``(B, 1, H, W)``."""
    idx = index[:, :, None].expand(-1, -1, outputs.shape[2], -1, -1)
    return torch.gather(outputs, 1, idx)[:, 0]


#: ``filter_fn(buffers, k) -> (1, 3, H, W)``: candidate ``k``'s output on ``buffers``.
FilterFn = Callable[[FeatureBuffers, int], Tensor]


def select_filtered(
    buffers: FeatureBuffers,
    filter_fn: FilterFn,
    n_candidates: int,
    *,
    base: int = 0,
    radius: int = RADIUS,
    output: str = "full",
    halves: tuple[FeatureBuffers, FeatureBuffers] | None = None,
    judges: tuple[Tensor, Tensor, Tensor, Tensor] | None = None,
) -> tuple[Tensor, Tensor]:
    """Choose per region among ``n_candidates`` filters by the two-buffer estimate.

    Args:
        buffers: an image with ``color_a``/``color_b`` (and their variances, else
            ``color_var``).
        filter_fn: runs candidate ``k`` on a :class:`FeatureBuffers` (the full image or one
            half, see :func:`half_buffers`); returns ``(1, 3, H, W)`` linear colour.
        n_candidates: how many candidates.
        base: the candidate whose full-buffer output makes the relMSE pilot (the unshifted one).
        radius: block radius of the choice.
        output: ``"full"`` (the chosen candidate on the full buffer) or ``"halves"`` (the mean
            of the chosen candidate on each half).
        halves: the two halves as made by :func:`half_buffers` (made here when ``None``).
        judges: ``(A, B, var_A, var_B)`` ``(1, C, H, W)`` to judge by instead of the raw halves
            (e.g. the halves after the firefly clamp the filter's preparation applies: a clamp
            changes the judge's mean a little and its variance a lot).

    Returns:
        ``(image (3, H, W), index (1, H, W))``.
    """
    if output not in ("full", "halves"):
        raise InputError(f"output must be 'full' or 'halves', got {output!r}")
    ha, hb = halves or (half_buffers(buffers, "a"), half_buffers(buffers, "b"))
    if judges is None:
        a, b = ha["color"][None].float(), hb["color"][None].float()
        var_a, var_b = _half_var(ha, a, b), _half_var(hb, a, b)
    else:
        a, b, var_a, var_b = judges
    full_base = filter_fn(buffers, base)
    pilot = box_mean(full_base, PILOT_RADIUS)
    den = pilot.square() + EPS
    errors, halves, fulls = [], [], []
    for k in range(n_candidates):
        oa, ob = filter_fn(ha, k), filter_fn(hb, k)
        e = cross_error(oa, ob, a, b, var_a, var_b) / den
        errors.append(e.mean(dim=1, keepdim=True))
        if output == "halves":
            halves.append((oa + ob) * 0.5)
        else:
            fulls.append(full_base if k == base else filter_fn(buffers, k))
    index = choose(torch.cat(errors, dim=1), radius)
    outs = torch.stack(halves if output == "halves" else fulls, dim=1)
    return pick(outs, index)[0], index[0]


def _clamped(batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
    """The colour and its variance ``(1, 3, H, W)`` of a prepared half after the preparation's
    firefly clamp (``irr · factor``), to judge the other half's outputs by."""
    factor = batch["factor"]
    return batch["irr"] * factor, batch["irr_var"] * factor.square()


def _half_var(half: FeatureBuffers, a: Tensor, b: Tensor) -> Tensor:
    v = half.get("color_var")
    if v is not None and bool(v.max() > 0):
        return v[None].float().clamp_min(0.0)
    return box_mean((a - b).square() * 0.5, 1)  # the two-buffer variance of one half


def shifts(kind: str, s: float) -> list[tuple[float, float]]:
    """The candidates' log-bandwidth shifts, ``(first, second)`` per candidate; ``(0, 0)`` is in
    the middle (index 4): spatial and colour bandwidths for ``xbf`` (both passes), ``k`` and
    the feature ``k_f`` for ``nlm``."""
    if kind not in ("xbf", "nlm"):
        raise InputError(f"unknown model kind {kind!r}")
    return [(d1, d2) for d1 in (-s, 0.0, s) for d2 in (-s, 0.0, s)]


def shifted_offsets(model: KalantariModel, o: Tensor, s: float) -> list[Tensor]:
    """The model's log-offsets ``(B, O, H, W)`` with the candidates' shifts (:func:`shifts`)."""
    outs = model.card.outputs
    if model.card.kind == "xbf":
        first = [outs.index(n) for n in ("spatial", "spatial2") if n in outs]
        second = [outs.index(n) for n in ("color", "color2") if n in outs]
    else:
        first = [outs.index("k")]
        second = [i for i, n in enumerate(outs) if n != "k"]
    res = []
    for d1, d2 in shifts(model.card.kind, s):
        oc = o.clone()
        oc[:, first] += d1
        if second:
            oc[:, second] += d2
        res.append(oc)
    return res


def select_kalantari(
    model: KalantariModel,
    buffers: FeatureBuffers,
    *,
    shift: float = SHIFT,
    radius: int = RADIUS,
    output: str = "full",
    fireflies: str | None = None,
    variance_prior: float | None = None,
    chunk_rows: int = 256,
) -> Tensor:
    """``kalantari-xbf``/``-nlm`` with the per-region choice among 9 shifted bandwidth sets.

    The model predicts its bandwidths on each buffer (full, ``A``, ``B``) from that buffer's
    own features; the candidates shift them (:func:`shifted_offsets`) and
    :func:`select_filtered` chooses per ``(2·radius + 1)²`` block. ``shift = 0`` is the model
    alone (what :func:`~mcdenoise.methods.kalantari.denoise_kalantari` computes). Returns ``(3, H, W)`` float32 linear colour (finite, >= 0).
    """
    cache: dict[int, tuple[dict[str, Tensor], list[Tensor]]] = {}

    def candidates(b: FeatureBuffers) -> tuple[dict[str, Tensor], list[Tensor]]:
        key = id(b)
        if key not in cache:
            item = prepare_for_model(
                model.card, b, features=False, fireflies=fireflies, variance_prior=variance_prior
            )
            del item["color"]
            feats = item_features(item, b.spp, regional=model.card.regional)
            h = item["irr"].shape[-2]
            rows = []
            for y in range(0, h, chunk_rows):
                band = feats(y, min(y + chunk_rows, h))
                rows += [
                    model.offsets(band[..., i : i + 32, :]) for i in range(0, band.shape[-2], 32)
                ]
            o = torch.cat(rows, dim=-2)
            batch = {k: v[None] for k, v in item.items()}
            cache[key] = (batch, shifted_offsets(model, o, shift))
        return cache[key]

    def filter_fn(b: FeatureBuffers, k: int) -> Tensor:
        batch, offs = candidates(b)
        return model.filter(batch, offs[k])

    n = len(shifts(model.card.kind, shift))
    with torch.no_grad(), single_threaded_ops():
        if shift == 0:  # every candidate is the model's own choice
            out = filter_fn(buffers, n // 2)[0]
        else:
            ha, hb = half_buffers(buffers, "a"), half_buffers(buffers, "b")
            (ja, va), (jb, vb) = _clamped(candidates(ha)[0]), _clamped(candidates(hb)[0])
            out, _ = select_filtered(
                buffers,
                filter_fn,
                n,
                base=n // 2,
                radius=radius,
                output=output,
                halves=(ha, hb),
                judges=(ja, jb, va, vb),
            )
    return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0).float()


__all__ = [
    "FilterFn",
    "choose",
    "half_buffers",
    "has_halves",
    "pick",
    "select_filtered",
    "select_kalantari",
    "shifted_offsets",
    "shifts",
]
