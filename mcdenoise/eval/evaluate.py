"""Evaluate denoised EXR outputs (and the noisy inputs they came from) against references.

Two entry points share one engine:

* :func:`evaluate` works on files: ``reference`` is one EXR (every output is compared with it)
  or a folder of EXRs (each output is matched with the reference whose stem is the longest
  prefix of the output's stem, see :func:`match_prefix`); ``outputs`` are EXR files or folders
  (scanned non-recursively for ``*.exr``, skipping ``.mcdenoise-tmp-*`` files).
* :func:`evaluate_arrays` works on ``(3, H, W)`` arrays already in memory.

Sequences: when ``reference`` is a folder of frames ``frame_0000.exr``, ``frame_0001.exr``, ...
(the layout of ``mcdenoise render --frames``: ``DIR/<id>/ref/``), :func:`evaluate` hands over
to :func:`~mcdenoise.eval.evaluate_sequences.evaluate_sequences` (:mod:`mcdenoise.eval.evaluate_sequences`): every output is a folder of frames (``mcdenoise denoise
SEQ_DIR -o OUT``), matched to the reference frames by name, and evaluated as one sequence
with per-frame and temporal metrics (:mod:`mcdenoise.eval.temporal_metrics`), the warm-up frames
reported apart.

For every output the noisy input it was made from is found from its ``mcdenoise:source``
header attribute when that file exists, else among ``inputs`` (the input whose stem is the
longest prefix of the output's stem); the noisy input is evaluated too, as a row of method
``"noisy"``, so every report shows what a method bought (``relmse_ratio``). A file given as an
output that has no ``mcdenoise:method`` attribute and is the noisy input of another output is
treated as that noisy input. Colour is the ``color`` buffer of :func:`mcdenoise.io.load_buffers`:
linear HDR RGB.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise import __version__
from mcdenoise.errors import InputError
from mcdenoise.eval.metrics import ArrayLike, as_image, check_same_shape, compute_metrics
from mcdenoise.eval.metrics import resolve_metrics as _resolve_metrics
from mcdenoise.eval.preview import choose_crop, crop, overview
from mcdenoise.eval.results import (
    ROLE_NOISY,
    ROLE_OUTPUT,
    EvalRecord,
    EvalResult,
    ScenePreview,
)
from mcdenoise.eval.temporal_metrics import (
    is_temporal,
)
from mcdenoise.eval.tonemap import auto_exposure
from mcdenoise.io.atomic import TMP_PREFIX

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
_FRAME_STEM = re.compile(r"^frame_(\d+)$")


# --- file discovery and matching ----------------------------------------------------------


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
        from mcdenoise.io.exr_messages import special_file_kind

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


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _file_id(p: Path) -> tuple[int, int] | None:
    """``(device, inode)`` of the file ``p`` (symlinks followed; what ``os.path.samefile``
    compares), ``None`` if it cannot be read."""
    try:
        st = os.stat(p)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _key(p: Path, part: str | None = None, profile: str | None = None) -> str:
    """Identity of an image: the resolved file, plus ``#part`` for one part of a multi-part
    file (a data set written by ``mcdenoise render`` keeps every spp level in one file), plus
    `` [profile]`` for an image a profile picks inside it (a Cycles view layer)."""
    return str(p.resolve()) + (f"#{part}" if part else "") + (f" [{profile}]" if profile else "")


def _cycles_layer(profile: str | None) -> str | None:
    """The view layer of a recorded ``cycles:<Layer>`` profile, else ``None``."""
    if profile and profile.startswith("cycles:") and len(profile) > len("cycles:"):
        return profile[len("cycles:") :]
    return None


# --- metadata -----------------------------------------------------------------------------


@dataclass
class _Meta:
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


def _as_int(v: Any) -> int | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return int(f) if np.isfinite(f) and f == int(f) and f > 0 else None


def _as_float(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


def _meta(
    path: Path,
    attributes: Mapping[str, Any],
    spp: int | None,
    part: str | None = None,
    profile: str | None = None,
) -> _Meta:
    attrs = dict(attributes)
    params = attrs.get(ATTR_PARAMS)
    if params is not None and not isinstance(params, str):
        params = json.dumps(params, sort_keys=True, default=str)
    method = attrs.get(ATTR_METHOD)
    source = attrs.get(ATTR_SOURCE)
    source_part = attrs.get(ATTR_SOURCE_PART)
    source_profile = attrs.get(ATTR_SOURCE_PROFILE)
    device = attrs.get(ATTR_DEVICE)
    spp_value = _as_int(attrs.get(ATTR_SPP)) or _as_int(spp)
    if spp_value is None:
        m = _SPP_IN_NAME.search(path.stem)
        spp_value = int(m.group(1)) if m else None
    return _Meta(
        path=path,
        part=part,
        profile=profile,
        method=str(method) if method not in (None, "") else None,
        source=str(source) if source not in (None, "") else None,
        source_part=str(source_part) if source_part not in (None, "") else None,
        source_profile=str(source_profile) if source_profile not in (None, "") else None,
        seconds=_as_float(attrs.get(ATTR_SECONDS)),
        device=str(device) if device not in (None, "") else None,
        params=params,
        spp=spp_value,
        identity={k: str(attrs[k]) for k in _IDENTITY if attrs.get(k) not in (None, "")},
    )


def _probe(path: Path, part: str | None = None, profile: str | None = None) -> _Meta:
    """Header metadata of one EXR (the first part, or the part named ``part``), without
    reading pixels; ``profile``: the profile it is to be read with (kept in the metadata)."""
    from mcdenoise.io.exr import probe_exr, select_part
    from mcdenoise.io.profiles.cycles import BLENDER_ATTR

    parts = probe_exr(path)
    # a Blender file's `part` may name a view layer; its attributes are in part 0 only
    if part is None or BLENDER_ATTR in parts[0].attributes:
        header = parts[0]
    else:
        header = select_part(parts, part, str(path))
    return _meta(path, header.attributes, None, part, profile)


def _load(
    path: Path, part: str | None = None, profile: str | None = None
) -> tuple[np.ndarray, _Meta]:
    """Colour ``(3, H, W)`` float32 linear HDR RGB and metadata of one EXR (or one part), read
    with ``profile`` (default: auto-detected)."""
    from mcdenoise.io import load_buffers

    buf = load_buffers(path, part=part, profile=profile or "auto")
    color = buf["color"].detach().cpu().numpy()
    return color, _meta(path, buf.attributes, buf.spp, part, profile)


def _reference_layers(path: Path) -> list[str]:
    """The Blender view layers of a reference file (none for any other layout)."""
    from mcdenoise.io.exr import probe_exr
    from mcdenoise.io.profiles.cycles import cycles_layers

    return list(cycles_layers([c for p in probe_exr(path) for c in p.channel_names]))


# --- does an output show the reference's scene? --------------------------------------------


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
    return not _conflicts(reference, source)


def _conflicts(reference: Mapping[str, str], source: Mapping[str, str]) -> list[str]:
    """The identity attributes both headers record with different values."""
    return [k for k in _IDENTITY if k in reference and k in source and reference[k] != source[k]]


def _source_identity(meta: _Meta, depth: int = 4) -> dict[str, str]:
    """Scene attributes of the file ``meta``'s output was made from: the output's own
    attributes when it records a scene (``mcdenoise denoise`` copies them), else its source's
    header (followed through a chain of outputs), else what the output itself records
    (often nothing)."""
    if ATTR_SCENE in meta.identity:
        return meta.identity
    src = _source_path(meta)
    if src is not None and depth > 0:
        try:
            upstream = _probe(src, meta.source_part)
        except (InputError, OSError):
            upstream = None
        if upstream is not None:
            if ATTR_SCENE in upstream.identity or upstream.source is None:
                return upstream.identity
            return _source_identity(upstream, depth - 1)
    return meta.identity


def _source_path(meta: _Meta) -> Path | None:
    """The file of ``meta``'s ``mcdenoise:source`` (relative: to the output), if it exists."""
    if meta.source is None:
        return None
    src = Path(meta.source)
    if not src.is_absolute() and not src.is_file():
        src = meta.path.parent / src
    return src if src.is_file() else None


def _describe_scene(identity: Mapping[str, str], keys: Sequence[str]) -> str:
    """``scene 'cornell'``, ``scene 'a', image 'a_2'``: the attributes ``keys`` of ``identity``."""
    shown = [ATTR_SCENE, *keys] if ATTR_SCENE in identity else list(keys)
    return ", ".join(
        f"{k.split(':')[-1]} {identity[k]!r}" for k in dict.fromkeys(shown) if k in identity
    )


# --- the engine ---------------------------------------------------------------------------


@dataclass
class _Job:
    """One image to evaluate: its record (metadata filled in) and how to get its pixels."""

    record: EvalRecord
    load: Callable[[], np.ndarray]
    input_key: str | None = None  # record.file of its noisy input row, if any
    extra_notes: list[str] = field(default_factory=list)


def _evaluate_scene(
    result: EvalResult,
    scene: str,
    reference_name: str,
    reference: np.ndarray,
    jobs: Sequence[_Job],
    progress: Callable[[], None] | None = None,
) -> None:
    """Compute metrics and preview crops of ``jobs`` against one reference; append records."""
    ref = as_image(reference, reference_name)
    preview = _preview(ref)
    result.references[scene] = reference_name
    result.previews[scene] = preview
    records: dict[str, EvalRecord] = {}
    for job in jobs:
        rec = job.record
        image = as_image(job.load(), rec.file)
        check_same_shape(image, ref, output_name=rec.file, reference_name=reference_name)
        values = compute_metrics(
            image, ref, result.metrics, output_name=rec.file, reference_name=reference_name
        )
        rec.metrics = values.values
        rec.unavailable = values.unavailable
        rec.failed = values.failed
        rec.reason = values.reason
        rec.bad_pixels = values.bad_pixels
        rec.notes.extend(job.extra_notes)
        preview.images[rec.file] = crop(image, preview.window)
        records[rec.file] = rec
        result.records.append(rec)
        if progress is not None:
            progress()
    for job in jobs:
        rec = job.record
        noisy = records.get(job.input_key) if job.input_key else None
        if rec.role == ROLE_NOISY:
            noisy = rec
        rec.relmse_ratio = _ratio(rec, noisy)


def _preview(ref: np.ndarray) -> ScenePreview:
    """The preview of a scene: its crop window, exposure and overview, from the reference."""
    exposure = auto_exposure(ref)
    window = choose_crop(ref, exposure)
    full = (ref.shape[1], ref.shape[2])
    preview = ScenePreview(
        window=window, full_shape=full, exposure=exposure, reference=crop(ref, window)
    )
    if window != (0, 0, *full):
        preview.overview, preview.overview_factor = overview(ref)
    return preview


def _ratio(rec: EvalRecord, noisy: EvalRecord | None) -> float | None:
    if noisy is None or rec.failed or noisy.failed:
        return None
    a, b = rec.metrics.get("relmse"), noisy.metrics.get("relmse")
    if a is None or b is None or b <= 0:
        return None
    return float(a) / float(b)


def _new_result(metrics: Sequence[str] | None) -> EvalResult:
    temporal = [m for m in metrics or () if is_temporal(str(m).strip().lower())]
    if temporal:
        raise InputError(
            f"metric {temporal[0]!r} is temporal: it needs sequences (a reference folder of "
            "frame_0000.exr, frame_0001.exr, ...)"
        )
    return EvalResult(
        metrics=_resolve_metrics(metrics),
        version=__version__,
        created=_dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds"),
    )


# --- arrays -------------------------------------------------------------------------------


def evaluate_arrays(
    reference: ArrayLike,
    outputs: Mapping[str, ArrayLike],
    *,
    noisy: ArrayLike | None = None,
    scene: str = "scene",
    metrics: Sequence[str] | None = None,
    info: Mapping[str, Mapping[str, Any]] | None = None,
) -> EvalResult:
    """Evaluate in-memory images of one scene; the array counterpart of :func:`evaluate`.

    Args:
        reference: ``(3, H, W)`` linear HDR RGB reference (numpy or torch).
        outputs: label -> ``(3, H, W)`` linear HDR RGB output; the label is the record's
            ``file`` and, unless ``info`` says otherwise, its method.
        noisy: the noisy input all outputs were made from; evaluated as the row ``"noisy"``.
        scene: scene name of every record.
        metrics: metric names (default: all registered).
        info: optional label -> ``{"method", "spp", "seconds", "device", "params"}``; the
            label ``"noisy"`` describes the noisy input.

    Raises:
        InputError: an image is not ``(3, H, W)``, differs in size from the reference, or a
            metric name is unknown.
    """
    result = _new_result(metrics)
    info = info or {}
    jobs: list[_Job] = []
    if noisy is not None:
        meta = dict(info.get("noisy", {}))
        rec = EvalRecord(
            scene=scene,
            file="noisy",
            role=ROLE_NOISY,
            method="noisy",
            spp=_as_int(meta.get("spp")),
        )
        jobs.append(_Job(rec, lambda: noisy))
    for label, array in outputs.items():
        meta = dict(info.get(label, {}))
        rec = EvalRecord(
            scene=scene,
            file=str(label),
            method=str(meta.get("method", label)),
            input="noisy" if noisy is not None else None,
            spp=_as_int(meta.get("spp")) or _as_int(info.get("noisy", {}).get("spp")),
            seconds=_as_float(meta.get("seconds")),
            device=meta.get("device"),
            params=None if meta.get("params") is None else str(meta.get("params")),
        )
        jobs.append(_Job(rec, lambda a=array: a, input_key="noisy" if noisy is not None else None))
    _evaluate_scene(result, scene, "reference", as_image(reference, "reference"), jobs)
    return result


# --- files --------------------------------------------------------------------------------


@dataclass
class _Planned:
    """An output file, its scene, and the noisy input it was made from."""

    meta: _Meta
    scene: str  # the reference's scene, `:<Layer>` added for a view layer of it
    key: str = ""  # _key of the output file
    input: Path | None = None
    input_part: str | None = None  # the part of ``input`` the output was made from
    input_profile: str | None = None  # the profile ``input`` was read with (a view layer)
    notes: list[str] = field(default_factory=list)
    input_key: str | None = None  # _key of the noisy input image (set with the input)
    input_file_key: str | None = None  # _key of its file, every part

    def set_input(self, path: Path, part: str | None = None) -> None:
        """The noisy input, and its keys (each path is resolved once, not at every lookup)."""
        self.input, self.input_part = path, part
        resolved = str(path.resolve())
        self.input_file_key = resolved + (f"#{part}" if part else "")
        self.input_key = self.input_file_key + (
            f" [{self.input_profile}]" if self.input_profile else ""
        )


@dataclass
class FilePlan:
    """What :func:`plan_files` matched: every output with its scene and noisy input, and
    every noisy input with its scene; keys are :func:`_key` of the image.

    Attributes:
        refs: scene (reference stem) -> reference file.
        given: every output file given, with its header metadata.
        planned: the outputs to evaluate (``given`` less the files that are noisy inputs).
        noisy_files: noisy input key -> (file, part, profile).
        noisy_meta: noisy input key -> its header metadata.
        noisy_scene: noisy input key -> its scene.
        scene_refs: scene -> (reference file, Blender view layer or ``None``).
    """

    refs: dict[str, Path]
    given: dict[str, _Meta]
    planned: dict[str, _Planned]
    noisy_files: dict[str, tuple[Path, str | None, str | None]]
    noisy_meta: dict[str, _Meta]
    noisy_scene: dict[str, str]
    scene_refs: dict[str, tuple[Path, str | None]]


def plan_files(
    reference: PathLike,
    outputs: Sequence[PathLike],
    *,
    inputs: Sequence[PathLike] | None = None,
    force: bool = False,
    warn: Callable[[str], None] | None = None,
) -> FilePlan:
    """Match outputs to references and noisy inputs (reading headers only, no pixels): the
    first half of :func:`evaluate_files`, whose docstring gives the rules and the errors.

    Linear in the number of files: every file is stat-ed, resolved and probed a bounded
    number of times, and names are matched through :class:`PrefixMatcher` (3000 outputs
    against 3000 references: ``benchmarks/bench_eval_matching.py``).
    """
    refs = _references(reference)
    single = Path(reference).is_file()
    ref_ids = {i for i in map(_file_id, refs.values()) if i is not None}
    ref_match = PrefixMatcher(refs)

    # 1. every given output, deduplicated, with its header metadata (pixels are read later)
    given: dict[str, _Meta] = {}
    for arg in outputs:
        from_folder = Path(arg).is_dir()
        for f in scan_exr(arg, what="output"):
            if _file_id(f) in ref_ids:
                if from_folder:
                    continue
                raise InputError(f"output {f} is the reference itself")
            key = _key(f)
            if key not in given:
                given[key] = _probe(f)
    if not given:
        raise InputError("no output to evaluate (only references were given)")
    noisy_given: dict[str, Path] = {}
    for arg in inputs or ():
        for f in scan_exr(arg, what="noisy input"):
            noisy_given[_key(f)] = f

    def scene_of(p: Path, what: str) -> str:
        if single:
            return next(iter(refs))
        hit = ref_match(p.stem)
        if hit is None:
            raise InputError(
                f"{what} {p} matches no reference in {reference} "
                f"(references: {', '.join(sorted(refs))})"
            )
        return hit

    # 2. find each output's noisy input; check that it shows the reference's scene
    planned: dict[str, _Planned] = {}
    ref_identity: dict[Path, dict[str, str]] = {}
    ref_layers: dict[Path, list[str]] = {}
    scene_refs: dict[str, tuple[Path, str | None]] = {s: (p, None) for s, p in refs.items()}
    by_stem = {p.stem: p for p in noisy_given.values()}
    noisy_match = PrefixMatcher(by_stem)
    for key, meta in given.items():
        base = scene_of(meta.path, "output")
        plan = _Planned(meta=meta, scene=base, key=key, input_profile=meta.source_profile)
        layer = _cycles_layer(meta.source_profile)
        if layer is not None:  # made from one view layer: the reference's layer of that name
            ref = refs[base]
            if ref not in ref_layers:
                ref_layers[ref] = _reference_layers(ref)
            if ref_layers[ref] and layer not in ref_layers[ref]:
                raise InputError(
                    f"reference {ref} has no Cycles view layer {layer!r} (output {meta.path} "
                    f"was made from that layer); its layers: "
                    f"{', '.join(map(repr, ref_layers[ref]))}"
                )
            if ref_layers[ref]:  # a reference without view layers is one image: as given
                plan.scene = f"{base}:{layer}"
                scene_refs[plan.scene] = (ref, layer)
        if meta.source is not None:
            src = _source_path(meta)  # a relative source: relative to the output
            if src is not None:
                plan.set_input(src, meta.source_part)
            else:
                plan.notes.append(f"noisy input {meta.source} ({ATTR_SOURCE}) not found")
            problem = _scene_mismatch(meta, refs[base], ref_identity)
            if problem is not None:
                if not force:
                    raise InputError(f"{problem}; give the reference of that scene, or --force")
                plan.notes.append(problem)
                (warn or _warn)(f"{problem} (evaluated anyway: --force)")
        if plan.input is None and noisy_given:
            hit = noisy_match(meta.path.stem)
            if hit is not None and _key(by_stem[hit]) != key:
                plan.set_input(by_stem[hit])
        planned[key] = plan

    # 3. a given file without a method attribute that is another output's input is a noisy row
    # (read as that output's source was: with its recorded profile, a view layer)
    sources = {p.input_key for p in planned.values() if p.input is not None}
    source_files = {p.input_file_key for p in planned.values() if p.input is not None}
    for key in list(planned):
        if planned[key].meta.method is None and (key in source_files or key in noisy_given):
            path = planned.pop(key).meta.path
            if key in sources or key in noisy_given:
                noisy_given.setdefault(key, path)
    # (an input that is itself an evaluated output, e.g. a denoiser chain, gets no noisy row;
    # a given input that every output read with a profile gets only those rows)
    noisy_files: dict[str, tuple[Path, str | None, str | None]] = {
        k: (p, None, None)
        for k, p in noisy_given.items()
        if k not in planned and (k in sources or k not in source_files)
    }
    for plan in planned.values():
        if plan.input is not None and plan.input_key not in planned:
            assert plan.input_key is not None
            noisy_files.setdefault(
                plan.input_key, (plan.input, plan.input_part, plan.input_profile)
            )

    # 4. noisy inputs: metadata and scene (the scene of the first output made from each)
    first_user: dict[str, str] = {}
    for plan in planned.values():
        if plan.input_key is not None:
            first_user.setdefault(plan.input_key, plan.scene)
    noisy_meta: dict[str, _Meta] = {}
    noisy_scene: dict[str, str] = {}
    for key, (path, part, profile) in noisy_files.items():
        noisy_meta[key] = given[key] if key in given else _probe(path, part, profile)
        user = first_user.get(key)
        noisy_scene[key] = user if user is not None else scene_of(path, "noisy input")
    return FilePlan(refs, given, planned, noisy_files, noisy_meta, noisy_scene, scene_refs)


def evaluate_files(
    reference: PathLike,
    outputs: Sequence[PathLike],
    *,
    inputs: Sequence[PathLike] | None = None,
    metrics: Sequence[str] | None = None,
    progress: bool | str = False,
    force: bool = False,
    warn: Callable[[str], None] | None = None,
) -> EvalResult:
    """Evaluate denoised EXR files (and their noisy inputs) against reference EXR(s): stills.

    :func:`mcdenoise.eval.run.evaluate` (``mcdenoise.eval.evaluate``) calls this for stills
    and :func:`mcdenoise.eval.evaluate_sequences.evaluate_sequences` for a reference folder of frames.

    An output whose recorded source (``mcdenoise:source``) records another scene than its
    reference does (see :func:`same_scene`) is refused, naming both; with ``force`` it is
    evaluated and ``warn`` (default: ``warnings.warn``) gets the message, which is also noted
    in the record. Where either side records no scene (no recorded source, files without
    ``mcdenoise:scene`` headers) the pairing the caller gave stands. An output made from one
    view layer of a Blender Cycles file (``mcdenoise:source_profile = "cycles:<Layer>"``) is
    compared with that layer of a multilayer reference (scene ``<ref>:<Layer>``), and its
    noisy row is that layer of its source; a reference without view layers is taken as given.
    The matching is :func:`plan_files`.

    Args:
        reference: a reference EXR, or a folder of reference EXRs (matched to each output by
            the longest stem prefix, see :func:`match_prefix`; the scene is the reference stem).
        outputs: denoised EXR files and/or folders of them (``*.exr``, not recursive).
        inputs: noisy input EXR files/folders, used for outputs whose ``mcdenoise:source`` is
            absent or missing on disk (matched by longest stem prefix); each is evaluated as a
            ``"noisy"`` row of the scene it matches.
        metrics: metric names (default: every registered metric; FLIP is reported as
            unavailable, with the reason, when ``flip_evaluator`` is not installed).
        progress: report progress on stderr (:func:`mcdenoise.progress.progress_bar`).
        force: evaluate outputs whose source shows another scene than the reference (warn).
        warn: receives the warning lines of ``force``.

    Returns:
        An :class:`~mcdenoise.eval.results.EvalResult` with one record per evaluated image.

    Raises:
        InputError: a path does not exist, an output matches no reference (the message names
            it), an output is a reference, a multilayer reference lacks an output's view
            layer (the message names it and the reference's layers), an output's source
            records another scene (without ``force``), or an image differs in size from its reference (the message
            names both files and sizes).
        mcdenoise.errors.ExrError: an EXR cannot be read.
    """
    result = _new_result(metrics)
    plan = plan_files(reference, outputs, inputs=inputs, force=force, warn=warn)
    given, planned, noisy_meta = plan.given, plan.planned, plan.noisy_meta

    # 5. jobs per scene: each noisy input (by spp, name) followed by its outputs, then the rest
    noisy_by_scene: dict[str, list[str]] = {}
    for key, scene in plan.noisy_scene.items():
        noisy_by_scene.setdefault(scene, []).append(key)
    outputs_by_scene: dict[str, list[_Planned]] = {}
    for p in planned.values():
        outputs_by_scene.setdefault(p.scene, []).append(p)
    total = len(plan.noisy_files) + len(planned)
    from mcdenoise.progress import progress_bar

    bar = progress_bar(total=total, desc="eval", unit="image", progress=progress)
    try:
        for scene in sorted({*noisy_by_scene, *outputs_by_scene}):
            jobs: list[_Job] = []
            scene_noisy = sorted(
                noisy_by_scene.get(scene, ()), key=lambda k: (noisy_meta[k].spp or 0, k)
            )
            scene_outputs = sorted(outputs_by_scene.get(scene, ()), key=lambda p: str(p.meta.path))
            by_input: dict[str, list[_Planned]] = {}
            for p in scene_outputs:
                if p.input_key is not None:
                    by_input.setdefault(p.input_key, []).append(p)
            placed: set[str] = set()
            for nkey in scene_noisy:
                jobs.append(_file_job(noisy_meta[nkey], scene, ROLE_NOISY, "noisy", None))
                for p in by_input.get(nkey, ()):
                    jobs.append(_output_job(p, noisy_meta[nkey]))
                    placed.add(p.key)
            for p in scene_outputs:
                if p.key not in placed:
                    upstream = given.get(p.input_key) if p.input_key else None
                    jobs.append(_output_job(p, upstream))
            ref_path, layer = plan.scene_refs[scene]
            ref_color = _load(ref_path, None, f"cycles:{layer}" if layer else None)[0]
            _evaluate_scene(
                result,
                scene,
                str(ref_path),
                ref_color,
                jobs,
                progress=bar.update,
            )
    finally:
        bar.close()
    return result


def _scene_mismatch(meta: _Meta, ref: Path, ref_ids: dict[Path, dict[str, str]]) -> str | None:
    """Why ``meta``'s output cannot show the scene of reference ``ref`` (a scene, image or
    frame that both headers record differently, see :func:`same_scene`), or ``None``."""
    if ref not in ref_ids:
        ref_ids[ref] = _probe(ref).identity
    identity = _source_identity(meta)
    keys = _conflicts(ref_ids[ref], identity)
    if not keys:
        return None
    return (
        f"output {meta.path} was made from {meta.source} "
        f"({_describe_scene(identity, keys)}) but the reference {ref} shows "
        f"{_describe_scene(ref_ids[ref], keys)}"
    )


def _warn(message: str) -> None:
    import warnings

    warnings.warn(message, stacklevel=3)


def _references(reference: PathLike) -> dict[str, Path]:
    """Scene (stem) -> reference file."""
    files = scan_exr(reference, what="reference")
    refs: dict[str, Path] = {}
    for f in files:
        if f.stem in refs:
            raise InputError(f"two references for scene {f.stem!r}: {refs[f.stem]} and {f}")
        refs[f.stem] = f
    return refs


def _label(meta: _Meta) -> str:
    """How an image is named in records: its file, plus ``#part`` for one part of a file,
    plus `` [profile]`` for an image a profile picks in it (``noisy.exr [cycles:Layer2]``)."""
    return (
        str(meta.path)
        + (f"#{meta.part}" if meta.part else "")
        + (f" [{meta.profile}]" if meta.profile else "")
    )


def _file_job(meta: _Meta, scene: str, role: str, method: str, upstream: _Meta | None) -> _Job:
    rec = EvalRecord(
        scene=scene,
        file=_label(meta),
        role=role,
        method=method,
        input=None if upstream is None else _label(upstream),
        spp=meta.spp,
        seconds=meta.seconds if role == ROLE_OUTPUT else None,
        device=meta.device if role == ROLE_OUTPUT else None,
        params=meta.params if role == ROLE_OUTPUT else None,
    )
    path, part, profile = meta.path, meta.part, meta.profile

    def load() -> np.ndarray:
        color, loaded = _load(path, part, profile)
        if rec.spp is None:
            rec.spp = loaded.spp
        return color

    return _Job(rec, load)


def _output_job(plan: _Planned, noisy: _Meta | None) -> _Job:
    meta = plan.meta
    method = meta.method or _method_from_name(meta.path.stem, noisy, plan.scene)
    job = _file_job(meta, plan.scene, ROLE_OUTPUT, method, noisy)
    if job.record.spp is None and noisy is not None:
        job.record.spp = noisy.spp
    job.input_key = None if noisy is None else _label(noisy)
    job.extra_notes = list(plan.notes)
    return job


def _method_from_name(stem: str, noisy: _Meta | None, scene: str) -> str:
    """Method of an output without ``mcdenoise:method``: its stem after the input's/scene's."""
    for prefix in (noisy.path.stem if noisy is not None else None, scene):
        if prefix and stem.startswith(prefix) and len(stem) > len(prefix):
            rest = stem[len(prefix) :].lstrip("_-.")
            if rest:
                return rest
    return stem
