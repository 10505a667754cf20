"""Experiment specs: which scenes, spp ladder, reference, methods, metrics and repetitions.

An experiment spec is a TOML file (``data/experiments/*.toml``) read by
``mcdenoise experiment SPEC -o DIR``. This module parses and validates it; it renders
nothing and runs nothing (that is :mod:`mcdenoise.experiments.runner`). Every key, with its
default, is in docs/experiments.md ("Every key of a spec").

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

import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcdenoise.eval.temporal_metrics import WARMUP_FRAMES
from mcdenoise.experiments.commands import spec_commands
from mcdenoise.experiments.spec_fields import (
    NOISY,
    ExperimentError,
    External,
    _animate,
    _check_params,
    _Ctx,
    _externals,
    _int,
    _list,
    _method_name,
    _metric_names,
    _scene_files,
    _spp_ladder,
    _str,
    _table,
)
from mcdenoise.render.config import VARIANT_CHOICES

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
_RENDER_KEYS = (
    "resolution",
    "spp",
    "ref_spp",
    "variant",
    "seed",
    "pass_spp",
    "folder",
    "frames",
    "halves",
)
_SWEEP_KEYS = ("method", "param", "values", "params")
_STATS_KEYS = ("baseline", "bootstrap", "confidence", "seed")
_REPORT_KEYS = ("strip_spp", "budgets", "outputs", "warmup_frames")


@dataclass(frozen=True)
class Sweep:
    """One ``[[sweep]]``: ``method`` run once per value of ``param`` (plus fixed ``params``)."""

    method: str
    param: str
    values: tuple[Any, ...]
    params: Mapping[str, Any] = field(default_factory=dict)


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
    #: also render two independent half-sample buffers per level (``mcdenoise render
    #: --halves``): what ``nfor`` and the reference-free error estimate need
    halves: bool = False
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
                **({"halves": True} if self.halves else {}),
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

    variant = _str(ctx, "render.variant", render.get("variant", "auto"))
    if variant not in VARIANT_CHOICES:
        raise ctx.error("render.variant", f"{variant!r} is not one of {', '.join(VARIANT_CHOICES)}")
    seed = _int(ctx, "render.seed", render.get("seed", 0), lo=0)
    pass_spp = _int(ctx, "render.pass_spp", render.get("pass_spp", 128), lo=1)
    render_folder = _str(ctx, "render.folder", render.get("folder", "data"))
    halves = render.get("halves", False)
    if not isinstance(halves, bool):
        raise ctx.error("render.halves", f"must be true or false, got {halves!r}")
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
        halves=halves,
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
