"""The ``kalantari-xbf`` and ``kalantari-nlm`` methods: buffers -> features -> MLP -> filter.

:func:`denoise_kalantari` prepares one image for a loaded model
(:func:`~mcdenoise.prep.kalantari.prepare_for_model`: the filter inputs and per-pixel features,
refusing an input without a guide the model was trained with) and runs it
(:meth:`~mcdenoise.models.kalantari.KalantariModel.denoise_item`). The ``model`` parameter is a
run folder or model file, default the shipped weights (:mod:`mcdenoise.models.weights`); an
input without albedo gets the shipped no-albedo variant where there is one. ``fireflies``
(``clamp``, the default, ``keep-energy`` or ``off``) is the firefly handling of the
preparation layer (:mod:`mcdenoise.prep.fireflies`): a firefly otherwise passes through the
learned filter as it does through the fixed one (``kalantari-nlm`` at 2 spp on the demo's
``caustics_glass``: relMSE 41).

A model needs every guide it was trained with and, for each guide it was trained with the
variance of, that variance (the shipped models: all four guides with their variances, the
no-albedo variant three). The methods' :attr:`~mcdenoise.method.Method.check_input` asks the
model that would run (:func:`model_for`) and refuses, with the reason, an input without them
(e.g. a plain Mitsuba ``aov`` file, which has no variances), so the default method passes it
over instead of failing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.settings import GUIDE_FEATURES
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
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
from mcdenoise.prep.fireflies import params_mode
from mcdenoise.prep.kalantari import check_inputs, item_features, prepare_for_model

#: Degrees of freedom ``ν₀`` of the pooled low-spp variance the methods run with (``-p
#: variance_prior``; :mod:`mcdenoise.prep.variance`, up to :data:`PRIOR_MAX_SPP`; with it the
#: features' prefilter is steered by :func:`~mcdenoise.prep.inputs.low_spp_prefilter_variance`). The shipped models
#: were trained on the renderer's per-pixel estimate, and the filter they steer is sensitive to
#: how much it is changed: at 2 spp the pooled value's weight is ``ν₀ / (1 + ν₀)``, a third
#: here. That is enough to lift the pixels whose two samples agreed (variance near 0, which
#: refuse every neighbour), which is what breaks at 2 spp; more moves the variance the models
#: learned to read. ``kalantari-nlm`` / ``kalantari-xbf`` relMSE at 2 spp with ν₀ = 0, 0.5, 3
#: (the nlm method's; measured before the prefilter steering, with both the demo's tables in
#: ``docs/results/robustness.md``): demo ``cornell`` 0.0165/0.0119/0.0267 and 0.0113/0.0119/0.0151,
#: ``caustics_glass`` 0.113/0.030/0.031 and 0.096/0.032/0.031; robust subset
#: ``interior_door`` 0.106/0.047/0.046 and 0.089/0.041/0.040, ``mesh_object``
#: 0.100/0.0137/0.0137 and 0.081/0.0149/0.0141. At 4 spp (ν₀ 0 -> 0.5) ``interior_door``
#: 0.041 -> 0.014 and 0.024 -> 0.011, the demo scenes 1-14 % lower except ``cornell`` with
#: ``kalantari-xbf`` (0.0065 -> 0.0100, 1.2× OIDN's). The pooled value is what the filter
#: and the features both read: giving it to the filter alone or to the features alone was
#: measured too (cornell 2 spp, ν₀ = 3: filter only 0.0263, features only 0.0159; the
#: caustics are fixed by the filter's share).
VARIANCE_PRIOR = 0.5
#: The most samples per pixel :data:`VARIANCE_PRIOR` applies at (``-p variance_prior_max_spp``):
#: 2, where the cliff is. At 4 spp it helped the robust subset's ``interior_door`` (relMSE
#: 0.041 -> 0.014 and 0.024 -> 0.011) but darkened the sample ``cornell_spp4`` with
#: ``kalantari-nlm`` from -1.8 % to -9.5 % (-8.0 % with ν₀ = 0.25; ``tests/methods/test_bias.py``
#: allows 2 %) and raised the demo ``cornell``'s ``kalantari-xbf`` relMSE 0.0065 -> 0.0100.
PRIOR_MAX_SPP = 2


def denoise_kalantari(
    model: KalantariModel,
    buffers: FeatureBuffers,
    *,
    chunk_rows: int = 256,
    fireflies: str | None = None,
    variance_prior: float | None = None,
    variance_prior_max_spp: float | None = None,
) -> Tensor:
    """Denoise one image with ``model``; returns ``(3, H, W)`` float32 linear HDR colour.

    ``fireflies``: ``clamp``, ``keep-energy`` or ``off`` (:mod:`mcdenoise.prep.fireflies`);
    ``None``: the model's filter settings' (``clamp`` unless it was trained otherwise).
    ``variance_prior``: the low-spp variance (:mod:`mcdenoise.prep.variance`); ``None``: the
    model's settings' (0 for the shipped models, the per-pixel estimate they were trained with).

    Raises:
        MissingFeatureError: the image lacks a guide the model was trained with.
    """
    with single_threaded_ops():  # parallel over tiles and row bands instead (filters/parallel.py)
        item = prepare_for_model(
            model.card,
            buffers,
            features=False,
            fireflies=fireflies,
            variance_prior=variance_prior,
            variance_prior_max_spp=variance_prior_max_spp,
        )
        del item["color"]  # not filtered (it keeps the sanitised copy of the colour alive)
        feats = item_features(item, buffers.spp, regional=model.card.regional)
        return model.denoise_item(item, chunk_rows=chunk_rows, features=feats)


def model_for(kind: str, buffers: FeatureBuffers, model: str) -> KalantariModel:
    """The model ``kalantari-<kind>`` runs on ``buffers`` for its ``model`` parameter: the
    shipped weights chosen for the buffers present, or the given model file / run folder.

    Raises:
        InputError: ``model`` is a model of the other kind. CheckpointError: no such model.
    """
    shipped = model in ("", SHIPPED)
    path = shipped_model_for(f"kalantari-{kind}", set(buffers.buffers)) if shipped else model
    loaded = load_kalantari(path)
    if loaded.card.kind != kind:
        raise InputError(f"{model}: is a kalantari-{loaded.card.kind} model, not kalantari-{kind}")
    return loaded


def _checker(kind: str) -> Callable[[FeatureBuffers, Mapping[str, Any]], str | None]:
    def check(b: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
        model = model_for(kind, b, str(params["model"]))
        try:
            check_inputs(model.card, b)  # what prepare_for_model refuses, before any work
        except MissingFeatureError as err:
            name = str(params["model"])
            which = "the shipped model" if name in ("", SHIPPED) else f"model {name}"
            card = model.card
            trained = ", ".join(card.guides)
            if set(card.guide_vars) == set(card.guides):
                trained += " and their variances"
            elif card.guide_vars:
                trained += f" and the variances of {', '.join(card.guide_vars)}"
            return f"needs {', '.join(err.missing)} ({which} was trained with {trained})"
        return None

    return check


def _runner(kind: str) -> Callable[[FeatureBuffers, Mapping[str, Any], torch.device], Tensor]:
    def run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
        model = model_for(kind, b, str(params["model"]))
        prior = params.get("variance_prior")
        return denoise_kalantari(
            model.to(device),
            b,
            fireflies=params_mode(params),
            variance_prior=None if prior in (None, "") else float(prior),
            variance_prior_max_spp=float(params.get("variance_prior_max_spp", PRIOR_MAX_SPP)),
        )

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
        defaults={
            "model": SHIPPED,
            "fireflies": "clamp",
            "variance_prior": VARIANCE_PRIOR,
            "variance_prior_max_spp": PRIOR_MAX_SPP,
        },
        run=_runner(kind),
        priority=priority,
        check_input=_checker(kind),
    )


XBF = _method("xbf", "cross-bilateral bandwidths", 30)
NLM = _method("nlm", "NLM k and feature k_f", 25)

__all__ = ["NLM", "PRIOR_MAX_SPP", "VARIANCE_PRIOR", "XBF", "denoise_kalantari", "model_for"]
