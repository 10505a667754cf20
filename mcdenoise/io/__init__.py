"""EXR feature buffers: reading, writing, renderer profiles.

Public API: :func:`load_buffers` / :func:`save_buffers` (FeatureBuffers <-> EXR through a
renderer profile), :func:`save_buffers_parts` (several images as the named parts of one
multi-part EXR), :func:`describe` (``mcdenoise info``), the low-level :func:`read_exr`,
:func:`write_exr`, :func:`write_exr_parts`, :func:`probe_exr`, and the profile helpers :func:`detect_profile`,
:func:`get_profile`, :func:`load_mapping`.

Names are imported lazily (PEP 562), so ``import mcdenoise.io.exr`` does not pay for
importing torch; ``from mcdenoise.io import load_buffers`` works as usual.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, str] = {
    # buffers
    "BUFFER_NAMES": "mcdenoise.io.buffers",
    "FEATURES": "mcdenoise.io.buffers",
    "FeatureBuffers": "mcdenoise.io.buffers",
    "MissingFeatureError": "mcdenoise.io.buffers",
    "sanitize": "mcdenoise.io.buffers",
    # FeatureBuffers <-> files
    "LoadResult": "mcdenoise.io.buffer_files",
    "load_buffers": "mcdenoise.io.buffer_files",
    "read_buffers": "mcdenoise.io.buffer_files",
    "save_buffers": "mcdenoise.io.buffer_files",
    "save_buffers_parts": "mcdenoise.io.buffer_files",
    # low-level EXR
    "ExrChannel": "mcdenoise.io.exr",
    "ExrImage": "mcdenoise.io.exr",
    "ExrPart": "mcdenoise.io.exr",
    "ExrPartData": "mcdenoise.io.exr_write",
    "WriteReport": "mcdenoise.io.exr_write",
    "probe_exr": "mcdenoise.io.exr",
    "read_exr": "mcdenoise.io.exr",
    "write_exr": "mcdenoise.io.exr_write",
    "write_exr_parts": "mcdenoise.io.exr_write",
    # info
    "BufferInfo": "mcdenoise.io.info",
    "FileInfo": "mcdenoise.io.info",
    "describe": "mcdenoise.io.info",
    # profiles
    "PROFILE_NAMES": "mcdenoise.io.profiles",
    "ChannelMap": "mcdenoise.io.profiles",
    "ChannelMapping": "mcdenoise.io.profiles",
    "IncompleteFeatureError": "mcdenoise.io.profiles",
    "Profile": "mcdenoise.io.profiles",
    "ProfileError": "mcdenoise.io.profiles",
    "canonical_channels": "mcdenoise.io.profiles",
    "detect_profile": "mcdenoise.io.profiles",
    "get_profile": "mcdenoise.io.profiles",
    "load_mapping": "mcdenoise.io.profiles",
}

__all__ = [
    "BUFFER_NAMES",
    "FEATURES",
    "PROFILE_NAMES",
    "BufferInfo",
    "ChannelMap",
    "ChannelMapping",
    "ExrChannel",
    "ExrImage",
    "ExrPart",
    "ExrPartData",
    "FeatureBuffers",
    "FileInfo",
    "IncompleteFeatureError",
    "LoadResult",
    "MissingFeatureError",
    "Profile",
    "ProfileError",
    "WriteReport",
    "canonical_channels",
    "describe",
    "detect_profile",
    "get_profile",
    "load_buffers",
    "load_mapping",
    "probe_exr",
    "read_buffers",
    "read_exr",
    "sanitize",
    "save_buffers",
    "save_buffers_parts",
    "write_exr",
    "write_exr_parts",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'mcdenoise.io' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs
    from mcdenoise.io.buffer_files import (
        LoadResult,
        load_buffers,
        read_buffers,
        save_buffers,
        save_buffers_parts,
    )
    from mcdenoise.io.buffers import (
        BUFFER_NAMES,
        FEATURES,
        FeatureBuffers,
        MissingFeatureError,
        sanitize,
    )
    from mcdenoise.io.exr import ExrChannel, ExrImage, ExrPart, probe_exr, read_exr
    from mcdenoise.io.exr_write import ExrPartData, WriteReport, write_exr, write_exr_parts
    from mcdenoise.io.info import BufferInfo, FileInfo, describe
    from mcdenoise.io.profiles import (
        PROFILE_NAMES,
        ChannelMap,
        ChannelMapping,
        IncompleteFeatureError,
        Profile,
        ProfileError,
        canonical_channels,
        detect_profile,
        get_profile,
        load_mapping,
    )
