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

**Half buffers.** ``-p select=auto`` weights per region, on an input with both colour halves
(``mcdenoise render --halves``) and at least :data:`SELECT_MIN_SPP` samples per pixel, among
the model's bandwidths shifted by ±0.7 in log and five fixed cross-bilateral filters, by the
two-buffer error estimate (:func:`mcdenoise.methods.selection.select_kalantari`; Rousselle
et al. 2012, Bitterli et al. 2016); ``select=on`` does so on any input with halves and
refuses one without. Measured on held-out renders (``docs/results/nfor.md``), geometric mean
of relMSE over the model's alone: ``kalantari-xbf`` 0.851 at 4 spp and 0.967 at 16 spp (11
images, at most 1.5 % worse on any), ``kalantari-nlm`` 0.691 and 0.847 (6 images, better on
every one). It runs 42 filters instead of one: ``kalantari-xbf`` on a 128² image, one thread,
38.8 CPU seconds against 1.3 (30×). **The default is** ``select=off``: renders carry halves
by default, and 30× the time for 15 % (4 spp) or 3 % (16 spp) less error is a poor trade for
every run (``make demo`` would grow by about 100 minutes). It is off the Pareto front of time
against error too: on the held-out renders of ``docs/results/nfor.md``, ``oidn`` (6.5 s/MP)
and ``kpcn`` (34 s/MP) have relMSE 0.0046 and 0.0062 at 4 spp, ``kalantari-xbf`` 0.0083
(174 s/MP) and, with selection, about 0.85 of that at about 30× the time. ``select=off`` is
the model alone, to the bit what an input without halves gets.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.settings import GUIDE_FEATURES, GUIDE_VARS
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError, has_halves
from mcdenoise.method import Method
from mcdenoise.methods.selection import select_kalantari
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
#: variance_prior``; :mod:`mcdenoise.prep.variance`, up to :data:`PRIOR_MAX_SPP`; with it
#: the features' prefilter is steered by
#: :func:`~mcdenoise.prep.inputs.low_spp_prefilter_variance`). The shipped models were
#: trained on the renderer's per-pixel estimate, and the filter they steer is sensitive to
#: how much it is changed: at 2 spp the pooled value's weight is ``ν₀ / (1 + ν₀)``, a
#: tenth here. That is enough to lift the pixels whose two samples agreed (variance near 0,
#: which refuse every neighbour), which is what breaks at 2 spp; more moves the variance the
#: models learned to read. ``kalantari-nlm`` / ``kalantari-xbf`` relMSE at 2 spp (robust
#: subset renders, ``docs/results/robustness.md``) with ν₀ = 0, 0.1, 0.25, 0.5:
#: ``cornell_direct`` 0.0109/0.0081/0.0162/0.0602 and 0.0095/0.0086/0.0125/0.0171 (at 0.5
#: above the noisy input's 0.032), ``caustics_glass`` 0.113/0.031/0.029/0.028 and
#: 0.095/0.033/0.031/0.031; with ν₀ = 0.1: ``interior_door`` 0.0192 and 0.0170 (0.5: 0.0169
#: and 0.0169; 0: 0.106 and 0.089), ``mesh_object`` 0.0159 and 0.0155 (0: 0.100 and 0.081),
#: ``sun_outdoor`` 0.0156 and 0.0112, ``cornell`` 0.0087 and 0.0100 (0: 0.0165 and 0.0113;
#: ν₀ = 3, the nlm method's: 0.0267 and 0.0151). The cost of a larger ν₀ is in the filter,
#: not in the features (cornell, ν₀ = 3: pooled variance in the filter only 0.0263, in the
#: features only 0.0159).
VARIANCE_PRIOR = 0.1
#: The most samples per pixel :data:`VARIANCE_PRIOR` applies at (``-p variance_prior_max_spp``):
#: 2, where the cliff is. At 4 spp it helped the robust subset's ``interior_door`` (relMSE
#: 0.041 -> 0.014 and 0.024 -> 0.011) but darkened the sample ``cornell_spp4`` with
#: ``kalantari-nlm`` from -1.8 % to -9.5 % with ν₀ = 0.5 (-8.0 % with 0.25;
#: ``tests/methods/test_bias.py`` allows 2 %) and raised the demo ``cornell``'s
#: ``kalantari-xbf`` relMSE 0.0065 -> 0.0100.
PRIOR_MAX_SPP = 2
#: Values of ``-p select`` (default ``off``, see the module docstring): ``auto`` selects per
#: region when the input has both colour halves and at least :data:`SELECT_MIN_SPP` samples
#: per pixel, ``on`` whenever it has halves (an input without them is refused), ``off`` never.
SELECT_MODES = ("auto", "on", "off")
#: The fewest samples per pixel ``select=auto`` selects at: 4, the lowest level measured
#: (below it each half has a single sample; see the module docstring).
SELECT_MIN_SPP = 4
#: The half buffers the per-region selection reads (:mod:`mcdenoise.methods.selection`).
HALF_BUFFERS = tuple(
    f"{f}{h}{v}" for f in ("color", *GUIDE_FEATURES) for h in ("_a", "_b") for v in ("", "_var")
)


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


def select_mode(params: Mapping[str, Any]) -> str:
    """The ``select`` parameter, checked (:data:`SELECT_MODES`)."""
    mode = str(params.get("select", "off")).strip().lower()
    if mode not in SELECT_MODES:
        raise InputError(f"parameter select={mode!r} is not one of {', '.join(SELECT_MODES)}")
    return mode


def selects(buffers: FeatureBuffers, params: Mapping[str, Any]) -> bool:
    """Whether the method selects per region on ``buffers`` (``-p select``)."""
    mode = select_mode(params)
    if mode == "off":
        return False
    if mode == "on":
        if not has_halves(buffers):
            raise InputError("select=on needs the half buffers color_a and color_b")
        return True
    return has_halves(buffers) and (buffers.spp or 0) >= SELECT_MIN_SPP


def _checker(kind: str) -> Callable[[FeatureBuffers, Mapping[str, Any]], str | None]:
    def check(b: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
        try:
            selects(b, params)
        except InputError as err:
            return str(err)
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
        common = {
            "fireflies": params_mode(params),
            "variance_prior": None if prior in (None, "") else float(prior),
            "variance_prior_max_spp": float(params.get("variance_prior_max_spp", PRIOR_MAX_SPP)),
        }
        if selects(b, params):
            return select_kalantari(model.to(device), b, **common)
        return denoise_kalantari(model.to(device), b, **common)

    return run


#: One-thread speeds (:attr:`~mcdenoise.method.Method.recorded_speed`); with ``select`` on an
#: input with halves the filter runs 42 times (docs/results/threads.md, docs/results/nfor.md).
RECORDED_SPEED = {
    "xbf": {"kalantari-xbf": (0.0361, 14.4), "kalantari-xbf+select": (0.0361, 1806.0)},
    "nlm": {"kalantari-nlm": (0.0622, 11.0), "kalantari-nlm+select": (0.0622, 1750.0)},
}


def _method(kind: str, what: str, priority: int) -> Method:
    # With a shipped no-albedo variant, inputs without albedo (AO renders) are served too.
    needs = GUIDE_FEATURES
    if shipped_model_path(f"kalantari-{kind}", NO_ALBEDO).is_file():
        needs = tuple(g for g in GUIDE_FEATURES if g != "albedo")
    return Method(
        name=f"kalantari-{kind}",
        summary=f"{what} predicted per pixel by an MLP (Kalantari 2015); -p model=RUN, select=off|auto|on",
        requires=("color", *needs),
        uses=("color_var", *GUIDE_FEATURES, *GUIDE_VARS, *HALF_BUFFERS),
        defaults={
            "model": SHIPPED,
            "select": "off",
            "fireflies": "clamp",
            "variance_prior": VARIANCE_PRIOR,
            "variance_prior_max_spp": PRIOR_MAX_SPP,
        },
        run=_runner(kind),
        priority=priority,
        check_input=_checker(kind),
        speed_key=lambda p: f"kalantari-{kind}" + ("" if select_mode(p) == "off" else "+select"),
        recorded_speed=RECORDED_SPEED[kind],
    )


XBF = _method("xbf", "cross-bilateral bandwidths", 30)
NLM = _method("nlm", "NLM k and feature k_f", 25)

__all__ = [
    "NLM",
    "PRIOR_MAX_SPP",
    "SELECT_MIN_SPP",
    "SELECT_MODES",
    "VARIANCE_PRIOR",
    "XBF",
    "denoise_kalantari",
    "model_for",
    "select_mode",
    "selects",
]
