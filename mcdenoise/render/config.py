"""Settings of one ``mcdenoise render`` run and their checks.

:class:`RenderConfig` holds what a run renders (size, spp levels, reference spp, pass size,
variant, shard, seed, frames); :meth:`RenderConfig.settings` is what every image of one
output folder shares (a folder holds one data set). :func:`check_spp_levels` and
:func:`check_shard` are the validating checks the config (and any caller that builds one from
other input, e.g. the CLI's parsers) applies.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcdenoise.errors import McdenoiseError
from mcdenoise.progress import Mode
from mcdenoise.render.animation import check_frames

#: Largest number of samples per pixel of one render call (one pass).
DEFAULT_PASS_SPP = 128
#: Values of ``RenderConfig.variant`` (``auto``: see :func:`mcdenoise.render.mitsuba_setup.ensure_variant`).
VARIANT_CHOICES: tuple[str, ...] = ("auto", "scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")


class RenderError(McdenoiseError, ValueError):
    """Bad render settings or an output folder that cannot take this run (one-line message)."""


@dataclass(frozen=True)
class RenderConfig:
    """Settings of one ``mcdenoise render`` run.

    Attributes:
        out: output folder (created if missing).
        width, height: image size in pixels.
        spp: the noisy levels, strictly increasing, rendered progressively.
        ref_spp: samples per pixel of the reference.
        variant: a Mitsuba variant or ``auto``.
        shard: ``(i, n)``, 1-based: render the images with index ``≡ i - 1 (mod n)``.
        pass_spp: most samples per pixel of one render call.
        seed: base seed; each image's seed is derived from it and the image id.
        compression: EXR compression of every file.
        progress: progress on stderr, a :data:`mcdenoise.progress.Mode`: ``True``/``"auto"``
            (a bar on a terminal, plain lines in a log), ``"bar"``, ``"lines"``,
            ``False``/``"off"`` (see :func:`mcdenoise.progress.progress_bar`).
        frames: ``None`` for still images, else every job is a sequence of this many frames
            (>= 2).
        halves: also write two independent half-sample buffers per level (``color_a``,
            ``color_b`` with their variances; feature halves where features are noisy):
            :mod:`mcdenoise.render.passes`.
    """

    out: Path
    width: int = 256
    height: int = 256
    spp: tuple[int, ...] = (4, 16, 64)
    ref_spp: int = 4096
    variant: str = "auto"
    shard: tuple[int, int] = (1, 1)
    pass_spp: int = DEFAULT_PASS_SPP
    seed: int = 0
    compression: str = "zip"
    progress: Mode = False
    frames: int | None = None
    halves: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "spp", tuple(self.spp))
        object.__setattr__(self, "shard", tuple(self.shard))
        for name in ("width", "height", "ref_spp", "pass_spp"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise RenderError(f"{name} must be an integer >= 1, got {value!r}")
        check_spp_levels(self.spp)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise RenderError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.variant not in VARIANT_CHOICES:
            raise RenderError(
                f"unknown Mitsuba variant {self.variant!r} (use {', '.join(VARIANT_CHOICES)})"
            )
        check_shard(self.shard)
        if not isinstance(self.halves, bool):
            raise RenderError(f"halves must be True or False, got {self.halves!r}")
        if self.frames is not None:
            try:
                check_frames(self.frames)
            except McdenoiseError as err:
                raise RenderError(str(err)) from None

    def settings(self) -> dict[str, Any]:
        """What every image of one folder shares (checked when a folder is reused)."""
        out: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "spp": list(self.spp),
            "ref_spp": self.ref_spp,
            "pass_spp": self.pass_spp,
        }
        if self.frames is not None:
            out["frames"] = self.frames
        if self.halves:  # absent = no halves (folders rendered before halves existed)
            out["halves"] = True
        return out


def check_spp_levels(levels: Sequence[int]) -> tuple[int, ...]:
    """Raise :class:`RenderError` unless ``levels`` are integers >= 1, strictly increasing."""
    out = tuple(levels)
    if not out:
        raise RenderError("spp needs at least one level")
    for v in out:
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise RenderError(f"spp levels must be integers >= 1, got {v!r}")
    if any(b <= a for a, b in itertools.pairwise(out)):
        raise RenderError(f"spp levels must be strictly increasing, got {','.join(map(str, out))}")
    return out


def check_shard(shard: Sequence[int]) -> tuple[int, int]:
    """Raise :class:`RenderError` unless ``shard`` is ``(i, n)`` with ``1 <= i <= n``."""
    if len(shard) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in shard):
        raise RenderError(f"shard must be (i, n), got {shard!r}")
    i, n = shard
    if n < 1 or not 1 <= i <= n:
        raise RenderError(f"shard {i}/{n}: need 1 <= i <= n (shards are numbered from 1)")
    return i, n
