"""The table of denoising methods: register, list, look up, choose the default.

The default for an input (:func:`choose_method`, :func:`best_method`) is the first method,
best first (priority, then name), that is available here and accepts the input
(:meth:`Method.accepts <mcdenoise.method.Method.accepts>`: its required buffers are present and
its own check, e.g. what a learned model was trained with, passes); the methods passed over
are kept with the reason, which ``mcdenoise denoise --verbose`` prints. A plugin's method is
never the default, whatever its priority: it runs when a user names it (or ``all``).

What a method is (per-frame or temporal) is :class:`~mcdenoise.method.Method`, re-exported
here. The built-in methods are loaded explicitly on first use of the table
(:func:`mcdenoise.methods.builtin_methods`), so :func:`methods` lists the same methods in the
same order whichever module was imported first.

Adding a method::

    register(Method(name="my-filter", summary="...", requires=("color",), uses=("albedo",),
                    defaults={"radius": 10}, run=my_run, priority=10))

Two ways in from outside, without a change to mcdenoise (docs/methods.md, "Bring your own
denoiser"):

* **plugins**: every entry point of the group ``mcdenoise.methods`` (:data:`PLUGIN_GROUP`) of
  the installed packages is loaded with the built-ins (:func:`_load_plugins`). It gives a
  :class:`Method`, or a callable returning one or a list of them. A plugin that fails to
  load, gives something else, or names a built-in method is listed as an unavailable method
  with the reason, never an error of ``mcdenoise methods``; a built-in keeps its name (also
  against a plugin that calls :func:`register` while it loads). Plugin methods are in the
  table (``mcdenoise methods``, ``--method NAME``, ``all``) but never the default
  (:func:`choose_method`): installing a package must not silently change what a plain
  ``mcdenoise denoise`` runs.
* **commands**: ``get_method("cmd:PROGRAM ARGS {input} {output}")`` builds the method of an
  external command (:mod:`mcdenoise.methods.external`; building it runs nothing); it is not
  in the table (never a default, never part of ``all``) but is found again by its name
  (``cmd-PROGRAM-xxxxxx``).

A method name read from a file someone else may have written (an output's
``mcdenoise:method`` header) is looked up with :func:`header_method`: only the table, never a
command, so a file cannot make mcdenoise run a program.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from importlib import metadata
from typing import Any

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
    "PLUGIN_GROUP",
    "CheckFn",
    "Method",
    "MethodChoice",
    "RunFn",
    "SequenceFn",
    "add_command",
    "aliases",
    "available_methods",
    "best_method",
    "choose_method",
    "command_template",
    "dataclass_defaults",
    "get_method",
    "header_method",
    "is_command",
    "is_plugin",
    "method_aliases",
    "methods",
    "params_from_strings",
    "parse_methods",
    "recorded_speed",
    "register",
]

_REGISTRY: dict[str, Method] = {}
_ALIASES: dict[str, str] = {}
#: ``cmd:`` methods built so far: their name and their ``cmd:...`` text -> the method.
_COMMANDS: dict[str, Method] = {}
#: Names of the table's methods that came from plugins (never the default).
_PLUGINS: set[str] = set()
#: A command method's generated name (:func:`mcdenoise.methods.external.method_name`).
_COMMAND_NAME = re.compile(r"^cmd-[A-Za-z0-9_.-]+-[0-9a-f]{6}$")
#: The entry-point group a package declares its methods in.
PLUGIN_GROUP = "mcdenoise.methods"
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
        from mcdenoise.methods import builtin_methods  # lazy: optional, see except

        builtin = builtin_methods()
        for method, aliases in builtin:
            _REGISTRY.setdefault(method.name, method)
            for alias in aliases:
                _ALIASES.setdefault(alias, method.name)
        reserved = {m.name for m, _ in builtin} | {a for _, al in builtin for a in al}
        for method in _load_plugins(reserved):
            _REGISTRY.setdefault(method.name, method)
            _PLUGINS.add(method.name)
    except BaseException:
        _builtins["state"] = "no"  # the next call raises the same error again
        raise
    _builtins["state"] = "done"


def _entry_points() -> Iterable[Any]:
    """The installed entry points of :data:`PLUGIN_GROUP` (a seam for tests)."""
    return metadata.entry_points(group=PLUGIN_GROUP)


def _load_plugins(reserved: Collection[str]) -> list[Method]:
    """The methods of every plugin entry point, in entry-point name order.

    An entry point's object is a :class:`Method`, or a callable returning a Method or an
    iterable of them. What fails (the import, the call, anything but Methods, a name in
    ``reserved``: the built-ins and their aliases) becomes an unavailable method named after
    the entry point (``plugin:NAME`` when that name is taken) whose reason is the error, one
    line; ``mcdenoise methods`` lists it, and using it says why it cannot run.
    """
    try:
        eps = sorted(_entry_points(), key=lambda ep: (ep.name, ep.value))
    except Exception as err:  # a broken installation: no plugins, said once
        return [_broken("plugins", "entry points", f"cannot list the installed plugins: {err}")]
    out: list[Method] = []
    seen = set(reserved)
    for ep in eps:
        try:
            obj = ep.load()
            got = obj() if callable(obj) and not isinstance(obj, Method) else obj
            if isinstance(got, Method):
                found = [got]
            elif isinstance(got, Iterable) and not isinstance(got, (str, bytes)):
                found = list(got)
            else:
                raise TypeError(f"gave {type(got).__name__}, not mcdenoise.method.Method")
            bad = [type(m).__name__ for m in found if not isinstance(m, Method)]
            if bad or not found:
                what = f"gave {', '.join(bad)}" if bad else "gave no method"
                raise TypeError(f"{what}, not mcdenoise.method.Method")
            taken = [m.name for m in found if m.name in seen]
            if taken:
                raise ValueError(f"method name {taken[0]!r} is already taken")
        except (Exception, SystemExit) as err:  # a plugin's sys.exit() is its failure too
            reason = " ".join(f"{type(err).__name__}: {err}".split())
            name = ep.name if ep.name not in seen else f"plugin:{ep.name}"
            seen.add(name)
            out.append(_broken(name, ep.value, reason))
            continue
        seen.update(m.name for m in found)
        out += found
    return out


def _broken(name: str, where: str, reason: str) -> Method:
    """The stand-in of a plugin that could not be loaded: unavailable, with the reason."""
    why = f"plugin {where} failed to load: {reason}"

    def refuse(b: FeatureBuffers, p: Any, d: Any) -> Any:
        raise InputError(f"method {name!r} is not available: {why}")

    unavailable: Callable[[], str | None] = lambda: why  # noqa: E731
    return Method(
        name, f"plugin {where} (not loaded)", ("color",), (), {}, refuse, -1000, unavailable
    )


def register(method: Method, *, aliases: Iterable[str] = ()) -> Method:
    """Add ``method`` to the registry (replacing one of the same name, built-ins included).

    Called by a plugin while the plugins load (its module's import, its entry point's
    callable), the method is a plugin's: never the default, and it may not take a name of
    the table (``InputError``, which makes that plugin an unavailable entry).
    """
    _ensure_builtins()
    if _builtins["state"] == "loading":
        taken = [n for n in (method.name, *aliases) if n in _REGISTRY or n in _ALIASES]
        if taken:
            raise InputError(f"method name {taken[0]!r} is already taken")
        _PLUGINS.add(method.name)
    _REGISTRY[method.name] = method
    for alias in aliases:
        _ALIASES[alias] = method.name
    return method


def methods() -> list[Method]:
    """All registered methods, best first (priority, then name)."""
    _ensure_builtins()
    return sorted(_REGISTRY.values(), key=lambda m: (-m.priority, m.name))


def recorded_speed(speed_name: str) -> tuple[float, float] | None:
    """The recorded one-thread speed ``(fixed seconds, seconds per megapixel)`` under
    ``speed_name`` (:meth:`Method.speed_name`), from the declaration of the registered method
    that records it (:attr:`Method.recorded_speed`); ``None`` when none does."""
    _ensure_builtins()
    for method in _REGISTRY.values():
        speed = method.recorded_speed.get(speed_name)
        if speed is not None:
            return speed
    return None


def get_method(name: str) -> Method:
    """The method called ``name`` (or an alias); ``InputError`` listing the known ones."""
    _ensure_builtins()
    if name.startswith("cmd:") or name in _COMMANDS:
        return _command(name)
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        known = ", ".join(m.name for m in methods())
        raise InputError(f"unknown method {name!r} (known: {known})")
    return _REGISTRY[key]


def is_command(name: str) -> bool:
    """Whether ``name`` is an external command: ``cmd:...``, a command built before, or a
    name of the generated form ``cmd-PROGRAM-xxxxxx`` that no table method has."""
    name = name.strip()
    if name.startswith("cmd:") or name in _COMMANDS:
        return True
    _ensure_builtins()
    return bool(_COMMAND_NAME.match(name)) and name not in _REGISTRY


def command_template(name: str) -> str | None:
    """The command template ``name`` runs: the text after ``cmd:``, or the template of a
    command built before under that name; ``None`` for anything else. Builds nothing."""
    name = name.strip()
    if name.startswith("cmd:"):
        return name.removeprefix("cmd:").strip()
    known = _COMMANDS.get(name)
    return None if known is None else str(known.defaults["command"])


def header_method(name: str, where: str, *, what: str = "its header") -> Method:
    """The method a file names: an output's header (``mcdenoise:method``), a model file's
    card (``what``), in the file ``where``. Only a method of the table (a built-in, an
    installed plugin) or one of its aliases: a file may come from anyone, so the name it
    holds never builds or finds an external command (that would run a program the file
    chose) and never names a method that is not installed here.

    Raises:
        InputError: one line naming ``where``: a command, or a method not in the table.
    """
    if is_command(name):
        raise InputError(
            f"{where}: {what} names the external command {name.strip()!r}: not run (a file "
            "never makes mcdenoise run a program; run it yourself with --method 'cmd:...')"
        )
    _ensure_builtins()
    key = _ALIASES.get(name, name)
    if key not in _REGISTRY:
        raise InputError(f"{where}: {what} names method {name!r}, which is not installed here")
    return _REGISTRY[key]


def _command(name: str) -> Method:
    """The method of an external command ``cmd:...`` (built once), or one built before,
    by its name."""
    key = name.strip()
    if key not in _COMMANDS:
        add_command(key.removeprefix("cmd:"))
    return _COMMANDS[key]


def add_command(command: str, *, name: str | None = None) -> Method:
    """The method of the external command template ``command`` (without ``cmd:``), found
    from now on by :func:`get_method` under ``name`` (default ``cmd-PROGRAM-xxxxxx``) and as
    ``cmd:COMMAND`` when it has no ``name`` (``cmd:COMMAND`` is always the default-named
    method, whatever was added before); not in the table, so never a default nor part of ``all``. For an
    experiment's named commands (``[[methods.external]] name = ..., command = ...``).

    Raises:
        InputError: a bad template, or ``name`` taken by a method of the table or by another
            command.
    """

    from mcdenoise.methods.external import command_method  # lazy: start-up (cmd: only)

    _ensure_builtins()
    method = command_method(command, name=name)
    if method.name in _REGISTRY or method.name in _ALIASES:
        raise InputError(f"external method name {method.name!r} is taken by a method")
    old = _COMMANDS.get(method.name)
    if old is not None and old.defaults["command"] != method.defaults["command"]:
        raise InputError(f"external method name {method.name!r} names two commands")
    _COMMANDS[method.name] = method
    if name is None:
        _COMMANDS["cmd:" + command.strip()] = method
    return method


def available_methods() -> list[Method]:
    """Registered methods that can run on this machine, best first."""
    return [m for m in methods() if m.unavailable() is None]


def is_plugin(name: str) -> bool:
    """Whether the table's method ``name`` came from a plugin (never the default)."""
    _ensure_builtins()
    return name in _PLUGINS


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
    """The default method for ``buffers``: the best available one that accepts them, among
    the methods that are not a plugin's (a plugin runs when named; ranked above the choice,
    it is in ``skipped`` with that reason).

    ``exclude``: names of methods not to consider (ones that already failed on this input;
    the caller keeps their reasons).

    Raises:
        InputError: no method accepts the input (the message gives each one's reason).
    """
    skipped: list[tuple[str, str]] = []
    for m in methods():
        if m.name in exclude:
            continue
        if m.name in _PLUGINS:
            skipped.append((m.name, "a plugin: never the default (name it with --method)"))
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
    best available method that is not a plugin's (what an input with every buffer and its
    variance gets)."""
    if buffers is not None:
        return choose_method(buffers).method
    for m in available_methods():
        if m.name not in _PLUGINS:
            return m
    raise InputError("no denoising method is available here")


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
