"""Which part of a scene the report shows: crop choice and overview thumbnail.

Reports show every image of a scene (noisy input, outputs, reference) through the *same* crop,
chosen once from the reference: the whole image when it is at most ``size`` pixels on each
side, otherwise the ``size × size`` window with the most visible structure (largest mean
gradient magnitude of the display-tonemapped reference luminance), so the crop shows edges and
texture where denoisers differ rather than a flat wall. Images are ``(3, H, W)`` linear HDR RGB.
"""

from __future__ import annotations

import numpy as np

from mcdenoise.eval.tonemap import luminance, to_srgb

#: Default crop side in pixels.
CROP_SIZE = 256


def choose_crop(
    reference: np.ndarray, exposure: float = 1.0, size: int = CROP_SIZE
) -> tuple[int, int, int, int]:
    """The informative crop ``(y0, x0, h, w)`` of a ``(3, H, W)`` linear HDR reference.

    Args:
        reference: ``(3, H, W)`` linear HDR RGB.
        exposure: display exposure used to judge visible structure.
        size: maximum crop side.

    Returns:
        ``(0, 0, H, W)`` when ``H, W <= size``; otherwise a window of side
        ``min(H, size) × min(W, size)`` maximising the mean gradient magnitude, searched on a
        grid of step ``max(1, size // 16)`` (plus the last position along each axis).

    >>> choose_crop(np.zeros((3, 10, 20)))
    (0, 0, 10, 20)
    """
    _, height, width = reference.shape
    h, w = min(height, size), min(width, size)
    if h == height and w == width:
        return (0, 0, height, width)
    lum = np.nan_to_num(luminance(reference), nan=0.0, posinf=0.0, neginf=0.0)
    shown = to_srgb(np.broadcast_to(lum, (1, *lum.shape)), exposure)[0]
    grad = np.zeros_like(shown)
    grad[:, 1:] += np.abs(np.diff(shown, axis=1))
    grad[1:, :] += np.abs(np.diff(shown, axis=0))
    integral = np.zeros((height + 1, width + 1))
    integral[1:, 1:] = grad.cumsum(0).cumsum(1)
    step = max(1, size // 16)
    ys = sorted({*range(0, height - h + 1, step), height - h})
    xs = sorted({*range(0, width - w + 1, step), width - w})
    yy, xx = np.meshgrid(np.array(ys), np.array(xs), indexing="ij")
    sums = integral[yy + h, xx + w] - integral[yy, xx + w] - integral[yy + h, xx] + integral[yy, xx]
    iy, ix = np.unravel_index(int(np.argmax(sums)), sums.shape)
    return (int(ys[iy]), int(xs[ix]), h, w)


def crop(image: np.ndarray, window: tuple[int, int, int, int]) -> np.ndarray:
    """``image[:, y0:y0+h, x0:x0+w]`` of a ``(C, H, W)`` array, as a float32 copy."""
    y0, x0, h, w = window
    return np.array(image[:, y0 : y0 + h, x0 : x0 + w], dtype=np.float32)


def overview(image: np.ndarray, max_side: int = CROP_SIZE) -> tuple[np.ndarray, int]:
    """Box-downscaled copy of a ``(3, H, W)`` image with its long side at most ``max_side``.

    Returns:
        ``(small, factor)``: the float32 ``(3, H // factor, W // factor)`` thumbnail (linear,
        non-finite pixels averaged as 0) and the integer downscale factor.
    """
    _, height, width = image.shape
    factor = max(1, -(-max(height, width) // max_side))
    hs, ws = max(1, height // factor), max(1, width // factor)
    src = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    src = src[:, : hs * factor, : ws * factor]
    small = src.reshape(3, hs, min(factor, height), ws, min(factor, width)).mean(axis=(2, 4))
    return small.astype(np.float32), factor
