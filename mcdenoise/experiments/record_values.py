"""Values read from unit records: a finite number or ``None``, a record's relMSE and mean bias,
and their means over scenes (geometric for errors), as every part of the report reads them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mcdenoise.eval.results import decode_float
from mcdenoise.geomean import geometric_mean


def number(value: Any) -> float | None:
    """A record value as a float (``"inf"`` strings decoded); ``None`` when missing."""
    try:
        v = decode_float(value)
    except (TypeError, ValueError):
        return None
    return v


def finite(value: Any) -> bool:
    """True for a finite number (not ``None``, not a JSON ``"inf"`` string)."""
    v = number(value)
    return v is not None and math.isfinite(v)


def relmse_of(record: Mapping[str, Any]) -> float | None:
    """relMSE of a record, ``None`` when it failed or has none."""
    if record.get("failed"):
        return None
    v = number((record.get("metrics") or {}).get("relmse"))
    return v if v is not None and math.isfinite(v) else None


def _short(text: str, limit: int = 160) -> str:
    """``text`` cut to ``limit`` characters (error messages can list every channel of a file)."""
    return text if len(text) <= limit else text[: limit - 1] + "\u2026"


def _geomean(values: Sequence[float | None]) -> float | None:
    return geometric_mean(values, invalid="none")


def bias_of(record: Mapping[str, Any]) -> float | None:
    """Mean bias of a record (output mean / reference mean − 1), ``None`` when failed, not
    computed or not finite."""
    if record.get("failed"):
        return None
    v = number((record.get("metrics") or {}).get("bias"))
    return v if v is not None and math.isfinite(v) else None


def _mean(values: Sequence[float | None]) -> float | None:
    """Arithmetic mean; ``None`` when any value is unknown (render time of data without
    manifest) or there is none."""
    if not values or any(v is None for v in values):
        return None
    return float(np.mean([float(v) for v in values if v is not None]))


def _num(v: float) -> str:
    return f"{v:.3g}"
