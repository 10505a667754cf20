"""The ``oidn`` method: Intel Open Image Denoise through ``pyoidn`` (extra ``mcdenoise[oidn]``).

OIDN is the industry's reference denoiser, so every experiment can be compared with it; it is
a peer, never the default (priority 0). We call
its ``RT`` filter in HDR mode with the auxiliary buffers OIDN documents: albedo in [0, 1] and
world- or view-space normals in [-1, 1] (both optional; ``clean_aux`` says they are noise-free,
so OIDN runs its filter trained on clean guides; without it, the one trained on noisy guides:
OIDN runs no separate prefilter pass, measured at the same time as colour alone,
``docs/results/aux-prefilter.md``). OIDN needs the colour to be non-negative and finite, so the caller passes
sanitised buffers.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import Method


def unavailable_reason() -> str | None:
    """``None`` when pyoidn can be imported, else a one-line reason with the install hint."""
    if importlib.util.find_spec("pyoidn") is None:
        return "pyoidn is not installed (pip install 'mcdenoise[oidn]')"
    return None


def _hwc(t: torch.Tensor) -> np.ndarray:
    # (3, H, W) -> contiguous (H, W, 3) float32
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())


def oidn_denoise(
    color: torch.Tensor,
    albedo: torch.Tensor | None = None,
    normal: torch.Tensor | None = None,
    *,
    quality: str = "high",
    clean_aux: bool = False,
) -> torch.Tensor:
    """Denoise ``color`` with OIDN's RT filter (HDR).

    Args:
        color: ``(3, H, W)`` linear HDR RGB, finite and >= 0.
        albedo: optional ``(3, H, W)`` reflectance; clamped to [0, 1] for OIDN.
        normal: optional ``(3, H, W)`` shading normal in [-1, 1]; only used together with
            albedo (OIDN's rule: normal requires albedo).
        quality: ``"high"``, ``"balanced"`` or ``"fast"``.
        clean_aux: the auxiliary buffers are noise-free (OIDN's filter for clean guides).

    Returns:
        ``(3, H, W)`` float32 tensor on ``color``'s device.
    """
    reason = unavailable_reason()
    if reason:
        raise InputError(reason)
    import pyoidn  # lazy: pyoidn is optional

    if quality not in ("high", "balanced", "fast", "default"):
        raise InputError(f"oidn quality must be high, balanced or fast, got {quality!r}")
    c = _hwc(color.clamp_min(0))
    a = _hwc(albedo.clamp(0, 1)) if albedo is not None else None
    n = _hwc(normal.clamp(-1, 1)) if (normal is not None and albedo is not None) else None
    out = pyoidn.denoise(c, a, n, hdr=True, clean_aux=clean_aux, quality=quality)
    return torch.from_numpy(np.asarray(out, dtype=np.float32)).permute(2, 0, 1).to(color.device)


def _run(b: FeatureBuffers, params: Mapping[str, Any], device: torch.device) -> torch.Tensor:
    return oidn_denoise(
        b["color"],
        b.get("albedo"),
        b.get("normal"),
        quality=str(params["quality"]),
        clean_aux=bool(params["clean_aux"]),
    )


METHOD = Method(
    name="oidn",
    summary="Intel Open Image Denoise (pyoidn), HDR, with albedo and normal when present",
    requires=("color",),
    uses=("albedo", "normal"),
    defaults={"quality": "high", "clean_aux": False},
    run=_run,
    priority=0,
    unavailable=unavailable_reason,
    devices=("cpu",),
    recorded_speed={"oidn": (0.121, 0.223)},
)

__all__ = ["METHOD", "oidn_denoise", "unavailable_reason"]
