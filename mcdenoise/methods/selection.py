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
the same for every candidate) it is in relMSE units, and averaged over a ``(2R+1)²`` block
around each pixel.

**Candidates and weights.** :func:`select_kalantari` offers the model's predicted
log-bandwidths shifted by ``-s, 0, +s`` (spatial × colour: 9) and five fixed cross-bilateral
filters (the training-set grid's best setting and its neighbours, :func:`fixed_candidates`),
and blends them with :func:`weights`' ``soft-smooth`` rule: a softmax of the block
estimates with the spread of the estimates as temperature, box-filtered over the block.
Taking the argmin per block instead (the first version) lost most of what the choice gained:
the estimate is noisy, neighbouring blocks flipped between candidates, and a wrong choice
costs more than a blend. On 11 held-out renders (``docs/results/nfor.md``) the argmin among
the shifts gave 0.973 / 1.003 of the model's relMSE at 4 / 16 spp, this default 0.851 / 0.967.

**Which output.** The estimate judges filters run on *half* the samples; the user's output is
the candidates on all of them, ``D_k(A ∪ B)``. With ``half_bandwidths="full"`` (the default)
each half is filtered with the bandwidths the full buffer's output will use, so the estimate
judges the applied filter at half its samples (``"own"``: with the bandwidths the model
predicts on the half, which carried over slightly worse). ``output="halves"`` gives NFOR's
output instead, ``(D_k(A) + D_k(B)) / 2``, for which the estimate is exactly unbiased but
which is much worse at 4 spp (each half has 2 samples). All are measured in
``benchmarks/headroom_kalantari.py``.

Everything here is model-agnostic: :func:`select_filtered` takes a callable that filters a
:class:`~mcdenoise.io.buffers.FeatureBuffers` with candidate ``k``; the Kalantari methods pass
their model (:func:`select_kalantari`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.box import box_mean
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.settings import XBF_VARIANCE_PRIOR
from mcdenoise.filters.two_buffer import cross_error
from mcdenoise.io.buffers import FeatureBuffers, half_inputs, has_halves
from mcdenoise.methods.cross_bilateral import denoise_xbf
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
#: Default rule, temperature and half-buffer bandwidths of :func:`select_kalantari` (chosen
#: among named variants on held-out renders, ``docs/results/nfor.md``).
RULE = "soft-smooth"
TAU = 0.3
HALF_BANDWIDTHS = "full"
#: The best two-pass fixed cross-bilateral settings of the training-set grid search, per spp
#: (``benchmarks/results/kalantari_grid_xbf2.json``, ``best``; ``bench_kalantari.py``'s
#: "best fixed" baseline): the fixed candidates are these and their grid neighbours
#: (:func:`fixed_candidates`).
FIXED_BEST: dict[int, dict[str, float | int]] = {
    4: {"passes": 2, "sigma_spatial": 4.0, "sigma_color": 4.0, "sigma_color_refine": 0.5},
    16: {"passes": 2, "sigma_spatial": 4.0, "sigma_color": 4.0, "sigma_color_refine": 0.25},
    64: {"passes": 2, "sigma_spatial": 4.0, "sigma_color": 4.0, "sigma_color_refine": 0.25},
}


def half_buffers(buffers: FeatureBuffers, half: str) -> FeatureBuffers:
    """The buffers of half ``"a"`` or ``"b"`` as an image of its own (``spp / 2`` samples;
    :func:`mcdenoise.io.buffers.half_inputs`).

    Colour: ``color_<h>`` with ``color_<h>_var`` (else twice ``color_var``, the variance of a
    mean of half the samples). Guides: their halves where the renderer wrote them (depth of
    field), with the halves' variances (else twice the full one), else the full guide.
    """
    if half not in ("a", "b"):
        raise InputError(f"half must be 'a' or 'b', got {half!r}")
    if not has_halves(buffers):
        raise InputError("half buffers color_a and color_b are needed")
    return half_inputs(buffers)[0 if half == "a" else 1]


def fixed_neighbours(best: Mapping[str, float | int]) -> list[dict[str, float | int]]:
    """``best`` and, for a two-pass setting, its neighbours along the spatial and the refining
    colour bandwidth (halved and doubled): 5 fixed candidates."""
    sets = [dict(best)]
    if best.get("passes") == 2:
        for key in ("sigma_spatial", "sigma_color_refine"):
            sets += [{**best, key: best[key] / 2}, {**best, key: best[key] * 2}]
    return sets


def fixed_candidates(spp: int | None) -> list[dict[str, float | int]]:
    """The fixed cross-bilateral candidates for an image of ``spp`` samples per pixel: the
    neighbours (:func:`fixed_neighbours`) of :data:`FIXED_BEST` at the nearest grid level
    (in log spp; 16 when the count is unknown)."""
    level = 16 if not spp else min(FIXED_BEST, key=lambda k: abs(math.log(k / spp)))
    return fixed_neighbours(FIXED_BEST[level])


def choose(errors: Tensor, radius: int) -> Tensor:
    """Index ``(B, 1, H, W)`` of the candidate with the lowest block-averaged estimate.

    ``errors``: ``(B, K, H, W)`` per-pixel estimates of ``K`` candidates (same units).
    """
    return box_mean(errors, radius).argmin(dim=1, keepdim=True)


#: How per-region estimates become candidate weights (:func:`weights`).
RULES = ("argmin", "smooth", "soft", "soft-smooth")


def weights(errors: Tensor, radius: int, rule: str = "argmin", tau: float = 0.3) -> Tensor:
    """Per-pixel candidate weights ``(B, K, H, W)`` (summing to 1) from per-pixel estimates.

    ``errors``: ``(B, K, H, W)`` per-pixel estimates of ``K`` candidates (same units), averaged
    over the ``(2·radius + 1)²`` block around each pixel first. ``rule``:

    * ``argmin``: all weight on the candidate with the lowest block estimate (:func:`choose`);
    * ``smooth``: that one-hot choice box-filtered over the same block, so neighbouring
      choices blend instead of meeting at a seam (NFOR smooths its selection maps so);
    * ``soft``: ``w_k ∝ exp(-(ê_k - min ê) / (tau · (mean ê - min ê)))``: candidates whose
      estimate is within the spread of the estimates share the weight (the spread of the
      estimates is the scale, so the rule has no unit);
    * ``soft-smooth``: the soft weights box-filtered over the block.
    """
    if rule not in RULES:
        raise InputError(f"rule must be one of {', '.join(RULES)}, got {rule!r}")
    e = box_mean(errors, radius)
    if rule in ("argmin", "smooth"):
        w = torch.zeros_like(e).scatter_(1, e.argmin(dim=1, keepdim=True), 1.0)
    else:
        lo = e.amin(dim=1, keepdim=True)
        scale = tau * (e.mean(dim=1, keepdim=True) - lo) + 1e-12
        w = torch.softmax(-(e - lo) / scale, dim=1)
    if rule in ("smooth", "soft-smooth"):
        w = box_mean(w, radius)
    return w


def blend(outputs: Tensor, w: Tensor) -> Tensor:
    """``(B, C, H, W)``: ``outputs`` ``(B, K, C, H, W)`` weighted by ``w`` ``(B, K, H, W)``."""
    return (outputs * w[:, :, None]).sum(dim=1)


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
    rule: str = "argmin",
    tau: float = 0.3,
    output: str = "full",
    halves: tuple[FeatureBuffers, FeatureBuffers] | None = None,
    judges: tuple[Tensor, Tensor, Tensor, Tensor] | None = None,
) -> tuple[Tensor, Tensor]:
    """Choose or weight per region among ``n_candidates`` filters by the two-buffer estimate.

    Args:
        buffers: an image with ``color_a``/``color_b`` (and their variances, else
            ``color_var``).
        filter_fn: runs candidate ``k`` on a :class:`FeatureBuffers` (the full image or one
            half, see :func:`half_buffers`); returns ``(1, 3, H, W)`` linear colour.
        n_candidates: how many candidates.
        base: the candidate whose full-buffer output makes the relMSE pilot (the unshifted one).
        radius: block radius of the choice.
        rule, tau: how the block estimates become weights (:func:`weights`).
        output: ``"full"`` (the weighted candidates on the full buffer) or ``"halves"`` (the
            weighted means of the candidates on each half).
        halves: the two halves as made by :func:`half_buffers` (made here when ``None``).
        judges: ``(A, B, var_A, var_B)`` ``(1, C, H, W)`` to judge by instead of the raw halves
            (e.g. the halves after the firefly clamp the filter's preparation applies: a clamp
            changes the judge's mean a little and its variance a lot).

    Returns:
        ``(image (3, H, W), weights (K, H, W))``. The full-buffer candidates run one at a
        time after the weights are known, and only where they have weight.
    """
    if output not in ("full", "halves"):
        raise InputError(f"output must be 'full' or 'halves', got {output!r}")
    ha, hb = halves or (half_buffers(buffers, "a"), half_buffers(buffers, "b"))
    if judges is None:
        a, b = ha["color"][None].float(), hb["color"][None].float()
        var_a, var_b = _half_var(ha, a, b), _half_var(hb, a, b)
    else:
        a, b, var_a, var_b = judges
    full_base = _finite(filter_fn(buffers, base))
    den = box_mean(full_base, PILOT_RADIUS).square() + EPS
    errors, means = [], []
    for k in range(n_candidates):
        oa, ob = _finite(filter_fn(ha, k)), _finite(filter_fn(hb, k))
        errors.append((cross_error(oa, ob, a, b, var_a, var_b) / den).mean(dim=1, keepdim=True))
        if output == "halves":
            means.append((oa + ob) * 0.5)
    w = weights(torch.cat(errors, dim=1), radius, rule, tau)
    out = torch.zeros_like(full_base)
    for k in range(n_candidates):
        wk = w[:, k : k + 1]
        if not bool(wk.max() > 0):
            continue
        if output == "halves":
            out += wk * means[k]
        else:
            out += wk * (full_base if k == base else _finite(filter_fn(buffers, k)))
    return out[0], w[0]


def _finite(x: Tensor) -> Tensor:
    return torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)


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


def _model_offsets(
    model: KalantariModel, item: dict[str, Tensor], spp: int | None, chunk_rows: int
) -> Tensor:
    """The model's log-offsets ``(1, O, H, W)`` of a prepared item, as
    :meth:`~mcdenoise.models.kalantari.KalantariModel.denoise_item` makes them
    (:meth:`~mcdenoise.models.kalantari.KalantariModel.banded_offsets`)."""
    feats = item_features(item, spp, regional=model.card.regional)
    return model.banded_offsets(feats, item["irr"].shape[-2], chunk_rows)


def select_kalantari(
    model: KalantariModel,
    buffers: FeatureBuffers,
    *,
    shift: float = SHIFT,
    radius: int = RADIUS,
    rule: str = RULE,
    tau: float = TAU,
    output: str = "full",
    half_bandwidths: str = HALF_BANDWIDTHS,
    fixed: Sequence[Mapping[str, float | int]] | None = None,
    fireflies: str | None = None,
    variance_prior: float | None = None,
    variance_prior_max_spp: float | None = None,
    chunk_rows: int = 256,
) -> Tensor:
    """``kalantari-xbf``/``-nlm`` with the per-region choice among 9 shifted bandwidth sets.

    The model predicts its bandwidths on each buffer (full, ``A``, ``B``) from that buffer's
    own features; the candidates shift them (:func:`shifted_offsets`) and
    :func:`select_filtered` weights them per ``(2·radius + 1)²`` block. The full buffer is
    prepared as :func:`~mcdenoise.methods.kalantari.denoise_kalantari` prepares it (so
    ``shift = 0`` gives its output); each half as a part of the full image, with the
    low-spp variance prior where the *full* image gets it (``variance_prior_max_spp`` halved,
    as measured in ``benchmarks/headroom_kalantari.py``).

    ``half_bandwidths``: ``"own"``: each half filtered with the bandwidths the model predicts
    on it (shifted), ``"full"``: with the full buffer's (shifted), the bandwidths the output
    will use, judged at half the samples. ``fixed``: settings of the fixed cross-bilateral
    filter (:func:`~mcdenoise.methods.cross_bilateral.denoise_xbf`, with the registered
    method's variance prior) added as candidates after the shifts (``None``:
    :func:`fixed_candidates` for the image's spp; ``()``: none). Returns ``(3, H, W)``
    float32 linear colour (finite, >= 0).
    """
    if half_bandwidths not in ("own", "full"):
        raise InputError(f"half_bandwidths must be 'own' or 'full', got {half_bandwidths!r}")
    cache: dict[int, tuple[dict[str, Tensor], list[Tensor]]] = {}
    full_max = variance_prior_max_spp
    if fixed is None:
        fixed = fixed_candidates(buffers.spp)

    def candidates(b: FeatureBuffers) -> tuple[dict[str, Tensor], list[Tensor]]:
        key = id(b)
        if key not in cache:
            max_spp = full_max
            if b is not buffers:
                max_spp = None if full_max is None else full_max / 2
            item = prepare_for_model(
                model.card,
                b,
                features=False,
                fireflies=fireflies,
                variance_prior=variance_prior,
                variance_prior_max_spp=max_spp,
            )
            del item["color"]
            batch = {k: v[None] for k, v in item.items()}
            if b is not buffers and half_bandwidths == "full":
                cache[key] = (batch, candidates(buffers)[1])
            else:
                o = _model_offsets(model, item, b.spp, chunk_rows)
                cache[key] = (batch, shifted_offsets(model, o, shift))
        return cache[key]

    n_shifts = len(shifts(model.card.kind, shift))

    def filter_fn(b: FeatureBuffers, k: int) -> Tensor:
        if k >= n_shifts:
            params = {"variance_prior": XBF_VARIANCE_PRIOR, **fixed[k - n_shifts]}
            return denoise_xbf(b, **params)[None]
        batch, offs = candidates(b)
        return model.filter(batch, offs[k])

    n = n_shifts + len(fixed)
    with torch.no_grad(), single_threaded_ops():
        if shift == 0 and not fixed:  # every candidate is the model's own choice
            out = filter_fn(buffers, n_shifts // 2)[0]
        else:
            ha, hb = half_buffers(buffers, "a"), half_buffers(buffers, "b")
            (ja, va), (jb, vb) = _clamped(candidates(ha)[0]), _clamped(candidates(hb)[0])
            out, _ = select_filtered(
                buffers,
                filter_fn,
                n,
                base=n_shifts // 2,
                radius=radius,
                rule=rule,
                tau=tau,
                output=output,
                halves=(ha, hb),
                judges=(ja, jb, va, vb),
            )
    return _finite(out).clamp_min(0.0).float()


__all__ = [
    "RULES",
    "FilterFn",
    "blend",
    "choose",
    "fixed_candidates",
    "fixed_neighbours",
    "half_buffers",
    "pick",
    "select_filtered",
    "select_kalantari",
    "shifted_offsets",
    "shifts",
    "weights",
]
