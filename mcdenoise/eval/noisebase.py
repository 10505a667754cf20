"""Noisebase's 8-bit display encoding and the two temporal metrics of one frame pair it defines
(tPSNR, tRMAE), ported literally; :mod:`mcdenoise.eval.temporal_metrics` registers them.

``tpsnr`` and ``trmae`` are Noisebase's (Balint et al. 2023, "Neural Partitioning Pyramids
for Denoising Monte Carlo Renderings"; ``noisebase/scripts/nb_compute_metrics.py``,
github.com/balintio/noisebase at commit 63056ed), ported literally so numbers compare with
that benchmark. Noisebase does not compute them on the HDR frames but on the PNGs its test
loader saved (``noisebase.loaders.torch.test_sample_v1.Sequence.save``): linear RGB through
``noisebase.data.ACES`` (BakingLab's fitted ACES RRT+ODT with its input and output
matrices, then clip to [0, 1] and gamma 1/2.2, no exposure), times 255 and cut to 8 bits by
``astype(np.uint8)`` (truncation, not rounding), and read back as ``uint8 / 255``
(:func:`noisebase_display`). Its ``rmae`` divides the mean over all channels by 3 once more
(its ``/ 3``): kept, so values equal Noisebase's. One departure: for a pair whose output
difference equals the reference's exactly, Noisebase's ``1 / mse`` raises
``ZeroDivisionError``; here tPSNR is ``+inf``, as :func:`mcdenoise.eval.metrics.psnr` is
for identical images. Noisebase computes in float32 torch, this module in float64 on the
same 8-bit values: results agree to float32 rounding (about 1e-6 relative).
"""

from __future__ import annotations

import math

import numpy as np

from mcdenoise.eval.images import ArrayLike, as_image

#: ε of Noisebase's ``rmae``: ``|x − r| / (|r| + 0.01)``.
NOISEBASE_RMAE_EPS = 0.01

#: Colour space of Noisebase's metrics.
NOISEBASE_DISPLAY = (
    "Noisebase 8-bit display: ACES (BakingLab fit), clip [0, 1], gamma 1/2.2, "
    "×255 truncated to uint8, /255"
)

SOURCE_NOISEBASE = "noisebase/scripts/nb_compute_metrics.py (github.com/balintio/noisebase)"

# noisebase.data.ACES, adapted there from github.com/TheRealMJP/BakingLab (ACES.hlsl)
_ACES_INPUT = np.array(
    [
        [0.59719, 0.35458, 0.04823],
        [0.07600, 0.90834, 0.01566],
        [0.02840, 0.13383, 0.83777],
    ]
)
_ACES_OUTPUT = np.array(
    [
        [1.60475, -0.53108, -0.07367],
        [-0.10208, 1.10813, -0.00605],
        [-0.00327, -0.07276, 1.07602],
    ]
)
_ACES_GAMMA = 2.2

_QUIET = {"invalid": "ignore", "over": "ignore", "divide": "ignore"}


# --- Noisebase's display encoding ------------------------------------------------------------


def noisebase_uint8(image: ArrayLike) -> np.ndarray:
    """The 8-bit frame Noisebase would have saved for a linear HDR frame: ``(3, H, W)`` uint8.

    ``noisebase.data.ACES`` (input matrix, the rational RRT+ODT fit
    ``(x(x + 0.0245786) − 0.000090537) / (x(0.983729x + 0.4329510) + 0.238081)``, output
    matrix, clip to [0, 1], power 1/2.2) in float64, then ``(· × 255).astype(np.uint8)``:
    truncated, as Noisebase's ``Sequence.save`` does. No exposure is applied.

    Args:
        image: ``(3, H, W)`` linear HDR RGB, finite.

    >>> noisebase_uint8(np.ones((3, 1, 1))).ravel().tolist()  # mid grey 1.0 -> 205.06 -> 205
    [205, 205, 205]
    """
    x = np.moveaxis(as_image(image), 0, -1)  # (H, W, 3), float64
    with np.errstate(**_QUIET):
        x = np.einsum("ji, hwi -> hwj", _ACES_INPUT, x)
        a = x * (x + 0.0245786) - 0.000090537
        b = x * (0.983729 * x + 0.4329510) + 0.238081
        x = np.einsum("ji, hwi -> hwj", _ACES_OUTPUT, a / b)
        x = np.power(np.clip(x, 0.0, 1.0), 1.0 / _ACES_GAMMA)
    return np.moveaxis((x * 255).astype(np.uint8), -1, 0)


def noisebase_display(image: ArrayLike) -> np.ndarray:
    """Noisebase's metric input for a linear HDR frame: :func:`noisebase_uint8` ``/ 255``,
    ``(3, H, W)`` float64 in [0, 1] (Noisebase's ``np_to_torch``, in float64)."""
    return noisebase_uint8(image).astype(np.float64) / 255.0


# --- one frame pair ----------------------------------------------------------------------------


def tpsnr_pair(o0: np.ndarray, o1: np.ndarray, r0: np.ndarray, r1: np.ndarray) -> float:
    # Noisebase: psnr(test - prev_test, reference - prev_ref) = 10 log10(1 / mse)
    err = float(np.mean(((o1 - o0) - (r1 - r0)) ** 2))
    return math.inf if err == 0.0 else 10.0 * math.log10(1.0 / err)


def trmae_pair(o0: np.ndarray, o1: np.ndarray, r0: np.ndarray, r1: np.ndarray) -> float:
    # Noisebase: rmae(test - prev_test, reference - prev_ref), its "/ 3" included
    dt, dr = o1 - o0, r1 - r0
    return float(np.mean(np.abs(dt - dr) / (np.abs(dr) + NOISEBASE_RMAE_EPS))) / 3
