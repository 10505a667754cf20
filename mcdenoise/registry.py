"""The table of denoising methods: register, list, look up, choose the default.

The default for an input (:func:`choose_method`, :func:`best_method`) is the first method,
best first (priority, then name), that is available here and accepts the input
(:meth:`Method.accepts <mcdenoise.method.Method.accepts>`: its required buffers are present and
its own check, e.g. what a learned model was trained with, passes); the methods passed over
are kept with the reason, which ``mcdenoise denoise --verbose`` prints.

What a method is (per-frame or temporal) is :class:`~mcdenoise.method.Method`, re-exported
here. The built-in methods are loaded explicitly on first use of the table
(:func:`mcdenoise.methods.builtin_methods`), so :func:`methods` lists the same methods in the
same order whichever module was imported first.

Adding a method::

    register(Method(name="my-filter", summary="...", requires=("color",), uses=("albedo",),
                    defaults={"radius": 10}, run=my_run, priority=10))
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from dataclasses import dataclass

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.method import (
    CheckFn,
    Method,
    RunFn,
    SequenceFn,
    dataclass_defaults,
    params_from_strings,
)

__all__ = [
    "CheckFn",
    "Method",
    "MethodChoice",
    "RunFn",
    "SequenceFn",
    "aliases",
    "available_methods",
    "best_method",
    "choose_method",
    "dataclass_defaults",
    "get_method",
    "methods",
    "params_from_strings",
    "register",
]

_REGISTRY: dict[str, Method] = {}
_ALIASES: dict[str, str] = {}
#: "no" (built-ins not loaded yet), "loading" (their modules are being imported), "done".
_builtins = {"state": "no"}


def _ensure_builtins() -> None:
    """Add the built-in methods to the table, once, before anything reads or changes it.

    An entry already in the table keeps its place (a method registered, or a test's stand-in,
    is never replaced by a built-in of the same name).
    """
    if _builtins["state"] != "no":
        return
    _builtins["state"] = "loading"
    try:
        from mcdenoise.methods import builtin_methods

        for method, aliases in builtin_methods():
            _REGISTRY.setdefault(method.name, method)
            for alias in aliases:
                _ALIASES.setdefault(alias, method.name)
    except BaseException:
        _builtins["state"] = "no"  # the next call raises the same error again
        raise
    _builtins["state"] = "done"


def register(method: Method, *, aliases: Iterable[str] = ()) -> Method:
    """Add ``method`` to the registry (replacing one of the same name, built-ins included)."""
    _ensure_builtins()
    _REGISTRY[method.name] = method
    for alias in aliases:
        _ALIASES[alias] = method.name
    return method


def methods() -> list[Method]:
    """All registered methods, best first (priority, then name)."""
    _ensure_builtins()
    return sorted(_REGISTRY.values(), key=lambda m: (-m.priority, m.name))


def get_method(name: str) -> Method:
    """The method called ``name`` (or an alias); ``InputError`` listing the known ones."""
    _ensure_builtins()
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        known = ", ".join(m.name for m in methods())
        raise InputError(f"unknown method {name!r} (known: {known})")
    return _REGISTRY[key]


def available_methods() -> list[Method]:
    """Registered methods that can run on this machine, best first."""
    return [m for m in methods() if m.unavailable() is None]


def aliases() -> dict[str, str]:
    """Every alias and the method it names (``{"xbf": "cross-bilateral", ...}``), sorted."""
    _ensure_builtins()
    return dict(sorted(_ALIASES.items()))


@dataclass(frozen=True)
class MethodChoice:
    """The default method for one input and the better-ranked methods passed over.

    Attributes:
        method: the first method, best first, that is available and accepts the input.
        skipped: ``(name, reason)`` of each method ranked above it, in rank order: not
            available here, or refusing the input (:meth:`Method.accepts`).
    """

    method: Method
    skipped: tuple[tuple[str, str], ...] = ()


def choose_method(buffers: FeatureBuffers, *, exclude: Collection[str] = ()) -> MethodChoice:
    """The default method for ``buffers``: the best available one that accepts them.

    ``exclude``: names of methods not to consider (ones that already failed on this input;
    the caller keeps their reasons).

    Raises:
        InputError: no method accepts the input (the message gives each one's reason).
    """
    skipped: list[tuple[str, str]] = []
    for m in methods():
        if m.name in exclude:
            continue
        reason = m.unavailable()
        if reason is not None:
            skipped.append((m.name, f"not available here: {reason}"))
            continue
        reason = m.accepts(buffers)
        if reason is None:
            return MethodChoice(m, tuple(skipped))
        skipped.append((m.name, reason))
    why = "; ".join(f"{name}: {reason}" for name, reason in skipped) or "no method registered"
    raise InputError(f"no denoising method can run on this input ({why})")


def best_method(buffers: FeatureBuffers | None = None) -> Method:
    """The default method for ``buffers`` (:func:`choose_method`); without ``buffers``, the
    best available method (what an input with every buffer and its variance gets)."""
    if buffers is not None:
        return choose_method(buffers).method
    for m in available_methods():
        return m
    raise InputError("no denoising method is available here")
