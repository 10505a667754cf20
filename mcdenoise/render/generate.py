"""Render a denoising data set with Mitsuba 3: the render loop, the files, the manifest, shards.

Each image (one scene spec, one seed) is rendered as the spec's effect plan says
(:mod:`mcdenoise.render.effects`): the integrator stack is ``moment`` -> ``aov`` (the plan's
feature buffers) -> the plan's radiance integrator, on a box-filtered film with an independent
sampler (:mod:`mcdenoise.render.moments`), so every buffer and its per-pixel variance of the
mean come from the same samples.

Progressive spp levels
    The requested levels (e.g. 4, 16, 64) are rendered as *increments* (4, then 12 more, then
    48 more) with distinct seeds, and each level pools the moments of every increment up to it:
    level 16 contains level 4's samples and costs only 12 more spp. Each level is still an
    unbiased Monte Carlo estimate (the mean of i.i.d. samples); levels of one image are *not*
    independent of each other (compare images, not levels of one image, when independence
    matters). An increment larger than ``pass_spp`` is split into passes of at most
    ``pass_spp`` samples (default :data:`DEFAULT_PASS_SPP` = 128 for every variant: the JIT
    variants hold a whole pass in memory, about ``width * height * pass_spp`` samples; scalar
    memory does not grow with spp, and the same default keeps seeds comparable).
Reference
    ``ref_spp`` samples in passes of at most ``pass_spp``, with seeds disjoint from the noisy
    ones: noisy pass ``k`` of an image with seed ``s`` uses sampler seed ``s + 2k``, reference
    pass ``k`` uses ``s + 2k + 1``. Colour, the features and all variances, float32: the
    reference's own variance of the mean tells later reports its remaining noise floor.
Time
    ``seconds`` of a pass is the wall time of ``mi.render`` plus reading the film; the
    cumulative ``render_seconds`` of a level is the sum over the passes of every increment up to
    it (scene loading, ``load_seconds``, is counted separately). In the JIT variants the first
    pass of a new size also compiles kernels; that share is recorded as ``jit_seconds``
    (Dr.Jit's kernel history) so "what accuracy costs in time" can leave it out.

Output folder layout (``DIR``)::

    DIR/<id>.exr          one multi-part EXR per image: part "spp<n>" per level, lowest first;
                          each part a complete canonical FeatureBuffers (color, color_var and
                          the plan's features with their _var), float32, header attributes
                          mcdenoise:spp, mcdenoise:scene, mcdenoise:image, mcdenoise:seed,
                          mcdenoise:render_seconds (cumulative), mcdenoise:effects,
                          mcdenoise:plan, mcdenoise:variant, mitsuba:version
    DIR/ref/<id>.exr      the reference (single part, same buffers, mcdenoise:passes too)
    DIR/manifest.shard-<i>-of-<n>.json    what shard i of n rendered (``1-of-1`` unsharded)
    DIR/manifest.json     all shard manifests merged: settings, and per image the spec
                          (SceneSpec.to_dict()), seeds, effect plan, variant, Mitsuba version,
                          per-level and reference seconds and passes, file names

``mcdenoise.io.load_buffers("DIR/<id>.exr", part="spp16")`` reads a level; without ``part``
it reads the first (lowest spp).

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
    Every job is then a sequence of ``N`` frames (:mod:`mcdenoise.render.sequences`: the
    spec's ``[animation]`` camera path and object motion, or a gentle default orbit). Each
    frame is rendered exactly like a still image (every level, the reference) with the
    frame's camera (``scene_dict(..., camera=...)``) and object positions, and its own image
    seed (:func:`frame_seed`), so the noise of consecutive frames is independent. Every level
    and the reference also get the frame's ``motion`` buffer (``motion.X/Y``, pixels to the
    previous frame, 0 in frame 0) and the validity mask buffer ``motion_valid``, both
    from an un-jittered pixel-centre geometry pass, identical in every part. Layout::

        DIR/<id>/frame_0000.exr       levels of frame 0 (parts spp<n>), + motion
        DIR/<id>/ref/frame_0000.exr   its reference, + motion

    so ``mcdenoise denoise DIR/<id>`` sees the frames and never the references. The manifest
    records one entry per sequence: the animation, and per frame its time, camera, object
    offsets, seeds, files and seconds (levels, reference, geometry pass). Shards split the
    work by sequence (frames need their predecessor's geometry); resume works per frame: the
    shard manifest is rewritten after every frame, a re-run renders only the frames missing
    (recomputing the cheap geometry pass of the frame before the first of them).

Determinism: the same spec, seed, settings and variant give identical pixel data.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import itertools
import json
import re
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from mcdenoise.errors import McdenoiseError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.render.effects import EffectPlan, plan_effects
from mcdenoise.render.manifest import (
    MANIFEST,
    ManifestError,
    latest_records,
    load_manifest,
    merge_manifests,
    record_seconds,
    shard_manifest_name,
    shard_manifests,
    write_shard_manifest,
)
from mcdenoise.render.moments import (
    Moments,
    buffers_from_moments,
    moment_integrator,
    render_moments,
)
from mcdenoise.render.spec import Camera, SceneSpec

__all__ = [
    "MANIFEST",
    "ManifestError",
    "load_manifest",
    "merge_manifests",
    "shard_manifests",
]

#: Largest number of samples per pixel of one render call (one pass).
DEFAULT_PASS_SPP = 128
#: Values of ``RenderConfig.variant`` (``auto``: see :func:`mcdenoise.render.scenes.ensure_variant`).
VARIANT_CHOICES: tuple[str, ...] = ("auto", "scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
_SEED_MOD = 2**31


class RenderError(McdenoiseError, ValueError):
    """Bad render settings or an output folder that cannot take this run (one-line message)."""


# --------------------------------------------------------------------------------------------
# Settings
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RenderConfig:
    """Settings of one ``mcdenoise render`` run.

    Attributes:
        out: output folder (created if missing).
        width, height: image size in pixels.
        spp: the noisy levels, strictly increasing, rendered progressively.
        ref_spp: samples per pixel of the reference.
        variant: a Mitsuba variant or ``auto``.
        shard: ``(i, n)``, 1-based: render the images with index ``≡ i - 1 (mod n)``.
        pass_spp: most samples per pixel of one render call.
        seed: base seed; each image's seed is derived from it and the image id.
        compression: EXR compression of every file.
        progress: show a tqdm progress bar (stderr).
        frames: ``None`` for still images, else every job is a sequence of this many frames
            (>= 2).
    """

    out: Path
    width: int = 256
    height: int = 256
    spp: tuple[int, ...] = (4, 16, 64)
    ref_spp: int = 4096
    variant: str = "auto"
    shard: tuple[int, int] = (1, 1)
    pass_spp: int = DEFAULT_PASS_SPP
    seed: int = 0
    compression: str = "zip"
    progress: bool = False
    frames: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "out", Path(self.out))
        object.__setattr__(self, "spp", tuple(self.spp))
        object.__setattr__(self, "shard", tuple(self.shard))
        for name in ("width", "height", "ref_spp", "pass_spp"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise RenderError(f"{name} must be an integer >= 1, got {value!r}")
        check_spp_levels(self.spp)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise RenderError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.variant not in VARIANT_CHOICES:
            raise RenderError(
                f"unknown Mitsuba variant {self.variant!r} (use {', '.join(VARIANT_CHOICES)})"
            )
        check_shard(self.shard)
        if self.frames is not None:
            from mcdenoise.render.sequences import check_frames

            try:
                check_frames(self.frames)
            except McdenoiseError as err:
                raise RenderError(str(err)) from None

    def settings(self) -> dict[str, Any]:
        """What every image of one folder shares (checked when a folder is reused)."""
        out: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "spp": list(self.spp),
            "ref_spp": self.ref_spp,
            "pass_spp": self.pass_spp,
        }
        if self.frames is not None:
            out["frames"] = self.frames
        return out


def check_spp_levels(levels: Sequence[int]) -> tuple[int, ...]:
    """Raise :class:`RenderError` unless ``levels`` are integers >= 1, strictly increasing."""
    out = tuple(levels)
    if not out:
        raise RenderError("spp needs at least one level")
    for v in out:
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise RenderError(f"spp levels must be integers >= 1, got {v!r}")
    if any(b <= a for a, b in itertools.pairwise(out)):
        raise RenderError(f"spp levels must be strictly increasing, got {','.join(map(str, out))}")
    return out


def check_shard(shard: Sequence[int]) -> tuple[int, int]:
    """Raise :class:`RenderError` unless ``shard`` is ``(i, n)`` with ``1 <= i <= n``."""
    if len(shard) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in shard):
        raise RenderError(f"shard must be (i, n), got {shard!r}")
    i, n = shard
    if n < 1 or not 1 <= i <= n:
        raise RenderError(f"shard {i}/{n}: need 1 <= i <= n (shards are numbered from 1)")
    return i, n


def parse_spp(text: str) -> tuple[int, ...]:
    """``"4,16,64"`` -> ``(4, 16, 64)`` (validated).

    >>> parse_spp("4, 16,64")
    (4, 16, 64)
    """
    try:
        levels = tuple(int(t) for t in str(text).split(",") if t.strip())
    except ValueError:
        raise RenderError(f"--spp {text!r}: expected integers separated by commas") from None
    try:
        return check_spp_levels(levels)
    except RenderError as err:
        raise RenderError(f"--spp {text!r}: {err}") from None


def parse_shard(text: str) -> tuple[int, int]:
    """``"2/5"`` -> ``(2, 5)``: shard 2 of 5, numbered from 1.

    >>> parse_shard("2/5")
    (2, 5)
    """
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not m:
        raise RenderError(f"--shard {text!r}: expected i/n, e.g. 1/4 (shards are numbered from 1)")
    return check_shard((int(m.group(1)), int(m.group(2))))


def parse_res(text: str) -> tuple[int, int]:
    """``"256"`` -> ``(256, 256)``; ``"320x240"`` -> ``(320, 240)`` (width, height).

    >>> parse_res("320x240")
    (320, 240)
    """
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX]\s*(\d+)\s*)?", str(text))
    if not m or int(m.group(1)) < 1 or (m.group(2) is not None and int(m.group(2)) < 1):
        raise RenderError(f"--res {text!r}: expected N or WxH with positive integers")
    w = int(m.group(1))
    return w, int(m.group(2)) if m.group(2) is not None else w


# --------------------------------------------------------------------------------------------
# Jobs, seeds and passes
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImageJob:
    """One image to render: its position in the job list, file stem, spec and seed."""

    index: int
    id: str
    spec: SceneSpec
    seed: int
    base_seed: int = 0


def image_seed(base_seed: int, image_id: str) -> int:
    """The seed of image ``image_id``: a hash of the base seed and the id, in ``[0, 2**31)``
    (stable when other images are added to or removed from the job list)."""
    digest = hashlib.blake2b(f"{base_seed}/{image_id}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") % _SEED_MOD


def _safe_id(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "scene"


def _unique_ids(names: Sequence[str], taken: set[str] | None = None) -> list[str]:
    seen = set(taken or ())
    out = []
    for name in names:
        base = _safe_id(name)
        candidate, k = base, 2
        while candidate in seen:
            candidate, k = f"{base}_{k}", k + 1
        seen.add(candidate)
        out.append(candidate)
    return out


def jobs_from_specs(specs: Sequence[SceneSpec], seed: int = 0, start: int = 0) -> list[ImageJob]:
    """One job per spec, ids from the spec names (file-name safe, made unique), indices from
    ``start``."""
    ids = _unique_ids([s.name for s in specs])
    return [
        ImageJob(start + k, i, s, image_seed(seed, i), seed)
        for k, (i, s) in enumerate(zip(ids, specs))
    ]


def jobs_from_random(
    count: int, seed: int = 0, start: int = 0, taken: Sequence[str] = ()
) -> list[ImageJob]:
    """``count`` procedural scenes ``random_spec(seed, k)``, ids ``random_s<seed>_<k>``."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise RenderError(f"--random must be an integer >= 1, got {count!r}")
    try:
        from mcdenoise.render.random_scenes import random_spec
    except ImportError:
        raise RenderError(
            "--random needs mcdenoise.render.random_scenes, which this installation lacks"
        ) from None
    ids = _unique_ids([f"random_s{seed}_{k:05d}" for k in range(count)], set(taken))
    return [
        ImageJob(start + k, ids[k], random_spec(seed, k), image_seed(seed, ids[k]), seed)
        for k in range(count)
    ]


def split_passes(spp: int, pass_spp: int) -> list[int]:
    """Pass sizes that sum to ``spp``, each at most ``pass_spp``.

    >>> split_passes(300, 128)
    [128, 128, 44]
    """
    full, rest = divmod(spp, pass_spp)
    return [pass_spp] * full + ([rest] if rest else [])


def level_passes(levels: Sequence[int], pass_spp: int) -> list[list[int]]:
    """For each level, the pass sizes of its increment over the previous level.

    >>> level_passes([4, 16, 300], 128)
    [[4], [12], [128, 128, 28]]
    """
    out, prev = [], 0
    for level in check_spp_levels(levels):
        out.append(split_passes(level - prev, pass_spp))
        prev = level
    return out


def noisy_seed(seed: int, k: int) -> int:
    """Sampler seed of noisy pass ``k`` (counted over all levels) of an image seeded ``seed``."""
    return seed + 2 * k


def reference_seed(seed: int, k: int) -> int:
    """Sampler seed of reference pass ``k``; never equal to a noisy pass seed of the image."""
    return seed + 2 * k + 1


def level_part(spp: int) -> str:
    """Part name of a level in the noisy file: ``spp16``."""
    return f"spp{spp}"


# --------------------------------------------------------------------------------------------
# Rendering one image
# --------------------------------------------------------------------------------------------
@dataclass
class RenderedImage:
    """The buffers and records of one rendered image (not yet written).

    ``levels`` maps part name (``spp4``, ...) to the buffers of that level; ``reference`` is
    the reference; ``level_records``/``reference_record`` hold seeds, passes and seconds.
    """

    job: ImageJob
    plan: EffectPlan
    variant: str
    mitsuba_version: str
    levels: dict[str, FeatureBuffers]
    reference: FeatureBuffers
    level_records: list[dict[str, Any]]
    reference_record: dict[str, Any]
    load_seconds: float


class _JitClock:
    """Seconds Dr.Jit spent compiling kernels since the last call (JIT variants only)."""

    def __init__(self, variant: str) -> None:
        self.enabled = not variant.startswith("scalar")
        self._dr: Any = None
        self._previous = False
        if self.enabled:
            import drjit as dr

            self._dr = dr
            self._previous = bool(dr.flag(dr.JitFlag.KernelHistory))
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()  # drop what came before

    def lap(self) -> float | None:
        if not self.enabled:
            return None
        ms = sum(
            float(k.get("codegen_time", 0.0)) + float(k.get("backend_time", 0.0))
            for k in self._dr.kernel_history()
        )
        return round(ms / 1000.0, 6)

    def close(self) -> None:
        if self.enabled:
            self._dr.kernel_history()
            self._dr.set_flag(self._dr.JitFlag.KernelHistory, self._previous)


def _render_passes(
    scene: Any,
    sizes: Sequence[int],
    seeds: Sequence[int],
    features: Sequence[str],
    clock: _JitClock,
    total: Moments | None,
) -> tuple[Moments, list[dict[str, Any]], float]:
    records, seconds = [], 0.0
    for n, s in zip(sizes, seeds):
        t0 = time.perf_counter()
        m = render_moments(scene, n, s, features)
        dt = time.perf_counter() - t0
        seconds += dt
        rec: dict[str, Any] = {"seed": s, "spp": n, "seconds": round(dt, 6)}
        jit = clock.lap()
        if jit is not None:
            rec["jit_seconds"] = jit
        records.append(rec)
        total = m if total is None else total.merge(m)
    assert total is not None
    return total, records, seconds


def _jit_total(passes: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """``{"jit_seconds": sum}`` over ``passes`` in JIT variants, else ``{}``."""
    jit = [p["jit_seconds"] for p in passes if "jit_seconds" in p]
    return {"jit_seconds": round(sum(jit), 6)} if jit else {}


def _load_scene(
    job: ImageJob, plan: EffectPlan, config: RenderConfig, camera: Camera | None = None
) -> Any:
    import mitsuba as mi

    from mcdenoise.render.scenes import scene_dict

    d = scene_dict(
        job.spec,
        plan,
        width=config.width,
        height=config.height,
        integrator=moment_integrator(plan.integrator_dict(), plan.features),
        camera=camera,
    )
    try:
        return mi.load_dict(d)
    except Exception as err:  # Mitsuba reports every load failure as a long RuntimeError
        first = next((ln.strip() for ln in str(err).splitlines() if ln.strip()), repr(err))
        raise RenderError(
            f"{job.spec.source or job.spec.name}: Mitsuba cannot load the scene: {first}"
        ) from None


def render_image(
    job: ImageJob,
    config: RenderConfig,
    variant: str,
    *,
    camera: Camera | None = None,
    attributes: Mapping[str, Any] | None = None,
) -> RenderedImage:
    """Render the noisy levels and the reference of ``job`` (variant already set).

    ``camera`` overrides ``job.spec.camera`` (a frame of a sequence); ``attributes`` are added
    to every part's header.

    Returns float32 buffers ``(C, H, W)``: colour in linear HDR RGB, features as in
    :mod:`mcdenoise.render.moments`, each with its variance of the mean.
    """
    import mitsuba as mi

    if mi.variant() != variant:
        raise RenderError(
            f"render_image: Mitsuba variant {mi.variant()!r} is set, not {variant!r} "
            "(call mcdenoise.render.scenes.ensure_variant first)"
        )
    plan = plan_effects(job.spec)
    t0 = time.perf_counter()
    scene = _load_scene(job, plan, config, camera)
    load_seconds = time.perf_counter() - t0
    common = {
        "mcdenoise:scene": job.spec.name,
        "mcdenoise:image": job.id,
        "mcdenoise:seed": job.seed,
        "mcdenoise:effects": ",".join(job.spec.effects),
        "mcdenoise:plan": plan.describe(),
        "mcdenoise:variant": variant,
        "mitsuba:version": str(mi.__version__),
        **dict(attributes or {}),
    }
    clock = _JitClock(variant)
    try:
        levels: dict[str, FeatureBuffers] = {}
        level_records: list[dict[str, Any]] = []
        total: Moments | None = None
        cumulative, k = 0.0, 0
        for level, sizes in zip(config.spp, level_passes(config.spp, config.pass_spp)):
            seeds = [noisy_seed(job.seed, k + j) for j in range(len(sizes))]
            k += len(sizes)
            total, passes, seconds = _render_passes(
                scene, sizes, seeds, plan.features, clock, total
            )
            cumulative += seconds
            part = level_part(level)
            levels[part] = buffers_from_moments(
                total, {**common, "mcdenoise:render_seconds": round(cumulative, 6)}
            )
            level_records.append(
                {
                    "spp": level,
                    "part": part,
                    "increment_spp": sum(sizes),
                    "passes": passes,
                    "increment_seconds": round(seconds, 6),
                    "render_seconds": round(cumulative, 6),
                    **_jit_total(passes),
                }
            )
        sizes = split_passes(config.ref_spp, config.pass_spp)
        seeds = [reference_seed(job.seed, j) for j in range(len(sizes))]
        ref_total, passes, ref_seconds = _render_passes(
            scene, sizes, seeds, plan.features, clock, None
        )
    finally:
        clock.close()
    reference = buffers_from_moments(
        ref_total,
        {
            **common,
            "mcdenoise:render_seconds": round(ref_seconds, 6),
            "mcdenoise:passes": len(sizes),
        },
    )
    return RenderedImage(
        job=job,
        plan=plan,
        variant=variant,
        mitsuba_version=str(mi.__version__),
        levels=levels,
        reference=reference,
        level_records=level_records,
        reference_record={
            "spp": config.ref_spp,
            "passes": passes,
            "render_seconds": round(ref_seconds, 6),
            **_jit_total(passes),
        },
        load_seconds=round(load_seconds, 6),
    )


def noisy_file(image_id: str) -> str:
    return f"{image_id}.exr"


def reference_file(image_id: str) -> str:
    """Relative to the output folder: references live in ``ref/``, named like their noisy
    file, so ``mcdenoise denoise DIR`` never picks them up and ``mcdenoise eval --ref DIR/ref``
    matches them by name (the layout of ``data/samples``)."""
    return f"ref/{image_id}.exr"


def write_image(rendered: RenderedImage, config: RenderConfig) -> dict[str, Any]:
    """Write ``<id>.exr`` (one part per level) and ``ref/<id>.exr`` atomically into
    ``config.out``; return the image's manifest record."""
    from mcdenoise.io.buffer_files import save_buffers, save_buffers_parts

    job = rendered.job
    out = config.out
    save_buffers_parts(out / noisy_file(job.id), rendered.levels, compression=config.compression)
    (out / reference_file(job.id)).parent.mkdir(parents=True, exist_ok=True)
    save_buffers(out / reference_file(job.id), rendered.reference, compression=config.compression)
    return {
        "id": job.id,
        "index": job.index,
        "scene": job.spec.name,
        "source": job.spec.source,
        "seed": job.seed,
        "base_seed": job.base_seed,
        "spec": _spec_dict(job.spec),
        "effects": list(job.spec.effects),
        "plan": rendered.plan.describe(),
        "integrator": rendered.plan.integrator_dict(),
        "features": list(rendered.plan.features),
        "variant": rendered.variant,
        "mitsuba_version": rendered.mitsuba_version,
        "width": config.width,
        "height": config.height,
        "files": {"noisy": noisy_file(job.id), "reference": reference_file(job.id)},
        "load_seconds": rendered.load_seconds,
        "levels": rendered.level_records,
        "reference": rendered.reference_record,
        "finished_at": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def _spec_dict(spec: SceneSpec) -> dict[str, Any]:
    """``spec.to_dict()`` as plain JSON values, without the (machine-dependent) source."""
    d = json.loads(json.dumps(spec.to_dict()))
    d.pop("source", None)
    return d


def _image_record(
    job: ImageJob, plan: EffectPlan, config: RenderConfig, variant: str, mitsuba_version: str
) -> dict[str, Any]:
    """The manifest fields an image and a sequence share."""
    return {
        "id": job.id,
        "index": job.index,
        "scene": job.spec.name,
        "source": job.spec.source,
        "seed": job.seed,
        "base_seed": job.base_seed,
        "spec": _spec_dict(job.spec),
        "effects": list(job.spec.effects),
        "plan": plan.describe(),
        "integrator": plan.integrator_dict(),
        "features": list(plan.features),
        "variant": variant,
        "mitsuba_version": mitsuba_version,
        "width": config.width,
        "height": config.height,
    }


# --------------------------------------------------------------------------------------------
# Sequences
# --------------------------------------------------------------------------------------------
def frame_seed(seed: int, frame: int) -> int:
    """Image seed of frame ``frame`` of a sequence seeded ``seed``: a hash, so the pass seeds
    (``+ 2k``, ``+ 2k + 1``) of different frames do not collide in practice."""
    return image_seed(seed, f"frame_{frame:04d}")


def frame_file(sequence_id: str, frame: int) -> str:
    """Relative to the output folder: ``<id>/frame_0000.exr``."""
    return f"{sequence_id}/frame_{frame:04d}.exr"


def frame_reference_file(sequence_id: str, frame: int) -> str:
    """Relative to the output folder: ``<id>/ref/frame_0000.exr`` (out of the frames' folder
    listing, matched by name as for stills)."""
    return f"{sequence_id}/ref/frame_{frame:04d}.exr"


def write_frame(
    rendered: RenderedImage,
    motion: torch.Tensor,
    valid: torch.Tensor,
    config: RenderConfig,
    sequence_id: str,
    frame: int,
) -> dict[str, str]:
    """Write frame ``frame`` of a sequence: its levels and reference with the ``motion``
    ``(2, H, W)`` and ``motion_valid`` ``(1, H, W)`` buffers added to every part, atomically;
    return the files (relative to ``config.out``)."""
    from mcdenoise.io.buffer_files import save_buffers, save_buffers_parts

    files = {
        "noisy": frame_file(sequence_id, frame),
        "reference": frame_reference_file(sequence_id, frame),
    }
    noisy, ref = config.out / files["noisy"], config.out / files["reference"]
    ref.parent.mkdir(parents=True, exist_ok=True)
    for fb in (*rendered.levels.values(), rendered.reference):
        fb["motion"] = motion
        fb["motion_valid"] = valid
    save_buffers_parts(noisy, rendered.levels, compression=config.compression)
    save_buffers(ref, rendered.reference, compression=config.compression)
    return files


def _frame_complete(out: Path, record: Mapping[str, Any]) -> bool:
    return isinstance(record, Mapping) and _image_complete(out, record)


def _sequence_complete(out: Path, record: Mapping[str, Any]) -> bool:
    frames = record.get("frames")
    count = (record.get("sequence") or {}).get("frames")
    return (
        bool(record.get("complete"))
        and isinstance(frames, list)
        and len(frames) == count
        and all(_frame_complete(out, f) for f in frames)
    )


def _camera_record(camera: Camera) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(camera)))


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
    import mitsuba as mi

    from mcdenoise.render import sequences as sq

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
        if isinstance(fr, Mapping) and _frame_complete(config.out, fr):
            kept[int(fr["frame"])] = dict(fr)
    record = _image_record(job, plan, config, variant, str(mi.__version__))
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

    previous_geometry: sq.GeometryBuffer | None = None
    for f in range(n):
        if f in kept:
            frames[f] = kept[f]
            previous_geometry = None
            continue
        if f > 0 and previous_geometry is None:  # resumed after frame f-1: redo its geometry
            previous_geometry = sq.render_geometry(
                sq.spec_at(spec, times[f - 1]), plan, cameras[f - 1], config.width, config.height
            )
        frame_spec = sq.spec_at(spec, times[f])
        t0 = time.perf_counter()
        geometry = sq.render_geometry(frame_spec, plan, cameras[f], config.width, config.height)
        motion, valid = sq.motion_vectors(
            geometry, previous_geometry, offsets[f] - offsets[f - 1] if f > 0 else None
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
                "mcdenoise:camera": json.dumps(_camera_record(cameras[f])),
            },
        )
        files = write_frame(rendered, motion, valid, config, job.id, f)
        frames[f] = {
            "frame": f,
            "time": times[f],
            "seed": frame_job.seed,
            "camera": _camera_record(cameras[f]),
            **({"object_offsets": offsets[f].tolist()} if moving else {}),
            "files": files,
            "valid_fraction": round(float(valid.mean()), 6),
            "load_seconds": rendered.load_seconds,
            "geometry_seconds": round(geometry_seconds, 6),
            "levels": rendered.level_records,
            "reference": rendered.reference_record,
        }
        previous_geometry = geometry
        if on_frame is not None:
            on_frame(snapshot(False))
    return snapshot(True)


# --------------------------------------------------------------------------------------------
# Completeness (what resume trusts)
# --------------------------------------------------------------------------------------------
def _image_complete(out: Path, record: Mapping[str, Any]) -> bool:
    from mcdenoise.io.exr import probe_exr

    if "sequence" in record:
        return _sequence_complete(out, record)
    files = record.get("files") or {}
    try:
        parts = probe_exr(out / files["noisy"])
        probe_exr(out / files["reference"])
    except (McdenoiseError, KeyError, TypeError):
        return False
    want = [lv.get("part") for lv in record.get("levels", [])]
    return bool(want) and [p.name for p in parts] == want


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------
@dataclass
class GenerateResult:
    """What a run did: ids rendered and skipped (already finished), the shard's image count,
    the merged manifest's path, the Mitsuba variant used (``None`` if nothing was rendered)."""

    rendered: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    shard_jobs: int = 0
    manifest: Path | None = None
    variant: str | None = None
    seconds: float = 0.0


def _require_mitsuba() -> None:
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        raise RenderError(
            "mcdenoise render needs Mitsuba 3: pip install 'mcdenoise[render]'"
        ) from None


def _prepare_folder(out: Path) -> None:
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


def _select_variant(requested: str) -> str:
    from mcdenoise.render.scenes import ensure_variant

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
    _prepare_folder(out)
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
        same = rec.get("spec") == _spec_dict(job.spec) and rec.get("seed") == job.seed
        if same and _image_complete(out, rec):
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
            from tqdm.auto import tqdm

            if config.frames is None:
                for job in tqdm(todo, desc="render", unit="image", disable=not config.progress):
                    rendered = render_image(job, config, result.variant)
                    record = write_image(rendered, config)
                    own_records[job.id] = record
                    write_shard_manifest(out, own_name, config.settings(), i, n, own_records)
                    result.rendered.append(job.id)
                    merge_manifests(out)
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
    from tqdm.auto import tqdm

    assert config.frames is not None and result.variant is not None
    out, (i, n) = config.out, config.shard
    total = len(todo) * config.frames
    with tqdm(total=total, desc="render", unit="frame", disable=not config.progress) as bar:
        for job in todo:

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
    return (
        f"--res {s.get('width')}x{s.get('height')} --spp {spp} --ref-spp {s.get('ref_spp')} "
        f"pass_spp {s.get('pass_spp')}{frames}"
    )
