"""What a denoising method is: the :class:`Method` contract, per-frame or temporal.

A method turns :class:`~mcdenoise.io.FeatureBuffers` into a denoised colour image. It is one
of two kinds:

* **per-frame** (``temporal=False``, the default): ``run(buffers, params, device)`` denoises
  one image; a sequence is denoised frame by frame, each frame on its own.
* **temporal** (``temporal=True``): ``run_sequence(frames, params, device)`` is a generator
  that receives the frames of *one* sequence in order and yields one output per frame. It may
  keep whatever state it needs between frames (a history buffer, the previous output, a
  moving average); it may read frame ``t + 1`` before yielding the output of frame ``t``. The
  motion buffers (``motion``, ``motion_valid``: see :mod:`mcdenoise.io.buffers`) reach it when
  the method lists them in ``requires`` or ``uses``.

Every frame a method sees is sanitised (no NaN/Inf, see :func:`mcdenoise.io.sanitize`), holds
only the buffers of ``requires`` and ``uses`` that the input has, and is on ``device``. Every
output is ``(3, H, W)`` linear HDR RGB on any device;
:func:`mcdenoise.denoise.denoise_sequence` moves it to the CPU, repairs and clamps it.

This module is the contract only; :mod:`mcdenoise.registry` holds the table of methods (and
re-exports these names), :mod:`mcdenoise.methods` the built-in ones.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers

#: ``run(buffers, params, device) -> (3, H, W)``: one frame.
RunFn = Callable[[FeatureBuffers, Mapping[str, Any], torch.device], torch.Tensor]
#: ``run_sequence(frames, params, device)`` yields one ``(3, H, W)`` per frame, in order.
SequenceFn = Callable[
    [Iterable[FeatureBuffers], Mapping[str, Any], torch.device], Iterator[torch.Tensor]
]
#: ``check_input(buffers, params) -> None`` when the method can run on ``buffers`` with
#: ``params`` (its defaults updated), else the reason it cannot, one line.
CheckFn = Callable[[FeatureBuffers, Mapping[str, Any]], str | None]


@dataclass(frozen=True)
class Method:
    """A denoiser that can be registered (:func:`mcdenoise.registry.register`).

    Attributes:
        name: registry key used by ``--method``.
        summary: one line for ``mcdenoise methods``.
        requires: buffers the method cannot run without (``MissingFeatureError`` otherwise).
        uses: buffers it uses when present.
        defaults: tunable parameters and their defaults (``--param key=value`` overrides;
            values are coerced to the default's type).
        run: ``run(buffers, params, device) -> (3, H, W)`` linear HDR RGB on any device.
            ``buffers`` are sanitised (no NaN/Inf) and on ``device``. ``None`` for a temporal
            method that only gives ``run_sequence``.
        priority: higher wins when the user gives no ``--method``.
        unavailable: returns ``None`` when the method can run here, else a reason.
        devices: devices the method supports (``"cpu"``, ``"cuda"``).
        temporal: the output of a frame depends on other frames of its sequence; the method
            gives ``run_sequence``.
        run_sequence: ``run_sequence(frames, params, device)``: a generator over the frames
            of one sequence (in order) yielding one ``(3, H, W)`` output per frame. Required
            when ``temporal``; a per-frame method leaves it ``None`` and
            :meth:`run_frames` runs ``run`` on each frame.
        check_input: ``check_input(buffers, params) -> str | None``: what the method needs
            beyond ``requires`` (a learned method: what its model was trained with, e.g. the
            variances of its guides); ``None`` when it can run, else the reason, one line.
            It looks at which buffers are present, not at their pixels. See :meth:`accepts`.
        speed_key: ``speed_key(params) -> str``: the name the method's speed is recorded
            under (:attr:`recorded_speed`) with these parameters, when they
            change its cost by far (``kalantari-xbf`` with ``select``); ``None``: its name.
        recorded_speed: the method's speed on one idle thread, ``speed name -> (fixed
            seconds, seconds per megapixel)`` (one frame of ``P`` megapixels is expected to
            take ``fixed + P * per_mp``), one entry per name :attr:`speed_key` gives; what
            :func:`mcdenoise.threads.check_speed` compares a run with (through
            :func:`mcdenoise.registry.recorded_speed`). ``benchmarks/bench_threads.py
            --calibrate`` prints the entries to paste; how they were measured is in
            ``docs/results/threads.md``. Empty: the method is never warned about.
    """

    name: str
    summary: str
    requires: tuple[str, ...]
    uses: tuple[str, ...]
    defaults: Mapping[str, Any]
    run: RunFn | None
    priority: int = 0
    unavailable: Callable[[], str | None] = field(default=lambda: None)
    devices: tuple[str, ...] = ("cpu", "cuda")
    temporal: bool = False
    run_sequence: SequenceFn | None = None
    check_input: CheckFn | None = None
    speed_key: Callable[[Mapping[str, Any]], str] | None = None
    recorded_speed: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    def speed_name(self, params: Mapping[str, Any]) -> str:
        """The key of this method's recorded speed with ``params`` (:attr:`speed_key`)."""
        return self.name if self.speed_key is None else self.speed_key(params)

    def __post_init__(self) -> None:
        if self.temporal and self.run_sequence is None:
            raise ValueError(f"method {self.name!r} is temporal but gives no run_sequence")
        if self.run is None and self.run_sequence is None:
            raise ValueError(f"method {self.name!r} gives neither run nor run_sequence")

    def run_frames(
        self, frames: Iterable[FeatureBuffers], params: Mapping[str, Any], device: torch.device
    ) -> Iterator[torch.Tensor]:
        """The outputs for ``frames`` (one sequence, in order): ``run_sequence`` when the
        method gives one, else ``run`` on each frame alone."""
        if self.run_sequence is not None:
            return iter(self.run_sequence(frames, params, device))
        run = self.run
        assert run is not None  # __post_init__
        return (run(f, params, device) for f in frames)

    def accepts(
        self, buffers: FeatureBuffers, params: Mapping[str, Any] | None = None
    ) -> str | None:
        """``None`` when the method can denoise ``buffers`` with ``params`` (overrides of its
        defaults), else why not, one line: a buffer of ``requires`` missing, or the method's
        own :attr:`check_input` (e.g. a model trained with variances the input does not have).

        The default method (:func:`mcdenoise.registry.choose_method`) skips a method that
        refuses, and ``--method all`` skips it on that input, with this reason.
        """
        missing = [r for r in self.requires if r not in buffers]
        if missing:
            have = ", ".join(sorted(buffers.buffers)) or "nothing"
            return f"needs {', '.join(missing)}; the input has {have}"
        if self.check_input is None:
            return None
        return self.check_input(buffers, self.resolve_params(params))

    def resolve_params(self, overrides: Mapping[str, Any] | None) -> dict[str, Any]:
        """Defaults updated with ``overrides`` (strings coerced to the default's type)."""
        params = dict(self.defaults)
        for key, value in (overrides or {}).items():
            if key not in params:
                known = ", ".join(sorted(params)) or "none"
                raise InputError(f"method {self.name!r} has no parameter {key!r} (known: {known})")
            params[key] = _coerce(key, value, params[key])
        return params


def _coerce(key: str, value: Any, default: Any) -> Any:
    if not isinstance(value, str) or isinstance(default, str):
        return value
    if isinstance(default, tuple):  # comma-separated list, e.g. features=albedo,normal
        return tuple(v.strip() for v in value.split(",") if v.strip())
    try:
        if isinstance(default, bool):
            low = value.lower()
            if low not in ("1", "0", "true", "false", "yes", "no"):
                raise ValueError(value)
            return low in ("1", "true", "yes")
        if isinstance(default, int):
            return int(value)
        if isinstance(default, float) or default is None:
            return float(value)
    except ValueError:
        kind = type(default).__name__ if default is not None else "number"
        raise InputError(f"parameter {key}={value!r} is not a valid {kind}") from None
    return value


def params_from_strings(items: Iterable[str], option: str = "--param") -> dict[str, str]:
    """Parse ``key=value`` strings (from ``option``, e.g. ``--param``) into a dict.

    >>> params_from_strings(["radius=7", " k = 0.5 "])
    {'radius': '7', 'k': '0.5'}
    """
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"{option} expects key=value, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def dataclass_defaults(cls: type) -> dict[str, Any]:
    """Defaults of a parameter dataclass as a plain dict (for :attr:`Method.defaults`)."""
    return {f.name: f.default for f in dataclasses.fields(cls)}


def check_choice(method: str, param: str, value: str, choices: Iterable[str]) -> str:
    """``value`` when it is one of ``choices``; else ``InputError`` naming the method and
    parameter (``"kpcn: prefilter must be one of ..."``)."""
    choices = tuple(choices)
    if value not in choices:
        raise InputError(f"{method}: {param} must be one of {', '.join(choices)}, got {value!r}")
    return value


def check_frame_size(
    method: str, index: int, shape: tuple[int, int], size: tuple[int, int] | None
) -> tuple[int, int]:
    """The size of a sequence, ``(H, W)``: frame ``index``'s ``shape`` when it is the first
    (``size`` ``None``), else ``size`` after checking that frame ``index`` has it
    (``InputError`` otherwise: a temporal method needs one size for every frame)."""
    if size is not None and shape != size:
        raise InputError(
            f"{method}: frame {index} is {shape[1]}x{shape[0]} but the sequence is "
            f"{size[1]}x{size[0]}: every frame of a sequence must have one size"
        )
    return shape if size is None else size


__all__ = [
    "CheckFn",
    "Method",
    "RunFn",
    "SequenceFn",
    "check_choice",
    "check_frame_size",
    "dataclass_defaults",
    "params_from_strings",
]
