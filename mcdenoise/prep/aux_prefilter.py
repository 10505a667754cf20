"""Prefilter of noisy auxiliary features whose noise the colour does not show (pixel mixing).

A feature written by a path tracer is the mean of the same few samples as the colour. Where
those samples land on different surfaces (depth of field, motion blur, silhouettes, the
background seen through a defocused edge) the feature is noisy, and the network multiplies its
filtered irradiance back by the albedo it is given, so what is left of that noise comes back
in the result (``prep/kpcn.py``). OIDN prefilters noisy auxiliary images for the same reason
(Áfra, Intel Open Image Denoise: ``cleanAux`` off, the albedo and normal are denoised first).

The one-scale prefilter of ``prep/inputs.py`` (variance-normalised NLM, 3×3 patches in a 7×7
window, :data:`~mcdenoise.prep.inputs.PREFILTER_ESTIMATED`) steers each feature without a
variance buffer by a variance estimated from its neighbourhood
(:func:`~mcdenoise.prep.inputs.estimate_feature_variance`), **capped** by what the colour's
relative noise allows (:func:`~mcdenoise.prep.inputs.feature_noise_cap`): the colour is about
albedo × irradiance, so an albedo noisier than the colour would be texture, not noise. That
premise fails where a pixel mixes a surface with the background or an emitter (albedo 0, yet
radiance): on a defocused horizon or silhouette the albedo jumps between 0 and the surface's
reflectance from sample to sample while the colour barely changes (a grey floor against a grey
sky), so the cap is near 0 and the albedo stays as noisy as it was written. Measured on a
depth-of-field scene focused near the camera (the ``dof`` sample spec with a 0.3 aperture
focused at 2.6, 128², 4 spp, 512-spp reference): `kpcn` relMSE 0.089 with the capped
prefilter, OIDN 0.0080; with OIDN's own prefiltered albedo and normal fed to `kpcn` 0.0071;
with the reference features 0.0041. The albedo is the lever, and the cap is what holds it.

What this module changes:

* **Mixing pixels lose the cap.** A sample-averaged normal is shorter than 1 where the samples
  of a pixel saw different orientations or nothing (the background's normal is 0): the
  normal-length deficit ``1 - |n|`` is exactly the pixel-mixing measure the colour lacks. Where
  it exceeds :data:`MIXING_THRESHOLD` (in a 3×3 neighbourhood), the feature's variance is its
  own neighbourhood estimate, uncapped; elsewhere the cap stays, so an in-focus texture on a
  flat surface (unit normals) is protected as before.
* A feature with a variance buffer keeps it (it is the sample variance, no estimate to cap).

Tried and left out: an outlier rule in mixing pixels (one farther from the mean of its 8
neighbours than 4 or 8 estimated standard deviations gets its squared excess as variance, as
:func:`~mcdenoise.prep.inputs.estimate_variance` does for the colour's fireflies, against the
rare-patch effect of NLM, Buades, Coll & Morel 2005). It helped the defocused tuning renders
at 4 spp (0.0116 against 0.0120 below) but averaged away the albedo of a few pixels beside a
bright opening, which the network then multiplied by a large irradiance: the plain
out-of-distribution ``dark_cellar`` at 4 spp went from 0.80× OIDN's relMSE to 2.40×, all of
it in 20 pixels.

The NLM is the same 7×7 window as before: the whole change costs a normal length and a 3×3
max. Measured alternatives on tuning renders (the four
``data/samples`` scenes and three renders of the ``dof`` spec, at 4 and 16 spp, plain copies;
not the out-of-distribution set), ``kpcn`` relMSE geometric mean over 14 images: the capped
one-scale prefilter 0.0162, this module 0.0120, with an 11×11 window 0.0110 (2.5× the
prefilter's time, which the 4K time bound does not leave); a 3×3-median guide for the patch
distances 0.0159 (4× better on the defocused horizon, 3× worse on the in-focus checkerboards);
no cap anywhere 0.0112, but 17-29 % worse than the capped prefilter at 16 spp on the textured
``dof`` and ``materials`` samples (the neighbourhood estimate takes texture for noise). Over
12 of those images (capped 0.0159, this module 0.0113), a 2×2-mean pyramid of NLM levels
merged where they agree within the noise (intersection of confidence intervals, Katkovnik
1999) gave 0.0146-0.0152 whatever the gate: the coarse levels blur the partly defocused
texture the reference keeps. Numbers and commands: ``docs/results/kpcn.md``.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor

from mcdenoise.prep.inputs import (
    PREFILTER_ESTIMATED,
    estimate_feature_variance,
    feature_noise_cap,
    prefilter_feature,
)

#: Normal-length deficit ``1 - |n|`` above which a pixel counts as mixing surfaces (or a
#: surface and the background): 0.05 is a 2×18° spread of two normals, or 5 % of the samples
#: on the background.
MIXING_THRESHOLD = 0.05
#: Radius of the neighbourhood (max) over which the mixing measure is taken: the noisy albedo
#: of a defocused edge spreads a pixel beyond where the normal shows it.
MIXING_RADIUS = 1


def mixing_mask(normal: Tensor, threshold: float = MIXING_THRESHOLD) -> Tensor:
    """``(B, 1, H, W)`` bool: pixels within :data:`MIXING_RADIUS` of one whose sample-averaged
    normal is shorter than ``1 - threshold``.

    Args:
        normal: ``(B, 3, H, W)`` per-pixel mean of unit shading normals (0 on the background).
    """
    # sqrt of the channel sum: Tensor.norm over dim 1 is ~40x slower on the CPU (0.77 s for
    # a 1024² normal on one thread)
    deficit = (1.0 - normal.square().sum(dim=1, keepdim=True).sqrt()).clamp_min(0.0)
    k = 2 * MIXING_RADIUS + 1
    return F.max_pool2d(deficit, k, stride=1, padding=MIXING_RADIUS) > threshold


def aux_feature_variance(
    feature: Tensor, color: Tensor, color_var: Tensor, mixing: Tensor | None
) -> Tensor:
    """Variance ``(B, 1, H, W)`` that steers the prefilter of a feature without a variance
    buffer: the neighbourhood estimate, capped by the colour's noise outside ``mixing``
    pixels, uncapped in them.

    Args:
        feature: ``(B, C, H, W)`` normalised feature.
        color, color_var: ``(B, 3, H, W)`` sanitised colour and ``(B, 1, H, W)`` its variance
            of the mean.
        mixing: :func:`mixing_mask`, or ``None`` (no normal: the cap everywhere).
    """
    est = estimate_feature_variance(feature)
    capped = torch.minimum(est, feature_noise_cap(color, color_var, feature))
    if mixing is None:
        return capped
    return torch.where(mixing, est, capped)


def prefilter_aux(
    features: Mapping[str, Tensor],
    variances: Mapping[str, Tensor],
    color: Tensor,
    color_var: Tensor,
    settings: Mapping[str, object] = PREFILTER_ESTIMATED,
) -> dict[str, Tensor]:
    """Every feature prefiltered by variance-normalised NLM (``settings``): steered by its
    variance buffer when ``variances`` has one, else by :func:`aux_feature_variance` with the
    mixing measure of ``features["normal"]`` (raw, before this prefilter).

    Args:
        features: name -> ``(B, C, H, W)`` normalised, not yet prefiltered feature.
        variances: name -> ``(B, 1 or C, H, W)`` variance of the mean, for those that have one.
        color, color_var: as :func:`aux_feature_variance`.

    Returns:
        name -> prefiltered feature, same shapes and dtypes.
    """
    normal = features.get("normal")
    mixing = mixing_mask(normal) if normal is not None and normal.shape[1] == 3 else None
    steer = {}
    for name, f in features.items():
        v = variances.get(name)
        steer[name] = v if v is not None else aux_feature_variance(f, color, color_var, mixing)
    # Features of the same shape (albedo and normal) are filtered in one batched call: each
    # batch element computes exactly what it computes alone (bit for bit), in ~10 % less time
    # at 1 MP than two calls (fewer passes of the tile loop).
    groups: dict[tuple[object, ...], list[str]] = {}
    for name, f in features.items():
        key = (f.shape, f.dtype, f.device, steer[name].shape)
        groups.setdefault(key, []).append(name)
    out = {}
    for names in groups.values():
        if len(names) == 1:
            out[names[0]] = prefilter_feature(features[names[0]], steer[names[0]], settings)
            continue
        batch = prefilter_feature(
            torch.cat([features[n] for n in names]), torch.cat([steer[n] for n in names]), settings
        )
        for name, res in zip(names, batch.split([features[n].shape[0] for n in names])):
            out[name] = res
    return {name: out[name] for name in features}


__all__ = [
    "MIXING_RADIUS",
    "MIXING_THRESHOLD",
    "aux_feature_variance",
    "mixing_mask",
    "prefilter_aux",
]
