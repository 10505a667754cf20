"""The ``kalantari-xbf`` and ``kalantari-nlm`` methods: buffers -> features -> MLP -> filter.

:func:`denoise_kalantari` prepares one image for a loaded model
(:func:`~mcdenoise.prep.kalantari.prepare_for_model`: the filter inputs and per-pixel features,
refusing an input without a guide the model was trained with) and runs it
(:meth:`~mcdenoise.models.kalantari.KalantariModel.denoise_item`). The ``model`` parameter is a
run folder or model file, default the shipped weights (:mod:`mcdenoise.models.weights`); an
input without albedo gets the shipped no-albedo variant where there is one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.settings import GUIDE_FEATURES
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method
from mcdenoise.methods.cross_bilateral import GUIDE_VARS
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.models.weights import (
    NO_ALBEDO,
    SHIPPED,
    load_kalantari,
    shipped_model_for,
    shipped_model_path,
)
from mcdenoise.prep.kalantari import prepare_for_model


def denoise_kalantari(
    model: KalantariModel, buffers: FeatureBuffers, *, chunk_rows: int = 256
) -> Tensor:
    """Denoise one image with ``model``; returns ``(3, H, W)`` float32 linear HDR colour.

    Raises:
        MissingFeatureError: the image lacks a guide the model was trained with.
    """
    item = prepare_for_model(model.card, buffers)
    return model.denoise_item(item, chunk_rows=chunk_rows)


def _runner(kind: str) -> Callable[[FeatureBuffers, Mapping[str, Any], torch.device], Tensor]:
    def run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
        name = str(params["model"])
        shipped = shipped_model_for(f"kalantari-{kind}", set(b.buffers))
        model = load_kalantari(shipped if name in ("", SHIPPED) else name)
        if model.card.kind != kind:
            raise InputError(
                f"{params['model']}: is a kalantari-{model.card.kind} model, not kalantari-{kind}"
            )
        return denoise_kalantari(model.to(device), b)

    return run


def _method(kind: str, what: str, priority: int) -> Method:
    # With a shipped no-albedo variant, inputs without albedo (AO renders) are served too.
    needs = GUIDE_FEATURES
    if shipped_model_path(f"kalantari-{kind}", NO_ALBEDO).is_file():
        needs = tuple(g for g in GUIDE_FEATURES if g != "albedo")
    return Method(
        name=f"kalantari-{kind}",
        summary=f"{what} predicted per pixel by an MLP (Kalantari 2015); -p model=RUN",
        requires=("color", *needs),
        uses=("color_var", *GUIDE_FEATURES, *GUIDE_VARS),
        defaults={"model": SHIPPED},
        run=_runner(kind),
        priority=priority,
    )


XBF = _method("xbf", "cross-bilateral bandwidths", 30)
NLM = _method("nlm", "NLM k and feature k_f", 25)

__all__ = ["NLM", "XBF", "denoise_kalantari"]
