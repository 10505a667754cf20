"""The ``cross-bilateral`` method: buffers -> prepared inputs -> cross-bilateral filter.

:func:`denoise_xbf` runs the whole pipeline: prepare (:func:`~mcdenoise.prep.inputs.prepare_inputs`),
demodulate by the (prefiltered) albedo when there is one -- filter the irradiance
``c / (albedo + ε)`` and multiply back, so texture detail never has to survive the filter --
filter, remodulate, clamp at 0. Its parameters are :class:`~mcdenoise.filters.settings.XbfSettings`.
It works with colour only (weaker: nothing tells texture from noise), and with any subset of
the guide features.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.errors import InputError
from mcdenoise.filters.albedo import remodulate
from mcdenoise.filters.cross_bilateral import cross_bilateral
from mcdenoise.filters.parallel import single_threaded_ops
from mcdenoise.filters.settings import (
    GUIDE_FEATURES,
    GUIDE_VARS,
    XBF_VARIANCE_PRIOR,
    XbfSettings,
    with_overrides,
)
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method, dataclass_defaults
from mcdenoise.prep.inputs import demodulate_inputs, guide_args, prepare_inputs


def denoise_xbf(buffers: FeatureBuffers, **overrides: object) -> Tensor:
    """Denoise with the cross-bilateral filter; returns the ``(3, H, W)`` float32 colour.

    Keyword overrides replace fields of :class:`XbfSettings` (an unknown name is an
    :class:`~mcdenoise.errors.InputError`; as a library function its ``variance_prior`` is
    XbfSettings' 0, the registered method passes
    :data:`~mcdenoise.filters.settings.XBF_VARIANCE_PRIOR`). Fireflies are clamped
    first (``fireflies``, :mod:`mcdenoise.prep.fireflies`). Works with colour only (the
    variance is then estimated) and with any subset of the guide features.

    Example:
        >>> fb = FeatureBuffers({"color": torch.full((3, 8, 8), 0.5)})
        >>> denoise_xbf(fb, kernel_size=5).shape
        torch.Size([3, 8, 8])
    """
    s = with_overrides(XbfSettings(), overrides)
    if s.passes < 1:
        raise InputError(f"passes must be >= 1, got {s.passes}")
    inp = prepare_inputs(
        buffers,
        features=s.features,
        prefilter=s.prefilter,
        fireflies=s.fireflies,
        variance_prior=s.variance_prior,
    )
    irr, var, factor = demodulate_inputs(inp, enabled=s.demodulate, eps=s.albedo_eps)
    sig, fvars, floors = guide_args(inp, s)
    common = {
        "kernel_size": s.kernel_size,
        "sigma_spatial": s.sigma_spatial,
        "sigma_features": sig,
        "color_var": var,
        "var_pair": s.var_pair,
        "var_cap": s.var_cap,
        "feature_vars": fvars,
        "feature_floor": floors,
        "feature_gradient": s.feature_gradient,
    }
    with torch.no_grad():
        out = cross_bilateral(irr, inp.features, sigma_color=s.sigma_color, **common)  # type: ignore[arg-type]
        for _ in range(s.passes - 1):
            out = cross_bilateral(
                irr,
                inp.features,
                sigma_color=s.sigma_color_refine,
                guide=out,
                **common,  # type: ignore[arg-type]
            )
    return remodulate(out, factor)


def _run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
    with single_threaded_ops():  # parallel over tiles instead (filters/parallel.py)
        return denoise_xbf(b, **params)


METHOD = Method(
    name="cross-bilateral",
    summary="cross-bilateral filter with colour and feature terms (Kalantari 2015 form)",
    requires=("color",),
    uses=("color_var", *GUIDE_FEATURES, *GUIDE_VARS),
    defaults={**dataclass_defaults(XbfSettings), "variance_prior": XBF_VARIANCE_PRIOR},
    run=_run,
    priority=10,
    recorded_speed={"cross-bilateral": (0.0275, 7.55)},
)
#: Other names ``--method`` accepts for it.
ALIASES = ("xbf", "cross_bilateral")

__all__ = ["ALIASES", "METHOD", "denoise_xbf"]
