"""The geometric mean, the one way this package averages errors and error ratios over images.

relMSE values and their ratios span orders of magnitude between scenes; their geometric mean
(``exp(mean(log v))``) weighs every image alike, where the arithmetic mean would be the
brightest scene's error. Training validation, :mod:`mcdenoise.experiments` and the benchmarks
all call :func:`geometric_mean`; they differ only in what a value that is not finite and
positive means to them, which the ``invalid`` argument states:

=============  ==========  ================  ===============  =====================
``invalid``    no value    a NaN (or None)   a 0 (or < 0)     +inf (no 0 present)
=============  ==========  ================  ===============  =====================
``"limit"``    ``nan``     ``nan``           ``0.0``          ``inf``
``"none"``     ``None``    ``None``          ``None``         ``None``
``"raise"``    ValueError  ValueError        ValueError       ValueError
=============  ==========  ================  ===============  =====================

``"limit"`` (the default; training and benchmarks) returns the limit of ``exp(mean(log v))``:
one exact match (error 0) makes the mean 0, and a missing value makes it unknown (``nan``
takes precedence over ``0.0``). ``"none"`` (experiment summaries) treats any such value as "no
summary" (``None``). ``"raise"`` (the bootstrap of ratios) refuses them.

This module imports numpy only, so every layer may use it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Literal, overload

import numpy as np

Invalid = Literal["limit", "none", "raise"]


@overload
def geometric_mean(
    values: Iterable[float | None], *, invalid: Literal["limit", "raise"] = "limit"
) -> float: ...


@overload
def geometric_mean(values: Iterable[float | None], *, invalid: Literal["none"]) -> float | None: ...


def geometric_mean(values: Iterable[float | None], *, invalid: Invalid = "limit") -> float | None:
    """``exp(mean(log v))`` of positive values, in float64.

    Args:
        values: the values (any iterable of numbers; ``None`` counts as a missing value, NaN).
        invalid: what a value that is not finite and positive, or no value at all, gives: see
            the module docstring (``"limit"``, ``"none"`` or ``"raise"``).

    Raises:
        ValueError: with ``invalid="raise"``, for no value or one not finite and > 0; for an
            unknown ``invalid``.

    >>> geometric_mean([0.5, 2.0, 1.0])
    1.0
    >>> geometric_mean([0.1, 0.0]), geometric_mean([]), geometric_mean([0.1, 0.0], invalid="none")
    (0.0, nan, None)
    """
    if invalid not in ("limit", "none", "raise"):
        raise ValueError(f"invalid must be 'limit', 'none' or 'raise', got {invalid!r}")
    v = np.asarray([math.nan if x is None else x for x in values], dtype=np.float64).ravel()
    if v.size and np.all(np.isfinite(v)) and np.all(v > 0):
        return float(np.exp(np.mean(np.log(v))))
    if invalid == "none":
        return None
    if invalid == "raise":
        raise ValueError(f"the geometric mean needs finite values > 0, got {v.tolist()}")
    if v.size == 0 or np.isnan(v).any():
        return math.nan
    if (v <= 0).any():
        return 0.0
    return math.inf  # finite and positive but for +inf


__all__ = ["Invalid", "geometric_mean"]
