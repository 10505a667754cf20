"""Learned models as pure ``nn.Module``\\ s with JSON-able cards.

* :mod:`~mcdenoise.models.kalantari` -- Kalantari 2015: per-pixel features -> MLP -> per-pixel
  bandwidths -> cross-bilateral or NLM filter (:class:`KalantariModel`, :class:`ModelCard`);
  :mod:`~mcdenoise.models.features` names and normalises its input features.
* :mod:`~mcdenoise.models.kpcn` -- the kernel-predicting CNN (:class:`KpcnModel`,
  :class:`KpcnCard`); :mod:`~mcdenoise.models.encoders` its input channels and encoders,
  :mod:`~mcdenoise.models.multiscale` its kernels and scale compositor.
* :mod:`~mcdenoise.models.weights` -- the shipped weights and a cached loader.

The modules take prepared tensors (the preparation layer ``prep/`` makes them from buffers) and read
and write model files through :mod:`mcdenoise.modelfile`. Importing this package has no side
effects.
"""

from mcdenoise.models.kalantari import KalantariModel, ModelCard
from mcdenoise.models.kpcn import KpcnCard, KpcnModel

__all__ = ["KalantariModel", "KpcnCard", "KpcnModel", "ModelCard"]
