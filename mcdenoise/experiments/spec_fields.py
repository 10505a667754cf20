"""The checked readers of an experiment spec's fields: each reads one value, checks it and names
the key (``render.spp[2]: ...``) in its :class:`ExperimentError`; the external-command table and
the animation of a scene. :func:`mcdenoise.experiments.spec.parse_experiment` puts them together.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcdenoise.errors import McdenoiseError
from mcdenoise.eval.metrics import resolve_metrics
from mcdenoise.eval.temporal_metrics import is_temporal, resolve_sequence_metrics
from mcdenoise.experiments.commands import spec_relative
from mcdenoise.methods.external import CommandParams
from mcdenoise.registry import add_command, aliases, get_method, methods
from mcdenoise.render.scene_spec import SpecError, collect_specs, load_spec


class ExperimentError(McdenoiseError, ValueError):
    """A bad experiment spec or experiment folder; the message names the file and key."""


class _Ctx:
    """Where we are in the spec, for error messages."""

    def __init__(self, source: str, base: Path | None) -> None:
        self.source = source
        self.base = base

    def error(self, key: str, msg: str) -> ExperimentError:
        return ExperimentError(f"{self.source}: {key + ': ' if key else ''}{msg}")

    def resolve(self, value: str) -> Path:
        p = Path(value).expanduser()
        if not p.is_absolute() and self.base is not None:
            p = self.base / p
        return p.resolve()


def _table(
    ctx: _Ctx, key: str, value: Any, allowed: Sequence[str] | None = None
) -> Mapping[str, Any]:
    """``value`` as a table; with ``allowed``, unknown keys are an error naming them."""
    if not isinstance(value, Mapping):
        raise ctx.error(key, f"must be a table, got {type(value).__name__}")
    if allowed is not None:
        unknown = sorted(set(value) - set(allowed))
        if unknown:
            raise ctx.error(
                key or "top level",
                f"unknown key(s) {', '.join(unknown)} (allowed: {', '.join(allowed)})",
            )
    return value


def _int(ctx: _Ctx, key: str, value: Any, *, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.error(key, f"must be an integer, got {value!r}")
    if value < lo:
        raise ctx.error(key, f"must be >= {lo}, got {value}")
    return value


def _str(ctx: _Ctx, key: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ctx.error(key, f"must be a non-empty string, got {value!r}")
    return value.strip()


def _list(ctx: _Ctx, key: str, value: Any) -> list[Any]:
    if isinstance(value, str) or not isinstance(value, Sequence) or not value:
        raise ctx.error(key, f"must be a non-empty list, got {value!r}")
    return list(value)


def _spp_ladder(ctx: _Ctx, key: str, value: Any) -> tuple[int, ...]:
    levels = tuple(_int(ctx, f"{key}[{i}]", v, lo=1) for i, v in enumerate(_list(ctx, key, value)))
    if any(b <= a for a, b in itertools.pairwise(levels)):
        raise ctx.error(key, f"must be strictly increasing, got {list(levels)}")
    return levels


def _scene_files(ctx: _Ctx, key: str, value: Any) -> tuple[Path, ...]:

    files: list[Path] = []
    for i, item in enumerate(_list(ctx, key, value)):
        p = ctx.resolve(_str(ctx, f"{key}[{i}]", item))
        try:
            files.extend(collect_specs([p]))
        except SpecError:  # named as the experiment spec names it
            what = (
                f"folder {item!r} holds no *.toml scene spec"
                if p.is_dir()
                else f"{item!r} not found (looked at {p})"
            )
            raise ctx.error(f"{key}[{i}]", what) from None
    if len(set(files)) != len(files):
        raise ctx.error(key, "names a scene spec twice")
    return tuple(files)


def _method_name(ctx: _Ctx, key: str, value: Any) -> str:

    name = _str(ctx, key, value)
    if name == NOISY:
        return name
    try:
        get_method(name)
    except McdenoiseError as err:
        raise ctx.error(key, str(err)) from None
    return name


def _check_params(ctx: _Ctx, key: str, method: str, params: Mapping[str, Any]) -> None:

    if method == NOISY:
        if params:
            raise ctx.error(key, "'noisy' (plain rendering) has no parameters")
        return
    try:
        m = get_method(method)
        if isinstance(m.defaults, CommandParams):  # checked without running the program
            m = dataclasses.replace(m, defaults=m.defaults.unasked())
        m.resolve_params(params)
    except McdenoiseError as err:
        raise ctx.error(key, str(err)) from None


def _externals(ctx: _Ctx, value: Any) -> tuple[External, ...]:
    """``[[external]]`` entries, checked and registered (:func:`mcdenoise.registry.add_command`)
    under their names, so the rest of the spec can name them."""
    if isinstance(value, Mapping):
        value = [value]  # `[external]` (one table) read as one entry
    if not isinstance(value, Sequence) or isinstance(value, str):
        raise ctx.error("external", "must be a list of [[external]] tables")

    builtin = {m.name for m in methods()} | set(aliases()) | {NOISY}
    out: list[External] = []
    for i, raw in enumerate(value):
        key = f"external[{i}]"
        entry = _table(ctx, key, raw, _EXTERNAL_KEYS)
        for required in ("name", "command"):
            if required not in entry:
                raise ctx.error(f"{key}.{required}", "missing")
        name = _str(ctx, f"{key}.name", entry["name"])
        if name in builtin:
            raise ctx.error(f"{key}.name", f"{name!r} is a built-in method; choose another name")
        if name.startswith("cmd:") or any(c in name for c in "[]"):
            raise ctx.error(f"{key}.name", f"{name!r}: a name may not start with 'cmd:' or hold []")
        if any(e.name == name for e in out):
            raise ctx.error(f"{key}.name", f"{name!r} names two [[external]] entries")
        command = spec_relative(ctx.base, _str(ctx, f"{key}.command", entry["command"]))
        timeout = entry.get("timeout")
        if timeout is not None and (
            isinstance(timeout, bool)
            or not isinstance(timeout, int | float)
            or not math.isfinite(timeout)
            or timeout <= 0
        ):
            raise ctx.error(f"{key}.timeout", f"must be seconds > 0, got {timeout!r}")
        try:
            add_command(command, name=name)
        except McdenoiseError as err:
            raise ctx.error(key, " ".join(str(err).split())) from None
        out.append(External(name, command, None if timeout is None else float(timeout)))
    return tuple(out)


def _metric_names(ctx: _Ctx, raw: Sequence[str], frames: int | None) -> tuple[str, ...]:
    """The spec's metrics: still ones (parts added), and temporal ones for sequences; relMSE
    (and for sequences temporal relMSE) required, since the curves and tables use them."""

    try:
        if frames is None:
            temporal = [m for m in raw if is_temporal(m.lower())]
            if temporal:
                raise ctx.error(
                    "metrics",
                    f"temporal metric(s) {', '.join(temporal)} need sequences "
                    "([render] frames = N)",
                )
            metrics = tuple(resolve_metrics(raw))
        else:
            metrics = tuple(resolve_sequence_metrics(raw))
    except ExperimentError:
        raise
    except McdenoiseError as err:
        raise ctx.error("metrics", str(err)) from None
    if "relmse" not in metrics:
        raise ctx.error("metrics", "must include relmse (the curves and tables use it)")
    if frames is not None and "trelmse" not in metrics:
        raise ctx.error(
            "metrics", "must include trelmse for sequences (the temporal tables use it)"
        )
    return metrics


def _animate(
    ctx: _Ctx, value: Any, specs: Sequence[Path], frames: int | None
) -> dict[str, dict[str, Any]]:
    """``[scenes.animate.<name>]``: per scene spec name, an ``animation`` table and a ``move``
    list (``{object, translate}``), checked for shape here and merged into the scene spec
    (validated by the render spec parser) when the jobs are made
    (:func:`mcdenoise.experiments.dataset.render_jobs`)."""
    table = _table(ctx, "scenes.animate", value)
    if not table:
        return {}
    if frames is None:
        raise ctx.error("scenes.animate", "only for sequences: set [render] frames = N")

    names: dict[str, Any] = {}
    for p in specs:
        try:
            names[load_spec(p).name] = p
        except SpecError as err:
            raise ctx.error("scenes.specs", str(err)) from None
    out: dict[str, dict[str, Any]] = {}
    for name, raw in table.items():
        key = f"scenes.animate.{name}"
        if name not in names:
            known = ", ".join(names) or "none"
            raise ctx.error(key, f"no scene spec named {name!r} (scenes: {known})")
        entry = dict(_table(ctx, key, raw, _ANIMATE_KEYS))
        if "animation" in entry:
            entry["animation"] = dict(_table(ctx, f"{key}.animation", entry["animation"]))
        moves = []
        for j, m in enumerate(entry.get("move", [])):
            mt = _table(ctx, f"{key}.move[{j}]", m, _MOVE_KEYS)
            if "object" not in mt or "translate" not in mt:
                raise ctx.error(f"{key}.move[{j}]", "needs object (an index) and translate")
            _int(ctx, f"{key}.move[{j}].object", mt["object"], lo=0)
            moves.append(dict(mt))
        if "move" in entry:
            entry["move"] = moves
        out[str(name)] = entry
    return out


@dataclass(frozen=True)
class External:
    """One ``[[external]]``: the command template ``command`` as the method ``name``."""

    name: str
    command: str
    timeout: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "command": self.command, "timeout": self.timeout}


#: The label of plain Monte Carlo rendering (no denoiser; denoise time 0).
NOISY = "noisy"


_ANIMATE_KEYS = ("animation", "move")


_EXTERNAL_KEYS = ("name", "command", "timeout")


_MOVE_KEYS = ("object", "translate")
