"""The built-in denoising methods, registered in :mod:`mcdenoise.registry` on import.

=================  ==========================================================  ========
name               what                                                        priority
=================  ==========================================================  ========
kalantari-xbf      two-pass cross-bilateral filter whose per-pixel bandwidths      30
                   a small MLP predicts from local features (Kalantari 2015);
                   ``model`` = a run folder or model file, default the shipped
                   weights
kalantari-nlm      the same learning for NLM (per-pixel k and feature k_f)         25
kpcn               kernel-predicting U-Net (Bako 2017) with source-aware           22
                   encoders and 3-scale kernels (Vogels 2018); ``model`` = a run
                   folder or model file, default the shipped weights
nlm                variance-normalised non-local means with feature weights    20
                   (Rousselle 2012/2013), albedo-demodulated
cross-bilateral    cross-bilateral filter with Kalantari 2015 terms, fixed     10
                   default bandwidths (alias ``xbf``)
oidn               Intel Open Image Denoise (pyoidn), colour + albedo +        0
                   normal; a peer to compare with, never the default
=================  ==========================================================  ========

The default method (no ``--method``) is the available one with the highest priority whose
required buffers the input has. The learned filters rank above the fixed ones because
``benchmarks/bench_kalantari.py`` measured them better at 4, 16 and 64 spp on held-out
renders; kalantari-xbf ranks first (geometric-mean relMSE 14 % below kalantari-nlm at 4 spp,
equal at 16, 2 % above at 64, and faster). kalantari-xbf serves inputs without albedo with
its shipped no-albedo variant; inputs without normal, depth or position go to kpcn when they
have albedo and normal, else to nlm. OIDN is
deliberately never the default: mcdenoise's own methods are what it reports on, OIDN is the
baseline they are compared with. ``kpcn`` ranks between ``kalantari-nlm`` and ``nlm``:
``benchmarks/bench_kpcn.py`` measured the shipped model (k = 5, 16000 CPU steps) at 1.15,
1.11 and 1.20x kalantari-xbf's relMSE on held-out renders at 4, 16 and 64 spp, so the learned
filters stay first where depth and position exist; on colour + albedo + normal files (no
variance, depth, position: Mitsuba AOV files, Cycles) it beats nlm at every level (relMSE
ratio 0.60, 0.69, 0.85), so it is the default there.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch

from mcdenoise.baselines.oidn import oidn_denoise, unavailable_reason
from mcdenoise.errors import InputError
from mcdenoise.filters.prepare import NlmSettings, XbfSettings, denoise_nlm, denoise_xbf
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.models.weights import (
    NO_ALBEDO,
    SHIPPED,
    load_kalantari,
    load_kpcn,
    shipped_model_for,
    shipped_model_path,
)
from mcdenoise.registry import Method, dataclass_defaults, register

GUIDES = ("albedo", "normal", "depth", "position")
GUIDE_VARS = tuple(g + "_var" for g in GUIDES)


def _run_nlm(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
    return denoise_nlm(b, **params)


def _run_xbf(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
    return denoise_xbf(b, **params)


def _run_oidn(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
    return oidn_denoise(
        b["color"],
        b.get("albedo"),
        b.get("normal"),
        quality=str(params["quality"]),
        clean_aux=bool(params["clean_aux"]),
    )


register(
    Method(
        name="nlm",
        summary="non-local means, variance-normalised patches + feature weights (Rousselle 2012/13)",
        requires=("color",),
        uses=("color_var", *GUIDES, *GUIDE_VARS),
        defaults=dataclass_defaults(NlmSettings),
        run=_run_nlm,
        priority=20,
    )
)
register(
    Method(
        name="cross-bilateral",
        summary="cross-bilateral filter with colour and feature terms (Kalantari 2015 form)",
        requires=("color",),
        uses=("color_var", *GUIDES, *GUIDE_VARS),
        defaults=dataclass_defaults(XbfSettings),
        run=_run_xbf,
        priority=10,
    ),
    aliases=("xbf", "cross_bilateral"),
)


def _run_kalantari(kind: str):
    def run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
        name = str(params["model"])
        shipped = shipped_model_for(f"kalantari-{kind}", set(b.buffers))
        model = load_kalantari(shipped if name in ("", SHIPPED) else name)
        if model.card.kind != kind:
            raise InputError(
                f"{params['model']}: is a kalantari-{model.card.kind} model, not kalantari-{kind}"
            )
        return model.to(device).denoise(b)

    return run


for _kind, _what in (("xbf", "cross-bilateral bandwidths"), ("nlm", "NLM k and feature k_f")):
    # With a shipped no-albedo variant, inputs without albedo (AO renders) are served too.
    _needs = GUIDES
    if shipped_model_path(f"kalantari-{_kind}", NO_ALBEDO).is_file():
        _needs = tuple(g for g in GUIDES if g != "albedo")
    register(
        Method(
            name=f"kalantari-{_kind}",
            summary=f"{_what} predicted per pixel by an MLP (Kalantari 2015); -p model=RUN",
            requires=("color", *_needs),
            uses=("color_var", *GUIDES, *GUIDE_VARS),
            defaults={"model": SHIPPED},
            run=_run_kalantari(_kind),
            priority=25 if _kind == "nlm" else 30,
        )
    )


def _run_kpcn(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
    name = str(params["model"])
    if name in ("", SHIPPED):
        path = shipped_model_path("kpcn")
        if not path.is_file():
            raise InputError("kpcn: no shipped weights in this install; pass -p model=RUN_FOLDER")
    else:
        path = name
    model = load_kpcn(path).to(device)
    source = str(params["source"])
    return model.denoise(b, source=None if source == "auto" else source, tile=int(params["tile"]))


register(
    Method(
        name="kpcn",
        summary="kernel-predicting CNN, source-aware encoder, 3-scale kernels (Bako 2017, "
        "Vogels 2018); -p model=RUN",
        requires=("color", "albedo", "normal"),
        uses=("color_var", *GUIDES, *GUIDE_VARS),
        defaults={"model": SHIPPED, "source": "auto", "tile": 1024},
        run=_run_kpcn,
        priority=22 if shipped_model_path("kpcn").is_file() else -1,
    )
)

register(
    Method(
        name="oidn",
        summary="Intel Open Image Denoise (pyoidn), HDR, with albedo and normal when present",
        requires=("color",),
        uses=("albedo", "normal"),
        defaults={"quality": "high", "clean_aux": False},
        run=_run_oidn,
        priority=0,
        unavailable=unavailable_reason,
        devices=("cpu",),
    )
)
