"""The files of a render folder: names, writing, manifest records, completeness.

Output folder layout (``DIR``)::

    DIR/<id>.exr          one multi-part EXR per image: part "spp<n>" per level, lowest first;
                          each part a complete canonical FeatureBuffers (color, color_var and
                          the plan's features with their _var; with halves color_a/color_b,
                          their _var, and feature halves with a thin lens), float32, header
                          attributes
                          mcdenoise:spp, mcdenoise:scene, mcdenoise:image, mcdenoise:seed,
                          mcdenoise:render_seconds (cumulative), mcdenoise:effects,
                          mcdenoise:plan, mcdenoise:variant, mitsuba:version,
                          mcdenoise:camera (JSON: the camera, its to_world matrix, near/far
                          clip, AO radius; a sequence frame's own camera)
    DIR/ref/<id>.exr      the reference (single part, same buffers, mcdenoise:passes too)
    DIR/manifest.shard-<i>-of-<n>.json    what shard i of n rendered (``1-of-1`` unsharded)
    DIR/manifest.json     all shard manifests merged (:mod:`mcdenoise.render.manifest`):
                          settings, and per image the spec (SceneSpec.to_dict()), seeds,
                          effect plan, variant, Mitsuba version, per-level and reference
                          seconds and passes, file names

``mcdenoise.io.load_buffers("DIR/<id>.exr", part="spp16")`` reads a level; without ``part``
it reads the first (lowest spp).

Sequences (``--frames N``) write one folder per sequence, every frame with the ``motion``,
``motion_valid``, ``motion_next`` and ``motion_next_valid`` buffers added to every part
(:mod:`mcdenoise.render.animation`)::

    DIR/<id>/frame_0000.exr       levels of frame 0 (parts spp<n>), + motion buffers
    DIR/<id>/ref/frame_0000.exr   its reference, + motion buffers

so ``mcdenoise denoise DIR/<id>`` sees the frames and never the references.

Completeness (what resume trusts): an image is complete when its record names both files and
the noisy file holds every level's part (:func:`image_complete`); a sequence when it is
marked complete and every frame is. Every file is written atomically.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from mcdenoise.errors import McdenoiseError
from mcdenoise.io.buffer_files import load_buffers, save_buffers, save_buffers_parts
from mcdenoise.io.exr import probe_exr
from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.effects import EffectPlan
from mcdenoise.render.jobs import ImageJob
from mcdenoise.render.manifest import load_manifest
from mcdenoise.render.passes import RenderedImage
from mcdenoise.render.scene_spec import Camera, SceneSpec
from mcdenoise.render.scenes import camera_metadata, far_clip


def noisy_file(image_id: str) -> str:
    """Relative to the output folder: ``<id>.exr`` (one part per level)."""
    return f"{image_id}.exr"


def reference_file(image_id: str) -> str:
    """Relative to the output folder: references live in ``ref/``, named like their noisy
    file, so ``mcdenoise denoise DIR`` never picks them up and ``mcdenoise eval --ref DIR/ref``
    matches them by name (the layout of ``data/samples``)."""
    return f"ref/{image_id}.exr"


def write_image(rendered: RenderedImage, config: RenderConfig) -> dict[str, Any]:
    """Write ``<id>.exr`` (one part per level) and ``ref/<id>.exr`` atomically into
    ``config.out``; return the image's manifest record."""

    job = rendered.job
    out = config.out
    save_buffers_parts(out / noisy_file(job.id), rendered.levels, compression=config.compression)
    (out / reference_file(job.id)).parent.mkdir(parents=True, exist_ok=True)
    save_buffers(out / reference_file(job.id), rendered.reference, compression=config.compression)
    return {
        **image_record(job, rendered.plan, config, rendered.variant, rendered.mitsuba_version),
        "files": {"noisy": noisy_file(job.id), "reference": reference_file(job.id)},
        "load_seconds": rendered.load_seconds,
        "levels": rendered.level_records,
        "reference": rendered.reference_record,
        "finished_at": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def spec_record(spec: SceneSpec) -> dict[str, Any]:
    """``spec.to_dict()`` as plain JSON values, without the (machine-dependent) source."""
    d = json.loads(json.dumps(spec.to_dict()))
    d.pop("source", None)
    return d


def image_record(
    job: ImageJob, plan: EffectPlan, config: RenderConfig, variant: str, mitsuba_version: str
) -> dict[str, Any]:
    """The manifest fields an image and a sequence share (``camera``: the spec's camera with
    its matrix, clip planes and AO radius, :func:`mcdenoise.render.scenes.camera_metadata`)."""

    return {
        "id": job.id,
        "index": job.index,
        "scene": job.spec.name,
        "source": job.spec.source,
        "seed": job.seed,
        "base_seed": job.base_seed,
        "spec": spec_record(job.spec),
        "effects": list(job.spec.effects),
        "plan": plan.describe(),
        "integrator": plan.integrator_dict(),
        "features": list(plan.features),
        "variant": variant,
        "mitsuba_version": mitsuba_version,
        "width": config.width,
        "height": config.height,
        "camera": camera_metadata(
            job.spec.camera, far=far_clip(job.spec, plan), ao_radius=plan.ao_radius
        ),
    }


def frame_file(sequence_id: str, frame: int) -> str:
    """Relative to the output folder: ``<id>/frame_0000.exr``."""
    return f"{sequence_id}/frame_{frame:04d}.exr"


def frame_reference_file(sequence_id: str, frame: int) -> str:
    """Relative to the output folder: ``<id>/ref/frame_0000.exr`` (out of the frames' folder
    listing, matched by name as for stills)."""
    return f"{sequence_id}/ref/frame_{frame:04d}.exr"


def write_frame(
    rendered: RenderedImage,
    motion: Mapping[str, torch.Tensor],
    config: RenderConfig,
    sequence_id: str,
    frame: int,
) -> dict[str, str]:
    """Write frame ``frame`` of a sequence: its levels and reference with the ``motion``
    buffers added to every part (``motion``, ``motion_valid``, ``motion_next``,
    ``motion_next_valid``: name -> ``(C, H, W)``), atomically; return the files (relative to
    ``config.out``)."""

    files = {
        "noisy": frame_file(sequence_id, frame),
        "reference": frame_reference_file(sequence_id, frame),
    }
    noisy, ref = config.out / files["noisy"], config.out / files["reference"]
    ref.parent.mkdir(parents=True, exist_ok=True)
    for fb in (*rendered.levels.values(), rendered.reference):
        for name, buffer in motion.items():
            fb[name] = buffer
    save_buffers_parts(noisy, rendered.levels, compression=config.compression)
    save_buffers(ref, rendered.reference, compression=config.compression)
    return files


def frame_complete(out: Path, record: Mapping[str, Any]) -> bool:
    """A frame record of a sequence whose files are complete (as :func:`image_complete`)."""
    return isinstance(record, Mapping) and image_complete(out, record)


def sequence_complete(out: Path, record: Mapping[str, Any]) -> bool:
    """A sequence record marked complete, with every frame recorded and complete."""
    frames = record.get("frames")
    count = (record.get("sequence") or {}).get("frames")
    return (
        bool(record.get("complete"))
        and isinstance(frames, list)
        and len(frames) == count
        and all(frame_complete(out, f) for f in frames)
    )


def camera_record(camera: Camera) -> dict[str, Any]:
    """The camera as plain JSON values (a frame's manifest record and EXR header)."""
    return json.loads(json.dumps(dataclasses.asdict(camera)))


def image_complete(out: Path, record: Mapping[str, Any]) -> bool:
    """``record``'s files exist and the noisy file holds every level's part (a sequence: see
    :func:`sequence_complete`); what resume trusts."""

    if "sequence" in record:
        return sequence_complete(out, record)
    files = record.get("files") or {}
    try:
        parts = probe_exr(out / files["noisy"])
        probe_exr(out / files["reference"])
    except (McdenoiseError, KeyError, TypeError):
        return False
    want = [lv.get("part") for lv in record.get("levels", [])]
    return bool(want) and [p.name for p in parts] == want


def prepare_folder(out: Path) -> None:
    """Create the output folder ``out`` if missing and check that it takes files.

    Raises:
        RenderError: ``out`` is a file, cannot be created, or is not writable.
    """
    if out.exists() and not out.is_dir():
        raise RenderError(f"{out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RenderError(
            f"{out}: cannot create the output folder ({err.strerror or err})"
        ) from None
    try:
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as err:
        raise RenderError(f"{out}: output folder is not writable ({err.strerror or err})") from None


# --------------------------------------------------------------------------------------------
# The samples layout (data/samples)
# --------------------------------------------------------------------------------------------
#: Buffers the samples layout stores as float32; every other buffer is written as half.
SAMPLES_FLOAT32: tuple[str, ...] = (
    "color",
    "color_var",
    "color_a",
    "color_b",
    "color_a_var",
    "color_b_var",
)
#: Buffers of a reference in the samples layout (float32 colour is nearly incompressible: with
#: the features the shipped folder would not stay small).
SAMPLES_REFERENCE: tuple[str, ...] = ("color",)


def samples_file(image_id: str, spp: int) -> str:
    """Relative to the samples folder: ``<id>_spp<n>.exr``, one level of one image."""
    return f"{image_id}_spp{spp}.exr"


def export_samples(folder: str | os.PathLike[str], out: str | os.PathLike[str]) -> list[Path]:
    """Copy the still images of the render folder ``folder`` into ``out`` in the layout of
    ``data/samples``, small enough to commit; return the files written.

    Per image of the manifest: every level as its own single-part file
    ``out/<id>_spp<n>.exr`` (:func:`samples_file`; colour and ``color_var`` float32, the
    features and their variances half) and the reference as ``out/ref/<id>.exr`` (colour
    only, float32); ZIP compression, every ``mcdenoise:*`` header attribute kept and
    ``mitsuba:version`` added from the manifest. ``mcdenoise denoise out`` sees the noisy files only and
    ``--ref out/ref`` finds each reference by the scene name.

    Raises:
        RenderError: ``folder`` holds sequences, or a feature exceeds the half range.
        ManifestError: ``folder`` has no readable manifest.
    """

    src, dst = Path(folder), Path(out)
    written: list[Path] = []

    def save(path: Path, fb: Any, record: Mapping[str, Any]) -> None:
        extra = {"mitsuba:version": str(record.get("mitsuba_version", ""))}
        half = [n for n in fb.names() if n not in SAMPLES_FLOAT32]
        path.parent.mkdir(parents=True, exist_ok=True)
        report = save_buffers(path, fb, half=half, compression="zip", attributes=extra)
        if report.total_clamped:
            raise RenderError(f"{path}: half overflow clamped in {report.clamped}")
        written.append(path)

    for record in load_manifest(src).get("images", []):
        if "sequence" in record:
            raise RenderError(f"{src}: {record['id']} is a sequence; the samples layout is stills")
        image_id, files = record["id"], record["files"]
        for level in record["levels"]:
            fb = load_buffers(src / files["noisy"], part=level["part"])
            save(dst / samples_file(image_id, int(level["spp"])), fb, record)
        ref = load_buffers(src / files["reference"])
        save(dst / reference_file(image_id), ref.subset(SAMPLES_REFERENCE), record)
    return written
