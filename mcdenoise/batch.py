"""``mcdenoise denoise``: many inputs, one or several methods, with progress and resume.

:func:`plan_jobs` / :func:`run_jobs` (together :func:`denoise_paths`): a folder of frames is
one sequence for a temporal method (:class:`SequenceJob`, checked from the headers by
:func:`~mcdenoise.denoise_files.scan_sequence` before anything is written, outputs written
frame by frame, a re-run resumes) and a batch of stills for a per-frame method (each through
:func:`~mcdenoise.output.denoise_file`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from mcdenoise.denoise import denoise_sequence
from mcdenoise.denoise_files import (
    ReadOptions,
    SequenceJob,
    WriteOptions,
    check_output_path,
    collect_inputs,
    make_output_folder,
    output_complete,
    plan_outputs,
    plan_sequences,
    refuse_overwriting_inputs,
)
from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError
from mcdenoise.models.weights import model_method
from mcdenoise.output import FileResult, denoise_file, write_result
from mcdenoise.progress import progress_bar
from mcdenoise.registry import Method, choose_method, header_method, methods, parse_methods

__all__ = [
    "DenoiseJob",
    "DenoisePlan",
    "JobOutcome",
    "OptionError",
    "denoise_paths",
    "plan_jobs",
    "run_jobs",
]


class OptionError(InputError):
    """Options that cannot work together (``mcdenoise denoise`` reports it as a usage error)."""


@dataclass(frozen=True)
class DenoiseJob:
    """One output to make: ``input`` denoised with ``method`` into ``output``.

    With ``--method auto`` both are ``None`` until the input is read: the method is then the
    best one its buffers can feed, and the output is named after it.
    """

    input: Path
    output: Path | None
    method: Method | None


@dataclass
class JobOutcome:
    """What became of one :class:`DenoiseJob`: its file result, or why it was skipped."""

    job: DenoiseJob  # method and output resolved
    result: FileResult | None = None
    skipped: str | None = None  # with --method all: why the method refused this input
    #: with --method auto: the better-ranked methods passed over for this input, and why
    passed_over: tuple[tuple[str, str], ...] = ()
    auto: bool = False  # the method was chosen for the input (--method auto)

    def choice_lines(self) -> list[str]:
        """What ``mcdenoise denoise --verbose`` says about the method used for this input."""
        name = self.job.input.name
        m = self.job.method
        lines = [f"{name}: skipped {n}: {reason}" for n, reason in self.passed_over]
        if m is not None and self.auto:
            lines.append(f"{name}: chose {m.name} (the best available method that accepts it)")
        elif m is not None and self.result is not None:
            lines.append(f"{name}: {m.name} (given by --method)")
        return lines

    def summary(self) -> str:
        """The line ``mcdenoise denoise`` prints for this outcome."""
        src, m = self.job.input, self.job.method
        if self.result is None:
            return f"skipped {m.name if m else '?'} on {src.name}: {self.skipped}"
        res = self.result
        extra = f", {res.clamped} values clamped to the half range" if res.clamped else ""
        fixed = sum(res.result.repaired.values())
        extra += f", {fixed} NaN/Inf/negative input values repaired" if fixed else ""
        est = res.estimate
        if est and est.get("relmse_estimated") is not None:
            extra += (
                f", relMSE {est['relmse_estimated']:.4g} "
                f"± {est['relmse_estimated_se']:.2g} (estimated from the halves)"
            )
        elif est and est.get("relmse_estimated_upper") is not None:
            extra += (
                f", relMSE < {est['relmse_estimated_upper']:.3g} (estimated from the halves: "
                f"below its own noise, ± {est['relmse_estimated_se']:.2g})"
            )
        elif est:
            extra += f", {est.get('estimate_note', 'no estimate')}"
        if est and est.get("estimate_warning"):
            extra += f"; WARNING {est['estimate_warning']}"
        return (
            f"{res.output}  [{res.result.method}, {res.result.seconds:.2f} s on "
            f"{res.result.device}{extra}]"
        )


@dataclass
class DenoisePlan:
    """The jobs of one ``mcdenoise denoise`` call and the settings they share."""

    jobs: list[DenoiseJob | SequenceJob]  # a sequence job: one temporal method, one sequence
    params: dict[str, Any]  # parameter overrides (one method only)
    output: Path | None  # -o: a file (one output) or a folder (created when run)
    part: str | None  # the level of a multi-part input (part of the output names)
    skip_missing: bool  # --method all: skip a method that refuses an input (with the reason)


def plan_jobs(
    inputs: Sequence[str | os.PathLike[str]],
    output: str | os.PathLike[str] | None = None,
    method: str = "auto",
    *,
    params: Mapping[str, Any] | None = None,
    model: str | None = None,
    part: str | None = None,
    read: ReadOptions | None = None,
) -> DenoisePlan:
    """Check the options of ``mcdenoise denoise`` and plan its outputs; of the inputs only
    the headers of a temporal method's frames are read (:func:`scan_sequence`).

    A per-frame method gets one job per input file (a folder: each of its ``*.exr``). A
    temporal method (:attr:`Method.temporal <mcdenoise.method.Method.temporal>`) gets one
    :class:`SequenceJob` per folder (the folder's frames, in frame order: the layout of
    ``mcdenoise render --frames``, whose ``ref/`` subfolder is not read) and one for the files
    given one by one, together; the sequence is checked here, before anything is written.

    Args:
        inputs: EXR files and folders of them (see :func:`collect_inputs`).
        output: one output file (one input, one method), a folder, or ``None`` (outputs beside
            the inputs); names as in :func:`plan_outputs`.
        method: ``auto`` (the best method for each input, chosen when it is read), ``all``
            (every available method; one that refuses an input, see
            :meth:`Method.accepts <mcdenoise.method.Method.accepts>`, is skipped there), a
            name or a comma-separated list.
        params: parameter overrides (one method only; not with ``auto`` unless ``model``
            names the method).
        model: a trained model (run folder or model file) for a learned method: the same as
            ``params["model"]``; with ``method="auto"`` the model file names the method.
        part: the level of multi-part inputs to read (``spp16``); part of the output names
            (default: ``read.part``).
        read: how the inputs are read (profile, mapping, part, spp): for the frame checks.

    Raises:
        OptionError: options that do not go together (several methods with one parameter
            set or one output file, ``--model`` with a method that takes no model, ...).
        InputError: a missing input, an unknown or unavailable method, a bad parameter, a
            sequence a temporal method cannot take (:func:`scan_sequence`; with ``all``
            that method is skipped on it instead).
    """
    read = read or ReadOptions(part=part)
    part = read.part if part is None else part
    files = collect_inputs(inputs, include_outputs=read.include_outputs)
    if model is not None and method == "auto":
        # the model file says which method: one of the table, never a command
        named = model_method(model)
        if named == "auxnet":
            raise InputError(
                f"{model}: an auxiliary-buffer prefilter (auxnet), not a denoiser; kpcn uses "
                "the shipped one with -p prefilter=learned"
            )
        method = header_method(named, str(model), what="its model card").name
    chosen = parse_methods(method)
    overrides = dict(params or {})
    if model is not None:
        learned = [m.name for m in chosen if "model" in m.defaults]
        if len(chosen) != 1 or not learned:
            raise OptionError("--model needs exactly one learned --method (e.g. --method kpcn)")
        overrides["model"] = model
    if overrides and len(chosen) != 1:
        raise OptionError("--param needs exactly one --method")
    for m in chosen:
        m.resolve_params(overrides)  # fail on a bad --param before reading anything
    if len(chosen) > 1 and output is not None and Path(output).suffix.lower() == ".exr":
        raise OptionError("several methods write several files: give -o a folder")
    if overrides and method == "auto":
        raise OptionError("--param needs an explicit --method (the default depends on the input)")
    jobs: list[DenoiseJob | SequenceJob] = []
    if method == "auto":  # decided per input, when it is read: the best method it can feed
        plan_outputs(files, output, "auto", part=part)  # refuses -o x.exr for several inputs
        jobs = [DenoiseJob(src, None, None) for src in files]
    else:
        for m in chosen:
            if m.temporal:
                jobs += plan_sequences(inputs, output, m, read, part, skip=method == "all")
                continue
            outs = plan_outputs(files, output, m.name, part=part)
            jobs += [DenoiseJob(src, dst, m) for src, dst in zip(files, outs)]
    pairs = [
        pair
        for j in jobs
        for pair in (
            zip(j.inputs, j.outputs) if isinstance(j, SequenceJob) else [(j.input, j.output)]
        )
    ]
    if method == "auto":  # any method may be chosen: every output name it could give
        pairs = [
            (f, o)
            for m in methods()
            for f, o in zip(files, plan_outputs(files, output, m.name, part=part))
        ]
    refuse_overwriting_inputs(files, [(f, o) for f, o in pairs if o is not None])
    return DenoisePlan(
        jobs,
        overrides,
        None if output is None else Path(output),
        part,
        skip_missing=method == "all",
    )


def run_jobs(
    plan: DenoisePlan,
    *,
    device: str | torch.device = "auto",
    read: ReadOptions | None = None,
    write: WriteOptions | None = None,
    progress: bool = True,
) -> Iterator[JobOutcome]:
    """Run the jobs of ``plan`` one after the other (each through :func:`denoise_file`; a
    :class:`SequenceJob` frame by frame through :func:`denoise_sequence`, see
    :func:`_run_sequence_job` for its resume).

    Creates the output folder first. Yields each job's outcome as soon as its file is
    written (one per frame of a sequence); with ``progress`` (see
    :func:`mcdenoise.progress.progress_bar`: a bar on a terminal, lines in a log) the images,
    or the frames when there is a sequence, are counted on stderr when there are several.
    """

    read = read or ReadOptions()
    out = plan.output
    if out is not None and out.suffix.lower() != ".exr":
        make_output_folder(out, exr_ok=True)
    units = sum(len(j.inputs) if isinstance(j, SequenceJob) else 1 for j in plan.jobs)
    frames = any(isinstance(j, SequenceJob) for j in plan.jobs)
    bar = progress_bar(
        total=units,
        desc="denoise",
        unit="frame" if frames else "image",
        progress=progress if units > 1 else False,
    )
    try:
        for job in plan.jobs:
            if isinstance(job, SequenceJob):
                yield from _run_sequence_job(job, plan, device, read, write or WriteOptions(), bar)
                continue
            buffers = None
            if job.method is None:
                bar.set_postfix_str(f"{job.input.name} auto")
                buffers = _load(job.input, read)
                res, job, passed_over = _run_auto(job, buffers, plan, out, device, read, write)
                bar.update(1)
                yield JobOutcome(job, res, passed_over=passed_over, auto=True)
                continue
            assert job.method is not None and job.output is not None
            bar.set_postfix_str(f"{job.input.name} {job.method.name}")
            try:
                if plan.skip_missing:  # --method all: a method that refuses is skipped
                    buffers = _load(job.input, read)
                    reason = job.method.accepts(buffers, plan.params)
                    if reason is not None:
                        bar.update(1)
                        yield JobOutcome(job, skipped=reason)
                        continue
                res = denoise_file(
                    job.input,
                    job.output,
                    job.method,
                    params=plan.params,
                    device=device,
                    read=read,
                    write=write,
                    buffers=buffers,
                )
            except MissingFeatureError as err:
                if not plan.skip_missing:
                    raise
                bar.update(1)
                yield JobOutcome(job, skipped=str(err))
                continue
            bar.update(1)
            yield JobOutcome(job, res)
    finally:
        bar.close()


def _run_sequence_job(
    job: SequenceJob,
    plan: DenoisePlan,
    device: str | torch.device,
    read: ReadOptions,
    write: WriteOptions,
    bar: Any,
) -> Iterator[JobOutcome]:
    """Denoise one sequence with its temporal method, writing each output as soon as it is
    finished; yield one outcome per frame.

    Resume: a frame whose output is complete (:func:`output_complete`) is not written again.
    The method's history is rebuilt exactly: the frames before the first missing output are
    run through the method again, their outputs discarded ("replayed"), so every output
    written equals that of an uninterrupted run, at the cost of denoising those frames once
    more. The run stops after the last missing output.
    """
    m = job.method
    if job.skipped is not None:  # --method all: one line for the whole sequence
        bar.update(len(job.inputs))
        yield JobOutcome(DenoiseJob(job.source, None, m), skipped=job.skipped)
        return
    frame_jobs = [DenoiseJob(s, d, m) for s, d in zip(job.inputs, job.outputs)]
    for src, dst in zip(job.inputs, job.outputs):
        check_output_path(src, dst)
    params = m.resolve_params(plan.params)
    done = [output_complete(d, s, m, params, plan.part) for s, d in zip(job.inputs, job.outputs)]
    todo = [i for i, d in enumerate(done) if not d]
    if not todo:
        for fj in frame_jobs:
            bar.update(1)
            yield JobOutcome(fj, skipped=f"{fj.output} is done (an earlier run wrote it)")
        return
    last = todo[-1]
    loaded: dict[int, FeatureBuffers] = {}

    def frames() -> Iterator[FeatureBuffers]:
        for i in range(last + 1):
            fb = _load(job.inputs[i], read)
            loaded[i] = FeatureBuffers(
                {},
                spp=fb.spp,
                source=fb.source,
                profile=fb.profile,
                attributes=fb.attributes,
                data_window=fb.data_window,
                display_window=fb.display_window,
            )
            yield fb

    def postfix(i: int) -> str:  # the frame being denoised; "history": replayed, not written
        return f"{job.inputs[i].name} {m.name}" + (" (history)" if i < todo[0] else "")

    bar.set_postfix_str(postfix(0))
    results = denoise_sequence(frames(), m, params=plan.params, device=device)
    try:
        for i, result in enumerate(results):
            fj, meta = frame_jobs[i], loaded.pop(i)
            if done[i]:
                bar.update(1)
                yield JobOutcome(fj, skipped=f"{fj.output} is done (an earlier run wrote it)")
            else:
                assert fj.output is not None
                res = write_result(fj.input, fj.output, meta, result, read, write)
                bar.update(1)
                yield JobOutcome(fj, res)
            if i == last:
                break
            bar.set_postfix_str(postfix(i + 1))
    finally:
        close = getattr(results, "close", None)
        if close is not None:
            close()
    for fj in frame_jobs[last + 1 :]:
        bar.update(1)
        yield JobOutcome(fj, skipped=f"{fj.output} is done (an earlier run wrote it)")


def _run_auto(
    job: DenoiseJob,
    buffers: FeatureBuffers,
    plan: DenoisePlan,
    out: Path | None,
    device: str | torch.device,
    read: ReadOptions,
    write: WriteOptions | None,
) -> tuple[FileResult, DenoiseJob, tuple[tuple[str, str], ...]]:
    """Denoise one input of ``--method auto``: the best method that accepts it; when that
    method's preparation still refuses the file for what its pixels hold (e.g. no usable
    scene extent), the next one (nothing is written by the one that refused)."""
    passed_over: list[tuple[str, str]] = []
    while True:
        try:
            choice = choose_method(buffers, exclude=[n for n, _ in passed_over])
        except InputError:
            if not passed_over:
                raise
            why = "; ".join(f"{n}: {r}" for n, r in passed_over)
            raise InputError(f"no denoising method can run on {job.input.name} ({why})") from None
        passed_over += choice.skipped
        m = choice.method
        dst = plan_outputs([job.input], out, m.name, part=plan.part)[0]
        job = DenoiseJob(job.input, dst, m)
        try:
            res = denoise_file(
                job.input,
                dst,
                m,
                params=plan.params,
                device=device,
                read=read,
                write=write,
                buffers=buffers,
            )
        except MissingFeatureError as err:
            passed_over.append((m.name, " ".join(str(err).split())))
            continue
        return res, job, tuple(passed_over)


def _load(path: Path, read: ReadOptions) -> FeatureBuffers:

    return load_buffers(
        path, profile=read.profile, mapping=read.mapping, part=read.part, spp=read.spp
    )


def denoise_paths(
    inputs: Sequence[str | os.PathLike[str]],
    output: str | os.PathLike[str] | None = None,
    method: str = "auto",
    *,
    params: Mapping[str, Any] | None = None,
    model: str | None = None,
    device: str | torch.device = "auto",
    read: ReadOptions | None = None,
    write: WriteOptions | None = None,
    progress: bool = True,
) -> Iterator[JobOutcome]:
    """``mcdenoise denoise``: :func:`plan_jobs` now (every option checked before any file is
    read), then the iterator of :func:`run_jobs` over the outcomes.

    ``read.part`` is the level read from multi-part inputs and part of the output names.
    """
    read = read or ReadOptions()
    plan = plan_jobs(inputs, output, method, params=params, model=model, part=read.part, read=read)
    if write is not None and write.estimate_error:
        temporal = sorted({j.method.name for j in plan.jobs if isinstance(j, SequenceJob)})
        if temporal:
            raise OptionError(
                f"--estimate-error judges still images; {', '.join(temporal)} denoises sequences"
            )
    return run_jobs(plan, device=device, read=read, write=write, progress=progress)
