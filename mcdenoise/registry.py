"""The method registry: what a denoising method is, and the table of registered methods.

Built-in methods register themselves in :mod:`mcdenoise.methods`; :mod:`mcdenoise.denoise`
imports that module, so going through ``mcdenoise.denoise`` always sees them.

Adding a method::

    register(Method(name="my-filter", summary="...", requires=("color",), uses=("albedo",),
                    defaults={"radius": 10}, run=my_run, priority=10))
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers

RunFn = Callable[[FeatureBuffers, Mapping[str, Any], torch.device], torch.Tensor]


@dataclass(frozen=True)
class Method:
    """A registered denoiser.

    Attributes:
        name: registry key used by ``--method``.
        summary: one line for ``mcdenoise methods``.
        requires: buffers the method cannot run without (``MissingFeatureError`` otherwise).
        uses: buffers it uses when present.
        defaults: tunable parameters and their defaults (``--param key=value`` overrides;
            values are coerced to the default's type).
        run: ``run(buffers, params, device) -> (3, H, W)`` linear HDR RGB on any device.
            ``buffers`` are sanitised (no NaN/Inf) and on ``device``.
        priority: higher wins when the user gives no ``--method``.
        unavailable: returns ``None`` when the method can run here, else a reason.
        devices: devices the method supports (``"cpu"``, ``"cuda"``).
    """

    name: str
    summary: str
    requires: tuple[str, ...]
    uses: tuple[str, ...]
    defaults: Mapping[str, Any]
    run: RunFn
    priority: int = 0
    unavailable: Callable[[], str | None] = field(default=lambda: None)
    devices: tuple[str, ...] = ("cpu", "cuda")

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


_REGISTRY: dict[str, Method] = {}
_ALIASES: dict[str, str] = {}


def register(method: Method, *, aliases: Iterable[str] = ()) -> Method:
    """Add ``method`` to the registry (replacing one of the same name)."""
    _REGISTRY[method.name] = method
    for alias in aliases:
        _ALIASES[alias] = method.name
    return method


def methods() -> list[Method]:
    """All registered methods, best first."""
    return sorted(_REGISTRY.values(), key=lambda m: (-m.priority, m.name))


def get_method(name: str) -> Method:
    """The method called ``name`` (or an alias); ``InputError`` listing the known ones."""
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        known = ", ".join(m.name for m in methods())
        raise InputError(f"unknown method {name!r} (known: {known})")
    return _REGISTRY[key]


def available_methods() -> list[Method]:
    """Registered methods that can run on this machine, best first."""
    return [m for m in methods() if m.unavailable() is None]


def best_method(buffers: FeatureBuffers | None = None) -> Method:
    """The best available method (for ``buffers``: one whose required buffers are present)."""
    for m in available_methods():
        if buffers is None or all(r in buffers for r in m.requires):
            return m
    raise InputError("no denoising method can run on this input")


def params_from_strings(items: Iterable[str], option: str = "--param") -> dict[str, str]:
    """Parse ``key=value`` strings (from ``option``, e.g. ``--param``) into a dict."""
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
