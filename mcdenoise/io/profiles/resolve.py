"""Resolution of a profile against one file: which channels make which buffer, the sample
count, and the arrays.

:func:`resolve_channels` picks the profile (detected, forced or a mapping), keeps the first
complete source of each buffer and checks completeness: ``color`` is required; any other
feature that is partially present (``albedo.R/G`` without ``albedo.B``) is an error naming the
missing channels and listing what the file has, never silently skipped; features simply
absent are fine. :func:`assemble` then builds float32 arrays from the channel pixels.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import BUFFER_NAMES, VAR_SUFFIX, MissingFeatureError
from mcdenoise.io.profiles.base import (
    AssembledBuffers,
    BufferSource,
    ChannelMap,
    IncompleteFeatureError,
    Profile,
    ProfileError,
    int_attribute,
)
from mcdenoise.io.profiles.detect import detect_with_reason, get_profile
from mcdenoise.io.profiles.mapping import ChannelMapping, MappingProfile, load_mapping
from mcdenoise.io.profiles.mcdenoise import SPP_ATTR

# Rec. 709 / sRGB luminance weights (row Y of the linear-sRGB -> XYZ matrix, D65).
_LUMA = (0.2126729, 0.7151522, 0.0721750)


def resolve_spp(
    prof: Profile,
    attributes: Mapping[str, Any],
    mapping: ChannelMapping | None,
    spp: int | None,
) -> tuple[int | None, str | None]:
    """The sample count of a file and where it came from, or ``(None, None)``.

    Sources: the ``mcdenoise:spp`` attribute (any profile), the renderer's own header
    attribute (:meth:`Profile.header_spp`), the mapping's ``spp`` and the caller's ``spp``.

    Raises:
        InputError: ``spp`` is not a positive integer, or the sources disagree.
    """
    if spp is not None and (isinstance(spp, bool) or not isinstance(spp, int) or spp <= 0):
        raise InputError(f"spp must be a positive integer, got {spp!r}")
    found: list[tuple[int, str]] = []
    for cand in (int_attribute(attributes, SPP_ATTR), prof.header_spp(attributes)):
        if cand is not None:
            found.append(cand)
    if mapping is not None and mapping.spp is not None:
        found.append((mapping.spp, f"spp in {mapping.source}"))
    if spp is not None:
        found.append((spp, "spp= argument"))
    values = {v for v, _ in found}
    if len(values) > 1:
        raise InputError(
            "conflicting sample counts: " + ", ".join(f"{v} ({src})" for v, src in found)
        )
    return (found[0][0], found[0][1]) if found else (None, None)


def resolve_channels(
    channels: Sequence[str],
    attributes: Mapping[str, Any],
    *,
    profile: str | Profile = "auto",
    mapping: str | os.PathLike[str] | Mapping[str, Any] | ChannelMapping | None = None,
    spp: int | None = None,
    strict: bool = True,
    source: str | None = None,
) -> ChannelMap:
    """Map a file's channels to buffers with a profile (detected or forced) and a mapping.

    Args:
        channels: the file's channel names.
        attributes: its header attributes.
        profile: ``"auto"``, a profile name (``"cycles:ViewLayer"``) or a Profile.
        mapping: a mapping file/dict (:func:`load_mapping`); its entries override the
            profile's for the buffers they name, and are required to be present.
        spp: samples per pixel if known (must agree with the header and the mapping).
        strict: raise on a missing ``color`` or an incomplete feature (else record them in
            ``problems``, for ``mcdenoise info``).
        source: file name used in error messages.

    Raises:
        ProfileError, MissingFeatureError, IncompleteFeatureError, InputError.
    """
    names = list(channels)
    present = set(names)
    cmapping = (
        mapping if isinstance(mapping, ChannelMapping) or mapping is None else load_mapping(mapping)
    )
    if isinstance(profile, str) and profile.strip().lower() == "auto":
        try:
            prof, reason = detect_with_reason(names, attributes)
        except ProfileError:
            if cmapping is None:
                raise
            prof, reason = MappingProfile(), f"mapping {cmapping.source} (no profile detected)"
    else:
        prof = get_profile(profile)
        reason = "forced" if not isinstance(profile, Profile) else "given"
    alts = prof.propose(names, attributes)
    spp_value, spp_source = resolve_spp(prof, attributes, cmapping, spp)
    if cmapping is not None:
        for buf, chans in cmapping.buffers.items():
            op = (
                "per_sample"
                if buf.endswith(VAR_SUFFIX) and cmapping.variance == "sample"
                else "copy"
            )
            alts[buf] = [BufferSource(chans, op)]
        if not isinstance(prof, MappingProfile):
            reason += f", overridden by {cmapping.source}"

    where = source
    sources: dict[str, tuple[BufferSource, ...]] = {}
    problems: list[str] = []
    notes: list[str] = []
    for buf in BUFFER_NAMES:
        cands = alts.get(buf, [])
        complete = [s for s in cands if all(c in present for c in s.file_channels())]
        if complete:
            checked = [s for s in complete if s.luminance_of]
            sources[buf] = tuple(checked) if checked else (complete[0],)
            continue
        forced = cmapping is not None and buf in cmapping.buffers
        partial = [s for s in cands if any(c in present for c in s.channels)]
        if partial or forced:
            best = max(partial or cands, key=lambda s: sum(c in present for c in s.channels))
            missing = [c for c in best.file_channels() if c not in present]
            found = [c for c in best.file_channels() if c in present]
            if not found:  # a mapping entry none of whose channels exist
                err: Exception = MissingFeatureError(
                    [f"{buf} ({', '.join(missing)})"],
                    [],
                    source=where,
                    channels=names,
                    needed_by=f"mapping {cmapping.source}" if cmapping else None,
                )
            else:
                err = IncompleteFeatureError(buf, missing, found, source=where, channels=names)
            if strict:
                raise err
            problems.append(str(err))
        elif buf == "color":
            err = MissingFeatureError(["color"], [], source=where, channels=names)
            if strict:
                raise err
            problems.append(str(err))

    used = {c for cands in sources.values() for s in cands for c in s.file_channels()}
    for buf in list(sources):
        needs = [s for s in sources[buf] if s.op in ("per_sample", "moments")]
        if not needs:
            continue
        if spp_value is None:
            notes.append(
                f"{buf} not produced: {needs[0].describe()} needs the sample count; "
                "pass spp= or put spp in a mapping file"
            )
            del sources[buf]
        elif spp_value < 2 and any(s.op == "moments" for s in needs):
            notes.append(f"{buf} not produced: a variance from moments needs spp >= 2")
            del sources[buf]
    unmapped = [c for c in names if c not in used]
    return ChannelMap(
        profile=prof.label,
        reason=reason,
        sources=sources,
        spp=spp_value,
        spp_source=spp_source,
        unmapped=unmapped,
        notes=notes,
        problems=problems,
    )


def _luminance(r: np.ndarray, g: np.ndarray, b: np.ndarray) -> np.ndarray:
    return _LUMA[0] * r + _LUMA[1] * g + _LUMA[2] * b


def assemble(cmap: ChannelMap, pixels: Mapping[str, np.ndarray]) -> AssembledBuffers:
    """Build the buffers of ``cmap`` from channel arrays.

    Args:
        cmap: from :func:`resolve_channels`.
        pixels: channel name -> float32 ``(H, W)`` (at least ``cmap.file_channels()``).

    Returns:
        :class:`AssembledBuffers` with float32 ``(C, H, W)`` arrays. NaN/Inf/negative values
        of copied channels are kept as stored; variances from moments are clamped at 0
        (negative only by rounding). A source's ``far`` marker becomes 0 and its ``scale``
        factors are applied; its ``note`` and values above its ``expect_max`` become
        ``warnings``.
    """
    arrays: dict[str, np.ndarray] = {}
    chosen: dict[str, BufferSource] = {}
    notes: list[str] = []
    warnings: list[str] = []
    spp = cmap.spp
    for buf, cands in cmap.sources.items():
        for src in cands:
            stack = np.stack([pixels[c] for c in src.channels]).astype(np.float32, copy=False)
            if src.op == "copy":
                out = stack
            elif src.op == "per_sample":
                assert spp is not None
                out = stack / np.float32(spp)
            elif src.op == "moments":
                assert spp is not None and spp >= 2
                m2 = np.stack([pixels[c] for c in src.m2]).astype(np.float32, copy=False)
                if src.luminance_of:
                    lum = _luminance(*(pixels[c] for c in src.luminance_of))
                    if not np.allclose(stack[0], lum, rtol=1e-3, atol=1e-5, equal_nan=True):
                        continue
                with np.errstate(invalid="ignore", over="ignore"):
                    diff = m2 - stack * stack
                    out = np.where(diff < 0, np.float32(0), diff) / np.float32(spp - 1)
            else:  # pragma: no cover - ops are fixed above
                raise ValueError(f"unknown op {src.op!r}")
            arrays[buf] = _convert(out, src)
            chosen[buf] = src
            warnings.extend(_convention_warnings(buf, src, arrays[buf]))
            break
        else:
            tried = "; ".join(s.describe() for s in cands)
            notes.append(
                f"{buf} not produced: no moment pair's first moment Y equals the luminance of "
                f"R,G,B (tried {tried})"
            )
    return AssembledBuffers(arrays, chosen, notes, warnings)


def _convert(out: np.ndarray, src: BufferSource) -> np.ndarray:
    """``src``'s "no hit" marker -> 0 and its per-channel factors, as float32."""
    if src.far is None and not src.scale:
        return np.ascontiguousarray(out, dtype=np.float32)
    out = np.array(out, dtype=np.float32, copy=True)
    if src.far is not None:
        out[out >= np.float32(src.far)] = 0.0
    if src.scale:
        out *= np.asarray(src.scale, dtype=np.float32).reshape(-1, 1, 1)
    return np.ascontiguousarray(out)


def _convention_warnings(buf: str, src: BufferSource, arr: np.ndarray) -> list[str]:
    """One line per way ``src`` departs from ``buf``'s canonical meaning (see BufferSource)."""
    out = [f"{buf}: {src.note}"] if src.note else []
    if src.expect_max is not None:
        with np.errstate(invalid="ignore"):
            above = np.any(arr > src.expect_max, axis=0)
        n = int(above.sum())
        if n:
            peak = float(np.nanmax(arr[:, above]))
            why = f" ({src.expect_why})" if src.expect_why else ""
            out.append(
                f"{buf}: {n} pixel(s) above {src.expect_max:g} (max {peak:.4g}){why}; "
                "kept as stored"
            )
    return out
