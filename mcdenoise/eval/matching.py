"""Which reference and which noisy input an output belongs to, read from names and headers.

The first step of an evaluation, for stills (:mod:`mcdenoise.eval.evaluate`) and sequences
(:mod:`mcdenoise.eval.evaluate_sequences`) alike: find the EXR files (:func:`scan_exr`), match
an output to the reference whose stem is the longest prefix of its own (:func:`match_prefix`,
:class:`PrefixMatcher`), read what its header says about how it was made (:class:`Meta`,
:func:`probe`: method, source, spp, timing, scene identity, without reading pixels), and check
that an output made from one scene is not judged against another (:func:`same_scene`,
:func:`scene_mismatch`).
"""

from __future__ import annotations

import json
import os
import re
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.io.exr import probe_exr, select_part
from mcdenoise.io.exr_messages import special_file_kind
from mcdenoise.io.profiles.cycles import BLENDER_ATTR, cycles_layers

PathLike = str | os.PathLike[str]

#: Header attributes written by ``mcdenoise denoise`` (read here when present).
ATTR_METHOD = "mcdenoise:method"
ATTR_PARAMS = "mcdenoise:params"
ATTR_SOURCE = "mcdenoise:source"
ATTR_SOURCE_PART = "mcdenoise:source_part"
#: The profile ``mcdenoise denoise`` read its source with, where it names an image inside the
#: file (``"cycles:Layer2"``: a Blender view layer); the source and the reference are read
#: with it.
ATTR_SOURCE_PROFILE = "mcdenoise:source_profile"
ATTR_SECONDS = "mcdenoise:seconds"
ATTR_DEVICE = "mcdenoise:device"
ATTR_SPP = "mcdenoise:spp"
#: Written by ``mcdenoise render`` (and copied into outputs by ``mcdenoise denoise``): which
#: scene, image and frame a file shows; :func:`same_scene` compares them.
ATTR_SCENE = "mcdenoise:scene"
ATTR_IMAGE = "mcdenoise:image"
ATTR_FRAME = "mcdenoise:frame"
_IDENTITY = (ATTR_SCENE, ATTR_IMAGE, ATTR_FRAME)

_SPP_IN_NAME = re.compile(r"(?:^|[_\-.])spp(\d+)(?:$|[_\-.])", re.IGNORECASE)
#: Stem of a frame of a sequence (``mcdenoise render --frames``, ``mcdenoise denoise SEQ_DIR``).
FRAME_STEM = re.compile(r"^frame_(\d+)$")


def scan_exr(path: PathLike, *, what: str = "file") -> list[Path]:
    """``[path]`` for a file, or the ``*.exr`` files of a folder (sorted, not recursive).

    Names starting with ``.mcdenoise-tmp-`` (unfinished atomic writes) are skipped.

    Raises:
        InputError: ``path`` does not exist, is not a regular file (a named pipe), or the
            folder holds no EXR file.
    """
    p = Path(path)
    if p.is_dir():
        found = sorted(
            f
            for f in p.iterdir()
            if f.is_file() and f.suffix.lower() == ".exr" and not f.name.startswith(TMP_PREFIX)
        )
        if not found:
            raise InputError(f"no *.exr {what} in folder {p}")
        return found
    if not p.exists():
        raise InputError(f"{what} not found: {p}")
    if not p.is_file():  # a named pipe would block the reader: refused before it is opened
        kind = special_file_kind(p.stat().st_mode)
        raise InputError(f"{p}: is {kind}, not a regular file; refused (reading could block)")
    return [p]


class PrefixMatcher:
    """:func:`match_prefix` against one set of candidates, in time that grows with the length
    of the stem, not with the number of candidates: the only candidates that can match a stem
    are the stem itself and its prefixes that end before a non-alphanumeric character, looked
    up in a set, longest first. Matching n outputs to n references is then linear in n (a loop
    over the candidates made ``eval --ref DIR`` with 3000 files quadratic).

    >>> refs = PrefixMatcher(["cornell", "cornell_spp16", "corn", "box"])
    >>> refs("cornell_spp16_nlm"), refs("cornell-x"), refs("boxes_nlm")
    ('cornell_spp16', 'cornell', None)
    """

    def __init__(self, candidates: Iterable[str]) -> None:
        self._names = frozenset(c for c in candidates if c)

    def __call__(self, stem: str) -> str | None:
        if stem in self._names:
            return stem
        for i in range(len(stem) - 1, 0, -1):
            if not stem[i].isalnum() and stem[:i] in self._names:
                return stem[:i]
        return None


def match_prefix(stem: str, candidates: Iterable[str]) -> str | None:
    """The longest candidate that is a prefix of ``stem`` at a word boundary, else ``None``.

    A candidate matches when ``stem`` equals it or continues it with a non-alphanumeric
    character (``_``, ``-``, ``.``), so reference ``cornell`` matches output
    ``cornell_spp16_nlm`` but reference ``box`` does not match output ``boxes_nlm``. To match
    many stems against the same candidates, build one :class:`PrefixMatcher`.

    >>> match_prefix("cornell_spp16_nlm", ["cornell", "cornell_spp16", "corn", "box"])
    'cornell_spp16'
    >>> match_prefix("boxes_nlm", ["box"]) is None
    True
    """
    return PrefixMatcher(candidates)(stem)


def same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def file_id(p: Path) -> tuple[int, int] | None:
    """``(device, inode)`` of the file ``p`` (symlinks followed; what ``os.path.samefile``
    compares), ``None`` if it cannot be read."""
    try:
        st = os.stat(p)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def image_key(p: Path, part: str | None = None, profile: str | None = None) -> str:
    """Identity of an image: the resolved file, plus ``#part`` for one part of a multi-part
    file (a data set written by ``mcdenoise render`` keeps every spp level in one file), plus
    `` [profile]`` for an image a profile picks inside it (a Cycles view layer)."""
    return str(p.resolve()) + (f"#{part}" if part else "") + (f" [{profile}]" if profile else "")


def cycles_layer(profile: str | None) -> str | None:
    """The view layer of a recorded ``cycles:<Layer>`` profile, else ``None``."""
    if profile and profile.startswith("cycles:") and len(profile) > len("cycles:"):
        return profile[len("cycles:") :]
    return None


@dataclass
class Meta:
    """What the header of one EXR says about how it was made."""

    path: Path
    part: str | None = None  # the part of ``path`` described (None: the default part)
    profile: str | None = None  # the profile ``path`` is read with (None: auto-detected)
    method: str | None = None
    source: str | None = None
    source_part: str | None = None
    source_profile: str | None = None
    seconds: float | None = None
    device: str | None = None
    params: str | None = None
    spp: int | None = None
    identity: dict[str, str] = field(default_factory=dict)  # scene, image, frame attributes


def as_int(v: Any) -> int | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return int(f) if np.isfinite(f) and f == int(f) and f > 0 else None


def as_float(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


def meta_from_attributes(
    path: Path,
    attributes: Mapping[str, Any],
    spp: int | None,
    part: str | None = None,
    profile: str | None = None,
) -> Meta:
    attrs = dict(attributes)
    params = attrs.get(ATTR_PARAMS)
    if params is not None and not isinstance(params, str):
        params = json.dumps(params, sort_keys=True, default=str)
    method = attrs.get(ATTR_METHOD)
    source = attrs.get(ATTR_SOURCE)
    source_part = attrs.get(ATTR_SOURCE_PART)
    source_profile = attrs.get(ATTR_SOURCE_PROFILE)
    device = attrs.get(ATTR_DEVICE)
    spp_value = as_int(attrs.get(ATTR_SPP)) or as_int(spp)
    if spp_value is None:
        m = _SPP_IN_NAME.search(path.stem)
        spp_value = int(m.group(1)) if m else None
    return Meta(
        path=path,
        part=part,
        profile=profile,
        method=str(method) if method not in (None, "") else None,
        source=str(source) if source not in (None, "") else None,
        source_part=str(source_part) if source_part not in (None, "") else None,
        source_profile=str(source_profile) if source_profile not in (None, "") else None,
        seconds=as_float(attrs.get(ATTR_SECONDS)),
        device=str(device) if device not in (None, "") else None,
        params=params,
        spp=spp_value,
        identity={k: str(attrs[k]) for k in _IDENTITY if attrs.get(k) not in (None, "")},
    )


def probe(path: Path, part: str | None = None, profile: str | None = None) -> Meta:
    """Header metadata of one EXR (the first part, or the part named ``part``), without
    reading pixels; ``profile``: the profile it is to be read with (kept in the metadata)."""
    parts = probe_exr(path)
    # a Blender file's `part` may name a view layer; its attributes are in part 0 only
    if part is None or BLENDER_ATTR in parts[0].attributes:
        header = parts[0]
    else:
        header = select_part(parts, part, str(path))
    return meta_from_attributes(path, header.attributes, None, part, profile)


def load_color(
    path: Path, part: str | None = None, profile: str | None = None
) -> tuple[np.ndarray, Meta]:
    """Colour ``(3, H, W)`` float32 linear HDR RGB and metadata of one EXR (or one part), read
    with ``profile`` (default: auto-detected)."""
    buf = load_buffers(path, part=part, profile=profile or "auto")
    color = buf["color"].detach().cpu().numpy()
    return color, meta_from_attributes(path, buf.attributes, buf.spp, part, profile)


def reference_layers(path: Path) -> list[str]:
    """The Blender view layers of a reference file (none for any other layout)."""
    return list(cycles_layers([c for p in probe_exr(path) for c in p.channel_names]))


def same_scene(reference: Mapping[str, str], source: Mapping[str, str]) -> bool:
    """Whether what the headers record allows an output made from ``source`` to show the
    scene of ``reference``.

    ``reference`` and ``source`` are the scene attributes of the two headers
    (``mcdenoise:scene``, ``mcdenoise:image``, ``mcdenoise:frame``, as written by
    ``mcdenoise render`` and kept in the shipped samples and in ``mcdenoise denoise``'s
    outputs). Only recorded provenance can contradict a pairing: every attribute that *both*
    headers record must be equal. Where one file records nothing (a user's own ``noisy.exr``
    and ``ref.exr``, another renderer's files) the pairing stands; file names are never taken
    for scenes.

    >>> same_scene({"mcdenoise:scene": "caustic"}, {"mcdenoise:scene": "cornell"})
    False
    >>> same_scene({"mcdenoise:scene": "cornell"}, {}), same_scene({}, {})
    (True, True)
    """
    return not conflicts(reference, source)


def conflicts(reference: Mapping[str, str], source: Mapping[str, str]) -> list[str]:
    """The identity attributes both headers record with different values."""
    return [k for k in _IDENTITY if k in reference and k in source and reference[k] != source[k]]


def source_identity(meta: Meta, depth: int = 4) -> dict[str, str]:
    """Scene attributes of the file ``meta``'s output was made from: the output's own
    attributes when it records a scene (``mcdenoise denoise`` copies them), else its source's
    header (followed through a chain of outputs), else what the output itself records
    (often nothing)."""
    if ATTR_SCENE in meta.identity:
        return meta.identity
    src = source_path(meta)
    if src is not None and depth > 0:
        try:
            upstream = probe(src, meta.source_part)
        except (InputError, OSError):
            upstream = None
        if upstream is not None:
            if ATTR_SCENE in upstream.identity or upstream.source is None:
                return upstream.identity
            return source_identity(upstream, depth - 1)
    return meta.identity


def source_path(meta: Meta) -> Path | None:
    """The file of ``meta``'s ``mcdenoise:source`` (relative: to the output), if it exists."""
    if meta.source is None:
        return None
    src = Path(meta.source)
    if not src.is_absolute() and not src.is_file():
        src = meta.path.parent / src
    return src if src.is_file() else None


def describe_scene(identity: Mapping[str, str], keys: Sequence[str]) -> str:
    """``scene 'cornell'``, ``scene 'a', image 'a_2'``: the attributes ``keys`` of ``identity``."""
    shown = [ATTR_SCENE, *keys] if ATTR_SCENE in identity else list(keys)
    return ", ".join(
        f"{k.split(':')[-1]} {identity[k]!r}" for k in dict.fromkeys(shown) if k in identity
    )


def scene_mismatch(meta: Meta, ref: Path, ref_ids: dict[Path, dict[str, str]]) -> str | None:
    """Why ``meta``'s output cannot show the scene of reference ``ref`` (a scene, image or
    frame that both headers record differently, see :func:`same_scene`), or ``None``."""
    if ref not in ref_ids:
        ref_ids[ref] = probe(ref).identity
    identity = source_identity(meta)
    keys = conflicts(ref_ids[ref], identity)
    if not keys:
        return None
    return (
        f"output {meta.path} was made from {meta.source} "
        f"({describe_scene(identity, keys)}) but the reference {ref} shows "
        f"{describe_scene(ref_ids[ref], keys)}"
    )


def default_warn(message: str) -> None:
    warnings.warn(message, stacklevel=3)


def references(reference: PathLike) -> dict[str, Path]:
    """Scene (stem) -> reference file."""
    files = scan_exr(reference, what="reference")
    refs: dict[str, Path] = {}
    for f in files:
        if f.stem in refs:
            raise InputError(f"two references for scene {f.stem!r}: {refs[f.stem]} and {f}")
        refs[f.stem] = f
    return refs


def image_label(meta: Meta) -> str:
    """How an image is named in records: its file, plus ``#part`` for one part of a file,
    plus `` [profile]`` for an image a profile picks in it (``noisy.exr [cycles:Layer2]``)."""
    return (
        str(meta.path)
        + (f"#{meta.part}" if meta.part else "")
        + (f" [{meta.profile}]" if meta.profile else "")
    )
