"""Tensor operators of the classical filters: per-pixel kernels, cross-bilateral, NLM.

* :mod:`~mcdenoise.filters.kernels` -- memory-bounded k×k weighted sums: explicit per-pixel
  kernels (:func:`apply_kernels`) or weights from a callback (:func:`accumulate_weighted`).
* :mod:`~mcdenoise.filters.cross_bilateral` -- Kalantari 2015 cross-bilateral filter with
  per-pixel bandwidths.
* :mod:`~mcdenoise.filters.nlm` -- Rousselle 2012 variance-normalised non-local means
  (+ Rousselle 2013 feature weights).
* :mod:`~mcdenoise.filters.box` -- window statistics (:func:`box_mean`, :func:`median3`).
* :mod:`~mcdenoise.filters.albedo` -- albedo demodulation (:func:`demodulate`).
* :mod:`~mcdenoise.filters.settings` -- the tuned parameters of the fixed filters
  (:class:`XbfSettings`, :class:`NlmSettings`).
* :mod:`~mcdenoise.filters.warp` -- backward warping by motion vectors with a validity mask
  (:func:`warp`), shared by the temporal methods.
* :mod:`~mcdenoise.filters.svgf` -- spatiotemporal variance-guided filtering (:class:`Svgf`,
  Schied 2017 after Falcor's ``SVGFPass``).

Everything here takes and returns tensors; the preparation layer (``prep/``) makes them from
buffers and the method adapters (``methods/``) run the whole pipelines.
"""

from mcdenoise.filters.albedo import demodulate, demodulated_variance
from mcdenoise.filters.box import box_mean, median3
from mcdenoise.filters.cross_bilateral import CrossBilateral, cross_bilateral
from mcdenoise.filters.kernels import Window, accumulate_weighted, apply_kernels
from mcdenoise.filters.nlm import NonLocalMeans, non_local_means
from mcdenoise.filters.settings import GUIDE_FEATURES, NlmSettings, XbfSettings
from mcdenoise.filters.svgf import Svgf
from mcdenoise.filters.svgf_guides import SvgfSettings
from mcdenoise.filters.warp import warp

__all__ = [
    "GUIDE_FEATURES",
    "CrossBilateral",
    "NlmSettings",
    "NonLocalMeans",
    "Svgf",
    "SvgfSettings",
    "Window",
    "XbfSettings",
    "accumulate_weighted",
    "apply_kernels",
    "box_mean",
    "cross_bilateral",
    "demodulate",
    "demodulated_variance",
    "median3",
    "non_local_means",
    "warp",
]
