"""The screen-space AO estimators as registry methods: ``ssao``, ``hbao``, ``alchemy``, ``gtao``.

They are not denoisers: they ignore the noisy colour and compute ambient occlusion from the
G-buffer of an AO render (``effects = ["ao"]``: depth, normal and the camera in the header,
:mod:`mcdenoise.io.camera`), so ``mcdenoise denoise ao.exr --method gtao`` gives the
screen-space answer to the same question the ray-traced ``mcd_ao`` render answers, and the
experiments can put both on one SSIM-against-time plot (the thesis's comparison). The output
is the AO as grey linear RGB in [0, 1], 1 where the ray escaped (the ``mcd_ao`` default
background).

Parameters shared by the four (``-p key=value``):

``radius``
    AO radius in scene units; default: the ray-traced render's (``ao_radius`` of the
    ``mcdenoise:camera`` header). An input without one must give it.
``fov``
    horizontal field of view in degrees, for inputs without a recorded camera (other
    renderers); overrides the recorded one when given. Without a camera-to-world matrix the
    world-space normals cannot be rotated into view space, so the normals are rebuilt from
    depth (:func:`mcdenoise.ao.geometry.normals_from_positions`).
``fov_axis``
    ``x`` (horizontal, mcdenoise's renders) or ``y`` (vertical) for ``fov``; default: the
    recorded one, else ``x``.
``falloff``
    fraction of the radius over which occluders fade out; 0 (default) is the reference's step.
``blur``
    the method's depth-aware blur (default on).

plus each method's own sample counts (see :mod:`mcdenoise.ao`). Priority -10: never chosen as
a default denoiser.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor

from mcdenoise.ao import alchemy, gtao, hbao, ssao
from mcdenoise.ao.geometry import ViewGBuffer, view_gbuffer
from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.io.camera import CameraInfo, camera_from_attributes
from mcdenoise.method import Method

#: Priority of the AO estimators: below every denoiser (they never denoise colour).
PRIORITY = -10

_COMMON: dict[str, Any] = {
    "radius": None,
    "fov": None,
    "fov_axis": "",
    "falloff": 0.0,
    "blur": True,
}


def camera_for(buffers: FeatureBuffers, params: Mapping[str, Any]) -> CameraInfo:
    """The camera of ``buffers`` (header) with ``fov``/``radius`` overrides from ``params``.

    Raises:
        InputError: no field of view or no AO radius, from the file or the parameters; or
            the file is a render of light, not of AO (its ``mcdenoise:effects``).
    """
    where = str(buffers.source or "input")
    effects = buffers.attributes.get("mcdenoise:effects")
    if effects is not None and "ao" not in str(effects).split(","):
        raise InputError(
            f"{where}: a render of {effects} light, not of ambient occlusion "
            "(mcdenoise:effects); the AO estimators are judged against ray-traced AO renders"
        )
    cam = camera_from_attributes(buffers.attributes, where)
    fov, radius = params.get("fov"), params.get("radius")
    axis = params.get("fov_axis") or None
    if cam is None:
        if fov is None:
            raise InputError(
                f"{where}: no camera recorded (mcdenoise:camera); give the field of view "
                "with -p fov=<degrees, horizontal> (and -p radius=<AO radius>)"
            )
        cam = CameraInfo(fov=float(fov), fov_axis=axis or "x")
    cam = cam.with_overrides(fov=fov, fov_axis=axis, ao_radius=radius)
    if cam.ao_radius is None:
        raise InputError(f"{where}: no AO radius recorded; give it with -p radius=<scene units>")
    return cam


def _check(buffers: FeatureBuffers, params: Mapping[str, Any]) -> str | None:
    try:
        camera_for(buffers, params)
    except InputError as err:
        return str(err)
    return None


def screen_space_ao(
    buffers: FeatureBuffers,
    estimator: Callable[..., Tensor],
    params: Mapping[str, Any],
) -> Tensor:
    """AO ``(3, H, W)`` (grey) of ``buffers`` by ``estimator`` (one of :mod:`mcdenoise.ao`);
    ``params`` holds the shared parameters (module docstring) and the estimator's own."""
    g, radius = gbuffer_for(buffers, params, needed_by="screen-space AO")
    own = {k: v for k, v in params.items() if k not in _COMMON}
    ao = estimator(g, radius, falloff=float(params["falloff"]), blur=bool(params["blur"]), **own)
    h, w = buffers["depth"].shape[-2:]
    return ao.unsqueeze(0).expand(3, h, w).contiguous()


def gbuffer_for(
    buffers: FeatureBuffers, params: Mapping[str, Any], *, needed_by: str
) -> tuple[ViewGBuffer, float]:
    """The view-space G-buffer of ``buffers`` and the AO radius (camera from the header, with
    the ``fov``/``radius`` overrides of ``params``); the normals are rebuilt from depth when
    the file has none or no camera-to-world matrix to bring them into view space."""
    cam = camera_for(buffers, params)
    buffers.require(("depth",), needed_by=needed_by)
    depth = buffers["depth"]
    h, w = depth.shape[-2:]
    normal = buffers.get("normal")
    rot = None
    if normal is not None and cam.to_world is not None:
        rot = torch.as_tensor(cam.world_to_view(), dtype=torch.float32)
    else:
        normal = None
    g = view_gbuffer(depth, cam.focal_pixels(w, h), normal=normal, world_to_view=rot)
    assert cam.ao_radius is not None  # camera_for
    return g, float(cam.ao_radius)


#: One-thread CPU speeds (:attr:`~mcdenoise.method.Method.recorded_speed`) from
#: ``benchmarks/bench_ao.py --speed`` (docs/results/threads.md).
AO_SPEED = {
    "ssao": (0.011, 2.01),
    "hbao": (0.012, 2.37),
    "alchemy": (0.005, 1.14),
    "gtao": (0.012, 3.31),
}


def _method(
    name: str, estimator: Callable[..., Tensor], summary: str, own: dict[str, Any]
) -> Method:
    def run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> Tensor:
        return screen_space_ao(b, estimator, params)

    return Method(
        name=name,
        summary=f"AO estimator (screen space, ignores colour): {summary}",
        requires=("depth",),
        uses=("normal",),
        defaults={**_COMMON, **own},
        run=run,
        priority=PRIORITY,
        check_input=_check,
        recorded_speed={name: AO_SPEED[name]},
    )


SSAO = _method(
    "ssao",
    ssao,
    "Crytek-style SSAO, normal-oriented hemisphere + range check (Mittring 2007)",
    {"samples": 16, "bias": 0.01, "seed": 0},
)
HBAO = _method(
    "hbao",
    hbao,
    "horizon-based AO (Bavoil & Sainz 2008)",
    {"directions": 8, "steps": 4, "bias": 0.05},
)
ALCHEMY = _method(
    "alchemy",
    alchemy,
    "Alchemy AO with scalable-AO spiral sampling (McGuire et al. 2011/2012)",
    {"samples": 12, "intensity": 1.0, "bias": 0.01},
)
GTAO = _method(
    "gtao",
    gtao,
    "ground-truth-based AO, cosine-weighted horizons (Jimenez 2016; XeGTAO)",
    {"slices": 4, "steps": 4},
)
#: The four, in the order ``mcdenoise methods`` lists them.
METHODS = (SSAO, HBAO, ALCHEMY, GTAO)

__all__ = [
    "ALCHEMY",
    "GTAO",
    "HBAO",
    "METHODS",
    "PRIORITY",
    "SSAO",
    "camera_for",
    "gbuffer_for",
    "screen_space_ao",
]
