"""The one entry point every front end calls: a sequence of frames in, one result per frame.

:func:`denoise_sequence` denoises the frames of one sequence with one method; :func:`denoise`
is its one-frame case and :func:`denoise_file` reads and writes EXR files around it.
:func:`plan_jobs` / :func:`run_jobs` are ``mcdenoise denoise``: a folder of frames is one
sequence for a temporal method (:class:`SequenceJob`, checked from the headers by
:func:`scan_sequence` before anything is written, outputs written frame by frame, a re-run
resumes) and a batch of stills for a per-frame method.
``mcdenoise denoise`` (:func:`denoise_paths`), ``mcdenoise eval --experiment`` and the
experiment runner all come through here, so a method registered in :mod:`mcdenoise.registry`
(see :mod:`mcdenoise.method` for what a method is: per-frame or temporal) is available
everywhere, with the same input sanitising, checks, timing and output repair.
"""

from __future__ import annotations

import itertools
import json
import os
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from mcdenoise import __version__
from mcdenoise.denoise_files import (
    FrameInfo,
    ReadOptions,
    SequenceJob,
    WriteOptions,
    check_output_folder,
    check_output_path,
    collect_inputs,
    collect_sequences,
    file_in_the_way,
    frame_info,
    make_output_folder,
    output_complete,
    plan_outputs,
    plan_sequences,
    refuse_overwriting_inputs,
    scan_sequence,
)
from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError, sanitize
from mcdenoise.registry import (
    Method,
    MethodChoice,
    aliases,
    available_methods,
    best_method,
    choose_method,
    get_method,
    header_method,
    methods,
    params_from_strings,
    register,
)
from mcdenoise.threads import check_speed, wait_policy

__all__ = [
    "DenoiseJob",
    "DenoisePlan",
    "DenoiseResult",
    "FileResult",
    "FrameInfo",
    "JobOutcome",
    "Method",
    "MethodChoice",
    "OptionError",
    "ReadOptions",
    "SequenceJob",
    "WriteOptions",
    "available_methods",
    "best_method",
    "check_output_folder",
    "choose_method",
    "collect_inputs",
    "collect_sequences",
    "denoise",
    "denoise_file",
    "denoise_paths",
    "denoise_sequence",
    "file_in_the_way",
    "frame_info",
    "get_method",
    "make_output_folder",
    "method_aliases",
    "methods",
    "output_complete",
    "params_from_strings",
    "parse_methods",
    "plan_jobs",
    "plan_outputs",
    "register",
    "resolve_device",
    "run_jobs",
    "scan_sequence",
]


class OptionError(InputError):
    """Options that cannot work together (``mcdenoise denoise`` reports it as a usage error)."""


def parse_methods(spec: str) -> list[Method]:
    """``"auto"`` -> [best available]; ``"all"`` -> every available method; ``"a,b"`` -> those.

    An external command (``cmd:PROGRAM ARGS``, :mod:`mcdenoise.methods.external`) runs to the
    end of ``spec`` or to the next ``,cmd:``, so its own commas stay its own:
    ``"nlm,cmd:den -s 1,2 {input} {output}"`` is nlm and one command.

    >>> [m.name for m in parse_methods("nlm")]
    ['nlm']
    """
    spec = spec.strip()
    if spec == "auto":
        return [best_method()]
    if spec == "all":
        return available_methods()
    head, *commands = ("," + spec if spec.startswith("cmd:") else spec).split(",cmd:")
    names = [s.strip() for s in head.split(",") if s.strip()]
    names += ["cmd:" + c.strip() for c in commands]
    if not names:
        raise InputError("--method is empty")
    chosen = [get_method(n) for n in names]
    for m in chosen:
        reason = m.unavailable()
        if reason:
            raise InputError(f"method {m.name!r} is not available: {reason}")
    if len({m.name for m in chosen}) != len(chosen):
        raise InputError(f"--method {spec!r} names a method twice")
    return chosen


def method_aliases() -> dict[str, list[str]]:
    """Method name -> its aliases (``{"cross-bilateral": ["cross_bilateral", "xbf"]}``), for
    ``mcdenoise methods`` and the ``--method`` help."""
    table: dict[str, list[str]] = {}
    for alias, name in aliases().items():
        table.setdefault(name, []).append(alias)
    return table


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; an unavailable CUDA is an ``InputError``."""
    name = str(device)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("--device cuda was requested but no CUDA device is available")
    if name != "cpu" and not name.startswith("cuda"):
        raise InputError(f"unknown device {name!r} (use auto, cpu or cuda)")
    return torch.device(name)


@dataclass
class DenoiseResult:
    """One denoised frame (what :func:`denoise` returns, :func:`denoise_sequence` yields):
    the image and how it was made."""

    image: torch.Tensor  # (3, H, W) float32, linear HDR, finite, >= 0
    method: str
    params: dict[str, Any]
    seconds: float  # wall time of the method on this frame (no file I/O, no sanitising)
    device: str
    repaired: dict[str, int] = field(default_factory=dict)  # NaN/Inf/negatives fixed per buffer

    def attributes(self) -> dict[str, str | int | float]:
        """EXR header attributes recording this result (``mcdenoise:*``)."""
        return {
            "mcdenoise:method": self.method,
            "mcdenoise:params": json.dumps(self.params, sort_keys=True),
            "mcdenoise:seconds": float(self.seconds),
            "mcdenoise:device": self.device,
            "mcdenoise:threads": int(torch.get_num_threads()),
            "mcdenoise:omp_wait_policy": wait_policy(),  # as the environment asks
            "mcdenoise:version": __version__,
        }


def denoise(
    buffers: FeatureBuffers,
    method: str | Method = "auto",
    *,
    params: Mapping[str, Any] | None = None,
    device: str | torch.device = "auto",
) -> DenoiseResult:
    """Denoise one image held in ``buffers`` with ``method`` ("auto" = best available).

    The one-frame case of :func:`denoise_sequence`: the input is sanitised first (NaN/Inf
    repaired, see :func:`mcdenoise.io.sanitize`); the output is float32 ``(3, H, W)`` on the
    CPU, finite and clamped at 0.
    """
    (result,) = denoise_sequence([buffers], method, params=params, device=device)
    return result


def denoise_sequence(
    frames: Iterable[FeatureBuffers],
    method: str | Method = "auto",
    *,
    params: Mapping[str, Any] | None = None,
    device: str | torch.device = "auto",
) -> Iterator[DenoiseResult]:
    """Denoise the frames of one sequence, in order, with one method: one result per frame.

    A per-frame method denoises each frame on its own; a temporal method
    (:attr:`Method.temporal <mcdenoise.method.Method.temporal>`) receives the frames in order
    and may carry state from one frame to the next. ``frames`` may be lazy (read from disk as
    they are needed); each frame is sanitised, cut to the buffers the method requires or uses,
    and moved to ``device`` when the method asks for it.

    With ``"auto"`` (and no ``params``), a method whose preparation still refuses the first
    frame for what its pixels hold (no usable scene extent: a frame with no geometry hit) is
    followed by the next one that accepts it, so the default fails only when no method can run.

    The method (``"auto"``: the best available one that accepts the first frame, see
    :func:`~mcdenoise.registry.choose_method`), its availability, the
    buffers of the first frame, the parameters and the device are checked before this returns;
    every later frame must hold the required buffers too (``MissingFeatureError`` when it is
    reached). Each result's ``seconds`` is the wall time of the method for that frame, without
    reading or sanitising frames; its ``image`` is float32 ``(3, H, W)`` linear HDR RGB on the
    CPU, finite and clamped at 0; ``repaired`` counts the NaN/Inf/negative values repaired in
    that frame.

    Raises:
        InputError: unknown or unavailable method, bad parameter, device the method does not
            support; ``MissingFeatureError`` (an ``InputError``) for a missing buffer.
    """
    source = iter(frames)
    first = next(source, None)
    if first is None:
        return iter(())
    m = (
        best_method(first)
        if method == "auto"
        else (method if isinstance(method, Method) else get_method(method))
    )
    reason = m.unavailable()
    if reason:
        raise InputError(f"method {m.name!r} is not available: {reason}")
    first.require(m.requires, needed_by=f"method {m.name!r}")
    resolved = m.resolve_params(params)
    dev = resolve_device(device)
    if dev.type not in m.devices:
        raise InputError(f"method {m.name!r} does not run on {dev.type}")
    if method == "auto" and not params:
        return _auto_sequence(m, first, source, resolved, dev)
    return _run_sequence(m, itertools.chain([first], source), resolved, dev)


_END = object()


def _auto_sequence(
    m: Method,
    first: FeatureBuffers,
    rest: Iterator[FeatureBuffers],
    params: dict[str, Any],
    dev: torch.device,
) -> Iterator[DenoiseResult]:
    """:func:`_run_sequence` of the default method ``m``; when its preparation refuses the
    first frame for what its pixels hold (``MissingFeatureError``, e.g. depth and position
    without a usable scene extent: a frame with no geometry hit) before any later frame was
    read, the next method that accepts the frame runs instead, so the default never fails
    where a method that can run exists."""
    pulled = [0]

    def counted() -> Iterator[FeatureBuffers]:
        for frame in rest:
            pulled[0] += 1
            yield frame

    later = counted()
    tried: list[str] = []
    while True:
        results = _run_sequence(m, itertools.chain([first], later), params, dev)
        try:
            result = next(results)
        except MissingFeatureError as err:
            if pulled[0]:
                raise
            tried.append(m.name)
            try:
                m = choose_method(first, exclude=tried).method
            except InputError:
                raise err from None
            if dev.type not in m.devices:
                raise err from None
            params = m.resolve_params(None)
            continue
        except StopIteration:
            return
        yield result
        yield from results
        return


def _run_sequence(
    m: Method, frames: Iterator[FeatureBuffers], params: dict[str, Any], dev: torch.device
) -> Iterator[DenoiseResult]:
    """The results of ``m`` on ``frames`` (checked by :func:`denoise_sequence`)."""
    needed = set(m.requires) | set(m.uses)
    shapes: list[tuple[int, int]] = []  # (H, W) of each frame handed to the method
    repairs: list[dict[str, int]] = []
    prep_seconds = [0.0]  # time spent reading and preparing frames, not the method's own

    def prepared() -> Iterator[FeatureBuffers]:
        while True:
            start = time.perf_counter()
            buffers = next(frames, _END)
            if buffers is _END:
                return
            assert isinstance(buffers, FeatureBuffers)
            buffers.require(m.requires, needed_by=f"method {m.name!r}")
            clean, repaired = sanitize(buffers.subset(needed))
            clean = clean.to(dev)
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
            shapes.append(buffers.shape)
            repairs.append(repaired)
            prep_seconds[0] += time.perf_counter() - start
            yield clean

    outputs = m.run_frames(prepared(), params, dev)
    try:
        for index in itertools.count():
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
            prep_before = prep_seconds[0]
            start = time.perf_counter()
            try:
                with torch.no_grad():  # the method's code runs inside this call
                    out = next(outputs)
            except StopIteration:
                if index < len(shapes) or next(frames, _END) is not _END:
                    raise RuntimeError(
                        f"method {m.name} returned {index} outputs for a longer sequence"
                    ) from None
                return
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
            seconds = time.perf_counter() - start - (prep_seconds[0] - prep_before)
            if index < len(shapes):  # far slower than recorded: say so, once per method
                check_speed(
                    m.speed_name(params), seconds, shapes[index][0] * shapes[index][1], dev.type
                )
            if index >= len(shapes):
                raise RuntimeError(f"method {m.name} returned more outputs than frames")
            out = out.detach().to("cpu", torch.float32)
            out = torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)
            if tuple(out.shape) != (3, *shapes[index]):
                raise RuntimeError(f"method {m.name} returned shape {tuple(out.shape)}")
            yield DenoiseResult(out, m.name, dict(params), seconds, str(dev), repairs[index])
    finally:
        close = getattr(outputs, "close", None)
        if close is not None:
            close()


# --- files ----------------------------------------------------------------------------------


@dataclass
class FileResult:
    input: Path
    output: Path
    result: DenoiseResult
    clamped: int = 0  # values clamped to the half range when writing
    estimate: dict[str, Any] | None = None  # --estimate-error: relmse_estimated, ... (JSON)

    def to_dict(self) -> dict[str, Any]:
        r = self.result
        return {
            "input": str(self.input),
            "output": str(self.output),
            "method": r.method,
            "params": r.params,
            "seconds": r.seconds,
            "device": r.device,
            "repaired": r.repaired,
            "clamped": self.clamped,
            **(self.estimate or {}),
        }


def denoise_file(
    input_path: str | os.PathLike[str],
    output_path: str | os.PathLike[str],
    method: str | Method = "auto",
    *,
    params: Mapping[str, Any] | None = None,
    device: str | torch.device = "auto",
    read: ReadOptions | None = None,
    write: WriteOptions | None = None,
    buffers: FeatureBuffers | None = None,
) -> FileResult:
    """Read ``input_path``, denoise it, write ``output_path`` atomically (colour only).

    The output keeps the input's data and display windows and records, as header attributes,
    the method, its parameters, the source file (and its part, and its profile where that
    names an image inside the file, e.g. ``mcdenoise:source_profile = "cycles:Layer2"``), the
    seconds the method took, the device, the sample count of the input and the input's scene
    attributes (:data:`SCENE_ATTRIBUTES`). ``buffers``: the input already read with ``read`` (it is
    then not read again).
    """
    from mcdenoise.io import load_buffers

    read = read or ReadOptions()
    write = write or WriteOptions()
    src, dst = Path(input_path), Path(output_path)
    check_output_path(src, dst)
    if buffers is None:
        buffers = load_buffers(
            src, profile=read.profile, mapping=read.mapping, part=read.part, spp=read.spp
        )
    if write.estimate_error:  # refuse an input without halves before any work
        from mcdenoise.eval.estimate import estimate_record, split_halves

        split_halves(buffers)
    result = denoise(buffers, method, params=params, device=device)
    estimate = None
    if write.estimate_error:  # the same method on each half, judged against the other
        name = result.method
        run = lambda b: denoise(b, name, params=params, device=device).image  # noqa: E731
        estimate = estimate_record(run, buffers, result.image)
    return _write_result(src, dst, buffers, result, read, write, estimate)


def _write_result(
    src: Path,
    dst: Path,
    buffers: FeatureBuffers,
    result: DenoiseResult,
    read: ReadOptions,
    write: WriteOptions,
    estimate: Mapping[str, Any] | None = None,
) -> FileResult:
    """Write ``result`` (the output of ``src``, read into ``buffers`` with ``read``) to
    ``dst`` atomically, with the header attributes :func:`denoise_file` describes
    (``estimate``: ``--estimate-error``'s fields, written as ``mcdenoise:<field>``)."""
    from mcdenoise.io import save_buffers

    out = FeatureBuffers(
        {"color": result.image},
        spp=buffers.spp,
        data_window=buffers.data_window,
        display_window=buffers.display_window,
    )
    attrs: dict[str, Any] = result.attributes()
    attrs["mcdenoise:source"] = str(src.resolve())
    for key in SCENE_ATTRIBUTES:  # which scene this is: `mcdenoise eval` checks it
        if key in buffers.attributes:
            attrs[key] = buffers.attributes[key]
    if read.part is not None:
        attrs["mcdenoise:source_part"] = str(read.part)
    if buffers.profile and ":" in buffers.profile:
        # the profile names an image inside the file (a Cycles view layer: "cycles:Layer2"):
        # `mcdenoise eval` reads the source, and the reference, with it
        attrs["mcdenoise:source_profile"] = buffers.profile
    if buffers.spp is not None:
        attrs["mcdenoise:spp"] = int(buffers.spp)
    for key, value in (estimate or {}).items():
        attrs[f"mcdenoise:{key}"] = value
    report = save_buffers(
        dst, out, half=write.half, compression=write.compression, attributes=attrs
    )
    clamped = sum(getattr(report, "clamped", {}).values())
    return FileResult(src, dst, result, clamped, dict(estimate) if estimate else None)


#: Header attributes of an input that say which scene it shows (written by
#: ``mcdenoise render``); copied into each output so ``mcdenoise eval`` can check the pairing.
SCENE_ATTRIBUTES = (
    "mcdenoise:scene",
    "mcdenoise:image",
    "mcdenoise:frame",
    "mcdenoise:sequence",
)


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
                res = _write_result(fj.input, fj.output, meta, result, read, write)
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


# --- jobs: many inputs, one or several methods ----------------------------------------------


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
        if res.estimate:
            extra += (
                f", relMSE {res.estimate['relmse_estimated']:.4g} "
                f"± {res.estimate['relmse_estimated_se']:.2g} (estimated from the halves)"
            )
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
        from mcdenoise.models.weights import model_method

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
    from mcdenoise.progress import progress_bar

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
    from mcdenoise.io import load_buffers

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
