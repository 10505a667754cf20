"""From a :class:`~mcdenoise.io.buffers.FeatureBuffers` to the tensors filters and models take.

* :mod:`~mcdenoise.prep.inputs` -- sanitise, normalise the guide features (depth / position
  over the scene extent), prefilter noisy features, the robust or estimated colour variance,
  albedo demodulation (:func:`prepare_inputs`, :func:`demodulate_inputs`).
* :mod:`~mcdenoise.prep.kalantari` -- the Kalantari models' per-pixel features and prepared
  items (:func:`~mcdenoise.prep.kalantari.prepare_item`).
* :mod:`~mcdenoise.prep.kpcn` -- the kpcn network's input source and prepared tensors
  (:func:`~mcdenoise.prep.kpcn.prepare_tensors`).

The tuned parameters of the fixed filters are :mod:`mcdenoise.filters.settings`.
"""

from mcdenoise.prep.inputs import (
    FilterInputs,
    demodulate_inputs,
    estimate_variance,
    prepare_inputs,
    robust_variance,
)

__all__ = [
    "FilterInputs",
    "demodulate_inputs",
    "estimate_variance",
    "prepare_inputs",
    "robust_variance",
]
