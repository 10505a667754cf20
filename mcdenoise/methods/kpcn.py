"""The ``kpcn`` method: buffers -> the source's prepared tensors -> kernel-predicting CNN.

:func:`denoise_kpcn` picks the input source the model knows and the buffers allow
(:func:`~mcdenoise.prep.kpcn.source_for`), prepares the image once
(:func:`~mcdenoise.prep.kpcn.prepare_tensors`) and runs the network tile by tile
(:meth:`~mcdenoise.models.kpcn.KpcnModel.denoise_tensors`). The ``model`` parameter is a run
folder or model file, default the shipped weights (``kpcn-learned.pt`` with
``-p prefilter=learned``, the weights trained on such inputs); the method ranks below the learned filters
and above ``nlm`` when those weights are installed, else last. Its
:attr:`~mcdenoise.method.Method.check_input` refuses, with the reason, an input none of whose
sources the model was trained with has all the buffers of.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES, GUIDE_VARS
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method, check_choice
from mcdenoise.methods._learned import missing_weights, model_path, source_needs
from mcdenoise.models.kpcn import STRIP, TILE, KpcnModel
from mcdenoise.models.precision import PRECISIONS, resolve_precision
from mcdenoise.models.weights import SHIPPED, load_kpcn, shipped_model_path
from mcdenoise.prep.kpcn import (
    DEFAULT_PREFILTER,
    EXPOSURE_MODES,
    PREFILTER_MODES,
    exposure_scale,
    prepare_tensors,
    scale_exposure,
    source_for,
)


@torch.no_grad()
def denoise_kpcn(
    model: KpcnModel,
    buffers: FeatureBuffers,
    *,
    source: str | None = None,
    prefilter: str = DEFAULT_PREFILTER,
    exposure: str = "auto",
    tile: int = TILE,
    strip: int = STRIP,
    precision: str = "fp32",
) -> Tensor:
    """Denoise one image; returns ``(3, H, W)`` float32 linear HDR colour (finite, >= 0).

    Args:
        source: force an input source (default: the first the model knows whose buffers
            are present, :func:`~mcdenoise.prep.kpcn.source_for`).
        prefilter: which noisy guide features are prefiltered first, a key of
            :data:`~mcdenoise.prep.kpcn.PREFILTER_MODES` (default ``adaptive``: every guide
            feature, steered by its variance buffer where it has one, else by its own
            estimate, uncapped where the pixel mixes surfaces).
        exposure: ``auto``: an image darker or brighter than the training renders is scaled
            into :data:`~mcdenoise.prep.kpcn.EXPOSURE_RANGE` and the result back
            (:func:`~mcdenoise.prep.kpcn.exposure_scale`); ``off``: as it is.
        tile: tile edge in pixels (rounded up to :attr:`KpcnModel.multiple`); the result does
            not depend on it (to float rounding).
        strip: rows of kernels materialised at once.
        precision: the trunk's, ``fp32``, ``bf16`` or ``auto`` (bf16 where the device has it
            natively, :mod:`~mcdenoise.models.precision`).
    """
    src = source or source_for(buffers, model.card.sources)
    if src not in model.card.sources:
        raise InputError(f"this kpcn model has no '{src}' source ({', '.join(model.card.sources)})")
    device = next(model.parameters()).device
    precision = resolve_precision(precision, device)
    t = {k: v[None].to(device) for k, v in prepare_tensors(buffers, src, prefilter).items()}
    k = exposure_scale(t["color"]) if exposure == "auto" else 1.0
    if k != 1.0:
        t = scale_exposure(t, k)
    out = model.denoise_tensors(t, src, tile=tile, strip=strip, precision=precision)[0]
    return out if k == 1.0 else out / k


#: Shipped variant trained with ``prefilter=learned`` features: with the shipped
#: weights and ``-p prefilter=learned`` the method loads it, so the network sees the inputs
#: it was trained on (``data/recipes/kpcn.md``).
LEARNED_VARIANT = "learned"


def _model(params: Mapping[str, Any]) -> KpcnModel:
    learned = str(params.get("prefilter", "")) == "learned"
    missing = "kpcn: no shipped weights in this install; pass -p model=RUN_FOLDER"
    return load_kpcn(model_path("kpcn", params, missing, LEARNED_VARIANT if learned else None))


def _check(b: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
    if reason := missing_weights("kpcn", params):
        return reason
    trained = _model(params).card.sources
    source = str(params["source"])
    if source != "auto" and source not in trained:
        return f"the model has no '{source}' source ({', '.join(trained)})"
    return source_needs(b, trained if source == "auto" else [source])


def _run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
    model = _model(params).to(device)
    source = str(params["source"])
    prefilter = check_choice("kpcn", "prefilter", str(params["prefilter"]), PREFILTER_MODES)
    exposure = check_choice("kpcn", "exposure", str(params["exposure"]), EXPOSURE_MODES)
    precision = check_choice("kpcn", "precision", str(params["precision"]), PRECISIONS)
    return denoise_kpcn(
        model,
        b,
        source=None if source == "auto" else source,
        prefilter=prefilter,
        exposure=exposure,
        tile=int(params["tile"]),
        precision=precision,
    )


METHOD = Method(
    name="kpcn",
    summary="kernel-predicting CNN, source-aware encoder, 3-scale kernels (Bako 2017, "
    "Vogels 2018); -p model=RUN, -p prefilter=adaptive|learned|auto|all|off, "
    "-p exposure=auto|off, -p precision=auto|fp32|bf16",
    requires=("color", "albedo", "normal"),
    uses=("color_var", *GUIDE_FEATURES, *GUIDE_VARS),
    defaults={
        "model": SHIPPED,
        "source": "auto",
        "prefilter": DEFAULT_PREFILTER,
        "exposure": "auto",
        "tile": 1024,
        "precision": "auto",
    },
    run=_run,
    check_input=_check,
    priority=35 if shipped_model_path("kpcn").is_file() else -1,
    recorded_speed={"kpcn": (0.0189, 1.48)},
)

__all__ = ["METHOD", "denoise_kpcn"]
