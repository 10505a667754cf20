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

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.eval.images import ArrayLike, as_image, check_same_shape
from mcdenoise.eval.matching import (
    ATTR_SOURCE,
    Meta,
    PathLike,
    PrefixMatcher,
    cycles_layer,
    file_id,
    image_key,
    image_label,
    load_color,
    probe,
    reference_layers,
    references,
    scan_exr,
    scene_mismatch,
    source_path,
)
from mcdenoise.eval.metrics import compute_metrics
from mcdenoise.eval.metrics import resolve_metrics as _resolve_metrics
from mcdenoise.eval.preview import crop
from mcdenoise.eval.results import ROLE_NOISY, ROLE_OUTPUT, EvalRecord, EvalResult
from mcdenoise.eval.steps import (
    DEFAULT_OPTIONS,
    EvalOptions,
    array_records,
    check_scene,
    fill_record,
    new_result,
    noisy_then_outputs,
    scene_preview,
    set_ratios,
)
from mcdenoise.eval.temporal_metrics import is_temporal
from mcdenoise.progress import progress_bar

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
    preview = scene_preview(ref)
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
        fill_record(rec, values)
        rec.notes.extend(job.extra_notes)
        preview.images[rec.file] = crop(image, preview.window)
        records[rec.file] = rec
        result.records.append(rec)
        if progress is not None:
            progress()
    set_ratios(jobs, records)


def _new_result(metrics: Sequence[str] | None) -> EvalResult:
    temporal = [m for m in metrics or () if is_temporal(str(m).strip().lower())]
    if temporal:
        raise InputError(
            f"metric {temporal[0]!r} is temporal: it needs sequences (a reference folder of "
            "frame_0000.exr, frame_0001.exr, ...)"
        )
    return new_result(_resolve_metrics(metrics))


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
    records = array_records(scene, outputs, info or {}, noisy=noisy is not None)
    jobs: list[_Job] = []
    if noisy is not None:
        jobs.append(_Job(next(records), lambda: noisy))
    for rec, array in zip(records, outputs.values()):
        jobs.append(_Job(rec, lambda a=array: a, input_key="noisy" if noisy is not None else None))
    _evaluate_scene(result, scene, "reference", as_image(reference, "reference"), jobs)
    return result


# --- files --------------------------------------------------------------------------------


@dataclass
class _Planned:
    """An output file, its scene, and the noisy input it was made from."""

    meta: Meta
    scene: str  # the reference's scene, `:<Layer>` added for a view layer of it
    key: str = ""  # image_key of the output file
    input: Path | None = None
    input_part: str | None = None  # the part of ``input`` the output was made from
    input_profile: str | None = None  # the profile ``input`` was read with (a view layer)
    notes: list[str] = field(default_factory=list)
    input_key: str | None = None  # image_key of the noisy input image (set with the input)
    input_file_key: str | None = None  # image_key of its file, every part

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
    every noisy input with its scene; keys are :func:`image_key` of the image.

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
    given: dict[str, Meta]
    planned: dict[str, _Planned]
    noisy_files: dict[str, tuple[Path, str | None, str | None]]
    noisy_meta: dict[str, Meta]
    noisy_scene: dict[str, str]
    scene_refs: dict[str, tuple[Path, str | None]]


def plan_files(
    reference: PathLike, outputs: Sequence[PathLike], options: EvalOptions = DEFAULT_OPTIONS
) -> FilePlan:
    """Match outputs to references and noisy inputs (reading headers only, no pixels): the
    first half of :func:`evaluate_files`, whose docstring gives the rules and the errors.

    Linear in the number of files: every file is stat-ed, resolved and probed a bounded
    number of times, and names are matched through :class:`PrefixMatcher` (3000 outputs
    against 3000 references: ``benchmarks/bench_eval_matching.py``).
    """
    refs = references(reference)
    single = Path(reference).is_file()
    ref_ids = {i for i in map(file_id, refs.values()) if i is not None}
    ref_match = PrefixMatcher(refs)

    # 1. every given output, deduplicated, with its header metadata (pixels are read later)
    given: dict[str, Meta] = {}
    for arg in outputs:
        from_folder = Path(arg).is_dir()
        for f in scan_exr(arg, what="output"):
            if file_id(f) in ref_ids:
                if from_folder:
                    continue
                raise InputError(f"output {f} is the reference itself")
            key = image_key(f)
            if key not in given:
                given[key] = probe(f)
    if not given:
        raise InputError("no output to evaluate (only references were given)")
    noisy_given: dict[str, Path] = {}
    for arg in options.inputs or ():
        for f in scan_exr(arg, what="noisy input"):
            noisy_given[image_key(f)] = f

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
        layer = cycles_layer(meta.source_profile)
        if layer is not None:  # made from one view layer: the reference's layer of that name
            ref = refs[base]
            if ref not in ref_layers:
                ref_layers[ref] = reference_layers(ref)
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
            src = source_path(meta)  # a relative source: relative to the output
            if src is not None:
                plan.set_input(src, meta.source_part)
            else:
                plan.notes.append(f"noisy input {meta.source} ({ATTR_SOURCE}) not found")
            check_scene(
                scene_mismatch(meta, refs[base], ref_identity), options, plan.notes, "scene"
            )
        if plan.input is None and noisy_given:
            hit = noisy_match(meta.path.stem)
            if hit is not None and image_key(by_stem[hit]) != key:
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
    noisy_meta: dict[str, Meta] = {}
    noisy_scene: dict[str, str] = {}
    for key, (path, part, profile) in noisy_files.items():
        noisy_meta[key] = given[key] if key in given else probe(path, part, profile)
        user = first_user.get(key)
        noisy_scene[key] = user if user is not None else scene_of(path, "noisy input")
    return FilePlan(refs, given, planned, noisy_files, noisy_meta, noisy_scene, scene_refs)


def evaluate_files(
    reference: PathLike, outputs: Sequence[PathLike], options: EvalOptions = DEFAULT_OPTIONS
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
        options: noisy inputs, metrics, progress, ``force`` (:class:`EvalOptions`; ``warmup``
            is for sequences only).

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
    result = _new_result(options.metrics)
    plan = plan_files(reference, outputs, options)
    given, planned, noisy_meta = plan.given, plan.planned, plan.noisy_meta

    # 5. jobs per scene: each noisy input (by spp, name) followed by its outputs, then the rest
    noisy_by_scene: dict[str, list[str]] = {}
    for key, scene in plan.noisy_scene.items():
        noisy_by_scene.setdefault(scene, []).append(key)
    outputs_by_scene: dict[str, list[_Planned]] = {}
    for p in planned.values():
        outputs_by_scene.setdefault(p.scene, []).append(p)
    total = len(plan.noisy_files) + len(planned)
    bar = progress_bar(total=total, desc="eval", unit="image", progress=options.progress)
    try:
        for scene in sorted({*noisy_by_scene, *outputs_by_scene}):
            scene_noisy = sorted(
                noisy_by_scene.get(scene, ()), key=lambda k: (noisy_meta[k].spp or 0, k)
            )
            scene_outputs = sorted(outputs_by_scene.get(scene, ()), key=lambda p: str(p.meta.path))
            jobs: list[_Job] = []
            for nkey, p in noisy_then_outputs(scene_noisy, scene_outputs, lambda p: p.input_key):
                if p is None:
                    assert nkey is not None
                    jobs.append(_file_job(noisy_meta[nkey], scene, ROLE_NOISY, "noisy", None))
                elif nkey is not None:
                    jobs.append(_output_job(p, noisy_meta[nkey]))
                else:
                    upstream = given.get(p.input_key) if p.input_key else None
                    jobs.append(_output_job(p, upstream))
            ref_path, layer = plan.scene_refs[scene]
            ref_color = load_color(ref_path, None, f"cycles:{layer}" if layer else None)[0]
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


def _file_job(meta: Meta, scene: str, role: str, method: str, upstream: Meta | None) -> _Job:
    rec = EvalRecord(
        scene=scene,
        file=image_label(meta),
        role=role,
        method=method,
        input=None if upstream is None else image_label(upstream),
        spp=meta.spp,
        seconds=meta.seconds if role == ROLE_OUTPUT else None,
        device=meta.device if role == ROLE_OUTPUT else None,
        params=meta.params if role == ROLE_OUTPUT else None,
    )
    path, part, profile = meta.path, meta.part, meta.profile

    def load() -> np.ndarray:
        color, loaded = load_color(path, part, profile)
        if rec.spp is None:
            rec.spp = loaded.spp
        return color

    return _Job(rec, load)


def _output_job(plan: _Planned, noisy: Meta | None) -> _Job:
    meta = plan.meta
    method = meta.method or _method_from_name(meta.path.stem, noisy, plan.scene)
    job = _file_job(meta, plan.scene, ROLE_OUTPUT, method, noisy)
    if job.record.spp is None and noisy is not None:
        job.record.spp = noisy.spp
    job.input_key = None if noisy is None else image_label(noisy)
    job.extra_notes = list(plan.notes)
    return job


def _method_from_name(stem: str, noisy: Meta | None, scene: str) -> str:
    """Method of an output without ``mcdenoise:method``: its stem after the input's/scene's."""
    for prefix in (noisy.path.stem if noisy is not None else None, scene):
        if prefix and stem.startswith(prefix) and len(stem) > len(prefix):
            rest = stem[len(prefix) :].lstrip("_-.")
            if rest:
                return rest
    return stem
