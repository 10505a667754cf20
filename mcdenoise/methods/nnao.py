"""``nnao``: Holden et al.'s neural-network AO as a registry method (an AO estimator).

Like the screen-space methods of :mod:`mcdenoise.methods.ao` it ignores the noisy colour,
reads depth, normal and the camera of an AO render (``mcdenoise denoise ao.exr --method
nnao``) and outputs the AO as grey RGB in ``[0, 1]``, 1 on empty pixels. The network
(:mod:`mcdenoise.models.nnao`) sees, per pixel, a golden-angle spiral of sample points in the
disk of the projected AO radius (its radial layout is recorded in the model card);
:func:`nnao_inputs` builds those inputs from the view-space G-buffer
(:func:`mcdenoise.ao.geometry.view_gbuffer`) for the method and for the trainer
(:mod:`mcdenoise.train.nnao`), so both see exactly the same thing.

Parameters: ``model`` (a model file or run folder; default the shipped
``mcdenoise/models/weights/nnao.pt``, trained by ``data/recipes/nnao.md``), and ``radius``,
``fov``, ``fov_axis`` as for the screen-space methods (the AO radius defaults to the
render's), and ``blur`` (default on): a depth-aware separable Gaussian of radius 2
(:func:`mcdenoise.ao.blur.gaussian_line_offsets`, HBAO+'s x and y passes). The pattern is the
same at every pixel, so there is no sampling noise, but the network's error changes from
pixel to pixel (samples snap to pixel centres differently at each pixel), and the blur
evens it out: it raised SSIM on the validation images (figures: ``docs/results/ao.md``,
"nnao").
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.ao.blur import blur_passes, gaussian_line_offsets
from mcdenoise.ao.geometry import ViewGBuffer
from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method
from mcdenoise.methods.ao import PRIORITY, camera_for
from mcdenoise.methods.ao import gbuffer_for as ao_gbuffer_for
from mcdenoise.modelfile import model_file
from mcdenoise.models.nnao import LEGACY_RADIAL_POWER, OFFSET_CLAMP, NnaoModel, sample_pattern
from mcdenoise.models.weights import SHIPPED, shipped_model_path


def nnao_inputs(
    g: ViewGBuffer, radius: float, samples: int, radial_power: float = LEGACY_RADIAL_POWER
) -> Tensor:
    """The network inputs ``(C, H, W)`` of every pixel of ``g`` (layout:
    :mod:`mcdenoise.models.nnao`; the spiral of :func:`sample_pattern`), 0 on empty pixels."""
    if not radius > 0:
        raise ValueError(f"AO radius must be > 0, got {radius}")
    u, v = g.pixel_grid()
    p = g.position
    z = p[2]
    rpix = torch.where(g.valid, g.focal * radius / z.clamp_min(1e-6), torch.zeros_like(z))
    pattern = sample_pattern(samples, radial_power).to(p.device)
    feats = []
    for k in range(samples):
        q, n, ok = g.fetch_with_normal(u + pattern[k, 0] * rpix, v + pattern[k, 1] * rpix)
        okf = (ok & g.valid).float()
        d = ((q - p) / radius).clamp(-OFFSET_CLAMP, OFFSET_CLAMP) * okf
        feats += [d, n * okf, okf.unsqueeze(0)]
    feats.append(g.normal)
    return torch.cat(feats, 0) * g.valid.float()


def gbuffer_for(buffers: FeatureBuffers, params: Mapping[str, Any]) -> tuple[ViewGBuffer, float]:
    """The view-space G-buffer of ``buffers`` and the AO radius, as the screen-space methods
    build them (:func:`mcdenoise.methods.ao.gbuffer_for`)."""
    return ao_gbuffer_for(buffers, params, needed_by="nnao")


@functools.lru_cache(maxsize=4)
def _load(path: str, mtime_ns: int) -> NnaoModel:
    return NnaoModel.load(path)


def load_nnao(model: str) -> NnaoModel:
    """The model of the ``model`` parameter (``shipped``, a file or a run folder), cached.

    Raises:
        InputError: no shipped weights. CheckpointError: no such file.
    """
    if model in ("", SHIPPED):
        path = shipped_model_path("nnao")
        if not path.is_file():
            raise InputError("nnao: no shipped weights in this install; pass -p model=RUN_FOLDER")
    else:
        path = model_file(model)
    return _load(str(path.resolve()), path.stat().st_mtime_ns)


def nnao(model: NnaoModel, g: ViewGBuffer, radius: float, blur: bool = True) -> Tensor:
    """AO ``(H, W)`` of ``g`` by ``model`` (then the depth-aware blur); 1 on empty pixels."""
    x = nnao_inputs(g, radius, model.card.samples, model.card.radial_power)
    dev = next(model.parameters()).device
    with torch.no_grad():
        ao = model(x.to(dev).permute(1, 2, 0)).to(x.device)
    if blur:
        passes = [gaussian_line_offsets(2, True), gaussian_line_offsets(2, False)]
        ao = blur_passes(ao, g, passes, radius)
    return torch.where(g.valid, ao, torch.ones_like(ao))


def _run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
    model = load_nnao(str(params["model"]))
    g, radius = gbuffer_for(b, params)
    ao = nnao(model, g, radius, blur=bool(params["blur"]))
    h, w = ao.shape
    return ao.unsqueeze(0).expand(3, h, w).contiguous()


def _check(b: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
    name = str(params["model"])
    if name in ("", SHIPPED) and not shipped_model_path("nnao").is_file():
        return "no shipped weights in this install (pass -p model=RUN_FOLDER)"
    try:
        camera_for(b, params)
    except InputError as err:
        return str(err)
    return None


METHOD = Method(
    name="nnao",
    summary="AO estimator (learned, ignores colour): per-pixel MLP over a G-buffer "
    "neighbourhood (Holden et al. 2016); -p model=RUN",
    requires=("depth",),
    uses=("normal",),
    defaults={"model": SHIPPED, "radius": None, "fov": None, "fov_axis": "", "blur": True},
    run=_run,
    priority=PRIORITY,
    check_input=_check,
    recorded_speed={"nnao": (0.003, 3.16)},  # CPU time, with its blur (docs/results/threads.md)
)

__all__ = ["METHOD", "gbuffer_for", "load_nnao", "nnao", "nnao_inputs"]
