"""Classical filters (cross-bilateral, NLM) and the shared per-pixel kernel routine.

* :mod:`~mcdenoise.filters.kernels` -- memory-bounded k×k weighted sums: explicit per-pixel
  kernels (:func:`apply_kernels`) or weights from a callback (:func:`accumulate_weighted`).
* :mod:`~mcdenoise.filters.cross_bilateral` -- Kalantari 2015 cross-bilateral filter with
  per-pixel bandwidths.
* :mod:`~mcdenoise.filters.nlm` -- Rousselle 2012 variance-normalised non-local means
  (+ Rousselle 2013 feature weights).
* :mod:`~mcdenoise.filters.prepare` -- buffers -> filter inputs, and ready-made denoisers with
  tuned defaults (:func:`denoise_xbf`, :func:`denoise_nlm`).
"""

from mcdenoise.filters.cross_bilateral import CrossBilateral, cross_bilateral
from mcdenoise.filters.kernels import Window, accumulate_weighted, apply_kernels
from mcdenoise.filters.nlm import NonLocalMeans, non_local_means
from mcdenoise.filters.prepare import (
    FilterInputs,
    NlmSettings,
    XbfSettings,
    denoise_nlm,
    denoise_xbf,
    estimate_variance,
    prepare_inputs,
)

__all__ = [
    "CrossBilateral",
    "FilterInputs",
    "NlmSettings",
    "NonLocalMeans",
    "Window",
    "XbfSettings",
    "accumulate_weighted",
    "apply_kernels",
    "cross_bilateral",
    "denoise_nlm",
    "denoise_xbf",
    "estimate_variance",
    "non_local_means",
    "prepare_inputs",
]
