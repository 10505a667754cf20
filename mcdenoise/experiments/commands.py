"""The external programs an experiment spec names: what it would run, and paths beside it.

A spec that runs programs is refused unless the user allows it
(:func:`mcdenoise.experiments.spec.parse_experiment`, ``--allow-commands``); the refusal lists
:func:`spec_commands`. :func:`spec_relative` makes a command's script beside the spec
absolute, so the spec runs from any folder. Both only read: they register and run nothing.
"""

from __future__ import annotations

import os
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.methods.external import is_interpreter
from mcdenoise.registry import command_template


def spec_commands(
    top: Mapping[str, Any], *, base: str | os.PathLike[str] | None = None
) -> list[tuple[str, str]]:
    """Every external command the spec ``top`` (a parsed TOML table) would run, as
    ``(where, command line)``: each ``[[external]]`` command (as it would run: paths beside
    the spec made absolute, :func:`spec_relative`) and each ``cmd:...`` method, or a command
    method built before in this process, named in ``methods``, ``[params]`` or a
    ``[[sweep]]``. Looks only: registers and runs nothing, and skips what is malformed
    (the parser says what is wrong with it)."""

    folder = None if base is None else Path(base)
    out: list[tuple[str, str]] = []

    def named(where: str, name: Any) -> None:
        text = command_template(name) if isinstance(name, str) else None
        if text is not None:
            out.append((where, text))

    ext = top.get("external", [])
    if isinstance(ext, Mapping):
        ext = [ext]
    elif not isinstance(ext, Sequence) or isinstance(ext, str):
        ext = []  # external = 5: malformed, the parser says so
    for i, entry in enumerate(ext):
        if isinstance(entry, Mapping) and isinstance(entry.get("command"), str):
            name = entry.get("name")
            where = f"external[{i}]" + (f" {name!r}" if isinstance(name, str) else "")
            out.append((where, spec_relative(folder, entry["command"].strip())))
    raw = top.get("methods")
    if isinstance(raw, Sequence) and not isinstance(raw, str):
        for i, name in enumerate(raw):
            named(f"methods[{i}]", name)
    params = top.get("params")
    if isinstance(params, Mapping):
        for name in params:
            named(f"params.{name}", name)
    sweeps = top.get("sweep")
    if isinstance(sweeps, Sequence) and not isinstance(sweeps, str):
        for i, sw in enumerate(sweeps):
            if isinstance(sw, Mapping):
                named(f"sweep[{i}].method", sw.get("method"))
    first: dict[str, str] = {}  # a command named twice is listed once
    for where, cmd in out:
        first.setdefault(cmd, where)
    return [(where, cmd) for cmd, where in first.items()]


def spec_relative(base: Path | None, command: str) -> str:
    """``command`` with the tokens that name a path, and exist relative to the spec's
    folder ``base``, made absolute, so a script beside the spec runs whatever folder
    mcdenoise is started in: the program when it holds a path separator (``./den``; a bare
    name is looked up on PATH), an interpreter's script (``python my.py``) and every other
    token holding a separator (``models/w.pt``). A plain word stays as written even when a
    file of that name lies beside the spec, as on the command line
    (:func:`mcdenoise.methods.external._absolute_args`); tokens with placeholders or options
    are left alone."""

    if base is None:
        return command
    try:
        tokens = shlex.split(command)
    except ValueError:
        return command  # the template parser names the problem
    changed = False
    for i, token in enumerate(tokens):
        if not token or token.startswith("-") or "{" in token or Path(token).is_absolute():
            continue
        script = i == 1 and is_interpreter(tokens[0])
        if not (script or os.sep in token or "/" in token):
            continue
        p = base / token
        if p.exists():
            tokens[i] = str(p.resolve())
            changed = True
    return shlex.join(tokens) if changed else command


__all__ = ["spec_commands", "spec_relative"]
