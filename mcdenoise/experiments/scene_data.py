"""The images of an experiment in memory: :class:`SceneData` (one image or sequence), its
:class:`Level` s (one per spp) and :class:`Frame` s, and how a level and a reference are read
(:func:`read_level`, :func:`read_reference`): a part of a render folder's multi-part file,
any renderer's EXR through the profiles, or an OIDN ``.hdr.exr`` with its feature files.
Where the scenes come from: :mod:`mcdenoise.experiments.dataset` (a render folder and its
manifest) and :mod:`mcdenoise.experiments.folder_data` (a folder without manifest)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcdenoise.io import load_buffers
from mcdenoise.io.oidn_layout import oidn_files, parse_oidn_name, read_oidn_level


@dataclass(frozen=True)
class Level:
    """One spp level of one image.

    Attributes:
        spp: samples per pixel.
        part: part name in the noisy file (``spp16``); ``""``: the file's only image.
        render_seconds: cumulative render seconds to reach this level, JIT excluded;
            ``None`` when unknown (a folder without manifest: nothing recorded them).
        jit_seconds: cumulative JIT compilation seconds that were left out.
        file: the level's own file when it is not a part of the scene's noisy file (a
            folder of one file per level; an OIDN ``.hdr.exr`` with its feature files).
    """

    spp: int
    part: str
    render_seconds: float | None
    jit_seconds: float = 0.0
    file: Path | None = None


@dataclass(frozen=True)
class Frame:
    """One frame of a sequence: its noisy file (one part per level) and its reference."""

    noisy: Path
    reference: Path


@dataclass(frozen=True)
class SceneData:
    """One rendered image of the data set: files, levels, seed, and a fingerprint of how it
    was made (spec, seed, render settings, variant), which keys cached results."""

    id: str
    noisy: Path
    reference: Path
    levels: tuple[Level, ...]
    reference_spp: int | None
    seed: int | None
    variant: str | None
    fingerprint: str
    record: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    #: the frames of a sequence, in order (``()`` for a still image; then ``noisy`` and
    #: ``reference`` are the sequence's folder and its ``ref`` folder)
    frames: tuple[Frame, ...] = ()

    @property
    def is_sequence(self) -> bool:
        return bool(self.frames)

    def files(self) -> list[Path]:
        """Every file of the image or sequence (what the data hash covers)."""
        if not self.frames:
            own = [lv.file for lv in self.levels if lv.file is not None] or [self.noisy]
            paths = [*own, self.reference]
            return [q for p in paths for q in (oidn_files(p) if parse_oidn_name(p.name) else [p])]
        return [p for f in self.frames for p in (f.noisy, f.reference)]

    def level(self, spp: int) -> Level:
        for lv in self.levels:
            if lv.spp == spp:
                return lv
        raise KeyError(spp)


def read_level(noisy: str | os.PathLike[str], level: Level) -> Any:
    """The level ``level`` of the image whose noisy file is ``noisy`` as ``FeatureBuffers``:
    a part of ``noisy``, or the level's own file (an OIDN colour file with its albedo and
    normal files; any other EXR through the renderer profiles, with the level's spp)."""

    if level.file is None:
        return load_buffers(noisy, part=level.part)
    if parse_oidn_name(level.file.name) is not None:
        return read_oidn_level(level.file, level.spp)
    buffers = load_buffers(level.file, part=level.part or None, spp=level.spp)
    if buffers.spp is None:
        buffers.spp = level.spp
    return buffers


def read_reference(path: str | os.PathLike[str]) -> Any:
    """A reference as ``FeatureBuffers`` (an OIDN ``.hdr.exr`` with its feature files, or
    any EXR through the renderer profiles)."""

    if parse_oidn_name(Path(path).name) is not None:
        return read_oidn_level(path)
    return load_buffers(path)
