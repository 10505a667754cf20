"""Validation and parameter helpers shared by the filters (private).

Every check raises :class:`mcdenoise.errors.InputError` with a one-line message that names the
offending argument, so the CLI can print it as it is.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from mcdenoise.errors import InputError

#: A filter bandwidth: one value for the whole batch, or a tensor (a 0-d tensor, ``(B, 1, 1, 1)``
#: per image, or ``(B, 1, H, W)`` per pixel) that a network may predict.
Param = float | Tensor

#: Guide features: a sequence of ``(B, C_k, H, W)`` tensors, or a mapping name -> tensor (the
#: names then appear in error messages).
Features = Sequence[Tensor] | Mapping[str, Tensor]


#: The largest window edge a filter takes (radius 64). A window's cost grows with its area,
#: so a parameter from someone else's file (an output header re-run by ``eval``) or a typo
#: of ``1e26`` would otherwise run for hours or exhaust memory; the shipped methods use 3-21.
MAX_WINDOW = 129


def check_kernel_size(value: object, name: str = "kernel_size") -> int:
    """An odd positive integer window size, at most :data:`MAX_WINDOW`."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"{name} must be an odd positive integer, got {value!r}")
    if value < 1 or value % 2 == 0:
        raise InputError(f"{name} must be an odd positive integer, got {value}")
    if value > MAX_WINDOW:
        raise InputError(f"{name} must be at most {MAX_WINDOW}, got {value}")
    return value


def check_radius(value: object, name: str) -> int:
    """A non-negative integer radius (window ``2 r + 1``), at most ``MAX_WINDOW // 2``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(f"{name} must be a non-negative integer, got {value!r}")
    if value > MAX_WINDOW // 2:
        raise InputError(f"{name} must be at most {MAX_WINDOW // 2}, got {value}")
    return value


def check_image(
    t: object, name: str, *, channels: int | None = None, finite: bool = True
) -> Tensor:
    """A floating ``(B, C, H, W)`` tensor with no NaN/Inf (those must be sanitised first)."""
    if not isinstance(t, Tensor):
        raise InputError(
            f"{name} must be a torch.Tensor of shape (B, C, H, W), got {type(t).__name__}"
        )
    if t.ndim != 4:
        raise InputError(f"{name} must have shape (B, C, H, W), got {tuple(t.shape)}")
    if not t.is_floating_point():
        raise InputError(f"{name} must be a floating-point tensor, got {t.dtype}")
    if channels is not None and t.shape[1] != channels:
        raise InputError(f"{name} must have {channels} channel(s), got shape {tuple(t.shape)}")
    if min(t.shape) == 0:
        raise InputError(f"{name} is empty: shape {tuple(t.shape)}")
    if finite and not _all_finite(t):
        bad = int((~torch.isfinite(t)).sum())
        raise InputError(
            f"{name} holds {bad} NaN/Inf value(s): sanitise the buffers first (io.buffers.sanitize)"
        )
    return t


def _all_finite(t: Tensor) -> bool:
    """True when ``t`` has no NaN/Inf; one reduction pass (a non-finite sum is re-checked
    element-wise, since large finite values can overflow the sum)."""
    if bool(torch.isfinite(t.sum())):
        return True
    return bool(torch.isfinite(t).all())


def check_same_size(ref: Tensor, t: Tensor, name: str, ref_name: str = "color") -> None:
    """``t`` must match ``ref`` in batch, height and width (never broadcast a wrong size)."""
    if t.shape[0] != ref.shape[0] or t.shape[2:] != ref.shape[2:]:
        raise InputError(
            f"{name} has shape {tuple(t.shape)} but {ref_name} has shape {tuple(ref.shape)}: "
            "batch, height and width must match"
        )
    if t.device != ref.device:
        raise InputError(f"{name} is on {t.device} but {ref_name} is on {ref.device}")


def check_variance(var: object, ref: Tensor, name: str) -> Tensor | None:
    """Optional variance of the mean, ``(B, 1 or C, H, W)``, non-negative, cast to ``ref``'s dtype."""
    if var is None:
        return None
    v = check_image(var, name)
    check_same_size(ref, v, name)
    if v.shape[1] not in (1, ref.shape[1]):
        raise InputError(
            f"{name} must have 1 or {ref.shape[1]} channel(s), got shape {tuple(v.shape)}"
        )
    if bool((v < 0).any()):
        raise InputError(f"{name} holds negative values: a variance must be >= 0")
    return v.to(ref.dtype)


def check_var_cap(value: object, name: str = "var_cap") -> float:
    """κ >= 1 of the capped variance pair ``min(κ v_i, v_j)`` (``inf`` allowed: the sum)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 1:
        raise InputError(f"{name} must be a number >= 1, got {value!r}")
    return float(value)


def check_param(value: object, name: str, ref: Tensor, *, allow_zero: bool = False) -> Param:
    """A bandwidth given as a float (must be > 0) or a tensor (0-d, ``(B,1,1,1)`` or ``(B,1,H,W)``).

    Floats are validated strictly (``<= 0``, NaN or Inf is an :class:`InputError`); tensors are
    predicted values and are only shape-checked: values at or below the dtype's floor are
    clamped when used (see :func:`inv_two_sq`), which gives the identity limit, never NaN.
    """
    if isinstance(value, bool):
        raise InputError(f"{name} must be a number or a tensor, got {value!r}")
    if isinstance(value, int | float):
        v = float(value)
        if not v == v or v in (float("inf"), float("-inf")):
            raise InputError(f"{name} must be finite, got {value!r}")
        if v < 0 or (v == 0 and not allow_zero):
            raise InputError(f"{name} must be > 0, got {value!r}")
        return v
    if not isinstance(value, Tensor):
        raise InputError(f"{name} must be a float or a tensor, got {type(value).__name__}")
    if not value.is_floating_point():
        raise InputError(f"{name} must be a floating-point tensor, got {value.dtype}")
    b, _, h, w = ref.shape
    if value.ndim == 0:
        return value.to(ref.dtype)
    ok = value.ndim == 4 and value.shape[0] == b and value.shape[1] == 1
    ok = ok and (tuple(value.shape[2:]) == (h, w) or tuple(value.shape[2:]) == (1, 1))
    if not ok:
        raise InputError(
            f"{name} must be a float or a tensor of shape (), ({b}, 1, 1, 1) or ({b}, 1, {h}, {w}); "
            f"got {tuple(value.shape)}"
        )
    if value.device != ref.device:
        raise InputError(f"{name} is on {value.device} but the image is on {ref.device}")
    return value.to(ref.dtype)


def bandwidth_floor(dtype: torch.dtype) -> float:
    """Smallest bandwidth used: ``tiny ** 0.25`` keeps ``1/σ²`` and its derivative ``1/σ³`` finite."""
    return float(torch.finfo(dtype).tiny) ** 0.25


def inv_two_sq(sigma: Param, dtype: torch.dtype) -> Param:
    """``1 / (2 σ²)`` with σ clamped at :func:`bandwidth_floor` (σ → 0 stays finite, no 0·∞)."""
    floor = bandwidth_floor(dtype)
    if isinstance(sigma, Tensor):
        return 0.5 * sigma.clamp_min(floor).pow(-2)
    s = max(float(sigma), floor)
    return 0.5 / (s * s)


def param_max(p: Param) -> float:
    """Largest value of a parameter (a plain float, detached from autograd)."""
    return float(p.detach().max()) if isinstance(p, Tensor) else float(p)


def named_features(features: Features | None, name: str = "features") -> list[tuple[str, Tensor]]:
    """``[(name, tensor), ...]`` from a sequence or a mapping of guide features."""
    if features is None:
        return []
    if isinstance(features, Tensor):
        raise InputError(
            f"{name} must be a sequence or mapping of (B, C, H, W) tensors, not a tensor"
        )
    if isinstance(features, Mapping):
        return [(str(k), v) for k, v in features.items()]
    return [(f"{name}[{i}]", v) for i, v in enumerate(features)]


def per_feature(value: object, names: list[str], what: str) -> list[object]:
    """Broadcast one parameter to every feature, or check one entry per feature."""
    if isinstance(value, Mapping):
        missing = [n for n in names if n not in value]
        extra = [k for k in value if k not in names]
        if missing or extra:
            raise InputError(
                f"{what} must give a value for each feature {names}; "
                f"missing {missing or 'none'}, unknown {extra or 'none'}"
            )
        return [value[n] for n in names]
    if isinstance(value, Sequence) and not isinstance(value, str):
        if len(value) != len(names):
            raise InputError(f"{what} has {len(value)} entries for {len(names)} feature(s)")
        return list(value)
    return [value] * len(names)


def gradient_sq(f: Tensor) -> Tensor:
    """Squared gradient magnitude ``(B, 1, H, W)`` (central differences, mean over channels).

    One-sided at the border; 0 along an axis of length 1.
    """
    gy = torch.zeros_like(f)
    gx = torch.zeros_like(f)
    if f.shape[2] > 1:
        d = f[:, :, 1:] - f[:, :, :-1]
        gy = torch.cat([d[:, :, :1], 0.5 * (d[:, :, 1:] + d[:, :, :-1]), d[:, :, -1:]], dim=2)
    if f.shape[3] > 1:
        d = f[:, :, :, 1:] - f[:, :, :, :-1]
        gx = torch.cat([d[..., :1], 0.5 * (d[..., 1:] + d[..., :-1]), d[..., -1:]], dim=3)
    return (gy.square() + gx.square()).mean(dim=1, keepdim=True)


def feature_normalizer(
    f: Tensor, var: Tensor | None, floor: float, *, use_gradient: bool
) -> Tensor | float:
    """Per-pixel denominator of a feature distance: ``max(floor, var_i, |∇f_i|²)``.

    ``var`` is averaged over channels. Without variance and gradient there is nothing to
    normalise by and the result is ``1.0`` (the raw squared distance is used).
    """
    terms: list[Tensor] = []
    if var is not None:
        terms.append(var.mean(dim=1, keepdim=True))
    if use_gradient:
        terms.append(gradient_sq(f))
    if not terms:
        return 1.0
    out = terms[0]
    for t in terms[1:]:
        out = torch.maximum(out, t)
    return out.clamp_min(floor)
