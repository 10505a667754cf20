"""The one entry point every front end calls: a sequence of frames in, one result per frame.

:func:`denoise_sequence` denoises the frames of one sequence with one method; :func:`denoise`
is its one-frame case. Files are read and written around it by :mod:`mcdenoise.output`
(:func:`~mcdenoise.output.denoise_file`), and ``mcdenoise denoise``'s batches of files and
sequences are :mod:`mcdenoise.batch`.
``mcdenoise denoise``, ``mcdenoise experiment`` and the
experiment runner all come through here, so a method registered in :mod:`mcdenoise.registry`
(see :mod:`mcdenoise.method` for what a method is: per-frame or temporal) is available
everywhere, with the same input sanitising, checks, timing and output repair.
"""

from __future__ import annotations

import itertools
import json
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch

from mcdenoise import __version__
from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers, MissingFeatureError, sanitize
from mcdenoise.registry import Method, best_method, choose_method, get_method
from mcdenoise.threads import check_speed, wait_policy

__all__ = [
    "DenoiseResult",
    "denoise",
    "denoise_sequence",
    "resolve_device",
]


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
