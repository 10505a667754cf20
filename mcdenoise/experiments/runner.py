"""Run an experiment: render what is missing, denoise every input with every method, time it,
measure it, and assemble the report.

:func:`run_experiment` is what ``mcdenoise experiment SPEC -o DIR`` calls:

1. :func:`~mcdenoise.experiments.dataset.prepare_data` renders the missing images into the
   render folder (``DIR/data`` by default; resumable, the layout of ``mcdenoise render``);
2. :func:`~mcdenoise.experiments.entries.plan_methods` turns the spec's methods and sweeps into labelled entries (``noisy``
   first: plain rendering, denoise time 0); methods that cannot run here (e.g. OIDN without
   ``pyoidn``) are *skipped*, with the reason, and listed in the report;
3. every **unit** — one (scene, spp level, method) — is run: the level is read, the method is
   run ``warmup`` times untimed and ``repetitions`` times timed
   (:mod:`~mcdenoise.experiments.timing`), the last output is written to
   ``DIR/outputs/<scene>_spp<n>_<label>.exr`` (with the method, parameters, median seconds,
   device and source in its header) and every metric is computed against the reference;
   the unit's record is then written atomically to ``DIR/work/<scene>/spp<n>/<label>.json``;
4. the report (``results.json``, ``results.csv``, ``report.html`` and its PNGs) is assembled
   from the unit records (:mod:`~mcdenoise.experiments.analysis`,
   :mod:`~mcdenoise.experiments.report`).

Resume: a unit whose record exists with the same fingerprint (scene data, spp, label, method,
resolved parameters, metrics, repetitions, warm-up, device, threads, mcdenoise version) is not
run again, so an interrupted experiment (Ctrl-C, a crash) continues where it stopped and a
finished one is only re-assembled. Delete ``DIR/work`` to time everything again.

Sequences (``[render] frames = N``): a unit is one (sequence, spp level, method), run over
the whole sequence with the times per frame and the per-frame and temporal metrics of
:mod:`mcdenoise.eval.temporal_metrics` (:mod:`~mcdenoise.experiments.sequence_units`); its outputs are a
folder of frames, ``DIR/outputs/<scene>_spp<n>_<label>/``. Resume works the same way.

A method that refuses an input (a :class:`~mcdenoise.errors.McdenoiseError`, e.g. a buffer it
requires is missing in an AO scene) gives a unit with ``error`` set, shown in the report;
any other exception stops the run (finished units stay valid).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcdenoise.denoise import resolve_device
from mcdenoise.eval.metrics import resolve_metrics
from mcdenoise.eval.results import jsonable
from mcdenoise.eval.temporal_metrics import resolve_sequence_metrics
from mcdenoise.experiments.analysis import assemble
from mcdenoise.experiments.applicability import plan_applicable
from mcdenoise.experiments.dataset import (
    Level,
    SceneData,
    folder_frames,
    load_dataset,
    prepare_data,
    read_level,
    read_reference,
)
from mcdenoise.experiments.entries import MethodEntry, plan_methods
from mcdenoise.experiments.report import write_experiment_report
from mcdenoise.experiments.sequence_units import load_frames, outputs_present
from mcdenoise.experiments.shards import (
    check_rendered,
    folder_lock,
    missing_message,
    shard_units,
    with_device,
    write_shard_record,
)
from mcdenoise.experiments.spec import ExperimentSpec
from mcdenoise.experiments.spec_fields import ExperimentError
from mcdenoise.experiments.timing import (
    machine_info,
    torch_threads,
)
from mcdenoise.experiments.units import (
    RunSettings,
    Unit,
    _load_color,
    _now,
    fingerprint,
    read_unit,
    run_sequence_unit,
    run_unit,
)
from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.progress import progress_bar


@dataclass
class RunSummary:
    """What :func:`run_experiment` did.

    Attributes:
        ran: keys ``(scene, spp, label)`` of the units run now.
        reused: keys of the units whose finished records were reused.
        rendered, render_skipped: image ids rendered now / already finished.
        paths: the report's files (``json``, ``csv``, ``html``, ``images``).
        result: the assembled :class:`~mcdenoise.experiments.analysis.ExperimentResult`
            (``None`` for a shard: it writes no report).
        shard: ``(i, n)`` of a shard run; ``shard_units`` the size of its share.
    """

    ran: list[tuple[str, int, str]] = field(default_factory=list)
    reused: list[tuple[str, int, str]] = field(default_factory=list)
    rendered: list[str] = field(default_factory=list)
    render_skipped: list[str] = field(default_factory=list)
    paths: dict[str, Path] = field(default_factory=dict)
    result: Any = None
    name: str = ""
    shard: tuple[int, int] | None = None
    shard_units: int = 0

    def messages(self) -> list[tuple[str, bool]]:
        """The lines ``mcdenoise experiment`` prints, each with ``True`` for stderr:
        what ran and was reused, the report's files (stdout); the skipped methods (stderr)."""
        result = self.result
        rendered = (
            f"rendered {len(self.rendered)} image(s), reused {len(self.render_skipped)}; "
            if self.rendered or self.render_skipped
            else ""
        )
        if self.shard is not None:
            i, n = self.shard
            return [
                (
                    f"experiment {self.name}, shard {i}/{n}: {self.shard_units} unit(s); "
                    f"{rendered}ran {len(self.ran)}, reused {len(self.reused)} finished",
                    False,
                ),
                (
                    "when every shard has finished, build the report with the same command "
                    "and --merge instead of --shard",
                    False,
                ),
            ]
        lines = [
            (
                f"experiment {self.name}: {len(result.scenes)} scene(s) x {len(result.spps)} "
                f"spp level(s) x {len(result.labels)} method(s); {rendered}ran "
                f"{len(self.ran)} unit(s), reused {len(self.reused)} finished",
                False,
            )
        ]
        lines += [(f"skipped {label}: {reason}", True) for label, reason in result.skipped.items()]
        lines += [(f"{kind}: {self.paths[kind]}", False) for kind in ("json", "csv")]
        lines.append((f"report: {self.paths['html']}", False))
        return lines


def plan_units(scenes: Sequence[SceneData], entries: Sequence[MethodEntry]) -> list[Unit]:
    """Every (scene, level, method), scene by scene, lowest level first, noisy first."""
    return [Unit(s, lv, e) for s in scenes for lv in s.levels for e in entries]


def run_units(
    units: Sequence[Unit],
    out: Path,
    settings: RunSettings,
    *,
    device: Any,
    progress: bool | str = False,
    summary: RunSummary | None = None,
    still_held: Callable[[], None] | None = None,
) -> dict[tuple[str, int, str], dict[str, Any]]:
    """Run the units that have no valid record yet; return every unit's record by key.

    Each record is written atomically as soon as its unit finishes, so an exception or
    Ctrl-C loses at most the unit in progress. ``progress``: units done / total, the current
    scene, level and method, and the time left, on stderr
    (:func:`mcdenoise.progress.progress_bar`). ``still_held``: called before each unit;
    raises when this run's folder lock was taken over (:func:`~.shards.folder_lock`).
    """

    summary = summary if summary is not None else RunSummary()
    records: dict[tuple[str, int, str], dict[str, Any]] = {}
    todo: list[Unit] = []
    for unit in units:
        cached = read_unit(unit.path(out), fingerprint(unit, settings))
        if cached is not None and _output_present(cached, out):
            records[unit.key] = cached
            summary.reused.append(unit.key)
        else:
            todo.append(unit)
    loaded: dict[str, Any] = {}
    with progress_bar(
        total=len(units),
        initial=len(units) - len(todo),
        desc="denoise",
        unit="unit",
        progress=progress if todo else False,
    ) as bar:
        for unit in todo:
            if still_held is not None:
                still_held()
            scene, level = unit.scene, unit.level
            ref_key = f"ref:{scene.id}"
            if ref_key not in loaded:
                loaded.clear()
                loaded[ref_key] = _load_reference(scene)
            level_key = f"{scene.id}#{level.spp}"
            if level_key not in loaded:
                for k in [k for k in loaded if not k.startswith("ref:")]:
                    del loaded[k]
                loaded[level_key] = _load_level(scene, level)
            bar.set_postfix_str(f"{scene.id} {level.spp} spp {unit.entry.label}")
            run = run_sequence_unit if scene.is_sequence else run_unit
            record = run(unit, loaded[level_key], loaded[ref_key], out, settings, device)
            path = unit.path(out)
            path.parent.mkdir(parents=True, exist_ok=True)
            text = json.dumps(jsonable(record), indent=1, ensure_ascii=False, allow_nan=False)
            write_text_atomic(path, text + "\n")
            records[unit.key] = read_unit(path) or record
            summary.ran.append(unit.key)
            bar.update(1)
    return records


def _load_reference(scene: SceneData) -> Any:
    """The reference colour ``(3, H, W)``, or for a sequence the list of its frames'."""
    if scene.is_sequence:
        return [_load_color(f.reference)[0] for f in scene.frames]
    return read_reference(scene.reference)["color"].numpy()


def _load_level(scene: SceneData, level: Level) -> Any:
    """The level as ``FeatureBuffers``, or for a sequence the list of its frames'."""
    if scene.is_sequence:
        return load_frames([f.noisy for f in scene.frames], level.part)
    return read_level(scene.noisy, level)


def _output_present(record: Mapping[str, Any], out: Path) -> bool:
    output = record.get("output")
    if not output:
        return True
    if record.get("output_frames"):
        return outputs_present(record, out)
    p = Path(output)
    return (p if p.is_absolute() else out / p).is_file()


def collect_units(
    units: Sequence[Unit], out: Path, settings: RunSettings
) -> dict[tuple[str, int, str], dict[str, Any]]:
    """The finished record of every unit, running nothing (what ``--merge`` reads).

    A record counts when its fingerprint matches with the device its shard ran with
    (``run_device``), so a merge on a machine that resolves another device still finds the
    shards' records; its output file must exist as for a resume.

    Raises:
        ExperimentError: some unit has no such record (one line: how many, which shards).
    """
    records: dict[tuple[str, int, str], dict[str, Any]] = {}
    missing: list[tuple[str, int, str]] = []
    for unit in units:
        rec = read_unit(unit.path(out))
        ok = rec is not None and _output_present(rec, out)
        if ok:
            assert rec is not None
            expected = fingerprint(unit, with_device(settings, rec.get("run_device")))
            ok = rec.get("fingerprint") == expected
        if ok:
            assert rec is not None
            records[unit.key] = rec
        else:
            missing.append(unit.key)
    if missing:
        raise ExperimentError(missing_message(out, missing, len(units)))
    return records


def run_experiment(
    spec: ExperimentSpec,
    out: str | os.PathLike[str],
    *,
    progress: bool | str = False,
    metrics: Sequence[str] | None = None,
    shard: tuple[int, int] | None = None,
    merge: bool = False,
) -> RunSummary:
    """Run the experiment ``spec`` into the folder ``out`` and write its report there.

    Args:
        spec: a validated :class:`~mcdenoise.experiments.spec.ExperimentSpec`.
        out: the experiment folder (created): ``report.html``, ``results.json``,
            ``results.csv``, ``images/``, ``outputs/``, ``work/`` and, by default, ``data/``.
        progress: progress on stderr, stage by stage: render, denoise (units done / total,
            scene, level, method, time left), report; a bar on a terminal, plain lines in a
            log (:func:`mcdenoise.progress.progress_bar`).
        metrics: overrides the spec's metrics (must include relmse).
        shard: ``(i, n)``: render and run only shard ``i`` of ``n``'s share of the units
            (:mod:`~mcdenoise.experiments.shards`); no report is written (``merge`` does).
        merge: render and run nothing; build the report from every unit's finished record.

    Returns:
        A :class:`RunSummary`.

    Raises:
        ExperimentError, SpecError, RenderError, InputError: bad spec, folder or settings;
            with ``merge``, a unit without a finished record.
        LockError: another live process runs in ``out`` (a plain run or merge, beside
            anything else; a shard, beside the same shard or a plain run), see
            :func:`~mcdenoise.experiments.shards.folder_lock`; one line naming it.
    """
    if shard is not None and merge:
        raise ExperimentError("a shard runs its share; --merge builds the report: not both")
    root = Path(out)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ExperimentError(
            f"cannot create the experiment folder {root}: {err.strerror or err}"
        ) from None
    with folder_lock(root, shard) as lock:  # one run per folder, or one process per shard
        return _run_locked(spec, root, lock.check, progress, metrics, shard, merge)


def _run_locked(
    spec: ExperimentSpec,
    root: Path,
    still_held: Callable[[], None],
    progress: bool | str,
    metrics: Sequence[str] | None,
    shard: tuple[int, int] | None,
    merge: bool,
) -> RunSummary:
    """:func:`run_experiment` once its folder lock is held (``still_held`` raises when it
    was taken over)."""

    sequences = (spec.frames if spec.folder is None else folder_frames(spec.folder)) is not None
    wanted = metrics if metrics is not None else spec.metrics
    names = resolve_sequence_metrics(wanted) if sequences else resolve_metrics(wanted)
    if "relmse" not in names:
        raise ExperimentError("the metrics must include relmse (the curves and tables use it)")
    if sequences and "trelmse" not in names:
        raise ExperimentError("the metrics of sequences must include trelmse (the tables use it)")
    entries, skipped = plan_methods(spec)
    device = resolve_device(spec.device)
    summary = RunSummary(name=spec.name, shard=shard)
    folder, ids, rendered = prepare_data(
        spec, root, progress=progress, shard=shard or (1, 1), render=not merge
    )
    if rendered is not None:
        summary.rendered = list(rendered.rendered)
        summary.render_skipped = list(rendered.skipped)
    if merge and spec.folder is None:
        check_rendered(folder, ids, root)
    # a shard of a rendering spec reads only the images it rendered (the others may not
    # exist yet); its share is whole scenes
    index = {image_id: k for k, image_id in enumerate(ids)}
    by_scene = shard is not None and spec.folder is None
    load_ids = ids
    if by_scene and shard is not None:
        load_ids = [x for x in ids if index[x] % shard[1] == shard[0] - 1]
    if by_scene and not load_ids:  # more shards than scenes: nothing to do here
        write_shard_record(root, shard, units=[], started=_now(), finished=True)
        return summary
    scenes = load_dataset(
        folder,
        load_ids or None,
        spec.spp if (spec.folder is None or spec.spp_given) else None,
        sequences=sequences,
        references=spec.references,
    )
    levels = [lv.spp for lv in scenes[0].levels]
    strip = spec.strip_level(levels)
    if strip not in levels:
        raise ExperimentError(f"{spec.source}: report.strip_spp {strip} is not a level of {levels}")
    settings = RunSettings(
        metrics=tuple(names),
        repetitions=spec.repetitions,
        warmup=spec.warmup,
        device=str(device),
        threads=spec.threads,
        save_output=lambda spp: spec.outputs == "all" or spp == strip,
        warmup_frames=spec.warmup_frames,
    )
    plan = plan_applicable(entries, scenes)
    entries = plan.entries
    units = [
        u
        for u in plan_units(scenes, entries)
        if (u.entry.label, u.scene.id, u.level.spp) in plan.runs
    ]
    at_start = machine_info()
    if shard is not None:
        mine = shard_units(units, shard, scene_index=index if by_scene else None)
        args = (mine, root, settings, device, progress, summary, shard, at_start, spec)
        _run_shard(*args, still_held=still_held)
        return summary
    if merge:
        records = collect_units(units, root, settings)
        summary.reused = [u.key for u in units]
    else:
        with torch_threads(spec.threads):
            records = run_units(
                units,
                root,
                settings,
                device=device,
                progress=progress,
                summary=summary,
                still_held=still_held,
            )
    with progress_bar(total=2, desc="report", unit="step", progress=progress) as bar:
        bar.set_postfix_str("statistics")
        result = assemble(
            spec,
            scenes=scenes,
            entries=entries,
            skipped=skipped,
            not_applicable=plan.notes(),
            records=[records[u.key] for u in units],
            metrics=names,
            data_folder=folder,
            strip_spp=strip,
            out=root,
            machine_at_start=at_start,
        )
        bar.update(1)
        bar.set_postfix_str("figures and report.html")
        summary.result = result
        summary.paths = write_experiment_report(result, root)
        bar.update(1)
    return summary


def _run_shard(
    mine: Sequence[Unit],
    root: Path,
    settings: RunSettings,
    device: Any,
    progress: bool | str,
    summary: RunSummary,
    shard: tuple[int, int],
    machine: Mapping[str, Any],
    spec: ExperimentSpec,
    still_held: Callable[[], None] | None = None,
) -> None:
    """Run one shard's units, recording the shard before (started) and after (finished)."""
    keys = [u.key for u in mine]
    started = _now()
    write_shard_record(root, shard, units=keys, started=started, finished=False, machine=machine)
    with torch_threads(spec.threads):
        records = run_units(
            mine,
            root,
            settings,
            device=device,
            progress=progress,
            summary=summary,
            still_held=still_held,
        )
    summary.shard_units = len(mine)
    refused = [k for k in keys if records[k].get("error")]
    write_shard_record(
        root,
        shard,
        units=keys,
        started=started,
        finished=True,
        ran=summary.ran,
        reused=summary.reused,
        refused=refused,
        machine=machine,
    )
