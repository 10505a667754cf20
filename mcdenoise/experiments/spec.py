"""Experiment specs: which scenes, spp ladder, reference, methods, metrics and repetitions.

An experiment spec is a TOML file (``data/experiments/*.toml``) read by
``mcdenoise experiment SPEC -o DIR``. This module parses and validates it; it renders
nothing and runs nothing (that is :mod:`mcdenoise.experiments.runner`). Schema::

    name = "demo"                         # default: the file's stem
    description = "..."                   # optional
    methods = "all"                       # every registered method (unavailable ones are
                                          # listed as skipped, with the reason), or a list of
                                          # registry names/aliases; "noisy" is always included
    metrics = ["relmse", "ssim"]          # default: every registered metric
    repetitions = 3                       # timed denoise runs per input (median reported)
    warmup = 1                            # untimed runs before them, per input
    device = "cpu"                        # auto, cpu or cuda (a method that cannot run there
                                          # runs on the CPU, and the record says so)
    threads = 2                           # torch threads while denoising (default: torch's)

    [[external]]                          # a denoiser program, judged like the built-ins
    name = "mine"                         # its name in `methods`, [params.mine] and the report
    command = "python my.py {input} {output}"   # a command template (see below)
    timeout = 600                         # optional: seconds per frame (default 600)

    [scenes]                              # either scene specs to render ...
    specs = ["../scenes/cornell.toml"]    # files or folders of *.toml, relative to this file
    random = 4                            # plus N procedural scenes (default 0), scene k
                                          # being random_spec([render] seed, k)
    # folder = "../generated/train"       # ... or an existing `mcdenoise render` folder
                                          # (relative to this file; used as it is, never
                                          # rendered into; a folder of sequences, rendered
                                          # with --frames, makes a sequence experiment)
    # references = "../refs"             # a folder without manifest.json: its inputs
                                          # (any profile; or OIDN's training layout) and
                                          # their references (default: its ref/), matched
                                          # by name; render time unknown (see below)

    [scenes.animate.cornell]              # sequences only: motion for the scene spec named
    animation = { camera_path = "orbit", angle = 12 }   # "cornell": its [animation] table
    move = [{ object = 5, translate = [0.3, 0, 0] }]    # and objects[5].motion (over the
                                          # sequence), merged into the spec before it is
                                          # parsed (a curated still gains motion without a copy)

    [render]                              # how missing images are rendered
    resolution = 128                      # N or [width, height]
    spp = [1, 2, 4, 8, 16, 32, 64]        # the noisy ladder (progressive levels)
    ref_spp = 1024
    variant = "auto"                      # Mitsuba variant
    seed = 0                              # base seed of the images' sampler seeds and of
                                          # the procedural scenes (as `mcdenoise render --seed`)
    pass_spp = 128
    folder = "data"                       # render folder, relative to the output folder DIR
                                          # (kept: a second run renders nothing)
    frames = 12                           # optional: every scene is a sequence of N >= 2
                                          # frames (`mcdenoise render --frames N`); see below

    [params.nlm]                          # parameter overrides of one method
    search_radius = 8

    [[sweep]]                             # one extra method per value, labelled
    method = "xbf"                        # "xbf[kernel_size=5]" etc.
    param = "kernel_size"
    values = [5, 11, 21]
    params = { sigma_spatial = 4.0 }      # optional: fixed overrides for every value

    [stats]
    baseline = "oidn"                     # per-scene relMSE ratios are taken to this method
                                          # (a label); "noisy" when it is not in the run
    bootstrap = 2000                      # bootstrap resamples of the scenes
    confidence = 0.95
    seed = 0                              # seed of the bootstrap

    [report]
    strip_spp = 8                         # spp level of the image strips (default: the middle
                                          # level of the ladder)
    budgets = [0.5, 1, 2, 4]              # equal-time budgets in seconds (default: 8
                                          # log-spaced budgets over the measured total times)
    outputs = "all"                       # keep the denoised EXR of every level ("all") or of
                                          # the strip level only ("strip")
    warmup_frames = 2                     # sequences: first frames reported apart (history
                                          # warm-up, :mod:`mcdenoise.eval.temporal_metrics`)

With ``[scenes] folder``, the ladder, size and reference come from that folder's manifest;
``[render]`` may then only give ``spp``, a subset of the folder's levels.
A ``[scenes] folder`` without ``manifest.json`` (inputs from any renderer profile, or OIDN's
training layout) is read by :mod:`mcdenoise.experiments.folder_data`: the levels come from the
file names (or parts ``spp<n>``), the render seconds are unknown.

Sequences (``frames = N``, or a folder rendered with ``--frames``): every scene is a sequence
of ``N`` frames (:mod:`mcdenoise.render.animation`; camera path and moving objects from the
scene spec's ``[animation]`` and ``objects[i].motion``, or from ``[scenes.animate.<name>]``).
Each (sequence, spp, method) is one unit: the method runs over the whole sequence (a temporal
method through its ``run_sequence``, a per-frame one frame by frame), times are per frame, and
the metrics are those of :func:`mcdenoise.eval.temporal_metrics.sequence_metrics`: the per-frame
metrics averaged past the warm-up, the temporal ones (``trelmse``, ``tpsnr``, ``trmae``) and
the warm-up frames apart. ``metrics`` may then name temporal metrics and must include
``relmse`` and ``trelmse``; its default is every still and temporal metric.

External methods (``[[external]]``, an array of tables at the top level: TOML cannot hold both
``methods = [...]`` and a ``[[methods.external]]`` table under the same key): each entry is
registered as a method named ``name`` through :func:`mcdenoise.registry.add_command` before
``methods`` is checked, so ``name`` goes wherever a method name goes (``methods``,
``[params.NAME]``, ``[[sweep]] method``, ``[stats] baseline``). ``command`` is a template of
:mod:`mcdenoise.methods.external` (``{input}``/``{output}``, or OIDN's ``{color}``,
``{albedo}``, ``{normal}``); the program, an interpreter's script (``python my.py``) and
every token holding a path separator that name a file or folder existing relative to the
spec's folder are made absolute (``python my.py ...`` beside the spec works from any current
folder; :func:`~mcdenoise.experiments.commands.spec_relative`). ``timeout`` becomes the method's ``timeout`` parameter
(giving it in ``[params.NAME]`` too is an error). Like ``cmd:...`` methods on the command
line, external methods are never part of ``methods = "all"``: a spec that declares one lists
it in ``methods`` (or sweeps it), and ``"all"`` with an ``[[external]]`` that nothing names
is refused. A missing name or command, a name given twice, a name that is a built-in method
or alias (or ``noisy``), or a bad template is refused with one line. An external method's
times are the whole process (writing its inputs, starting it, its work, reading its output);
the report marks them (:func:`mcdenoise.experiments.timing.timing_clock`).

A spec that runs programs (an ``[[external]]`` entry, or a ``cmd:...`` method in ``methods``,
``[params]`` or a ``[[sweep]]``) is code: someone else's spec could run anything. Unless
``allow_commands`` is given (``mcdenoise experiment SPEC --allow-commands``) it is
refused before anything is registered or run, in one line listing every command line it
would run (:func:`~mcdenoise.experiments.commands.spec_commands`). Parsing runs no program either way: a command's
``--version`` is asked only when its parameters are resolved for a run
(:class:`mcdenoise.methods.external.CommandParams`).

Errors are :class:`ExperimentError` naming the file and the key, e.g.
``demo.toml: sweep[0].values[1]: method 'cross-bilateral' ...``. Method names and sweep
parameters are checked against the registry (:mod:`mcdenoise.registry`) when the spec is
loaded, so a typo fails before anything is rendered.
"""

from __future__ import annotations

import itertools
import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcdenoise.errors import McdenoiseError
from mcdenoise.experiments.commands import spec_commands, spec_relative

#: The label of plain Monte Carlo rendering (no denoiser; denoise time 0).
NOISY = "noisy"
#: Values of ``[report] outputs``.
OUTPUT_MODES = ("all", "strip")
#: Values of ``device``.
DEVICES = ("auto", "cpu", "cuda")

_TOP_KEYS = (
    "name",
    "description",
    "methods",
    "metrics",
    "repetitions",
    "warmup",
    "device",
    "threads",
    "external",
    "scenes",
    "render",
    "params",
    "sweep",
    "stats",
    "report",
)
_SCENE_KEYS = ("specs", "random", "folder", "references", "animate")
_ANIMATE_KEYS = ("animation", "move")
_MOVE_KEYS = ("object", "translate")
_RENDER_KEYS = (
    "resolution",
    "spp",
    "ref_spp",
    "variant",
    "seed",
    "pass_spp",
    "folder",
    "frames",
)
_SWEEP_KEYS = ("method", "param", "values", "params")
_EXTERNAL_KEYS = ("name", "command", "timeout")
_STATS_KEYS = ("baseline", "bootstrap", "confidence", "seed")
_REPORT_KEYS = ("strip_spp", "budgets", "outputs", "warmup_frames")


class ExperimentError(McdenoiseError, ValueError):
    """A bad experiment spec or experiment folder; the message names the file and key."""


@dataclass(frozen=True)
class Sweep:
    """One ``[[sweep]]``: ``method`` run once per value of ``param`` (plus fixed ``params``)."""

    method: str
    param: str
    values: tuple[Any, ...]
    params: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class External:
    """One ``[[external]]``: the command template ``command`` as the method ``name``."""

    name: str
    command: str
    timeout: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "command": self.command, "timeout": self.timeout}


@dataclass(frozen=True)
class ExperimentSpec:
    """A validated experiment spec (see the module docstring for the TOML schema).

    Paths are absolute (resolved against the spec file's folder), except ``render_folder``,
    which is relative to the output folder unless absolute.
    """

    name: str
    source: str = "<spec>"
    description: str = ""
    scene_specs: tuple[Path, ...] = ()
    random: int = 0
    folder: Path | None = None
    #: references of a folder without manifest (default: its ``ref/``)
    references: Path | None = None
    width: int = 128
    height: int = 128
    spp: tuple[int, ...] = (1, 2, 4, 8, 16)
    ref_spp: int = 1024
    variant: str = "auto"
    seed: int = 0
    pass_spp: int = 128
    render_folder: str = "data"
    methods: str | tuple[str, ...] = "all"
    params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    sweeps: tuple[Sweep, ...] = ()
    metrics: tuple[str, ...] | None = None
    repetitions: int = 3
    warmup: int = 1
    device: str = "cpu"
    threads: int | None = None
    baseline: str = NOISY
    bootstrap: int = 2000
    confidence: float = 0.95
    stats_seed: int = 0
    strip_spp: int | None = None
    budgets: tuple[float, ...] | None = None
    outputs: str = "all"
    spp_given: bool = True
    frames: int | None = None
    animate: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    warmup_frames: int = 2
    externals: tuple[External, ...] = ()

    def strip_level(self, levels: Sequence[int]) -> int:
        """The spp level of the image strips among ``levels``: ``strip_spp`` or the middle."""
        if self.strip_spp is not None:
            return self.strip_spp
        ordered = sorted(levels)
        return ordered[(len(ordered) - 1) // 2]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form, written into results.json (the resolved spec of the run)."""
        d = self._to_dict()
        if self.frames is not None or self.animate:  # a still experiment's form is unchanged
            d["render"]["frames"] = self.frames
            d["scenes"]["animate"] = {k: dict(v) for k, v in self.animate.items()}
            d["report"]["warmup_frames"] = self.warmup_frames
        if self.references is not None:  # a spec without it keeps its form
            d["scenes"]["references"] = str(self.references)
        if self.externals:  # a spec without externals keeps its form
            d["external"] = [e.to_dict() for e in self.externals]
        return d

    def _to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "source": self.source,
            "description": self.description,
            "scenes": {
                "specs": [str(p) for p in self.scene_specs],
                "random": self.random,
                "folder": None if self.folder is None else str(self.folder),
            },
            "render": {"spp": list(self.spp) if self.spp_given else None, "from_folder": True}
            if self.folder is not None
            else {
                "width": self.width,
                "height": self.height,
                "spp": list(self.spp),
                "ref_spp": self.ref_spp,
                "variant": self.variant,
                "seed": self.seed,
                "pass_spp": self.pass_spp,
                "folder": self.render_folder,
            },
            "methods": self.methods if isinstance(self.methods, str) else list(self.methods),
            "params": {k: dict(v) for k, v in self.params.items()},
            "sweeps": [
                {"method": s.method, "param": s.param, "values": list(s.values), **_fixed(s)}
                for s in self.sweeps
            ],
            "metrics": None if self.metrics is None else list(self.metrics),
            "repetitions": self.repetitions,
            "warmup": self.warmup,
            "device": self.device,
            "threads": self.threads,
            "stats": {
                "baseline": self.baseline,
                "bootstrap": self.bootstrap,
                "confidence": self.confidence,
                "seed": self.stats_seed,
            },
            "report": {
                "strip_spp": self.strip_spp,
                "budgets": None if self.budgets is None else list(self.budgets),
                "outputs": self.outputs,
            },
        }


def _fixed(s: Sweep) -> dict[str, Any]:
    return {"params": dict(s.params)} if s.params else {}


# --- parsing ------------------------------------------------------------------------------


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
    from mcdenoise.render.scene_spec import SpecError, collect_specs

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
    from mcdenoise.registry import get_method

    name = _str(ctx, key, value)
    if name == NOISY:
        return name
    try:
        get_method(name)
    except McdenoiseError as err:
        raise ctx.error(key, str(err)) from None
    return name


def _check_params(ctx: _Ctx, key: str, method: str, params: Mapping[str, Any]) -> None:
    import dataclasses

    from mcdenoise.methods.external import CommandParams
    from mcdenoise.registry import get_method

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


def parse_experiment(
    data: Mapping[str, Any],
    *,
    source: str = "<spec>",
    base: str | os.PathLike[str] | None = None,
    allow_commands: bool = False,
) -> ExperimentSpec:
    """Validate an experiment spec given as a mapping (a parsed TOML file).

    ``base`` is the folder relative scene paths are resolved against (the spec's folder).
    ``allow_commands``: the spec may run external programs (``[[external]]``, ``cmd:...``);
    without it such a spec is refused (module docstring).

    Raises:
        ExperimentError: a missing, unknown or invalid key; the message names ``source`` and
            the key path. A spec that names commands without ``allow_commands``: one line
            listing each command line.
    """
    ctx = _Ctx(source, Path(base) if base is not None else None)
    top = _table(ctx, "", data, _TOP_KEYS)
    if not allow_commands:
        commands = spec_commands(top, base=ctx.base)
        if commands:
            listed = "; ".join(f"{cmd!r} ({where})" for where, cmd in commands)
            raise ctx.error(
                "",
                f"the spec runs {len(commands)} external program(s) as you, refused "
                f"without --allow-commands: {listed}",
            )
    name = top.get("name", Path(source).stem if source != "<spec>" else "experiment")
    name = _str(ctx, "name", name)
    description = top.get("description", "")
    if not isinstance(description, str):
        raise ctx.error("description", "must be a string")

    # scenes
    scenes = _table(ctx, "scenes", top.get("scenes", {}), _SCENE_KEYS)
    folder = None
    references = None
    specs: tuple[Path, ...] = ()
    random = _int(ctx, "scenes.random", scenes.get("random", 0), lo=0)
    if "folder" in scenes:
        if "specs" in scenes or random:
            raise ctx.error("scenes", "give either folder or specs/random, not both")
        folder = ctx.resolve(_str(ctx, "scenes.folder", scenes["folder"]))
        if not folder.is_dir():
            raise ctx.error("scenes.folder", f"{scenes['folder']!r} is not a folder ({folder})")
        if "references" in scenes:
            references = ctx.resolve(_str(ctx, "scenes.references", scenes["references"]))
            if not references.is_dir():
                raise ctx.error(
                    "scenes.references",
                    f"{scenes['references']!r} is not a folder ({references})",
                )
    elif "references" in scenes:
        raise ctx.error("scenes.references", "goes with scenes.folder (a folder of inputs)")
    else:
        if "specs" in scenes:
            specs = _scene_files(ctx, "scenes.specs", scenes["specs"])
        if not specs and not random:
            raise ctx.error("scenes", "no scenes: give specs, random = N, or folder")

    # render
    render = _table(ctx, "render", top.get("render", {}), _RENDER_KEYS)
    if folder is not None:
        extra = sorted(set(render) - {"spp"})
        if extra:
            raise ctx.error(
                f"render.{extra[0]}",
                "not allowed with scenes.folder (size, reference and seeds come from the "
                "folder's manifest; only spp, a subset of its levels, may be given)",
            )
    res = render.get("resolution", 128)
    if isinstance(res, Sequence) and not isinstance(res, str):
        if len(res) != 2:
            raise ctx.error("render.resolution", f"must be N or [width, height], got {res!r}")
        width = _int(ctx, "render.resolution[0]", res[0], lo=1)
        height = _int(ctx, "render.resolution[1]", res[1], lo=1)
    else:
        width = height = _int(ctx, "render.resolution", res, lo=1)
    spp_given = "spp" in render
    spp = _spp_ladder(ctx, "render.spp", render.get("spp", [1, 2, 4, 8, 16]))
    ref_spp = _int(ctx, "render.ref_spp", render.get("ref_spp", 1024), lo=1)
    if folder is None and ref_spp <= spp[-1]:
        raise ctx.error("render.ref_spp", f"must exceed the highest level {spp[-1]}, got {ref_spp}")
    from mcdenoise.render.config import VARIANT_CHOICES

    variant = _str(ctx, "render.variant", render.get("variant", "auto"))
    if variant not in VARIANT_CHOICES:
        raise ctx.error("render.variant", f"{variant!r} is not one of {', '.join(VARIANT_CHOICES)}")
    seed = _int(ctx, "render.seed", render.get("seed", 0), lo=0)
    pass_spp = _int(ctx, "render.pass_spp", render.get("pass_spp", 128), lo=1)
    render_folder = _str(ctx, "render.folder", render.get("folder", "data"))
    frames = None
    if "frames" in render:
        frames = _int(ctx, "render.frames", render["frames"], lo=2)
    animate = _animate(ctx, scenes.get("animate", {}), specs, frames)

    # methods, parameters, sweeps
    externals = _externals(ctx, top.get("external", []))
    raw_methods = top.get("methods", "all")
    methods: str | tuple[str, ...]
    if raw_methods == "all":
        methods = "all"
        swept = {str(sw.get("method")) for sw in top.get("sweep", []) if isinstance(sw, Mapping)}
        for i, ext in enumerate(externals):
            if ext.name not in swept:
                raise ctx.error(
                    f"external[{i}].name",
                    f'{ext.name!r} would never run: methods = "all" takes the registered '
                    "methods, never an external command; list the methods to run "
                    f'(methods = ["{ext.name}", "nlm", ...])',
                )
    elif isinstance(raw_methods, str):
        raise ctx.error("methods", f'must be "all" or a list of method names, got {raw_methods!r}')
    else:
        names = [
            _method_name(ctx, f"methods[{i}]", v)
            for i, v in enumerate(_list(ctx, "methods", raw_methods))
        ]
        if len(set(names)) != len(names):
            raise ctx.error("methods", "names a method twice")
        methods = tuple(names)
    params_t = _table(ctx, "params", top.get("params", {}))
    params: dict[str, dict[str, Any]] = {}
    for mname, values in params_t.items():
        key = f"params.{mname}"
        _method_name(ctx, key, mname)
        table = dict(_table(ctx, key, values))
        _check_params(ctx, key, mname, table)
        params[mname] = table
    for ext in externals:
        if ext.timeout is None:
            continue
        if "timeout" in params.get(ext.name, {}):
            raise ctx.error(f"params.{ext.name}.timeout", "also given by its [[external]] entry")
        params[ext.name] = {**params.get(ext.name, {}), "timeout": ext.timeout}
    raw_sweeps = top.get("sweep", [])
    if not isinstance(raw_sweeps, Sequence) or isinstance(raw_sweeps, str):
        raise ctx.error("sweep", "must be a list of [[sweep]] tables")
    sweeps = []
    for i, raw in enumerate(raw_sweeps):
        key = f"sweep[{i}]"
        s = _table(ctx, key, raw, _SWEEP_KEYS)
        for required in ("method", "param", "values"):
            if required not in s:
                raise ctx.error(f"{key}.{required}", "missing")
        method = _method_name(ctx, f"{key}.method", s["method"])
        if method == NOISY:
            raise ctx.error(f"{key}.method", "'noisy' has no parameters to sweep")
        param = _str(ctx, f"{key}.param", s["param"])
        values = _list(ctx, f"{key}.values", s["values"])
        fixed = dict(_table(ctx, f"{key}.params", s.get("params", {})))
        if param in fixed:
            raise ctx.error(f"{key}.params", f"also sets the swept parameter {param!r}")
        _check_params(ctx, f"{key}.params", method, fixed)
        for j, v in enumerate(values):
            if isinstance(v, Mapping | list):
                raise ctx.error(
                    f"{key}.values[{j}]", f"must be a number, string or bool, got {v!r}"
                )
            _check_params(ctx, f"{key}.values[{j}]", method, {**fixed, param: v})
        if len({repr(v) for v in values}) != len(values):
            raise ctx.error(f"{key}.values", "lists a value twice")
        sweeps.append(Sweep(method, param, tuple(values), fixed))

    # metrics and timing
    metrics = None
    if "metrics" in top:
        raw = _list(ctx, "metrics", top["metrics"])
        metrics = _metric_names(ctx, [_str(ctx, "metrics", m) for m in raw], frames)
    repetitions = _int(ctx, "repetitions", top.get("repetitions", 3), lo=1)
    warmup = _int(ctx, "warmup", top.get("warmup", 1), lo=0)
    device = _str(ctx, "device", top.get("device", "cpu"))
    if device not in DEVICES:
        raise ctx.error("device", f"{device!r} is not one of {', '.join(DEVICES)}")
    threads = top.get("threads")
    if threads is not None:
        threads = _int(ctx, "threads", threads, lo=1)

    # statistics
    stats = _table(ctx, "stats", top.get("stats", {}), _STATS_KEYS)
    baseline = _str(ctx, "stats.baseline", stats.get("baseline", NOISY))
    bootstrap = _int(ctx, "stats.bootstrap", stats.get("bootstrap", 2000), lo=100)
    confidence = stats.get("confidence", 0.95)
    if (
        isinstance(confidence, bool)
        or not isinstance(confidence, int | float)
        or not 0.5 <= confidence < 1
    ):
        raise ctx.error("stats.confidence", f"must be a number in [0.5, 1), got {confidence!r}")
    stats_seed = _int(ctx, "stats.seed", stats.get("seed", 0), lo=0)

    # report
    report = _table(ctx, "report", top.get("report", {}), _REPORT_KEYS)
    strip_spp = report.get("strip_spp")
    if strip_spp is not None:
        strip_spp = _int(ctx, "report.strip_spp", strip_spp, lo=1)
        if (folder is None or spp_given) and strip_spp not in spp:
            raise ctx.error("report.strip_spp", f"{strip_spp} is not a level of {list(spp)}")
    budgets = None
    if "budgets" in report:
        raw_b = _list(ctx, "report.budgets", report["budgets"])
        for j, b in enumerate(raw_b):
            if (
                isinstance(b, bool)
                or not isinstance(b, int | float)
                or not math.isfinite(b)
                or b <= 0
            ):
                raise ctx.error(f"report.budgets[{j}]", f"must be seconds > 0, got {b!r}")
        budgets = tuple(sorted(float(b) for b in raw_b))
    outputs = _str(ctx, "report.outputs", report.get("outputs", "all"))
    from mcdenoise.eval.temporal_metrics import WARMUP_FRAMES

    warmup_frames = _int(
        ctx, "report.warmup_frames", report.get("warmup_frames", WARMUP_FRAMES), lo=0
    )
    if outputs not in OUTPUT_MODES:
        raise ctx.error("report.outputs", f"{outputs!r} is not one of {', '.join(OUTPUT_MODES)}")

    return ExperimentSpec(
        name=name,
        source=source,
        description=description,
        scene_specs=specs,
        random=random,
        folder=folder,
        references=references,
        width=width,
        height=height,
        spp=spp,
        ref_spp=ref_spp,
        variant=variant,
        seed=seed,
        pass_spp=pass_spp,
        render_folder=render_folder,
        methods=methods,
        params=params,
        sweeps=tuple(sweeps),
        metrics=metrics,
        repetitions=repetitions,
        warmup=warmup,
        device=device,
        threads=threads,
        baseline=baseline,
        bootstrap=bootstrap,
        confidence=float(confidence),
        stats_seed=stats_seed,
        strip_spp=strip_spp,
        budgets=budgets,
        outputs=outputs,
        spp_given=spp_given,
        frames=frames,
        animate=animate,
        warmup_frames=warmup_frames,
        externals=externals,
    )


def _externals(ctx: _Ctx, value: Any) -> tuple[External, ...]:
    """``[[external]]`` entries, checked and registered (:func:`mcdenoise.registry.add_command`)
    under their names, so the rest of the spec can name them."""
    if isinstance(value, Mapping):
        value = [value]  # `[external]` (one table) read as one entry
    if not isinstance(value, Sequence) or isinstance(value, str):
        raise ctx.error("external", "must be a list of [[external]] tables")
    from mcdenoise.registry import add_command, aliases, methods

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
    from mcdenoise.eval.metrics import resolve_metrics
    from mcdenoise.eval.temporal_metrics import is_temporal, resolve_sequence_metrics

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
    from mcdenoise.render.scene_spec import SpecError, load_spec

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


def load_experiment(
    path: str | os.PathLike[str], *, allow_commands: bool = False
) -> ExperimentSpec:
    """Read and validate an experiment spec (TOML); paths in it are relative to its folder.
    ``allow_commands``: it may run external programs (:func:`parse_experiment`).

    Raises:
        ExperimentError: the file is missing, not TOML, or invalid (message names file and
            key), or names commands without ``allow_commands``.
    """
    p = Path(path)
    if not p.is_file():
        raise ExperimentError(
            f"{p}: experiment spec not found" if not p.exists() else f"{p}: not a file"
        )
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ExperimentError(f"{p}: not valid TOML: {' '.join(str(err).split())}") from None
    return parse_experiment(data, source=str(p), base=p.parent, allow_commands=allow_commands)
