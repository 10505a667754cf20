"""Per-pixel features for learning filter parameters (Kalantari, Bako, Sen 2015, section 4).

The features describe, at every pixel, what the filter is about to average: how noisy the
colour is, how much the scene's geometry and texture vary around it, and how many samples
there are. They are computed from :class:`~mcdenoise.filters.prepare.FilterInputs` (sanitised,
normalised, prefiltered buffers) and the demodulated irradiance the filter sees, on the
*whole image*, so a training patch sees exactly the values inference computes.

Primary features (Kalantari 2015: screen position, colour, world position, shading normal,
texture value of the first hit; the second-bounce texture and direct-light visibility are not
in mcdenoise's data and are left out):

=====================  ================================================================
``screen.x/y``         pixel centre / image size, [0, 1]
``color.r/g/b``        ``log1p`` of the demodulated irradiance
``<guide>.<ch>``       each guide feature present (albedo r/g/b, normal x/y/z, depth,
                       position x/y/z over the scene extent, as the filter sees them)
=====================  ================================================================

Secondary features (Kalantari 2015 computes means, standard deviations, gradients and the
mean absolute deviation of the primary ones over small blocks, and the sample count):

=========================  ============================================================
``lum.mean.w``             local mean of the log-luminance over a ``w × w`` window
``lum.std.w``              its local standard deviation (w = 3, 7, 21)
``<guide>.std.w``          local standard deviation of a guide (channel mean), w = 3, 7, 21
``lum.grad``, ``<guide>.grad``   gradient magnitude (central differences, channel mean)
``lum.mad``                mean absolute deviation of the log-luminance over 3 × 3
``color.relvar``           ``log`` of the colour's relative variance of the mean
                           ``v / (L² + 10⁻⁴)`` -- the noise level the filter must remove
``<guide>.var``            ``log(10⁻⁶ + variance of the mean)`` of a guide that has one
``spp``                    ``log2(spp)`` (the training mean when the input does not say)
=========================  ============================================================

Regional features (``regional=True``; not in the paper): the means over a ``63 × 63`` window
(:data:`REGION`) of ``color.relvar``, ``lum.std.7``, ``lum.grad`` and each ``<guide>.grad``,
named ``region.relvar``, ``region.lum.std``, ``region.lum.grad``, ``region.<guide>.grad``. A
pixel's own statistics are noisy estimates of how noisy and how detailed its surroundings
are; averaged over a region they are precise, and a filter's best bandwidths vary slowly
across an image (fitted per 16×16 block they reach most of what per-pixel fits reach; see the
README). The shipped cross-bilateral model uses them.

The ordered names depend only on which guides are present (:func:`feature_names`); a model
stores them and refuses inputs whose names differ (:func:`check_feature_names`).
Normalisation (per-feature mean and standard deviation over the training pixels,
:class:`FeatureStats`) is stored with the model; normalised values are clamped to ±8 so a
firefly or an absurd depth cannot drive the network out of its training range.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.prepare import GUIDE_FEATURES, FilterInputs, box_mean

#: Window edges of the local statistics.
WINDOWS: tuple[int, ...] = (3, 7, 21)
#: Window edge of the regional means (``regional=True``).
REGION = 63
#: Channel names of each guide feature (as in :mod:`mcdenoise.io.buffers`).
GUIDE_CHANNELS: dict[str, tuple[str, ...]] = {
    "albedo": ("r", "g", "b"),
    "normal": ("x", "y", "z"),
    "depth": ("z",),
    "position": ("x", "y", "z"),
}
#: Normalised features are clamped to ``±CLAMP``.
CLAMP = 8.0


def feature_names(
    guides: Sequence[str], with_guide_vars: Sequence[str] = (), regional: bool = False
) -> list[str]:
    """The ordered feature names for inputs with ``guides`` (and variances of
    ``with_guide_vars``), with the regional means last when ``regional``."""
    guides = [g for g in GUIDE_FEATURES if g in guides]
    names = ["screen.x", "screen.y", "color.r", "color.g", "color.b"]
    for g in guides:
        names += [f"{g}.{c}" for c in GUIDE_CHANNELS[g]]
    names += [f"lum.mean.{w}" for w in WINDOWS] + [f"lum.std.{w}" for w in WINDOWS]
    for g in guides:
        names += [f"{g}.std.{w}" for w in WINDOWS]
    names += ["lum.grad"] + [f"{g}.grad" for g in guides]
    names += ["lum.mad", "color.relvar"]
    names += [f"{g}.var" for g in guides if g in with_guide_vars]
    names += ["spp"]
    if regional:
        names += ["region.relvar", "region.lum.std", "region.lum.grad"]
        names += [f"region.{g}.grad" for g in guides]
    return names


def check_feature_names(
    expected: Sequence[str], got: Sequence[str], what: str, got_label: str = "the input"
) -> None:
    """Raise an :class:`InputError` naming the difference when ``got != expected``.

    ``expected`` are a model's feature names, ``got`` those computed for ``got_label``.
    """
    if list(expected) == list(got):
        return
    missing = [n for n in expected if n not in got]
    extra = [n for n in got if n not in expected]
    if missing or extra:
        detail = []
        if missing:
            detail.append(f"the model uses {', '.join(_group(missing))}, which {got_label} lacks")
        if extra:
            detail.append(
                f"{got_label} has {', '.join(_group(extra))}, which the model was not trained with"
            )
        raise InputError(f"{what}: feature set differs: {'; '.join(detail)}")
    raise InputError(f"{what}: feature order differs from the model's")


def _group(names: Sequence[str]) -> list[str]:
    """Collapse ``albedo.r, albedo.g, ...`` into ``albedo.*`` for short messages."""
    out: list[str] = []
    for n in names:
        head = n.rsplit(".", 1)[0]
        same = [m for m in names if m.rsplit(".", 1)[0] == head]
        label = f"{head}.*" if len(same) > 1 else n
        if label not in out:
            out.append(label)
    return out


def _local_std(x: Tensor, w: int) -> Tensor:
    """Channel-mean local standard deviation ``(B, 1, H, W)`` over ``w × w``."""
    m = box_mean(x, w // 2)
    v = (box_mean(x * x, w // 2) - m * m).clamp_min(0)
    return v.mean(1, keepdim=True).sqrt()


def _grad(x: Tensor) -> Tensor:
    """Channel-mean gradient magnitude by central differences (replicate border)."""
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    gx = (p[..., 1:-1, 2:] - p[..., 1:-1, :-2]) * 0.5
    gy = (p[..., 2:, 1:-1] - p[..., :-2, 1:-1]) * 0.5
    return (gx.square() + gy.square()).mean(1, keepdim=True).sqrt()


def _mad3(x: Tensor) -> Tensor:
    """Mean absolute deviation from the 3×3 mean, ``(B, 1, H, W)``."""
    m = box_mean(x, 1)
    h, w = x.shape[-2:]
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    dev = [(p[..., dy : dy + h, dx : dx + w] - m).abs() for dy in range(3) for dx in range(3)]
    return torch.stack(dev).mean(0).mean(1, keepdim=True)


def compute_features(
    inp: FilterInputs,
    irradiance: Tensor,
    irradiance_var: Tensor,
    spp: float | None,
    *,
    regional: bool = False,
) -> tuple[Tensor, list[str]]:
    """Raw (un-normalised) features ``(1, F, H, W)`` and their names.

    Args:
        inp: prepared filter inputs of one image (batch 1).
        irradiance: ``(1, 3, H, W)`` what the filter averages (demodulated colour, or colour).
        irradiance_var: ``(1, 1, H, W)`` its variance of the mean.
        spp: samples per pixel, or ``None`` when unknown (the ``spp`` feature is then NaN and
            :meth:`FeatureStats.normalize` replaces it by the training mean).
        regional: also the regional means (see the module docstring).
    """
    _, _, h, w = irradiance.shape
    dt, dev = irradiance.dtype, irradiance.device
    ys = (
        torch.linspace(0, 1, h, dtype=dt, device=dev)
        if h > 1
        else torch.zeros(1, dtype=dt, device=dev)
    )
    xs = (
        torch.linspace(0, 1, w, dtype=dt, device=dev)
        if w > 1
        else torch.zeros(1, dtype=dt, device=dev)
    )
    sy, sx = torch.meshgrid(ys, xs, indexing="ij")
    color = torch.log1p(irradiance.clamp_min(0))
    lum_lin = irradiance.clamp_min(0).mean(1, keepdim=True)
    lum = torch.log1p(lum_lin)
    guides = [g for g in GUIDE_FEATURES if g in inp.features]
    chans: list[Tensor] = [sx[None, None], sy[None, None], color]
    chans += [inp.features[g] for g in guides]
    lum_std = [_local_std(lum, k) for k in WINDOWS]
    chans += [box_mean(lum, k // 2) for k in WINDOWS] + lum_std
    for g in guides:
        chans += [_local_std(inp.features[g], k) for k in WINDOWS]
    grads = [_grad(lum)] + [_grad(inp.features[g]) for g in guides]
    chans += grads
    chans += [_mad3(lum)]
    relvar = torch.log((irradiance_var + 1e-12) / (lum_lin.square() + 1e-4))
    chans += [relvar]
    with_vars = [g for g in guides if g in inp.feature_vars]
    chans += [torch.log(inp.feature_vars[g].mean(1, keepdim=True) + 1e-6) for g in with_vars]
    s = math.log2(spp) if spp else math.nan
    chans += [torch.full_like(lum, s)]
    if regional:
        r = REGION // 2
        chans += [box_mean(x, r) for x in [relvar, lum_std[WINDOWS.index(7)], *grads]]
    feats = torch.cat(chans, dim=1)
    names = feature_names(guides, with_vars, regional)
    if feats.shape[1] != len(names):  # a programming error, not an input error
        raise AssertionError(f"{feats.shape[1]} feature channels for {len(names)} names")
    return feats, names


@dataclass
class FeatureStats:
    """Per-feature mean and standard deviation over the training pixels.

    Attributes:
        names: feature names, in channel order.
        mean, std: one float per feature (``std`` floored at 1e-6).
    """

    names: list[str]
    mean: list[float]
    std: list[float]

    @staticmethod
    def from_samples(names: Sequence[str], samples: Sequence[Tensor]) -> FeatureStats:
        """Statistics of ``(1, F, H, W)`` feature maps (NaNs -- unknown spp -- ignored)."""
        if not samples:
            raise InputError("no feature maps to compute normalisation statistics from")
        flat = torch.cat([s.double().flatten(2)[0] for s in samples], dim=1)  # (F, N)
        ok = torch.isfinite(flat)
        n = ok.sum(1).clamp_min(1)
        z = torch.where(ok, flat, torch.zeros_like(flat))
        mean = z.sum(1) / n
        var = (torch.where(ok, flat - mean[:, None], torch.zeros_like(flat)).square()).sum(1) / n
        return FeatureStats(list(names), mean.tolist(), var.sqrt().clamp_min(1e-6).tolist())

    def to_dict(self) -> dict[str, list]:
        return {"names": list(self.names), "mean": list(self.mean), "std": list(self.std)}

    @staticmethod
    def from_dict(d: dict) -> FeatureStats:
        try:
            names, mean, std = (
                list(d["names"]),
                [float(v) for v in d["mean"]],
                [float(v) for v in d["std"]],
            )
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"model file: bad feature statistics ({err})") from None
        if not (len(names) == len(mean) == len(std)):
            raise InputError("model file: feature statistics have inconsistent lengths")
        return FeatureStats(names, mean, std)

    def normalize(self, feats: Tensor) -> Tensor:
        """``(feats - mean) / std`` clamped to ±:data:`CLAMP`; NaN/Inf -> 0 (the mean)."""
        m = torch.tensor(self.mean, dtype=feats.dtype, device=feats.device)[None, :, None, None]
        s = torch.tensor(self.std, dtype=feats.dtype, device=feats.device)[None, :, None, None]
        z = (feats - m) / s
        z = torch.nan_to_num(z, nan=0.0, posinf=CLAMP, neginf=-CLAMP)
        return z.clamp(-CLAMP, CLAMP)
