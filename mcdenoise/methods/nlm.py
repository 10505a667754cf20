"""The ``nlm`` method: buffers -> prepared inputs -> variance-normalised non-local means.

The same pipeline as :mod:`mcdenoise.methods.cross_bilateral` (prepare, demodulate by the
albedo, filter, remodulate, clamp at 0) with Rousselle 2012's NLM and, where guide features
are present, Rousselle 2013's feature weights. Its parameters are
:class:`~mcdenoise.filters.settings.NlmSettings`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.filters.albedo import remodulate
from mcdenoise.filters.nlm import non_local_means
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.settings import GUIDE_FEATURES, GUIDE_VARS, NlmSettings, with_overrides
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method, dataclass_defaults
from mcdenoise.prep.inputs import demodulate_inputs, guide_args, prepare_inputs

#: κ of the variance pair ``min(κ v_i, v_j)`` the ``nlm`` method runs with (``-p var_cap``).
#: With the plain minimum (1, :class:`NlmSettings`' value, which the learned ``kalantari-nlm``
#: was trained with) a pixel that drew a bright sample takes in its darker neighbours while
#: they refuse it, and the image darkens: by 2.8 % on ``cornell_spp4``, 1.13 % with 16, at a
#: lower relMSE (``docs/results/bias.md``).
VAR_CAP = 16.0
#: Degrees of freedom of the pooled variance the ``nlm`` method shrinks the per-pixel
#: variance towards at 2-8 spp (``-p variance_prior``; :mod:`mcdenoise.prep.variance`): on the
#: demo renders at 2 spp, after the firefly clamp, relMSE 0.137 -> 0.032 on ``caustics_glass``,
#: 0.021 -> 0.011 on ``cornell``
#: (``docs/results/bias.md``, "Fireflies and low spp"). NlmSettings keeps 0, the per-pixel
#: estimate the learned ``kalantari-nlm`` was trained with.
VARIANCE_PRIOR = 3.0
#: ``patch_trim`` of the ``nlm`` method (``-p patch_trim=2`` caps the largest context term of a
#: patch at 2 noise units per channel, :func:`~mcdenoise.filters.nlm.non_local_means`): off.
#: Measured with 2: demo ``caustics_glass`` relMSE at 16/32/64 spp 0.0268/0.0250/0.0163 ->
#: 0.0159/0.0155/0.0142, ``textured_floors`` at 2/4 spp 0.0258/0.0131 -> 0.0272/0.0139, and
#: the sample ``cornell_spp4`` at equal relMSE (0.00294 -> 0.00292) darker, mean bias
#: -1.51 % -> -2.42 %, outside issue 20's 2 % (``tests/methods/test_bias.py``).
PATCH_TRIM = float("inf")


def denoise_nlm(buffers: FeatureBuffers, **overrides: object) -> Tensor:
    """Denoise with variance-normalised NLM; returns the ``(3, H, W)`` float32 colour.

    Keyword overrides replace fields of :class:`NlmSettings` (as a library function its
    ``var_cap`` is NlmSettings' 1 and its ``variance_prior`` 0, the fixed filter a learned model
    starts from; the registered ``nlm`` method passes :data:`VAR_CAP` and
    :data:`VARIANCE_PRIOR`). Fireflies are clamped first (``fireflies``,
    :mod:`mcdenoise.prep.fireflies`). Without a variance buffer the
    variance is estimated from the colour (:func:`~mcdenoise.prep.inputs.estimate_variance`);
    guide features, when present, add Rousselle 2013 feature weights (``features=()`` turns
    them off).

    Example:
        >>> fb = FeatureBuffers({"color": torch.full((3, 8, 8), 0.5)})
        >>> denoise_nlm(fb, search_radius=2).shape
        torch.Size([3, 8, 8])
    """
    s = with_overrides(NlmSettings(), overrides)
    inp = prepare_inputs(
        buffers,
        features=s.features,
        prefilter=s.prefilter,
        fireflies=s.fireflies,
        variance_prior=s.variance_prior,
    )
    irr, var, factor = demodulate_inputs(inp, enabled=s.demodulate, eps=s.albedo_eps)
    sig, fvars, floors = guide_args(inp, s)
    with torch.no_grad():
        out = non_local_means(
            irr,
            search_radius=s.search_radius,
            patch_radius=s.patch_radius,
            k=s.k,
            alpha=s.alpha,
            color_var=var,
            var_pair=s.var_pair,  # type: ignore[arg-type]
            var_cap=s.var_cap,
            features=inp.features or None,
            feature_k=sig,
            feature_vars=fvars,
            feature_floor=floors,
            feature_gradient=s.feature_gradient,
            combine=s.combine,  # type: ignore[arg-type]
            patch_trim=s.patch_trim,
        )
    return remodulate(out, factor)


def _run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
    with single_threaded_ops():  # parallel over tiles instead (filters/parallel.py)
        return denoise_nlm(b, **params)


METHOD = Method(
    name="nlm",
    summary="non-local means, variance-normalised patches + feature weights (Rousselle 2012/13)",
    requires=("color",),
    uses=("color_var", *GUIDE_FEATURES, *GUIDE_VARS),
    defaults={
        **dataclass_defaults(NlmSettings),
        "var_cap": VAR_CAP,
        "variance_prior": VARIANCE_PRIOR,
        "patch_trim": PATCH_TRIM,
    },
    run=_run,
    priority=20,
    recorded_speed={"nlm": (0.049, 9.24)},
)

__all__ = ["METHOD", "PATCH_TRIM", "VARIANCE_PRIOR", "VAR_CAP", "denoise_nlm"]
