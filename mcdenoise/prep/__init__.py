"""From a :class:`~mcdenoise.io.buffers.FeatureBuffers` to the tensors filters and models take.

* :mod:`~mcdenoise.prep.inputs` -- sanitise, normalise the guide features (depth / position
  over the scene extent), prefilter noisy features, the robust or estimated colour variance,
  albedo demodulation (:func:`prepare_inputs`, :func:`demodulate_inputs`).
* :mod:`~mcdenoise.prep.fireflies` -- outlier pixels found against their 5×5 neighbourhood and
  clamped, or clamped with their excess energy spread over their surface
  (:func:`remove_fireflies`; ``prepare_inputs(fireflies=...)``).
* :mod:`~mcdenoise.prep.variance` -- the per-pixel colour variance shrunk towards a pooled one
  at 2-8 spp (:func:`low_spp_variance`; ``prepare_inputs(variance_prior=...)``).
* :mod:`~mcdenoise.prep.kalantari` -- the Kalantari models' per-pixel features and prepared
  items (:func:`~mcdenoise.prep.kalantari.prepare_item`).
* :mod:`~mcdenoise.prep.kpcn` -- the kpcn network's input source and prepared tensors
  (:func:`~mcdenoise.prep.kpcn.prepare_tensors`).

The tuned parameters of the fixed filters are :mod:`mcdenoise.filters.settings`.
"""

from mcdenoise.prep.fireflies import FIREFLY_MODES, remove_fireflies
from mcdenoise.prep.inputs import (
    FilterInputs,
    demodulate_inputs,
    estimate_variance,
    prepare_inputs,
    robust_variance,
)
from mcdenoise.prep.variance import low_spp_variance

__all__ = [
    "FIREFLY_MODES",
    "FilterInputs",
    "demodulate_inputs",
    "estimate_variance",
    "low_spp_variance",
    "prepare_inputs",
    "remove_fireflies",
    "robust_variance",
]
