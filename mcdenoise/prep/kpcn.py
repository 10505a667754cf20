"""The kpcn network's inputs from a FeatureBuffers: which source, and its prepared tensors.

A *source* (:data:`~mcdenoise.models.encoders.SOURCES`) is a fixed set of buffers a renderer
writes; the network has one encoder per source it was trained with. :func:`choose_source`
takes the first of ``full``, ``basic``, ``color`` whose buffers the input has (among those
the model knows). :func:`prepare_tensors` sanitises and normalises the image once
(:func:`~mcdenoise.prep.inputs.prepare_inputs`: depth / position over the scene extent, the
robust colour variance) and prefilters the noisy guide features as :data:`PREFILTER_MODES`
says; the network turns these tensors into its input channels per crop or tile
(:func:`~mcdenoise.models.encoders.source_channels`).

Prefiltering matters where the features are noisy: depth of field, motion blur, texture finer
than a pixel. The network demodulates the colour by the albedo and multiplies the filtered
irradiance back by it, so every bit of noise in the albedo comes back in the result; a
source without feature variances (``basic``) cannot even tell the network that the albedo is
noisy. ``all`` prefilters every guide feature with variance-normalised NLM (3×3 patches in a
7×7 window, :data:`~mcdenoise.prep.inputs.PREFILTER_ESTIMATED`; the classical filters' 7×7
patches in an 11×11 window were slower and no better here): one with a variance buffer steered
by it, one without by a variance estimated from its neighbourhood
(:func:`~mcdenoise.prep.inputs.estimate_feature_variance`) and capped by the colour's relative
noise. ``adaptive`` (the default) is ``all`` except for features without a variance buffer,
which it prefilters by :func:`~mcdenoise.prep.aux_prefilter.prefilter_aux`: the cap is dropped
where the sample-averaged normal is short (the pixel mixes surfaces or the background, as on a
defocused horizon, where the colour shows no noise), and outliers there are averaged away; on a
render with every feature variance it is ``all``, bit for bit. ``auto`` leaves the features
that have a variance as they are (the ``full`` source also hands that variance to the
network); ``off`` prefilters nothing. ``all`` became the default after measuring both on the
``full`` source (``docs/results/kpcn.md``, "Out of distribution"): held-out relMSE at 4/16/64
spp 0.00813/0.00323/0.00159 with ``auto``, 0.00703/0.00299/0.00154 with ``all``; on the
out-of-distribution renders ``dof_extreme`` at 4 spp 14.4× OIDN's relMSE with ``auto``, 3.0×
with ``all``. ``adaptive`` replaced it for files without variances (Mitsuba ``aov``, Cycles):
``docs/results/ood.md``.

Exposure: the network sees ``log1p`` of the demodulated colour, so its behaviour depends on
the image's brightness, and it has only seen the training scenes' exposures. With
``exposure="auto"`` (the default of the ``kpcn`` method), :func:`exposure_scale` scales an
image whose 90th percentile of luminance lies outside :data:`EXPOSURE_RANGE` (about the
training renders' range) to the nearest end of it, and the result is divided by the same
factor; an image inside the range is not touched.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
from mcdenoise.models.encoders import FEATURE_VARS, SOURCES
from mcdenoise.prep.aux_prefilter import prefilter_aux
from mcdenoise.prep.inputs import (
    EXPOSURE_QUANTILE,
    EXPOSURE_RANGE,
    PREFILTER_ESTIMATED,
    exposure_scale,
    prepare_inputs,
)
from mcdenoise.prep.learned_prefilter import learned_aux

#: Tensors of a prepared image and their channel counts.
PREPARED = {
    "color": 3,
    "color_var": 1,
    "albedo": 3,
    "normal": 3,
    "depth": 1,
    "position": 3,
    **{f"{g}_var": 1 for g in FEATURE_VARS},
}
#: ``prefilter`` modes of :func:`prepare_tensors`: which guide features are prefiltered.
PREFILTER_MODES = {
    "adaptive": "every feature; one without a variance buffer by its own estimate, not "
    "capped by the colour's noise where the pixel mixes surfaces (prep/aux_prefilter.py)",
    "auto": "the features without a variance buffer (variance estimated from the feature)",
    "all": "every feature (its variance buffer when there is one, else estimated)",
    "off": "none: the features as the renderer wrote them",
    "learned": "adaptive, except the albedo and normal of pixels that mix surfaces: by the "
    "learned prefilter (prep/learned_prefilter.py)",
}
#: Default ``prefilter`` mode.
DEFAULT_PREFILTER = "adaptive"

#: ``exposure`` modes of the ``kpcn`` method.
EXPOSURE_MODES = {
    "auto": "scale the input into EXPOSURE_RANGE (and the result back)",
    "off": "the colour as it is",
}


def scale_exposure(t: Mapping[str, Tensor], k: float) -> dict[str, Tensor]:
    """Prepared tensors with ``color`` (and ``reference``) times ``k``, ``color_var`` times
    ``k²``; the features do not change."""
    out = dict(t)
    for key in ("color", "reference"):
        if key in out:
            out[key] = out[key] * k
    if "color_var" in out:
        out["color_var"] = out["color_var"] * (k * k)
    return out


#: Tensors that hold RGB colour (permuted together by the colour augmentation).
COLOR_TENSORS = ("color", "albedo", "reference")


def choose_source(present: set[str] | Sequence[str], trained: Sequence[str]) -> str | None:
    """The first source of :data:`SOURCES` among ``trained`` whose buffers are all present."""
    have = set(present)
    for name, needs in SOURCES.items():
        if name in trained and have.issuperset(needs):
            return name
    return None


def source_for(buffers: FeatureBuffers, trained: Sequence[str]) -> str:
    """The source a model trained with ``trained`` sources uses for ``buffers``.

    Raises:
        MissingFeatureError: no trained source's buffers are all present (the message names
        the buffers of the least demanding one).
    """
    src = choose_source(set(buffers.buffers), trained)
    if src is None:
        needs = min((SOURCES[s] for s in trained), key=len)
        raise MissingFeatureError(
            [b for b in needs if b not in buffers],
            sorted(buffers.buffers),
            source=buffers.source,
            needed_by=f"this kpcn model (sources {', '.join(trained)})",
        )
    return src


def prepare_tensors(
    buffers: FeatureBuffers, source: str, prefilter: str = DEFAULT_PREFILTER
) -> dict[str, Tensor]:
    """Sanitised, normalised tensors ``{name: (C, H, W)}`` of one image for ``source``.

    Args:
        prefilter: which guide features to prefilter, a key of :data:`PREFILTER_MODES`.

    Raises:
        InputError: an unknown ``prefilter`` mode.
        MissingFeatureError: a buffer the source needs is absent (or, for depth / position,
        has no usable scene extent).
    """
    buffers.require(list(SOURCES[source]), needed_by=f"the kpcn '{source}' source")
    guides = [g for g in GUIDE_FEATURES if g in SOURCES[source]]
    if prefilter not in PREFILTER_MODES:
        raise InputError(
            f"prefilter must be one of {', '.join(PREFILTER_MODES)}, got {prefilter!r}"
        )
    adaptive = prefilter in ("adaptive", "learned")
    inp = prepare_inputs(
        buffers,
        features=guides,
        prefilter=prefilter == "all",
        estimate_missing=prefilter in ("all", "auto"),
        prefilter_settings=PREFILTER_ESTIMATED,
    )
    if prefilter == "learned":
        inp.features.update(learned_aux(inp.features, inp.feature_vars, inp.color, inp.color_var))
    elif adaptive:
        inp.features.update(prefilter_aux(inp.features, inp.feature_vars, inp.color, inp.color_var))
    missing = [g for g in guides if g not in inp.features]
    if missing:
        raise MissingFeatureError(
            missing,
            sorted(buffers.buffers),
            source=buffers.source,
            needed_by="kpcn (no scene extent)",
        )
    out = {"color": inp.color[0]}
    if source == "full":
        out["color_var"] = inp.color_var[0]
        for g in FEATURE_VARS:
            v = inp.feature_vars.get(g)
            out[f"{g}_var"] = v[0].mean(0, keepdim=True) if v is not None else inp.color_var[0] * 0
    for g in guides:
        out[g] = inp.features[g][0]
    return out


__all__ = [
    "COLOR_TENSORS",
    "DEFAULT_PREFILTER",
    "EXPOSURE_MODES",
    "EXPOSURE_QUANTILE",
    "EXPOSURE_RANGE",
    "PREFILTER_MODES",
    "PREPARED",
    "choose_source",
    "exposure_scale",
    "prepare_tensors",
    "scale_exposure",
    "source_for",
]
