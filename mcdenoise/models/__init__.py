"""Learned models: per-pixel features and the Kalantari 2015 filter-parameter MLP.

:mod:`~mcdenoise.models.features` computes the per-pixel features,
:mod:`~mcdenoise.models.kalantari` holds the model (features -> MLP -> per-pixel bandwidths ->
cross-bilateral or NLM filter) and its file format, :mod:`~mcdenoise.models.weights` the
shipped weights. Importing this package has no side effects.
"""

from mcdenoise.models.kalantari import KalantariModel, ModelCard

__all__ = ["KalantariModel", "ModelCard"]
