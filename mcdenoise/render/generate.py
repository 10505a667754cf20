"""Render a denoising data set with Mitsuba 3: the run over many jobs, resume and shards.

:func:`generate` renders a list of jobs (:mod:`mcdenoise.render.jobs`) into one output folder
with one :class:`~mcdenoise.render.config.RenderConfig`: every image through
:func:`~mcdenoise.render.passes.render_image`, written as :mod:`mcdenoise.render.layout` says,
recorded in the manifests of :mod:`mcdenoise.render.manifest`.

Resume and shards
    An image is finished when a shard manifest records it with the same spec and seed and both
    of its files exist (the noisy file with every level's part); anything else (e.g. killed
    while rendering the reference) is rendered again. Re-running skips finished images.
    ``shard = (i, n)`` (1-based: ``1 <= i <= n``) renders only the images whose 0-based index
    in the job list is ``≡ i - 1 (mod n)``, and writes ``manifest.shard-<i>-of-<n>.json``;
    every run (sharded or not) then rebuilds ``manifest.json`` from all shard manifests in
    ``DIR`` under a lock file (``DIR/.manifest.lock``), so ``n`` cluster jobs writing into one
    shared folder end with one merged manifest. Every file is written atomically and the shard
    manifest is rewritten after each image, so an interrupted run (Ctrl-C) leaves complete
    images and valid manifests. A folder holds one data set: a run whose settings (size, spp
    levels, reference spp, pass size) differ from a manifest already there is refused.

Sequences (``frames = N``, ``--frames N``)
    Every job is then a sequence of ``N`` frames (:mod:`mcdenoise.render.animation`: the
    spec's ``[animation]`` camera path and object motion, or a gentle default orbit). Each
    frame is rendered exactly like a still image (every level, the reference) with the
    frame's camera (``scene_dict(..., camera=...)``) and object positions, and its own image
    seed (:func:`~mcdenoise.render.jobs.frame_seed`), so the noise of consecutive frames is
    independent. Every level and the reference also get the frame's ``motion`` buffer
    (``motion.X/Y``, pixels to the previous frame, 0 in frame 0), ``motion_next``
    (``motion_next.X/Y``, pixels to the next frame, 0 in the last frame) and their validity
    masks ``motion_valid`` and ``motion_next_valid``, all from the un-jittered pixel-centre
    geometry passes of the frame and its neighbours, identical in every part (files:
    :func:`~mcdenoise.render.layout.write_frame`). The manifest records one entry per
    sequence: the animation, and per frame its time, camera, object offsets, seeds, files,
    the valid fractions of both masks and seconds (levels, reference, the geometry passes run
    for the frame: its own or its successor's, each pass counted once). Shards split the work
    by sequence (frames need their neighbours' geometry); resume works per frame: the shard
    manifest is rewritten after every frame, a re-run renders only the frames missing
    (recomputing the cheap geometry passes of the frames next to them).

Determinism: the same spec, seed, settings and variant give identical pixel data.
"""

from __future__ import annotations

import datetime as _dt
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.progress import progress_bar
from mcdenoise.render import animation as sq
from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.effects import plan_effects
from mcdenoise.render.jobs import ImageJob, frame_seed, make_jobs
from mcdenoise.render.layout import (
    camera_record,
    export_samples,
    frame_complete,
    image_complete,
    image_record,
    prepare_folder,
    spec_record,
    write_frame,
    write_image,
)
from mcdenoise.render.manifest import (
    MANIFEST,
    latest_records,
    merge_manifests,
    record_seconds,
    shard_manifest_name,
    shard_manifests,
    write_shard_manifest,
)
from mcdenoise.render.mitsuba_setup import ensure_variant
from mcdenoise.render.passes import render_image
from mcdenoise.render.scene_spec import collect_specs


@dataclass
class GenerateResult:
    """What a run did: ids rendered and skipped (already finished), the shard's image count,
    the merged manifest's path, the Mitsuba variant used (``None`` if nothing was rendered),
    the files written in the samples layout (:func:`render_dataset`'s ``samples_out``)."""

    rendered: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    shard_jobs: int = 0
    manifest: Path | None = None
    variant: str | None = None
    seconds: float = 0.0
    exported: list[Path] = field(default_factory=list)


def _require_mitsuba() -> None:
    try:
        import mitsuba  # noqa: F401  # lazy: optional, see except
    except ImportError:
        raise RenderError(
            "mcdenoise render needs Mitsuba 3: pip install 'mcdenoise[render]'"
        ) from None


def _select_variant(requested: str) -> str:

    try:
        return ensure_variant(requested)
    except McdenoiseError:
        raise
    except Exception as err:  # Mitsuba's own errors: one line
        raise RenderError(f"Mitsuba variant {requested!r}: {' '.join(str(err).split())}") from None


def generate(jobs: Sequence[ImageJob], config: RenderConfig) -> GenerateResult:
    """Render ``jobs`` (this shard's share of them) into ``config.out``; see the module doc.

    Every spec is checked against its effects before anything is rendered. Returns what was
    rendered and skipped; ``manifest.json`` is rebuilt at the end (also after Ctrl-C).

    Raises:
        SpecError: a spec whose effects and content disagree.
        RenderError: bad settings, unwritable folder, folder of other settings, Mitsuba
            missing or the variant unusable, a scene Mitsuba cannot load.
    """
    ids = [j.id for j in jobs]
    if len(set(ids)) != len(ids):
        raise RenderError("two images share an id; ids must be unique")
    for job in jobs:  # fail fast: every spec is checked before hours of rendering
        plan_effects(job.spec)
    out = config.out
    prepare_folder(out)
    i, n = config.shard
    mine = [j for j in jobs if j.index % n == i - 1]
    existing = shard_manifests(out)
    for name, m in existing.items():
        if m.get("settings") != config.settings():
            raise RenderError(
                f"{out / name} was rendered with {_describe_settings(m.get('settings'))}, "
                f"this run asks for {_describe_settings(config.settings())}; "
                "use another output folder"
            )
    recorded = latest_records([r for m in existing.values() for r in m.get("images", [])])
    own_name = shard_manifest_name(i, n)
    own = existing.get(own_name, {}).get("images", [])
    own_records = {r["id"]: r for r in own if isinstance(r.get("id"), str)}

    result = GenerateResult(shard_jobs=len(mine))
    todo: list[ImageJob] = []
    partial: dict[str, dict[str, Any]] = {}  # sequences interrupted in an earlier run
    for job in mine:
        rec = recorded.get(job.id) or {}
        same = rec.get("spec") == spec_record(job.spec) and rec.get("seed") == job.seed
        if same and image_complete(out, rec):
            result.skipped.append(job.id)
        else:
            todo.append(job)
            if same and config.frames is not None and "sequence" in rec:
                partial[job.id] = rec

    t_start = time.perf_counter()
    try:
        if todo:
            _require_mitsuba()
            result.variant = _select_variant(config.variant)

            if config.frames is None:
                with progress_bar(
                    total=len(mine),
                    initial=len(mine) - len(todo),
                    desc="render",
                    unit="image",
                    progress=config.progress,
                ) as bar:
                    for job in todo:
                        bar.set_postfix_str(job.id)
                        rendered = render_image(job, config, result.variant)
                        record = write_image(rendered, config)
                        own_records[job.id] = record
                        write_shard_manifest(out, own_name, config.settings(), i, n, own_records)
                        result.rendered.append(job.id)
                        merge_manifests(out)
                        bar.update(1)
            else:
                _render_sequences(todo, partial, config, result, own_records, own_name)
        elif own_name not in existing:  # record that this shard ran (nothing was left to do)
            write_shard_manifest(out, own_name, config.settings(), i, n, own_records)
    finally:
        result.seconds = time.perf_counter() - t_start
        if shard_manifests(out):
            merge_manifests(out)
            result.manifest = out / MANIFEST
    return result


def render_dataset(
    paths: Sequence[str | os.PathLike[str]],
    config: RenderConfig,
    *,
    random: int | None = None,
    samples_out: str | os.PathLike[str] | None = None,
) -> GenerateResult:
    """What ``mcdenoise render`` runs: the scene specs of ``paths`` (files or folders of
    ``*.toml``, :func:`~mcdenoise.render.scene_spec.collect_specs`) and ``random`` procedural scenes
    rendered into ``config.out`` by :func:`generate`, ids and seeds from ``config.seed``.

    ``samples_out``: afterwards, also write every image of the folder in the layout of
    ``data/samples`` there (:func:`~mcdenoise.render.layout.export_samples`).

    Raises:
        InputError: neither specs nor ``random``.
        SpecError, RenderError: as :func:`generate` and the spec loaders.
    """

    if not paths and random is None:
        raise InputError("nothing to render: give SPEC.toml files (or folders) or --random N")
    jobs = make_jobs(collect_specs(paths), random=random, seed=config.seed)
    result = generate(jobs, config)
    if samples_out is not None:
        result.exported = export_samples(config.out, samples_out)
    return result


def _render_sequences(
    todo: Sequence[ImageJob],
    partial: Mapping[str, Mapping[str, Any]],
    config: RenderConfig,
    result: GenerateResult,
    own_records: dict[str, Any],
    own_name: str,
) -> None:
    """The per-frame loop of :func:`generate`: the shard manifest is rewritten after every
    frame, so an interrupted sequence resumes at its first missing frame."""

    assert config.frames is not None and result.variant is not None
    out, (i, n) = config.out, config.shard
    total = len(todo) * config.frames
    with progress_bar(total=total, desc="render", unit="frame", progress=config.progress) as bar:
        for job in todo:
            bar.set_postfix_str(job.id)

            def on_frame(record: dict[str, Any], job_id: str = job.id) -> None:
                own_records[job_id] = record
                write_shard_manifest(out, own_name, config.settings(), i, n, own_records)
                bar.update(1)

            record = render_sequence(
                job, config, result.variant, previous=partial.get(job.id), on_frame=on_frame
            )
            own_records[job.id] = record
            write_shard_manifest(out, own_name, config.settings(), i, n, own_records)
            result.rendered.append(job.id)
            merge_manifests(out)


def _describe_settings(s: Any) -> str:
    if not isinstance(s, Mapping):
        return repr(s)
    spp = ",".join(str(v) for v in s.get("spp", []))
    frames = f" --frames {s['frames']}" if s.get("frames") is not None else " (stills)"
    halves = " --halves" if s.get("halves") else " --no-halves"
    return (
        f"--res {s.get('width')}x{s.get('height')} --spp {spp} --ref-spp {s.get('ref_spp')} "
        f"pass_spp {s.get('pass_spp')}{frames}{halves}"
    )


def render_sequence(
    job: ImageJob,
    config: RenderConfig,
    variant: str,
    *,
    previous: Mapping[str, Any] | None = None,
    on_frame: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Render and write every frame of the sequence ``job`` (``config.frames`` frames);
    return its manifest record.

    ``previous``: a record of the same sequence (same spec and seed) from an interrupted run;
    frames it records whose files are complete are kept, not rendered again. ``on_frame`` is
    called with the (incomplete) record after every frame written.
    """
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    if config.frames is None:
        raise RenderError("render_sequence needs config.frames")
    n = config.frames
    spec = job.spec
    plan = plan_effects(spec)
    animation = sq.sequence_animation(spec, n)
    cameras = sq.frame_cameras(spec, n)
    times = sq.frame_times(n)
    offsets = [sq.object_offsets(spec, s) for s in times]
    moving = any(o.motion is not None for o in spec.objects)
    kept: dict[int, dict[str, Any]] = {}
    for fr in (previous or {}).get("frames", []) or []:
        if isinstance(fr, Mapping) and frame_complete(config.out, fr):
            kept[int(fr["frame"])] = dict(fr)
    record = image_record(job, plan, config, variant, str(mi.__version__))
    record["files"] = {"folder": job.id}
    record["sequence"] = {
        "frames": n,
        "animation": animation.to_dict(),
        "default_animation": spec.animation is None,
        "moving_objects": [i for i, o in enumerate(spec.objects) if o.motion is not None],
    }
    frames: dict[int, dict[str, Any]] = {}

    def snapshot(complete: bool) -> dict[str, Any]:
        out = dict(record)
        out["frames"] = [frames[f] for f in sorted(frames)]
        out["complete"] = complete
        out["render_seconds"] = round(sum(record_seconds(f) for f in out["frames"]), 6)
        out["finished_at"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        return out

    geometries: dict[int, sq.GeometryBuffer] = {}  # frames f - 1, f, f + 1 at most

    def geometry_of(g: int) -> sq.GeometryBuffer:
        if g not in geometries:  # each pass once (a resumed run redoes its neighbours')
            geometries[g] = sq.render_geometry(
                sq.spec_at(spec, times[g]), plan, cameras[g], config.width, config.height
            )
        return geometries[g]

    for f in range(n):
        geometries.pop(f - 2, None)
        if f in kept:
            frames[f] = kept[f]
            continue
        frame_spec = sq.spec_at(spec, times[f])
        t0 = time.perf_counter()
        geometry = geometry_of(f)
        previous = geometry_of(f - 1) if f > 0 else None
        following = geometry_of(f + 1) if f + 1 < n else None
        motion, valid = sq.motion_vectors(
            geometry, previous, offsets[f] - offsets[f - 1] if f > 0 else None
        )
        motion_next, next_valid = sq.next_motion_vectors(
            geometry, following, offsets[f + 1] - offsets[f] if f + 1 < n else None
        )
        geometry_seconds = time.perf_counter() - t0
        frame_job = ImageJob(
            job.index, f"{job.id}/frame_{f:04d}", frame_spec, frame_seed(job.seed, f), job.seed
        )
        rendered = render_image(
            frame_job,
            config,
            variant,
            camera=cameras[f],
            attributes={
                "mcdenoise:sequence": job.id,
                "mcdenoise:frame": f,
                "mcdenoise:frames": n,
            },
        )
        motions = {
            "motion": motion,
            "motion_valid": valid,
            "motion_next": motion_next,
            "motion_next_valid": next_valid,
        }
        files = write_frame(rendered, motions, config, job.id, f)
        frames[f] = {
            "frame": f,
            "time": times[f],
            "seed": frame_job.seed,
            "camera": camera_record(cameras[f]),
            **({"object_offsets": offsets[f].tolist()} if moving else {}),
            "files": files,
            "valid_fraction": round(float(valid.mean()), 6),
            "next_valid_fraction": round(float(next_valid.mean()), 6),
            "load_seconds": rendered.load_seconds,
            "geometry_seconds": round(geometry_seconds, 6),
            "levels": rendered.level_records,
            "reference": rendered.reference_record,
        }
        if on_frame is not None:
            on_frame(snapshot(False))
    return snapshot(True)
