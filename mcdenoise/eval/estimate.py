"""The error of a denoiser's output without a reference, from two independent half buffers.

A render with halves (``mcdenoise render --halves``; :data:`mcdenoise.io.buffers.HALF_NAMES`)
holds two colour buffers ``A`` and ``B``, each the mean of ``spp/2`` samples from disjoint
sample streams, so ``A = μ + a`` and ``B = μ + b`` with ``a``, ``b`` independent and of mean 0
(Monte Carlo is unbiased) and nothing assumed about their distribution (heavy tails, fireflies:
that is where SURE from the variance buffer fails, ``benchmarks/headroom_kalantari.py``). Run a
denoiser ``D`` on each half: ``D_A = D(A)``, ``D_B = D(B)``.

The construction
    Rousselle, Knaus, Zwicker 2012 ("Adaptive rendering with non-local means filtering") and
    Bitterli et al. 2016 (NFOR, "Nonlinearly weighted first-order regression for denoising
    Monte Carlo renderings") judge the filtered half ``D_A`` against the other half ``B``:
    since ``B``'s noise is independent of ``D_A``,

        E[(D_A − B)²] = E[(D_A − μ)²] + Var B          (the cross term has mean 0)

    so ``(D_A − B)² − v_B`` (``v_B``: the unbiased variance of the mean of ``B``,
    ``color_b_var``) is an unbiased per-pixel estimate of the squared error of ``D_A``
    (:func:`half_error`), and ``Var B`` is the same for every candidate filter, so it drops out
    of a comparison (NFOR selects among candidate filters per pixel this way, then averages the
    two filtered halves). The estimate is unbiased for *any* deterministic ``D``, linear or
    not, and any noise distribution with a mean; only its spread depends on the tails.

What the user gets, and the estimate of it
    ``D`` on a half works at half the samples. As in NFOR, the output whose error is estimated
    exactly is the mean of the two filtered halves ``D̄ = (D_A + D_B) / 2``. With
    ``β_A = E[D_A] − μ`` (and ``β_B``) the two outputs are independent, so
    ``E[(D_A − D_B)²] = MSE_A + MSE_B − 2 β_A·β_B`` and
    ``MSE(D̄) = (MSE_A + MSE_B + 2 β_A·β_B) / 4 = (MSE_A + MSE_B) / 2 − E[(D_A − D_B)²] / 4``.
    Hence the per-pixel estimate (:func:`cross_error`)

        ê = ½[(D_A − B)² − v_B + (D_B − A)² − v_A] − ¼(D_A − D_B)²

    is unbiased for the squared error of ``D̄`` with no other assumption. The variance term
    ``½(Var A + Var B)`` need not come from the variance buffers: ``E[(A − B)²] = Var A +
    Var B`` for any two independent unbiased halves, so :func:`squared_error` subtracts
    ``½(A − B)²`` instead, which needs no variance estimate at all (an input without
    variance buffers can be judged). Which of the two spreads less depends on the filter and
    the tails (``python benchmarks/bench_estimate.py synthetic`` measures both).
    For the identity (the noisy input itself) it is ``¼(A − B)²``, whose mean is ``Var x``
    exactly.

    Expanding the squares, the difference form is exactly
    ``ê = ¼(D_A − D_B)² + (A − D_A)(B − D_B)``: the spread of the two filtered halves plus
    the product of what the filter removed from each half. The two residuals are
    independent, so the product's mean is ``β_A·β_B`` (the bias part) and its noise is a
    product of the halves' own noise: where both halves happen to hold a firefly at one
    pixel (a caustic sampled once in each half) it is large and positive, and nothing in
    the two halves tells it from a real bias. Clipping the product (winsorising) biases the
    estimate and is no better on renders, so the estimate stays unbiased and such pixels
    stay in its noise.

    The output most users keep is ``D`` on the full buffer, ``D(x)``, ``x = (A + B)/2``. Writing
    ``MSE = bias² + variance``: ``ê`` estimates ``β² + Var(D_A)/2`` (the bias of a half-sample
    filter and its variance halved), which is ``MSE(D(x))`` where the filter's bias does not
    change between ``spp/2`` and ``spp`` and its output variance falls as ``1/spp`` (exact for
    a linear filter of fixed weights). A filter that adapts to the noise (narrower where there
    is less) has a lower bias on ``x``, so ``ê`` tends to overestimate its ``D(x)`` error;
    ``benchmarks/bench_estimate.py`` measures the relation on held-out renders.

Relative MSE
    relMSE divides by ``r² + ε`` with the reference ``r`` and the ε of the metric
    (:data:`mcdenoise.losses.RELMSE_EPS`). Without a reference something must stand in for
    ``r`` (Rousselle et al. 2011 normalise their error estimate by the filtered value):
    ``--estimate-error`` uses the output with its 5×5 local mean put back to the noisy
    input's (:func:`matched_normaliser`: the denoiser's output alone darkens what it takes
    for noise and inflates its own fireflies); ``mcdenoise eval`` without ``--ref``, given
    several outputs of one input, normalises all of them (and the noisy input) by one
    image, the same matching applied to the pixelwise median of the outputs
    (:func:`pseudo_reference`), so every method is judged against the same image and no
    method's own errors shrink or swell its own estimate. The image value is the mean over
    pixels and channels; its uncertainty is the standard error over ``block × block``
    blocks (pixels of one block share a filter footprint, blocks barely do), so it reflects
    heavy tails too. The per-pixel estimate may be negative (it is unbiased, not a square).
    An image value below its own standard error is not reported as a value (a clamped ``0.0``
    would read as a perfect output): it is reported as an upper bound,
    ``relmse_estimated_upper`` = max(mean, 0) + 2 standard errors (one-sided, about 97.5 %
    under a normal approximation), shown as ``< x``. The normaliser does not touch the
    squared-error estimate, which stays unbiased; a normaliser that depends on the noise makes relMSE's
    ratio a little biased either way, as the output itself did.

Guides shared by both halves
    The construction needs ``D_A`` to be independent of ``B``'s noise. A filter guided by
    features (albedo, normal, depth, position) breaks that when the features are not halved
    too: the full buffer's albedo holds B's samples, and on a texture finer than a pixel it is
    as noisy as the colour, so ``D_A`` follows B's noise, the cross term ``(D_A − B)`` no
    longer averages out, and the estimate comes out low (2–5× on textured scenes, issue 36).
    ``mcdenoise render`` halves every feature. An input whose colour is halved and whose
    guides are not (:func:`mcdenoise.io.buffers.shared_guides`) is still estimated, with
    ``estimate_warning`` saying so, and with a measured check of how much the shared guides
    move it: the estimate again with those guides smoothed by a 3×3 box
    (``relmse_estimated_smoothed_guides``; less of their noise reaches the filter, so a
    biased estimate rises).

Every figure measured for these choices (spreads, winsorising, normalisers, the radius)
is in docs/results/estimate.md.

Inputs without halves cannot be judged: :func:`split_halves` raises naming what is missing.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.eval.results import printable
from mcdenoise.filters.box import box_mean
from mcdenoise.filters.two_buffer import (
    BLOCK,
    block_means,
    cross_error,
    half_error,
    squared_error,
)
from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.io.buffers import (
    VAR_SUFFIX,
    FeatureBuffers,
    check_halves,
    half_inputs,
    has_halves,
    sanitize,
    shared_guides,
)
from mcdenoise.losses import RELMSE_EPS

__all__ = [
    "BLOCK",
    "SHARED_WARNING",
    "ErrorEstimate",
    "block_means",
    "cross_error",
    "estimate_error",
    "estimate_from_outputs",
    "estimate_record",
    "format_estimates",
    "half_error",
    "matched_normaliser",
    "pseudo_reference",
    "relative",
    "shown_value",
    "smoothed_guides",
    "split_halves",
    "squared_error",
    "upper_bound",
    "write_estimate_report",
]

Denoiser = Callable[[FeatureBuffers], Tensor]


def split_halves(buffers: FeatureBuffers) -> tuple[FeatureBuffers, FeatureBuffers]:
    """The two half-sample inputs of ``buffers`` (:func:`mcdenoise.io.buffers.half_inputs`).

    Raises:
        InputError: no ``color_a``/``color_b`` (or only one of them), naming how to get them.
    """
    check_halves(buffers)
    if not has_halves(buffers):
        where = f"{buffers.source}: " if buffers.source else ""
        odd = f" (this level has {buffers.spp} spp: halves exist at even levels only)"
        raise InputError(
            f"{where}no half buffers (color_a, color_b): the error can only be estimated on a "
            "render with halves (mcdenoise render --halves)"
            + (odd if buffers.spp is not None and buffers.spp % 2 else "")
        )
    return half_inputs(buffers)


def relative(squared_error: Tensor, judged: Tensor, eps: float = RELMSE_EPS) -> Tensor:
    """``squared_error / (judged² + ε)``: a squared error in relMSE units, the judged image
    standing in for the reference (module docstring)."""
    return squared_error / (judged.square() + eps)


#: Radius of the window of :func:`matched_normaliser` (5×5).
MATCH_RADIUS = 2


#: How relMSE estimates are normalised (:func:`matched_normaliser`), as reports name it.
MATCHED = "5x5 mean matched to the input"
#: The normaliser ``--estimate-error`` uses: the output, its local mean matched.
OWN = f"own output, {MATCHED}"
#: The normaliser of an output written before ``mcdenoise:estimate_normaliser`` existed.
OWN_OLD = "own output"


def matched_normaliser(image: Tensor, noisy: Tensor, radius: int = MATCH_RADIUS) -> Tensor:
    """What relMSE divides by without a reference: ``image`` (a denoised output, or the
    :func:`pseudo_reference` of several) with its local mean put back to the noisy input's,
    ``image + box(noisy − image)`` over a ``(2·radius + 1)²`` window (in-image box mean).
    ``image``, ``noisy``: ``(C, H, W)`` linear radiance; returns float64 ``(C, H, W)``.

    relMSE divides by the reference squared. A denoised image stands in for it well where
    it is right, but every denoiser removes some real energy as if it were noise: a caustic
    or a small highlight that is bright in both halves (so the squared-error estimate is
    large there) comes out dark, and dividing that error by a near-zero square made two
    pixels of ``caustics_glass`` dominate a method's whole estimate. The noisy input's box mean is an unbiased estimate
    of the reference's box mean (Monte Carlo is unbiased), so the sum brings that energy
    back spread over the window, keeps the image's detail (``image − box(image)``) and adds
    only the box mean's noise (``1/(2r+1)²`` of the input's variance). The radius was
    measured against other forms (3×3, one-sided, ``max(image, box(noisy))``).
    """

    img = image.double()
    return img + box_mean((noisy.double() - img)[None], radius)[0]


def pseudo_reference(outputs: Sequence[Tensor]) -> Tensor:
    """The pixelwise median of several denoisers' outputs of one input (each ``(C, H, W)``;
    float64; for an even count the mean of the two middle values, so two outputs give their
    mean).

    It normalises every output's relMSE estimate when several outputs of one input are
    judged together (:func:`mcdenoise.eval.estimate_files.estimate_files`). Each denoiser is
    wrong somewhere else (one blurs a caustic, another leaves fireflies); the median keeps,
    per pixel, a value between the others, so (from three outputs on) one failing output
    does not move it, while an output's own value inflates its square where its residual
    noise is (the noisy input's fireflies) and deflates it where it darkens. The noisy input is not among the outputs:
    its noise would bias the square upwards.
    """
    x = torch.stack([o.double() for o in outputs])
    n = x.shape[0]
    s = x.sort(0).values
    return s[(n - 1) // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


@dataclass
class ErrorEstimate:
    """The estimated error of one output.

    Attributes:
        squared_error: ``(3, H, W)`` per-pixel unbiased estimate of the squared error
            (may be negative).
        relmse_map: ``(H, W)`` per-pixel relMSE estimate (channel mean).
        relmse: image relMSE estimate (mean of ``relmse_map``, clamped at 0).
        relmse_se: its standard error over blocks (over pixels for an image of one block).
        mse: image MSE estimate (clamped at 0).
        judged: what the estimate is of: ``"halves-mean"`` (``(D(A) + D(B)) / 2``, exact in
            expectation) or ``"full"`` (``D`` on the full buffer, through the relation in the
            module docstring).
        upper: the upper bound reported instead of ``relmse`` when the mean is below its
            standard error (``max(mean, 0) + 2·se``), else ``None``.
    """

    squared_error: Tensor
    relmse_map: Tensor
    relmse: float
    relmse_se: float
    mse: float
    judged: str
    upper: float | None = None

    @property
    def reported(self) -> float:
        """What a report shows: the estimate, or its upper bound when it is below its noise."""
        return self.relmse if self.upper is None else self.upper

    def to_dict(self) -> dict[str, Any]:
        """The scalars, for JSON records: ``relmse_estimated`` is ``None`` (null) when only
        ``relmse_estimated_upper`` is known."""
        out: dict[str, Any] = {
            "relmse_estimated": self.relmse if self.upper is None else None,
            "relmse_estimated_se": self.relmse_se,
            "mse_estimated": self.mse,
            "estimate_of": self.judged,
        }
        if self.upper is not None:
            out["relmse_estimated_upper"] = self.upper
        return out


def upper_bound(mean: float, se: float) -> float | None:
    """The upper bound reported for an image estimate ``mean`` below its standard error
    ``se`` (``max(mean, 0) + 2·se``), or ``None`` when the mean stands above its noise."""
    if not math.isfinite(se) or mean >= se:
        return None
    return max(mean, 0.0) + 2.0 * se


def estimate_from_outputs(
    out_a: Tensor,
    out_b: Tensor,
    buffers: FeatureBuffers,
    *,
    output: Tensor | None = None,
    normaliser: Tensor | None = None,
    block: int = BLOCK,
    eps: float = RELMSE_EPS,
) -> ErrorEstimate:
    """The :class:`ErrorEstimate` of a denoiser whose outputs on the two halves of
    ``buffers`` are ``out_a`` and ``out_b`` (``(3, H, W)``).

    ``output``: the image the user keeps (``D`` on the full buffer); the estimate is then of
    it (``judged="full"``); ``None``: of ``(out_a + out_b) / 2``. ``normaliser``: what relMSE
    divides by (squared, plus ε): by default the judged image itself; several outputs of one
    input judged together share :func:`pseudo_reference`.
    """
    check_halves(buffers)
    if not has_halves(buffers):
        raise InputError("estimate_from_outputs: the buffers have no color_a/color_b")
    a, b = buffers["color_a"], buffers["color_b"]
    out_a, out_b = out_a.to(a), out_b.to(a)
    sq = squared_error(out_a.double(), out_b.double(), a.double(), b.double())
    judged_img = (out_a + out_b) / 2 if output is None else output.to(a)
    norm = judged_img if normaliser is None else normaliser.to(a)
    rel = relative(sq, norm.double(), eps).mean(0)
    means, counts = block_means(rel, block)
    n = means.numel()
    mean = float((means * counts).sum() / counts.sum())
    if n > 1:
        se = float(means.std(unbiased=True) / n**0.5)
    else:  # one block: pixels are correlated, so this understates the spread
        se = float(rel.std() / rel.numel() ** 0.5) if rel.numel() > 1 else float("nan")
    return ErrorEstimate(
        squared_error=sq.float(),
        relmse_map=rel.float(),
        relmse=max(mean, 0.0),
        relmse_se=se,
        mse=max(float(sq.mean()), 0.0),
        judged="halves-mean" if output is None else "full",
        upper=upper_bound(mean, se),
    )


def estimate_error(
    denoiser: Denoiser,
    buffers: FeatureBuffers,
    *,
    output: Tensor | None = None,
    block: int = BLOCK,
) -> ErrorEstimate:
    """Run ``denoiser`` (FeatureBuffers -> ``(3, H, W)``) on both halves of ``buffers`` and
    estimate the error of its output (:func:`estimate_from_outputs`; ``output``: the
    denoiser's output on the full buffer, when that is what the user keeps).

    Raises:
        InputError: ``buffers`` has no halves (or only one).
    """
    half_a, half_b = split_halves(buffers)
    return estimate_from_outputs(
        denoiser(half_a), denoiser(half_b), buffers, output=output, block=block
    )


#: The warning an estimate carries when noisy guides are shared by both halves.
SHARED_WARNING = "guides shared by both halves ({}): the estimate is biased low"
#: Radius of the box that smooths shared guides for the check of their effect (3×3).
GUIDE_CHECK_RADIUS = 1


def smoothed_guides(buffers: FeatureBuffers, names: Sequence[str]) -> FeatureBuffers:
    """``buffers`` with the features ``names`` replaced by their 3×3 box mean (their
    variances divided by 9, as for independent pixels): less of their noise, which both
    halves share, reaches a filter guided by them."""
    out = buffers.to()
    out.buffers = dict(buffers.buffers)
    for n in names:
        out.buffers[n] = box_mean(buffers[n][None].double(), GUIDE_CHECK_RADIUS)[0].to(buffers[n])
        if n + VAR_SUFFIX in buffers.buffers:
            out.buffers[n + VAR_SUFFIX] = buffers[n + VAR_SUFFIX] / 9
    return out


def estimate_record(
    denoiser: Denoiser,
    buffers: FeatureBuffers,
    output: Tensor,
    *,
    method: str = "the method",
    reads: Sequence[str] | None = None,
) -> dict[str, Any]:
    """What ``mcdenoise denoise --estimate-error`` records: ``denoiser`` run on each half of
    ``buffers`` (repaired as the denoiser's input is, :func:`mcdenoise.io.sanitize`), the
    estimate of the error of ``output`` (the denoiser on the full buffer), as the JSON fields
    ``relmse_estimated`` (or ``relmse_estimated_upper``, :class:`ErrorEstimate`),
    ``relmse_estimated_se``, ``mse_estimated``, ``estimate_of``, ``estimate_normaliser``
    (:func:`matched_normaliser` of the output) and ``estimate_seconds``.

    ``reads``: the features the method reads; those of them that both halves share
    (:func:`mcdenoise.io.buffers.shared_guides`) add ``estimate_warning`` and
    ``relmse_estimated_smoothed_guides`` (module docstring). A method that does not run on
    one half alone (``nfor`` needs both halves itself) gets no estimate:
    ``relmse_estimated`` is ``None`` and ``estimate_note`` says why.
    """

    t0 = time.perf_counter()
    half_a, half_b = split_halves(buffers)
    try:
        out_a, out_b = denoiser(half_a), denoiser(half_b)
    except InputError as e:  # e.g. nfor: a half has no halves of its own
        why = " ".join(str(e).split())
        note = (
            f"no estimate: {method} uses both halves itself, so it cannot be run on one half "
            "and judged by the other"
            if "half buffers" in why
            else f"no estimate: {method} did not run on one half alone ({why})"
        )
        return {
            "relmse_estimated": None,
            "estimate_note": note,
            "estimate_seconds": round(time.perf_counter() - t0, 6),
        }
    clean, _ = sanitize(buffers)
    norm = matched_normaliser(output, clean["color"])
    est = estimate_from_outputs(out_a, out_b, clean, output=output, normaliser=norm)
    record: dict[str, Any] = {**est.to_dict(), "estimate_normaliser": OWN}
    shared = shared_guides(buffers, reads)
    if shared:
        record["estimate_warning"] = SHARED_WARNING.format(", ".join(shared))
        smooth_a, smooth_b = split_halves(smoothed_guides(buffers, shared))
        check = estimate_from_outputs(
            denoiser(smooth_a), denoiser(smooth_b), clean, output=output, normaliser=norm
        )
        record["relmse_estimated_smoothed_guides"] = check.reported
    record["estimate_seconds"] = round(time.perf_counter() - t0, 6)
    return record


# --- reports without a reference (mcdenoise eval without --ref) ------------------------------
#: Columns of the reference-free report, in order.
ESTIMATE_COLUMNS = (
    "scene",
    "method",
    "spp",
    "relmse_estimated",
    "relmse_estimated_upper",
    "relmse_estimated_se",
    "estimate_of",
    "normaliser",
    "file",
    "warning",
    "note",
)


def shown_value(row: dict[str, Any], digits: int = 5) -> str:
    """A row's estimate as a report shows it: the value, ``< bound`` when only an upper bound
    is known (the estimate is below its own noise), ``-`` when there is none."""
    v, up = row.get("relmse_estimated"), row.get("relmse_estimated_upper")
    if v is not None:
        return f"{v:.{digits}g}"
    return f"< {up:.3g}" if up is not None else "-"


def format_estimates(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a text table, titled as estimates, each with its normaliser."""
    lines = [
        "relMSE ESTIMATED without a reference (from the half buffers; ± one standard error)",
        f"{'scene':28s} {'spp':>5s} {'method':18s} {'relMSE (est.)':>14s} {'± se':>10s}  "
        "normalised by",
    ]
    for r in rows:
        se = r["relmse_estimated_se"]
        val = f"{shown_value(r):>14s}"
        unc = f"{se:10.2g}" if se is not None else f"{'':>10s}"
        spp = str(r["spp"]) if r["spp"] is not None else "-"
        warn = f"WARNING {r['warning']}" if r.get("warning") else ""
        note = printable("; ".join(x for x in (warn, r.get("normaliser") or "", r["note"]) if x))
        scene, method = printable(str(r["scene"])), printable(str(r["method"]))
        lines.append(f"{scene:28s} {spp:>5s} {method:18s} {val} {unc}  {note}")
    return "\n".join(lines)


def _cell(value: Any) -> str:
    """An HTML cell's text: floats to 4 significant digits (the JSON and CSV keep them all)."""
    if value is None:
        return ""
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def write_estimate_report(
    rows: Sequence[dict[str, Any]], out_dir: str | os.PathLike[str]
) -> dict[str, Path]:
    """``estimate.json``, ``estimate.csv`` and ``estimate.html`` in ``out_dir`` (created),
    every one saying that the values are estimated without a reference."""

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / f"estimate.{k}" for k in ("json", "csv", "html")}
    note = (
        "relMSE estimated without a reference from two independent half buffers "
        "(mcdenoise.eval.estimate); not measured"
    )
    # every file atomically (a full disk leaves no half report); JSON without NaN: a value
    # that is not finite (a crafted header's) is null, like a value not estimated
    finite = [
        {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in r.items()}
        for r in rows
    ]
    text = json.dumps({"estimated": True, "note": note, "rows": finite}, indent=1, allow_nan=False)
    write_text_atomic(paths["json"], text)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow([*ESTIMATE_COLUMNS, "estimated"])
    for r in rows:
        w.writerow([*(r.get(c) for c in ESTIMATE_COLUMNS), True])
    write_text_atomic(paths["csv"], buf.getvalue())
    cells = "".join(
        "<tr>"
        + "".join(
            f"<td>{html.escape(shown_value(r, 4) if c == 'relmse_estimated' else _cell(r.get(c)))}"
            "</td>"
            for c in ESTIMATE_COLUMNS
        )
        + "</tr>"
        for r in rows
    )
    head = "".join(f"<th>{c}</th>" for c in ESTIMATE_COLUMNS)
    write_text_atomic(
        paths["html"],
        f"<!doctype html><meta charset='utf-8'><title>Estimated relMSE</title>"
        f"<h1>Estimated relMSE (no reference)</h1><p><b>{html.escape(note)}.</b> "
        "± is one standard error over 16×16 blocks. <i>normaliser</i>: what relMSE divides "
        "by — the median of the outputs of one input when several are given (every method "
        "judged against the same image), else the output itself; either with its 5×5 local "
        "mean matched to the noisy input's. <i>&lt; x</i>: the estimate is below its own "
        "standard error, x is an upper bound (mean + 2 se). <i>warning</i>: noisy guides "
        "shared by both halves bias the estimate low.</p>"
        f"<table border='1'><tr>{head}</tr>{cells}</table>",
    )
    return paths
