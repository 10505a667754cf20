"""mcdenoise: a batch tool for Monte Carlo denoising experiments.

Subpackages follow the data flow (see README "Architecture"):
``io`` (EXR feature buffers), ``filters`` (classical filters), ``eval`` (metrics, reports),
``models`` / ``train`` (learned denoisers), ``render`` (Mitsuba 3 data generation).
"""

__version__ = "0.1.0"
