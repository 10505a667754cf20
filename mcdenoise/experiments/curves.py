"""A scene's curves from its unit records: the noisy input's error against spp (the ``1/N`` fit),
each method's (time, error) points, and the reference's own noise floor.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.experiments.dataset import SceneData, read_reference
from mcdenoise.experiments.quality import (
    NoisyCurve,
    reference_noise_floor,
)
from mcdenoise.experiments.record_values import (
    number,
    relmse_of,
)
from mcdenoise.experiments.spec_fields import NOISY
from mcdenoise.experiments.tradeoff import (
    Point,
)


def _noise_floor(scene: SceneData) -> tuple[float | None, str | None]:
    """The reference's noise floor; of a sequence, the mean of its frames' floors."""
    if scene.is_sequence:
        floors = []
        for f in scene.frames:
            floor, note = _floor_of(f.reference)
            if floor is None:
                return None, note
            floors.append(floor)
        return float(np.mean(floors)), None
    return _floor_of(scene.reference)


def _floor_of(reference: Path) -> tuple[float | None, str | None]:

    buffers = read_reference(reference)
    if "color_var" not in buffers:
        return None, f"{reference.name} has no color_var: the reference's noise floor is unknown"
    floor = reference_noise_floor(buffers["color"].numpy(), buffers["color_var"].numpy())
    return (floor if math.isfinite(floor) else None), None


def _noisy_curve(records: Sequence[Mapping[str, Any]]) -> NoisyCurve | None:
    pts = []
    for r in sorted(records, key=lambda r: r["spp"]):
        e = relmse_of(r)
        if r["method"] == NOISY and e is not None and e > 0:
            seconds = number(r.get("render_seconds"))  # unknown: NaN, no seconds per spp
            pts.append((int(r["spp"]), e, math.nan if seconds is None else seconds))
    if not pts:
        return None
    spp, err, sec = zip(*pts)
    return NoisyCurve(tuple(spp), tuple(err), tuple(sec))


def _points(records: Sequence[Mapping[str, Any]]) -> list[Point]:
    pts = []
    for r in records:
        e = relmse_of(r)
        t = number(r.get("total_seconds"))
        if e is not None and t is not None and math.isfinite(t):
            pts.append(Point(r["method"], int(r["spp"]), t, e))
    return pts
