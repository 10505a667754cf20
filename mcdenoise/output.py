"""One denoised file: :func:`denoise_file` reads an input, denoises it with
:func:`mcdenoise.denoise.denoise` and writes the output atomically; :func:`write_result`
writes a result with its header attributes (the method, its parameters, the source, the
scene: :data:`SCENE_ATTRIBUTES`).

Used by ``mcdenoise denoise`` (:mod:`mcdenoise.batch`), one file or one frame of a sequence
at a time.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from mcdenoise.denoise import DenoiseResult, denoise
from mcdenoise.denoise_files import ReadOptions, WriteOptions, check_output_path
from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers, save_buffers
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.registry import Method, get_method

__all__ = [
    "SCENE_ATTRIBUTES",
    "FileResult",
    "denoise_file",
    "write_result",
]


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

    read = read or ReadOptions()
    write = write or WriteOptions()
    src, dst = Path(input_path), Path(output_path)
    check_output_path(src, dst)
    if buffers is None:
        buffers = load_buffers(
            src, profile=read.profile, mapping=read.mapping, part=read.part, spp=read.spp
        )
    if write.estimate_error:  # refuse an input without halves before any work
        from mcdenoise.eval.estimate import (  # lazy: start-up of mcdenoise denoise
            estimate_record,
            split_halves,
        )

        split_halves(buffers)
    result = denoise(buffers, method, params=params, device=device)
    estimate = None
    if write.estimate_error:  # the same method on each half, judged against the other
        name = result.method
        run = lambda b: denoise(b, name, params=params, device=device).image  # noqa: E731
        m = get_method(name)
        reads = (*m.requires, *m.uses)
        estimate = estimate_record(run, buffers, result.image, method=name, reads=reads)
    return write_result(src, dst, buffers, result, read, write, estimate)


def write_result(
    src: Path,
    dst: Path,
    buffers: FeatureBuffers,
    result: DenoiseResult,
    read: ReadOptions,
    write: WriteOptions,
    estimate: Mapping[str, Any] | None = None,
    *,
    attributes: Mapping[str, Any] | None = None,
    source_profile: bool = True,
) -> FileResult:
    """Write ``result`` (the output of ``src``, read into ``buffers`` with ``read``) to
    ``dst`` atomically, with the header attributes :func:`denoise_file` describes
    (``estimate``: ``--estimate-error``'s fields, written as ``mcdenoise:<field>``).

    The one writer of denoised outputs: ``mcdenoise denoise`` (:func:`denoise_file`,
    :mod:`mcdenoise.batch`), the experiment runner's outputs and a sequence experiment's
    frames (:mod:`mcdenoise.experiments`). ``attributes``: more header attributes, set last
    (they override the ones above: an experiment's median seconds, its label, its level's
    spp, a frame's number); ``source_profile=False`` leaves ``mcdenoise:source_profile``
    out (experiment outputs do not record it).
    """

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
    if source_profile and buffers.profile and ":" in buffers.profile:
        # the profile names an image inside the file (a Cycles view layer: "cycles:Layer2"):
        # `mcdenoise eval` reads the source, and the reference, with it
        attrs["mcdenoise:source_profile"] = buffers.profile
    if buffers.spp is not None:
        attrs["mcdenoise:spp"] = int(buffers.spp)
    for key, value in (estimate or {}).items():
        if value is not None:  # a null of the JSON record is no header attribute
            attrs[f"mcdenoise:{key}"] = value
    attrs.update(attributes or {})
    try:  # `-o out/x.exr` with no out/ yet: created now that there is something to write
        dst.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"cannot create the output folder {dst.parent}: {err.strerror}") from err
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
