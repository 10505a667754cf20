"""The data of an experiment: render what is missing, then read the render folder's manifest.

An experiment's images are an ``mcdenoise render`` folder (layout in
:mod:`mcdenoise.render.layout`): ``<id>.exr`` with one part ``spp<n>`` per level of the
ladder, ``ref/<id>.exr``, and ``manifest.json`` with each level's cumulative
``render_seconds`` and its ``jit_seconds``. :func:`prepare_data` renders into the folder
through :func:`mcdenoise.render.generate.generate` (resumable: finished images are skipped,
so a second run renders nothing); :func:`load_dataset` reads it back as :class:`SceneData`.

Render time of a level, as used by the experiment: the level's cumulative ``render_seconds``
minus the JIT compilation seconds of every increment up to it (Dr.Jit compiles kernels on
the first pass of each size; that is a one-off cost of the process, not of the samples).
Scene loading (``load_seconds``) is not included either.

Sequences (``[render] frames = N``; layout in :mod:`mcdenoise.render.layout`):
``<id>/frame_0000.exr`` (parts ``spp<n>``, with the motion buffers) and
``<id>/ref/frame_0000.exr``; a :class:`SceneData` then lists its :class:`Frame` files, and
the render seconds of a level are *per frame*: the mean over the frames of each frame's
render seconds, JIT excluded as above (each frame is a render of its own, so the JIT share of
every frame is left out). ``[scenes.animate.<name>]`` of the experiment is merged into that
scene spec's TOML before it is parsed (:func:`render_jobs`).

A ``[scenes] folder`` without ``manifest.json`` (inputs and references from any renderer, or
OIDN's training layout) is read by :mod:`mcdenoise.experiments.folder_data`; its render
seconds are unknown (``None``). The in-memory types (:class:`SceneData`, :class:`Level`,
:class:`Frame`) and the readers of a level and a reference live in
:mod:`mcdenoise.experiments.scene_data` and are re-exported here.
"""

from __future__ import annotations

import hashlib
import json
import os
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.experiments.folder_data import has_manifest, scan_folder
from mcdenoise.experiments.scene_data import Frame, Level, SceneData, read_level, read_reference
from mcdenoise.experiments.spec import ExperimentSpec
from mcdenoise.experiments.spec_fields import ExperimentError
from mcdenoise.render.config import RenderConfig
from mcdenoise.render.generate import generate
from mcdenoise.render.jobs import jobs_from_random, jobs_from_specs
from mcdenoise.render.manifest import MANIFEST, load_manifest, shard_manifests
from mcdenoise.render.scene_spec import SpecError, load_spec, parse_spec

__all__ = [
    "Frame",
    "Level",
    "SceneData",
    "folder_frames",
    "load_dataset",
    "prepare_data",
    "read_level",
    "read_reference",
    "render_folder",
    "render_jobs",
]


def render_folder(spec: ExperimentSpec, out: str | os.PathLike[str]) -> Path:
    """The folder the experiment's images are in: ``[scenes] folder``, else ``[render]
    folder`` (relative to ``out`` unless absolute)."""
    if spec.folder is not None:
        return Path(spec.folder)
    p = Path(spec.render_folder).expanduser()
    return p if p.is_absolute() else Path(out) / p


def render_jobs(spec: ExperimentSpec) -> list[Any]:
    """The :class:`~mcdenoise.render.jobs.ImageJob` list of the spec's scenes (curated
    specs, then ``random`` procedural scenes), seeded by ``[render] seed``."""

    jobs = jobs_from_specs([_scene_spec(spec, p) for p in spec.scene_specs], seed=spec.seed)
    if spec.random:
        jobs += jobs_from_random(
            spec.random, spec.seed, start=len(jobs), taken=[j.id for j in jobs]
        )
    return jobs


def _scene_spec(spec: ExperimentSpec, path: Path) -> Any:
    """The scene spec at ``path``, with the experiment's ``[scenes.animate.<name>]`` merged
    into its TOML (``animation`` replaces its ``[animation]``, each ``move`` sets
    ``objects[i].motion``) and validated by :func:`mcdenoise.render.scene_spec.parse_spec`."""

    scene = load_spec(path)
    extra = spec.animate.get(scene.name)
    if not extra:
        return scene
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    if "animation" in extra:
        data["animation"] = dict(extra["animation"])
    objects = data.get("objects", [])
    for j, move in enumerate(extra.get("move", [])):
        i = int(move["object"])
        if i >= len(objects):
            raise ExperimentError(
                f"{spec.source}: scenes.animate.{scene.name}.move[{j}].object: {scene.name} "
                f"has {len(objects)} objects (0 to {len(objects) - 1}), got {i}"
            )
        objects[i] = {**objects[i], "motion": {"translate": move["translate"]}}
    try:
        return parse_spec(data, source=str(path), base=Path(path).parent)
    except SpecError as err:
        raise ExperimentError(f"{spec.source}: scenes.animate.{scene.name}: {err}") from None


def prepare_data(
    spec: ExperimentSpec,
    out: str | os.PathLike[str],
    *,
    progress: bool = False,
    shard: tuple[int, int] = (1, 1),
    render: bool = True,
) -> tuple[Path, list[str], Any]:
    """Render the spec's images that are missing; return ``(folder, image ids, result)``.

    With ``[scenes] folder`` nothing is rendered: the ids are every image of that folder's
    manifest and ``result`` is ``None``. Otherwise ``result`` is the
    :class:`~mcdenoise.render.generate.GenerateResult` (what was rendered and skipped).
    ``shard = (i, n)``: render only the images of ``mcdenoise render --shard i/n`` (the ids
    are still every image of the spec). ``render=False`` (a merge) renders nothing and
    returns ``result = None``.

    Raises:
        ExperimentError: the render folder holds a data set of other settings.
        SpecError, RenderError: from the scene specs and the renderer.
    """
    folder = render_folder(spec, out)
    if spec.folder is not None:
        if not has_manifest(folder):  # inputs + references: load_dataset reads them all
            return folder, [], None
        manifest = _manifest(folder)
        return folder, [str(r["id"]) for r in manifest.get("images", [])], None

    config = RenderConfig(
        out=folder,
        width=spec.width,
        height=spec.height,
        spp=spec.spp,
        ref_spp=spec.ref_spp,
        variant=spec.variant,
        pass_spp=spec.pass_spp,
        halves=spec.halves,
        seed=spec.seed,
        progress=progress,
        frames=spec.frames,
        shard=shard,
    )
    if not render:
        return folder, [j.id for j in render_jobs(spec)], None
    if folder.is_dir():
        for name, m in shard_manifests(folder).items():
            if m.get("settings") != config.settings():
                raise ExperimentError(
                    f"{spec.source}: render.folder {folder} holds images rendered with other "
                    f"settings ({folder / name}: {json.dumps(m.get('settings'))}); set "
                    "[render] folder to a new folder, or delete that one"
                )
    jobs = render_jobs(spec)
    result = generate(jobs, config)
    return folder, [j.id for j in jobs], result


def _manifest(folder: Path) -> dict[str, Any]:

    if not (folder / MANIFEST).is_file():
        raise ExperimentError(
            f"{folder}: no {MANIFEST}; an experiment needs a folder written by "
            "`mcdenoise render` (it records the render seconds of every level)"
        )
    return load_manifest(folder)


def _fingerprint(record: Mapping[str, Any], settings: Mapping[str, Any]) -> str:
    payload = {
        "spec": record.get("spec"),
        "seed": record.get("seed"),
        "variant": record.get("variant"),
        "mitsuba_version": record.get("mitsuba_version"),
        "settings": settings,
    }
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _levels(record: Mapping[str, Any], where: str) -> list[Level]:
    out: list[Level] = []
    jit_total = 0.0
    for lv in record.get("levels") or []:
        try:
            spp = int(lv["spp"])
            part = str(lv["part"])
            seconds = float(lv["render_seconds"])
        except (KeyError, TypeError, ValueError):
            raise ExperimentError(
                f"{where}: a level record lacks spp/part/render_seconds"
            ) from None
        jit_total += float(lv.get("jit_seconds") or 0.0)
        out.append(Level(spp, part, max(seconds - jit_total, 0.0), round(jit_total, 6)))
    return out


def folder_frames(folder: str | os.PathLike[str]) -> int | None:
    """The frame count of a render folder's sequences (``None``: it holds still images, or
    it is a folder of inputs without manifest)."""

    if not has_manifest(folder):
        return None
    frames = (_manifest(Path(folder)).get("settings") or {}).get("frames")
    return None if frames is None else int(frames)


def load_dataset(
    folder: str | os.PathLike[str],
    ids: Sequence[str] | None = None,
    spp: Sequence[int] | None = None,
    *,
    sequences: bool = False,
    references: str | os.PathLike[str] | None = None,
) -> list[SceneData]:
    """Read the images ``ids`` (default: all) of a render folder, restricted to the levels
    ``spp`` (default: all of the folder's levels); with ``sequences``, the folder must hold
    sequences (``--frames``) and each :class:`SceneData` lists its frames.

    A folder without ``manifest.json`` is a folder of inputs and references (or OIDN's
    training layout), read by :func:`mcdenoise.experiments.folder_data.scan_folder` with
    ``references`` (default: its ``ref/``); its render seconds are unknown.

    Raises:
        ExperimentError: no manifest, an id or level missing, a sequence folder without
            ``sequences`` (or a still folder with it), or a file missing on disk.
    """
    root = Path(folder).resolve()

    if not has_manifest(root):
        if sequences:
            raise ExperimentError(f"{root}: sequences need a folder of `mcdenoise render`")
        found = scan_folder(root, references=references, spp=spp)
        if ids:
            by_id = {s.id: s for s in found}
            unknown = [x for x in ids if x not in by_id]
            if unknown:
                raise ExperimentError(f"{root}: image {unknown[0]!r} is not in this folder")
            found = [by_id[x] for x in ids]
        return found
    manifest = _manifest(root)
    settings = manifest.get("settings") or {}
    if settings.get("frames") is not None and not sequences:
        raise ExperimentError(
            f"{root}: holds sequences (--frames); set [render] frames in the experiment spec"
        )
    if settings.get("frames") is None and sequences:
        raise ExperimentError(f"{root}: holds still images, not sequences (--frames)")
    have = [int(v) for v in settings.get("spp", [])]
    wanted = list(spp) if spp is not None else have
    missing = [v for v in wanted if v not in have]
    if missing:
        raise ExperimentError(
            f"{root}: has no level(s) {', '.join(map(str, missing))} (levels: "
            f"{', '.join(map(str, have))})"
        )
    records = {str(r.get("id")): r for r in manifest.get("images", [])}
    order = list(ids) if ids is not None else list(records)
    scenes: list[SceneData] = []
    for image_id in order:
        rec = records.get(image_id)
        if rec is None:
            raise ExperimentError(f"{root}: image {image_id!r} is not in the manifest")
        if sequences:
            scenes.append(_sequence(root, rec, settings, wanted))
            continue
        files = rec.get("files") or {}
        noisy, ref = root / str(files.get("noisy", "")), root / str(files.get("reference", ""))
        for p in (noisy, ref):
            if not p.is_file():
                raise ExperimentError(f"{root}: image {image_id!r}: file {p} is missing")
        levels = [lv for lv in _levels(rec, f"{root}: image {image_id!r}") if lv.spp in wanted]
        scenes.append(
            SceneData(
                id=image_id,
                noisy=noisy,
                reference=ref,
                levels=tuple(sorted(levels, key=lambda lv: lv.spp)),
                reference_spp=(rec.get("reference") or {}).get("spp", settings.get("ref_spp")),
                seed=rec.get("seed"),
                variant=rec.get("variant"),
                fingerprint=_fingerprint(rec, settings),
                record=rec,
            )
        )
    if not scenes:
        raise ExperimentError(f"{root}: no image to evaluate")
    return scenes


def _sequence(
    root: Path, rec: Mapping[str, Any], settings: Mapping[str, Any], wanted: Sequence[int]
) -> SceneData:
    """A sequence record of the manifest as :class:`SceneData`: its frames, and its levels
    with the render seconds *per frame* (mean over the frames, JIT excluded frame by frame)."""
    image_id = str(rec.get("id"))
    where = f"{root}: sequence {image_id!r}"
    count = int(settings.get("frames") or 0)
    records = rec.get("frames") or []
    if not rec.get("complete") or len(records) != count:
        raise ExperimentError(
            f"{where}: {len(records)} of {count} frames finished; render it again to complete it"
        )
    frames: list[Frame] = []
    per_frame: list[list[Level]] = []
    for fr in records:
        files = fr.get("files") or {}
        frame = Frame(root / str(files.get("noisy", "")), root / str(files.get("reference", "")))
        for p in (frame.noisy, frame.reference):
            if not p.is_file():
                raise ExperimentError(f"{where}: file {p} is missing")
        frames.append(frame)
        per_frame.append([lv for lv in _levels(fr, where) if lv.spp in wanted])
    levels = []
    for k, lv in enumerate(sorted(per_frame[0], key=lambda lv: lv.spp)):
        same = [sorted(f, key=lambda lv: lv.spp)[k] for f in per_frame]
        levels.append(
            Level(
                lv.spp,
                lv.part,
                sum(x.render_seconds for x in same) / len(same),
                round(sum(x.jit_seconds for x in same) / len(same), 6),
            )
        )
    first = records[0]
    folder = root / str((rec.get("files") or {}).get("folder", image_id))
    return SceneData(
        id=image_id,
        noisy=folder,
        reference=folder / "ref",
        levels=tuple(levels),
        reference_spp=(first.get("reference") or {}).get("spp", settings.get("ref_spp")),
        seed=rec.get("seed"),
        variant=rec.get("variant"),
        fingerprint=_fingerprint(rec, settings),
        record=rec,
        frames=tuple(frames),
    )
