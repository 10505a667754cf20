"""mcdenoise: a batch tool for Monte Carlo denoising experiments.

Subpackages follow the data flow (docs/architecture.md): ``render`` (Mitsuba 3 data),
``io`` (EXR feature buffers and renderer profiles), ``prep`` (buffers -> tensors), ``filters``
(tensor operators), ``models`` (pure networks), ``methods`` (one adapter per denoiser, called
through ``denoise``), ``train``, ``eval`` (metrics, reports) and ``experiments``.
"""

__version__ = "0.1.0"
