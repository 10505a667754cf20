"""The ``nfor`` method: two half buffers -> NFOR (Bitterli et al. 2016), training-free.

NFOR needs what only the renderer can give: two independent half buffers of the colour
(``color_a``, ``color_b``: the means of two disjoint halves of each pixel's samples;
``mcdenoise render --halves`` writes them, see :mod:`mcdenoise.io.buffers`). Every decision
it makes -- which neighbours to trust, which bandwidth to keep per pixel -- is judged by one
half against the other, so that no assumption on the noise's distribution is needed (the
variance buffer alone misleads on Monte Carlo's heavy tails: ``benchmarks/headroom_kalantari.py``).
An input without halves is refused with one line naming them and how to get them: the mean of
all samples cannot be split again, and a variance-only substitute would be a different method
(the project's ``nlm`` and ``cross-bilateral`` are exactly that).

Per half, the adapter gathers

* the colour and its variance of the mean: ``color_a_var`` / ``color_b_var``, else twice
  ``color_var``, else the two-buffer estimate ``(A - B)² / 2`` averaged over 3×3 (also where
  the renderer wrote 0, as it does for one sample);
* the features of ``features`` (Tungsten's set: albedo, normal, depth): their halves
  ``<f>_a`` / ``<f>_b`` where the renderer wrote them (a feature that is noisy: depth of
  field, motion), with ``<f>_a_var``, twice ``<f>_var`` or the two-buffer estimate; a feature
  without halves is taken as it is for both (noise-free first-hit features are not
  prefiltered);

clamps the fireflies the full buffer has in the half that drew them (``fireflies``,
:mod:`mcdenoise.prep.fireflies`, detected as for the other classical filters; ``-p
fireflies=off`` is the paper's NFOR), and runs
:func:`mcdenoise.filters.nfor.nfor`. The output is clamped at 0.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor
from torch.nn import functional as F

from mcdenoise.errors import InputError
from mcdenoise.filters.nfor import NforSettings, nfor
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method, dataclass_defaults
from mcdenoise.prep.fireflies import check_mode, remove_fireflies

#: Tungsten's feature set (``README.md`` of ``src/denoiser``).
FEATURES = ("albedo", "normal", "depth")
#: Features the method can use.
KNOWN_FEATURES = ("albedo", "normal", "depth", "position", "visibility")
#: How to get half buffers, for the refusal.
HOW = "render with `mcdenoise render --halves`, or read a Tungsten/KPCN file with its A/B buffers"


def missing_halves(buffers: FeatureBuffers) -> str | None:
    """Why ``buffers`` cannot be denoised by NFOR (one line), or ``None``."""
    lacking = [n for n in ("color_a", "color_b") if n not in buffers]
    if not lacking:
        return None
    return (
        f"needs the half buffers {', '.join(lacking)} (two independent halves of the "
        f"samples, which NFOR judges one against the other); {HOW}"
    )


def _half_variance(b: FeatureBuffers, name: str, a: Tensor, bb: Tensor) -> tuple[Tensor, Tensor]:
    """``(var_a, var_b)`` ``(1, C, H, W)`` of the halves of ``name`` (see the module docstring)."""
    est = None

    def estimate() -> Tensor:
        nonlocal est
        if est is None:
            est = F.avg_pool2d((a - bb).square() * 0.5, 3, 1, 1, count_include_pad=False)
        return est

    out = []
    for half in ("_a", "_b"):
        v = b.get(f"{name}{half}_var")
        if v is None and f"{name}_var" in b:
            v = b[f"{name}_var"] * 2.0
        v = estimate() if v is None or not bool(v.max() > 0) else v[None].float()
        out.append(v.clamp_min(0.0))
    return out[0], out[1]


def denoise_nfor(buffers: FeatureBuffers, **overrides: object) -> Tensor:
    """Denoise with NFOR; returns the ``(3, H, W)`` float32 colour, clamped at 0.

    Keyword overrides: the fields of :class:`~mcdenoise.filters.nfor.NforSettings`,
    ``features`` (names, default :data:`FEATURES`) and ``fireflies`` (``clamp``, ``off``).

    Raises:
        InputError: without ``color_a``/``color_b`` (:func:`missing_halves`), or for halves of
            different sizes.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> half = lambda: 0.5 + 0.1 * torch.randn(3, 16, 16, generator=g)
        >>> fb = FeatureBuffers({"color_a": half(), "color_b": half()})
        >>> denoise_nfor(fb, search_radius=3).shape
        torch.Size([3, 16, 16])
    """
    reason = missing_halves(buffers)
    if reason:
        raise InputError(f"nfor {reason}")
    params = dict(overrides)
    features = tuple(params.pop("features", FEATURES))
    unknown = [f for f in features if f not in KNOWN_FEATURES]
    if unknown:
        raise InputError(f"nfor: unknown feature(s) {unknown}; known: {list(KNOWN_FEATURES)}")
    mode = check_mode(str(params.pop("fireflies", "clamp")))
    if mode == "keep-energy":
        raise InputError("nfor: fireflies must be 'clamp' or 'off'")
    if "bandwidths" in params:
        try:
            params["bandwidths"] = tuple(float(k) for k in params["bandwidths"])  # type: ignore[union-attr]
        except (TypeError, ValueError):
            raise InputError(
                f"nfor: bandwidths must be numbers, got {params['bandwidths']!r}"
            ) from None
    known = set(dataclass_defaults(NforSettings))
    bad = [k for k in params if k not in known]
    if bad:
        raise InputError(f"nfor has no parameter {', '.join(bad)}")
    settings = NforSettings(**params)  # type: ignore[arg-type]

    ca, cb = buffers["color_a"][None].float(), buffers["color_b"][None].float()
    if ca.shape != cb.shape or ca.shape[1] != 3:
        raise InputError(
            f"nfor: color_a {tuple(ca.shape[1:])} and color_b {tuple(cb.shape[1:])} must both "
            "be (3, H, W) of one size"
        )
    va, vb = _half_variance(buffers, "color", ca, cb)
    fa_list, fb_list, fva, fvb = [], [], [], []
    for name in features:
        if f"{name}_a" in buffers and f"{name}_b" in buffers:
            a, bb = buffers[f"{name}_a"][None].float(), buffers[f"{name}_b"][None].float()
            v1, v2 = _half_variance(buffers, name, a, bb)
        elif name in buffers:
            a = bb = buffers[name][None].float()
            var = buffers.get(f"{name}_var")
            v1 = v2 = var[None].float() if var is not None else torch.zeros_like(a)
        else:
            continue
        fa_list.append(a)
        fb_list.append(bb)
        fva.append(v1.expand_as(a))
        fvb.append(v2.expand_as(bb))
    if mode == "clamp":
        ca, va, cb, vb = _clamp_fireflies(buffers, ca, va, cb, vb)
    cat = (lambda xs: torch.cat(xs, dim=1)) if fa_list else (lambda xs: None)
    with torch.no_grad():
        out = nfor(
            ca,
            cb,
            va,
            vb,
            cat(fa_list),
            cat(fb_list),
            cat(fva),
            cat(fvb),
            settings=settings,
        )
    return out.clamp_min(0.0)[0]


def _clamp_fireflies(
    buffers: FeatureBuffers, ca: Tensor, va: Tensor, cb: Tensor, vb: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Clamp the fireflies of the halves where the *full* buffer has one.

    Detection runs on the mean of the halves with its variance, as for the other classical
    filters (:func:`~mcdenoise.prep.fireflies.remove_fireflies`); each half is then scaled at
    those pixels to at most the full buffer's reference level, so the half that drew the
    bright sample is clamped and the other is left alone. Detecting on each half instead
    (half the samples, twice the variance: many more pixels pass the test) lost the energy of
    legitimate bright paths: held-out ``random_s2000_00002`` at 16 spp, relMSE 0.0119 against
    0.0042 without any clamp (``docs/results/nfor.md``).
    """
    albedo, normal = buffers.get("albedo"), buffers.get("normal")
    full = (ca + cb) * 0.5
    full_var = ((va + vb) * 0.25).mean(1, keepdim=True)
    ff = remove_fireflies(
        full,
        full_var,
        "clamp",
        albedo=albedo[None].float() if albedo is not None else None,
        normal=normal[None].float() if normal is not None else None,
    )
    if not bool(ff.mask.any()):
        return ca, va, cb, vb
    ref = ff.color.mean(1, keepdim=True)  # the clamped luminance where masked

    def clamp(c: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        lum = c.mean(1, keepdim=True).clamp_min(1e-30)
        fac = torch.where(ff.mask, (ref / lum).clamp(max=1.0), torch.ones_like(lum))
        return c * fac, v * fac.square()

    ca, va = clamp(ca, va)
    cb, vb = clamp(cb, vb)
    return ca, va, cb, vb


def _check(buffers: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
    return missing_halves(buffers)


def _run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
    with single_threaded_ops():  # parallel over tiles instead (filters/parallel.py)
        return denoise_nfor(b, **params)


_HALVES = ("color_a", "color_b", "color_a_var", "color_b_var")
_FEATURE_BUFFERS = tuple(
    f + s for f in KNOWN_FEATURES for s in ("", "_var", "_a", "_b", "_a_var", "_b_var")
)

METHOD = Method(
    name="nfor",
    summary=(
        "NFOR (Bitterli 2016): first-order regression on the features with NL-means weights "
        "across two half buffers, bandwidth chosen per pixel by the two-buffer error; needs "
        "color_a/color_b (mcdenoise render --halves)"
    ),
    requires=("color",),
    uses=(*_HALVES, "color_var", *_FEATURE_BUFFERS),
    defaults={
        **{k: v for k, v in dataclass_defaults(NforSettings).items() if k != "tile"},
        "features": FEATURES,
        "fireflies": "clamp",
    },
    run=_run,
    priority=3,
    check_input=_check,
    recorded_speed={"nfor": (0.15, 543.0)},  # CPU time (docs/results/nfor.md)
)

__all__ = ["FEATURES", "METHOD", "denoise_nfor", "missing_halves"]
