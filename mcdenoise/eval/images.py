"""The ``(3, H, W)`` float64 arrays the metrics compute on: numpy arrays or torch tensors
converted, sizes compared with both images named (never broadcast), non-finite pixels counted."""

from __future__ import annotations

from typing import Any

import numpy as np

from mcdenoise.errors import InputError

ArrayLike = Any  # numpy array or torch tensor of layout (3, H, W)


def as_image(x: ArrayLike, name: str = "image") -> np.ndarray:
    """Convert a ``(3, H, W)`` numpy array or torch tensor to a float64 numpy array.

    Raises:
        InputError: if ``x`` is not of layout ``(3, H, W)`` with ``H, W >= 1``.
    """
    if hasattr(x, "detach"):  # torch.Tensor, without importing torch here
        x = x.detach().cpu().double().numpy()
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[0] != 3 or arr.shape[1] < 1 or arr.shape[2] < 1:
        raise InputError(
            f"{name}: expected an RGB image of layout (3, H, W), got shape {arr.shape}"
        )
    return arr


def check_same_shape(
    output: np.ndarray,
    reference: np.ndarray,
    *,
    output_name: str = "output",
    reference_name: str = "reference",
) -> None:
    """Raise :class:`~mcdenoise.errors.InputError` unless both ``(C, H, W)`` shapes are equal.

    The message names both images and their sizes as ``WxH``; nothing is ever broadcast.
    """
    if output.shape != reference.shape:
        raise InputError(
            f"{output_name} is {_size(output)} but reference {reference_name} is "
            f"{_size(reference)}: sizes must match"
        )


def _size(a: np.ndarray) -> str:
    return f"{a.shape[2]}x{a.shape[1]}" + (f" ({a.shape[0]} channels)" if a.shape[0] != 3 else "")


def nonfinite_pixels(image: ArrayLike) -> int:
    """Number of pixels (spatial positions) of a ``(C, H, W)`` image with any NaN/Inf channel."""
    a = as_image(image)
    return int((~np.isfinite(a)).any(axis=0).sum())
