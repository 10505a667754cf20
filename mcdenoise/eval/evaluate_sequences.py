"""Evaluate sequences: folders of frames against a reference folder of frames.

:func:`~mcdenoise.eval.run.evaluate` hands over to :func:`evaluate_sequences` when the
reference is a folder of ``frame_0000.exr``, ``frame_0001.exr``, ... (the layout of
``mcdenoise render --frames``: ``DIR/<id>/ref/``): every output is a folder of frames
(``mcdenoise denoise SEQ_DIR -o OUT``), matched to the reference frames by name, and evaluated
as one sequence with per-frame and temporal metrics (:mod:`mcdenoise.eval.temporal_metrics`), the
warm-up frames reported apart. :func:`evaluate_sequence_arrays` is its in-memory counterpart.
File matching, header probing and the scene check are shared with
:mod:`mcdenoise.eval.evaluate`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.eval.images import ArrayLike, as_image
from mcdenoise.eval.matching import (
    ATTR_SOURCE,
    FRAME_STEM,
    Meta,
    PathLike,
    PrefixMatcher,
    as_float,
    image_key,
    load_color,
    probe,
    same_file,
    scan_exr,
    scene_mismatch,
    source_path,
)
from mcdenoise.eval.preview import crop
from mcdenoise.eval.results import (
    ROLE_NOISY,
    ROLE_OUTPUT,
    EvalRecord,
    EvalResult,
    FrameRecord,
    ScenePreview,
    SequenceDetail,
)
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
from mcdenoise.eval.temporal_metrics import (
    WARMUP_FRAMES,
    SequenceEvaluator,
    _frames,
    resolve_sequence_metrics,
)
from mcdenoise.io.atomic import TMP_PREFIX
from mcdenoise.io.exr import probe_exr
from mcdenoise.progress import progress_bar


def sequence_frames(folder: PathLike) -> list[Path] | None:
    """The frame files of a sequence folder in frame order, or ``None`` when ``folder`` is
    not a sequence.

    A sequence folder holds at least one EXR and only EXRs named ``frame_<number>.exr``
    (``frame_0000.exr``, as ``mcdenoise render --frames`` and ``mcdenoise denoise SEQ_DIR``
    write them; unfinished ``.mcdenoise-tmp-*`` files are skipped). Any other EXR name makes
    it a folder of stills.

    Raises:
        InputError: the numbering has a gap (the message names the missing frame) or a
            frame number twice.
    """
    p = Path(folder)
    if not p.is_dir():
        return None
    numbered: list[tuple[int, Path]] = []
    for f in p.iterdir():
        if not f.is_file() or f.suffix.lower() != ".exr" or f.name.startswith(TMP_PREFIX):
            continue
        m = FRAME_STEM.match(f.stem)
        if m is None:
            return None
        numbered.append((int(m.group(1)), f))
    if not numbered:
        return None
    numbered.sort()
    for (a, fa), (b, fb) in itertools.pairwise(numbered):
        if a == b:
            raise InputError(f"sequence {p} has frame {a} twice: {fa.name} and {fb.name}")
        if b != a + 1:
            width = len(fa.stem) - len("frame_")
            gone = f"frame_{a + 1:0{width}d}.exr" + (f" to frame {b - 1}" if b - a > 2 else "")
            raise InputError(
                f"sequence {p} has a gap: {gone} missing between {fa.name} and {fb.name}"
            )
    return [f for _, f in numbered]


@dataclass
class _SeqJob:
    """One sequence to evaluate: its record, its per-frame files and how to read frame t."""

    record: EvalRecord
    files: list[str]  # label of each frame's image
    load: Callable[[int], np.ndarray]
    seconds: list[float | None]
    input_key: str | None = None  # record.file of its noisy row, if any


def _evaluate_sequence(
    result: EvalResult,
    scene: str,
    reference_name: str,
    frame_names: Sequence[str],
    reference_files: Sequence[str],
    load_reference: Callable[[int], np.ndarray],
    jobs: Sequence[_SeqJob],
    warmup: int,
    progress: Callable[[], None] | None = None,
) -> None:
    """Per-frame and temporal metrics of ``jobs`` against one reference sequence, read frame
    by frame in lockstep (each reference frame once; two frames per job in memory); the
    preview shows the last frame. Appends one record per job."""
    evaluators = [
        SequenceEvaluator(result.metrics, warmup=warmup, name=j.record.file) for j in jobs
    ]
    n = len(frame_names)
    preview: ScenePreview | None = None
    first_shape: tuple[int, ...] | None = None
    for t in range(n):
        ref = as_image(load_reference(t), reference_files[t])
        if first_shape is None:
            first_shape = ref.shape
        elif ref.shape != first_shape:
            raise InputError(
                f"reference frame {reference_files[t]} is {ref.shape[2]}x{ref.shape[1]} but "
                f"{reference_files[0]} is {first_shape[2]}x{first_shape[1]}: the frames of a "
                "sequence must have one size"
            )
        if t == n - 1:
            preview = scene_preview(ref)
        for job, ev in zip(jobs, evaluators):
            image = as_image(job.load(t), job.files[t])
            ev.feed(
                image,
                ref,
                frame=frame_names[t],
                output_name=job.files[t],
                reference_name=reference_files[t],
            )
            if preview is not None:
                preview.images[job.record.file] = crop(image, preview.window)
            if progress is not None:
                progress()
    result.references[scene] = reference_name
    if preview is not None:
        result.previews[scene] = preview
    records: dict[str, EvalRecord] = {}
    for job, ev in zip(jobs, evaluators):
        summary, rec = ev.summary(), job.record
        fill_record(rec, summary)
        rec.sequence = SequenceDetail(
            warmup=warmup,
            frames=[
                FrameRecord(
                    frame=f.frame,
                    index=f.index,
                    file=job.files[f.index],
                    warmup=f.warmup,
                    seconds=job.seconds[f.index],
                    metrics=f.values,
                    unavailable=f.unavailable,
                    failed=f.failed,
                    reason=f.reason,
                    bad_pixels=f.bad_pixels,
                )
                for f in summary.frames
            ],
            warmup_metrics=summary.warmup_values,
            warmup_unavailable=summary.warmup_unavailable,
            all_metrics=summary.all_values,
            all_unavailable=summary.all_unavailable,
        )
        if rec.role == ROLE_OUTPUT and job.seconds and all(v is not None for v in job.seconds):
            rec.seconds = float(np.mean([float(v) for v in job.seconds if v is not None]))
        records[rec.file] = rec
        result.records.append(rec)
    set_ratios(jobs, records)


def _check_warmup(warmup: int) -> int:
    if isinstance(warmup, bool) or int(warmup) != warmup or warmup < 0:
        raise InputError(f"warm-up must be a whole number of frames >= 0, got {warmup}")
    return int(warmup)


def _sequence_result(metrics: Sequence[str] | None, warmup: int) -> EvalResult:
    return new_result(resolve_sequence_metrics(metrics), warmup)


def evaluate_sequence_arrays(
    reference: ArrayLike | Sequence[ArrayLike],
    outputs: Mapping[str, ArrayLike | Sequence[ArrayLike]],
    *,
    noisy: ArrayLike | Sequence[ArrayLike] | None = None,
    scene: str = "sequence",
    metrics: Sequence[str] | None = None,
    warmup: int = WARMUP_FRAMES,
    info: Mapping[str, Mapping[str, Any]] | None = None,
) -> EvalResult:
    """Evaluate in-memory sequences of one scene; the array counterpart of
    :func:`evaluate_sequences`.

    Args:
        reference: ``(T, 3, H, W)`` or ``T`` frames ``(3, H, W)``, linear HDR RGB.
        outputs: label -> the output's frames, same layout and count.
        noisy: the noisy frames all outputs were made from; evaluated as the row ``"noisy"``.
        scene: scene name of every record.
        metrics: still and temporal metric names (default: all).
        warmup: number of first frames reported apart.
        info: optional label -> ``{"method", "spp", "seconds", "device", "params"}``
            (``seconds``: per frame); the label ``"noisy"`` describes the noisy frames.

    Raises:
        InputError: frame counts or sizes differ, or a metric name is unknown.
    """
    warmup = _check_warmup(warmup)
    result = _sequence_result(metrics, warmup)
    info = info or {}
    refs = _frames(reference, "reference")
    n = len(refs)
    if not n:
        raise InputError("the reference sequence has no frame")
    names = [f"frame_{t:04d}" for t in range(n)]
    jobs: list[_SeqJob] = []

    def job(label: str, frames: Any, rec: EvalRecord, key: str | None) -> _SeqJob:
        seq = _frames(frames, label)
        if len(seq) != n:
            raise InputError(f"{label} has {len(seq)} frames but the reference has {n}")
        secs = as_float(info.get(label, {}).get("seconds"))
        return _SeqJob(rec, [f"{label} {x}" for x in names], seq.__getitem__, [secs] * n, key)

    records = array_records(scene, outputs, info, noisy=noisy is not None, seconds=False)
    if noisy is not None:
        jobs.append(job("noisy", noisy, next(records), None))
    for rec, (label, frames) in zip(records, outputs.items()):
        jobs.append(job(str(label), frames, rec, "noisy" if noisy is not None else None))
    _evaluate_sequence(
        result,
        scene,
        "reference",
        names,
        [f"reference {x}" for x in names],
        refs.__getitem__,
        jobs,
        warmup,
    )
    return result


def _sequence_label(folder: Path, suffix: str) -> str:
    """How an output sequence is named: its folder, or ``folder/frame_*<suffix>.exr`` when
    the folder holds several sequences told apart by a suffix."""
    return str(folder) if not suffix else str(folder / f"frame_*{suffix}.exr")


def _noisy_label(frames: Sequence[tuple[Path, str | None, str | None]]) -> str:
    path, part, profile = frames[0]
    return str(path.parent) + (f"#{part}" if part else "") + (f" [{profile}]" if profile else "")


def evaluate_sequences(
    reference: PathLike, outputs: Sequence[PathLike], options: EvalOptions = DEFAULT_OPTIONS
) -> EvalResult:
    """Evaluate denoised sequences (folders of frames) against a reference sequence.

    ``reference`` is a folder of frames ``frame_0000.exr``, ``frame_0001.exr``, ... (see
    :func:`sequence_frames`; ``DIR/<id>/ref`` of ``mcdenoise render --frames``, whose scene
    name is then ``<id>``). Each output is a folder of frames; an output frame is matched to
    the reference frame whose stem is the longest prefix of its own (:func:`match_prefix`:
    ``frame_0003.exr`` and ``frame_0003_nlm.exr`` both show ``frame_0003``), and the frames of
    one folder with one suffix are one sequence, which must cover every reference frame.
    Per sequence: the per-frame metrics, the temporal ones and their means with the first
    ``warmup`` frames apart (:class:`~mcdenoise.eval.temporal_metrics.SequenceEvaluator`). The noisy
    frames an output was made from (``mcdenoise:source``, its part and profile) are evaluated
    as a ``"noisy"`` sequence, or, where no output records its source, the ``inputs``
    folder of frames that covers the sequence. An output frame whose source records another
    scene or frame than its reference frame (see :func:`same_scene`) is refused unless
    ``force``.

    Returns:
        An :class:`~mcdenoise.eval.results.EvalResult` with one record per sequence, each
        with its :class:`~mcdenoise.eval.results.SequenceDetail`.

    Raises:
        InputError: the reference is not a sequence or has a gap; an output is a file, has a
            frame that matches no reference frame or lacks one (the message names it); the
            frames of one output were made by different methods; a frame differs in size
            from its reference or from the sequence's first frame; a frame's source shows
            another scene or frame (without ``force``); an unknown metric; a bad ``warmup``.
        mcdenoise.errors.ExrError: an EXR cannot be read.
    """
    warmup = _check_warmup(options.warmup)
    ref_dir = Path(reference)
    ref_frames = sequence_frames(ref_dir)
    if ref_frames is None:
        raise InputError(
            f"reference {ref_dir} is not a sequence: a folder of frame_0000.exr, "
            "frame_0001.exr, ..."
        )
    result = _sequence_result(options.metrics, warmup)
    stems = [f.stem for f in ref_frames]
    index = {stem: i for i, stem in enumerate(stems)}
    n = len(stems)
    span = f"{stems[0]} to {stems[-1]}" if n > 1 else stems[0]
    frame_of = PrefixMatcher(stems)
    scene = ref_dir.resolve().parent.name if ref_dir.resolve().name == "ref" else ref_dir.name
    scene = scene or "sequence"

    # 1. output sequences: (folder, suffix) -> frame index -> header metadata
    groups: dict[tuple[str, str], dict[int, Meta]] = {}
    folder_of: dict[tuple[str, str], Path] = {}
    for arg in outputs:
        p = Path(arg)
        if not p.exists():
            raise InputError(f"output not found: {p}")
        if not p.is_dir():
            raise InputError(
                f"output {p} is a file, but the reference {ref_dir} is a sequence: give each "
                "output sequence as its folder of frames"
            )
        if same_file(p, ref_dir):
            continue
        for f in scan_exr(p, what="output"):
            hit = frame_of(f.stem)
            if hit is None:
                raise InputError(
                    f"output {f} matches no frame of the reference sequence {ref_dir} ({span})"
                )
            key = (str(p.resolve()), f.stem[len(hit) :])
            folder_of[key] = p
            groups.setdefault(key, {})[index[hit]] = probe(f)
    if not groups:
        raise InputError("no output to evaluate (only the reference sequence was given)")

    # 2. per sequence: complete, one method, its noisy frames, the scene of every frame
    noisy_given = _noisy_sequences(options.inputs or (), stems, index)
    ref_ids: dict[Path, dict[str, str]] = {}
    plans: list[tuple[_SeqJob, tuple[str, ...] | None]] = []
    made_by: set[str] = set()  # methods recorded in the outputs' headers
    noisy_frames: dict[tuple[str, ...], list[tuple[Path, str | None, str | None]]] = {}
    for key, frames in groups.items():
        folder, suffix = folder_of[key], key[1]
        label = _sequence_label(folder, suffix)
        missing = [stems[i] for i in range(n) if i not in frames]
        if missing:
            more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
            raise InputError(
                f"output sequence {label} lacks {missing[0]}{suffix}.exr{more}: the reference "
                f"sequence {ref_dir} has {n} frame{'s' if n != 1 else ''} ({span})"
            )
        metas = [frames[i] for i in range(n)]
        methods = sorted({m.method for m in metas if m.method})
        if len(methods) > 1:
            raise InputError(
                f"the frames of {label} were made by different methods: {', '.join(methods)}"
            )
        notes: list[str] = []
        sources = [source_path(m) for m in metas]
        src_frames: list[tuple[Path, str | None, str | None]] | None = None
        if all(src is not None for src in sources):
            src_frames = [
                (src, m.source_part, m.source_profile)
                for src, m in zip(sources, metas)
                if src is not None
            ]
        elif any(m.source is not None for m in metas):
            lost = [m for m, src in zip(metas, sources) if m.source is not None and src is None]
            notes.append(
                f"noisy input of {len(lost)} frame(s) not found ({ATTR_SOURCE}), e.g. "
                f"{lost[0].source}: no noisy row"
                if lost
                else "some frames record no source"
            )
        elif noisy_given:
            src_frames = noisy_given[0]
        problems = [
            problem
            for i, m in enumerate(metas)
            if m.source is not None
            and (problem := scene_mismatch(m, ref_frames[i], ref_ids)) is not None
        ]
        if problems:
            more = f" (and {len(problems) - 1} more frames)" if len(problems) > 1 else ""
            check_scene(problems[0] + more, options, notes, "sequence")
        nkey = None
        if src_frames is not None:
            nkey = tuple(image_key(*f) for f in src_frames)
            noisy_frames.setdefault(nkey, src_frames)
        made_by.update(methods)
        method = methods[0] if methods else (suffix.lstrip("_-.") or folder.name)
        rec = EvalRecord(
            scene=scene,
            file=label,
            role=ROLE_OUTPUT,
            method=method,
            input=None if src_frames is None else _noisy_label(src_frames),
            spp=metas[0].spp,
            device=metas[0].device,
            params=metas[0].params,
            notes=notes,
        )
        paths = [m.path for m in metas]
        plans.append(
            (
                _SeqJob(
                    rec,
                    [str(p) for p in paths],
                    lambda t, paths=paths: load_color(paths[t])[0],
                    [m.seconds for m in metas],
                ),
                nkey,
            )
        )

    # 3. a folder of frames without a method that holds another sequence's noisy frames is
    # that noisy row, not an output
    noisy_paths = {frozenset(str(f[0].resolve()) for f in fr) for fr in noisy_frames.values()}
    plans = [
        (job, nkey)
        for job, nkey in plans
        if job.record.method in made_by
        or frozenset(str(Path(f).resolve()) for f in job.files) not in noisy_paths
    ]

    # 4. jobs: each noisy sequence (by spp) followed by its outputs, then the rest
    jobs: list[_SeqJob] = []
    noisy_spp = {k: probe(*fr[0]).spp for k, fr in noisy_frames.items()}
    label = ""
    ordered = sorted(plans, key=lambda p: p[0].record.file)
    noisy_order = sorted(noisy_frames, key=lambda k: (noisy_spp[k] or 0, k))
    for nkey, plan in noisy_then_outputs(noisy_order, ordered, lambda p: p[1]):
        if plan is None:  # the noisy sequence nkey
            assert nkey is not None
            fr = noisy_frames[nkey]
            label = _noisy_label(fr)
            rec = EvalRecord(
                scene=scene, file=label, role=ROLE_NOISY, method="noisy", spp=noisy_spp[nkey]
            )
            jobs.append(
                _SeqJob(
                    rec,
                    [str(f[0]) + (f"#{f[1]}" if f[1] else "") for f in fr],
                    lambda t, fr=fr: load_color(*fr[t])[0],
                    [None] * n,
                )
            )
            continue
        job = plan[0]
        if nkey is not None:  # made from the noisy sequence just listed
            job.input_key = label
            if job.record.spp is None:
                job.record.spp = noisy_spp[nkey]
        jobs.append(job)

    bar = progress_bar(total=n * len(jobs), desc="eval", unit="frame", progress=options.progress)
    try:
        _evaluate_sequence(
            result,
            scene,
            str(ref_dir),
            stems,
            [str(f) for f in ref_frames],
            lambda t: load_color(ref_frames[t])[0],
            jobs,
            warmup,
            progress=bar.update,
        )
    finally:
        bar.close()
    return result


def _noisy_sequences(
    inputs: Sequence[PathLike], stems: Sequence[str], index: Mapping[str, int]
) -> list[list[tuple[Path, str | None, str | None]]]:
    """The given noisy folders of frames that cover every reference frame (matched by name),
    as (file, part, profile) per frame; a multi-part frame is read with its first part."""
    found = []
    frame_of = PrefixMatcher(stems)
    for arg in inputs:
        by_frame: dict[int, Path] = {}
        for f in scan_exr(arg, what="noisy input"):
            hit = frame_of(f.stem)
            if hit is not None:
                by_frame.setdefault(index[hit], f)
        if len(by_frame) == len(stems):
            found.append(
                [(f, _first_part(f), None) for f in (by_frame[i] for i in range(len(stems)))]
            )
    return found


def _first_part(path: Path) -> str | None:
    """The name of the first part of a multi-part EXR (the lowest spp level of a file written
    by ``mcdenoise render``), else ``None``."""
    parts = probe_exr(path)
    return parts[0].name or None if len(parts) > 1 else None
