"""The one entry point every front end calls: ``denoise`` (in memory) and ``denoise_file``.

``mcdenoise denoise``, ``mcdenoise eval`` and the experiment runner all go through
:func:`denoise` (in memory) or :func:`denoise_file` (EXR in, EXR out), so a method registered
in :mod:`mcdenoise.registry` (see there for what a method is) is available everywhere.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from mcdenoise import __version__
from mcdenoise import methods as _builtin_methods  # noqa: F401  (registers the built-ins)
from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers, sanitize
from mcdenoise.registry import (
    Method,
    available_methods,
    best_method,
    get_method,
    methods,
    params_from_strings,
    register,
)

__all__ = [
    "DenoiseResult",
    "FileResult",
    "Method",
    "ReadOptions",
    "WriteOptions",
    "available_methods",
    "best_method",
    "collect_inputs",
    "denoise",
    "denoise_file",
    "get_method",
    "methods",
    "params_from_strings",
    "parse_methods",
    "plan_outputs",
    "register",
    "resolve_device",
]


def parse_methods(spec: str) -> list[Method]:
    """``"auto"`` -> [best available]; ``"all"`` -> every available method; ``"a,b"`` -> those.

    >>> [m.name for m in parse_methods("nlm")]
    ['nlm']
    """
    spec = spec.strip()
    if spec == "auto":
        return [best_method()]
    if spec == "all":
        return available_methods()
    names = [s.strip() for s in spec.split(",") if s.strip()]
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
    """What :func:`denoise` returns: the image and how it was made."""

    image: torch.Tensor  # (3, H, W) float32, linear HDR, finite, >= 0
    method: str
    params: dict[str, Any]
    seconds: float  # wall time of the method itself (no file I/O)
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

    The input is sanitised first (NaN/Inf repaired, see :func:`mcdenoise.io.sanitize`); the
    output is float32 ``(3, H, W)`` on the CPU, finite and clamped at 0.
    """
    m = (
        best_method(buffers)
        if method == "auto"
        else (method if isinstance(method, Method) else get_method(method))
    )
    reason = m.unavailable()
    if reason:
        raise InputError(f"method {m.name!r} is not available: {reason}")
    buffers.require(m.requires, needed_by=f"method {m.name!r}")
    resolved = m.resolve_params(params)
    dev = resolve_device(device)
    if dev.type not in m.devices:
        raise InputError(f"method {m.name!r} does not run on {dev.type}")
    clean, repaired = sanitize(buffers.subset(set(m.requires) | set(m.uses)))
    clean = clean.to(dev)
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    start = time.perf_counter()
    with torch.no_grad():
        out = m.run(clean, resolved, dev)
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
    seconds = time.perf_counter() - start
    out = torch.nan_to_num(out.detach().to("cpu", torch.float32), nan=0.0, posinf=0.0, neginf=0.0)
    out = out.clamp_min(0.0)
    if tuple(out.shape) != (3, *buffers.shape):
        raise RuntimeError(f"method {m.name} returned shape {tuple(out.shape)}")
    return DenoiseResult(out, m.name, resolved, seconds, str(dev), repaired)


# --- files ----------------------------------------------------------------------------------


@dataclass
class ReadOptions:
    """How input files are read (see :func:`mcdenoise.io.load_buffers`)."""

    profile: str = "auto"
    mapping: str | None = None
    part: str | None = None
    spp: int | None = None


@dataclass
class WriteOptions:
    """How outputs are written: ``half`` (float16, clamped and counted) and compression."""

    half: bool = False
    compression: str = "zip"


@dataclass
class FileResult:
    input: Path
    output: Path
    result: DenoiseResult
    clamped: int = 0  # values clamped to the half range when writing

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
    the method, its parameters, the source file, the seconds the method took, the device and
    the sample count of the input. ``buffers``: the input already read with ``read`` (it is
    then not read again).
    """
    from mcdenoise.io import load_buffers, save_buffers

    read = read or ReadOptions()
    write = write or WriteOptions()
    src, dst = Path(input_path), Path(output_path)
    _check_output_path(src, dst)
    if buffers is None:
        buffers = load_buffers(
            src, profile=read.profile, mapping=read.mapping, part=read.part, spp=read.spp
        )
    result = denoise(buffers, method, params=params, device=device)
    out = FeatureBuffers(
        {"color": result.image},
        spp=buffers.spp,
        data_window=buffers.data_window,
        display_window=buffers.display_window,
    )
    attrs: dict[str, Any] = result.attributes()
    attrs["mcdenoise:source"] = str(src.resolve())
    if read.part is not None:
        attrs["mcdenoise:source_part"] = str(read.part)
    if buffers.spp is not None:
        attrs["mcdenoise:spp"] = int(buffers.spp)
    report = save_buffers(
        dst, out, half=write.half, compression=write.compression, attributes=attrs
    )
    clamped = sum(getattr(report, "clamped", {}).values())
    return FileResult(src, dst, result, clamped)


def _check_output_path(src: Path, dst: Path) -> None:
    if dst.exists() and dst.is_dir():
        raise InputError(f"output {dst} is a folder; give a file name ending in .exr")
    if dst.suffix.lower() != ".exr":
        raise InputError(f"output {dst} must end in .exr")
    if src.exists() and dst.exists() and src.resolve() == dst.resolve():
        raise InputError(f"output {dst} is the input file; choose another name")
    parent = dst.parent if str(dst.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"output folder {parent} is not writable")


def collect_inputs(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """Expand files and folders (``*.exr``, not recursive, sorted) into a list of EXR files."""
    from mcdenoise.io.atomic import TMP_PREFIX

    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(
                q
                for q in p.iterdir()
                if q.suffix.lower() == ".exr" and q.is_file() and not q.name.startswith(TMP_PREFIX)
            )
            if not found:
                raise InputError(f"folder {p} holds no .exr files")
            files.extend(found)
        elif p.exists():
            files.append(p)
        else:
            raise InputError(f"input {p} does not exist")
    if not files:
        raise InputError("no input files given")
    if len(set(f.resolve() for f in files)) != len(files):
        raise InputError("the same input file is given twice")
    return files


def plan_outputs(
    inputs: Sequence[Path],
    output: str | os.PathLike[str] | None,
    method_name: str,
    *,
    part: str | None = None,
) -> list[Path]:
    """Output path for each input.

    * one input and ``output`` a file name (``*.exr``) -> that file;
    * ``output`` a folder (existing, or a name without ``.exr``) -> ``folder/<stem>_<method>.exr``;
    * no ``output`` -> ``<stem>_<method>.exr`` next to each input.

    With ``part`` (a level of a multi-part file, e.g. ``spp16``) the name is
    ``<stem>_<part>_<method>.exr``, so outputs of different levels never collide.
    """
    if output is not None:
        out = Path(output)
        if out.suffix.lower() == ".exr" and not out.is_dir():
            if len(inputs) != 1:
                raise InputError(
                    f"{len(inputs)} inputs but -o {out} names one file; give a folder instead"
                )
            return [out]
        if out.exists() and not out.is_dir():
            raise InputError(f"output {out} exists and is not a folder")
        folders = [out] * len(inputs)
    else:
        folders = [p.parent for p in inputs]
    tag = f"_{part}" if part else ""
    outs = [f / f"{p.stem}{tag}_{method_name}.exr" for f, p in zip(folders, inputs)]
    if len(set(outs)) != len(outs):
        raise InputError("two inputs would write the same output name; use separate folders")
    return outs
