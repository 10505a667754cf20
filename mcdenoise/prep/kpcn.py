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
noisy. ``auto`` (the default) prefilters the features that come without a variance buffer,
with a variance estimated from their neighbourhood
(:func:`~mcdenoise.prep.inputs.estimate_feature_variance`), and leaves the ones with a
variance as they are (the ``full`` source hands that variance to the network).
"""

from __future__ import annotations

from collections.abc import Sequence

from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
from mcdenoise.models.encoders import FEATURE_VARS, SOURCES
from mcdenoise.prep.inputs import prepare_inputs

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
    "auto": "the features without a variance buffer (variance estimated from the feature)",
    "all": "every feature (its variance buffer when there is one, else estimated)",
    "off": "none: the features as the renderer wrote them",
}
#: Default ``prefilter`` mode.
DEFAULT_PREFILTER = "auto"

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
    inp = prepare_inputs(
        buffers,
        features=guides,
        prefilter=prefilter == "all",
        estimate_missing=prefilter != "off",
    )
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
    "PREFILTER_MODES",
    "PREPARED",
    "choose_source",
    "prepare_tensors",
    "source_for",
]
