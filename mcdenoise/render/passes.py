"""Rendering one image: the passes of every spp level and of the reference, with their times.

:func:`render_image` renders a job as the spec's effect plan says
(:mod:`mcdenoise.render.effects`): the integrator stack is ``moment`` -> ``aov`` (the plan's
feature buffers) -> the plan's radiance integrator, on a box-filtered film with an
independent sampler (:mod:`mcdenoise.render.moments`), so every buffer and its per-pixel
variance of the mean come from the same samples. The levels are rendered progressively and
the reference in bounded passes, with the seeds of :mod:`mcdenoise.render.jobs`.

Time
    ``seconds`` of a pass is the wall time of ``mi.render`` plus reading the film; the
    cumulative ``render_seconds`` of a level is the sum over the passes of every increment up to
    it (scene loading, ``load_seconds``, is counted separately). In the JIT variants the first
    pass of a new size also compiles kernels; that share is recorded as ``jit_seconds``
    (Dr.Jit's kernel history) so "what accuracy costs in time" can leave it out.

Halves (``config.halves``)
    Every increment is rendered as the passes of half A, then those of half B
    (:func:`~mcdenoise.render.jobs.half_level_passes`), each pass with the next noisy seed;
    A and B are pooled separately over the levels and written as ``color_a``/``color_b``
    (:func:`~mcdenoise.render.moments.buffers_from_halves`) at every even level, the full
    buffers being their mean. Every feature of the plan is halved with the colour
    (``albedo_a``, ``normal_b``...): a guide is noisy wherever the samples of a pixel see
    different surfaces or texels (a sub-pixel texture, foliage, an edge, a thin lens), and a
    guide shared by both halves carries each half's noise into the other's filtered output,
    which biases the reference-free estimate low (:mod:`mcdenoise.eval.estimate`, issue 36).
    The features come from the same passes as the colour, so halving them costs file size,
    not render time. (The renderer has no motion blur: motion is only the sequences'
    per-frame vectors.) A pass record gets ``"half": "a"`` or ``"b"``.

Determinism: the same spec, seed, settings and variant give identical pixel data.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.effects import EffectPlan, plan_effects
from mcdenoise.render.jobs import (
    ImageJob,
    half_level_passes,
    level_part,
    level_passes,
    noisy_seed,
    reference_seed,
    split_passes,
)
from mcdenoise.render.mitsuba_setup import load_scene
from mcdenoise.render.moments import (
    Moments,
    buffers_from_halves,
    buffers_from_moments,
    moment_integrator,
    render_moments,
)
from mcdenoise.render.scene_spec import Camera
from mcdenoise.render.scenes import camera_metadata, far_clip, scene_dict


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
            import drjit as dr  # lazy: Mitsuba is optional and slow to import

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
    half: str | None = None,
) -> tuple[Moments | None, list[dict[str, Any]], float]:
    records, seconds = [], 0.0
    for n, s in zip(sizes, seeds):
        t0 = time.perf_counter()
        m = render_moments(scene, n, s, features)
        dt = time.perf_counter() - t0
        seconds += dt
        rec: dict[str, Any] = {"seed": s, "spp": n, "seconds": round(dt, 6)}
        if half is not None:
            rec["half"] = half
        jit = clock.lap()
        if jit is not None:
            rec["jit_seconds"] = jit
        records.append(rec)
        total = m if total is None else total.merge(m)
    return total, records, seconds


def _render_levels(
    scene: Any,
    job: ImageJob,
    config: RenderConfig,
    plan: EffectPlan,
    clock: _JitClock,
    common: Mapping[str, Any],
) -> tuple[dict[str, FeatureBuffers], list[dict[str, Any]]]:
    """Every noisy level, progressively (and in halves with ``config.halves``)."""
    levels: dict[str, FeatureBuffers] = {}
    level_records: list[dict[str, Any]] = []
    total: Moments | None = None
    halves: list[Moments | None] = [None, None]
    halve = ("color", *plan.features)
    cumulative, k = 0.0, 0
    if config.halves:
        increments = half_level_passes(config.spp, config.pass_spp)
    else:
        increments = [(sizes, []) for sizes in level_passes(config.spp, config.pass_spp)]
    for level, (sizes_a, sizes_b) in zip(config.spp, increments):
        passes: list[dict[str, Any]] = []
        seconds = 0.0
        for h, sizes in enumerate((sizes_a, sizes_b) if config.halves else (sizes_a,)):
            seeds = [noisy_seed(job.seed, k + j) for j in range(len(sizes))]
            k += len(sizes)
            previous = halves[h] if config.halves else total
            tag = "ab"[h] if config.halves else None
            merged, recs, secs = _render_passes(
                scene, sizes, seeds, plan.features, clock, previous, tag
            )
            if config.halves:
                halves[h] = merged
            else:
                total = merged
            passes += recs
            seconds += secs
        cumulative += seconds
        part = level_part(level)
        attrs = {**common, "mcdenoise:render_seconds": round(cumulative, 6)}
        if config.halves:
            levels[part] = buffers_from_halves(halves[0], halves[1], halve, attrs)
        else:
            assert total is not None
            levels[part] = buffers_from_moments(total, attrs)
        level_records.append(
            {
                "spp": level,
                "part": part,
                "increment_spp": level - sum(r["increment_spp"] for r in level_records),
                "passes": passes,
                "increment_seconds": round(seconds, 6),
                "render_seconds": round(cumulative, 6),
                **_jit_total(passes),
            }
        )
    return levels, level_records


def _jit_total(passes: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """``{"jit_seconds": sum}`` over ``passes`` in JIT variants, else ``{}``."""
    jit = [p["jit_seconds"] for p in passes if "jit_seconds" in p]
    return {"jit_seconds": round(sum(jit), 6)} if jit else {}


def _load_scene(
    job: ImageJob, plan: EffectPlan, config: RenderConfig, camera: Camera | None = None
) -> Any:

    d = scene_dict(
        job.spec,
        plan,
        width=config.width,
        height=config.height,
        integrator=moment_integrator(plan.integrator_dict(), plan.features),
        camera=camera,
    )
    try:
        return load_scene(d)
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
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    if mi.variant() != variant:
        raise RenderError(
            f"render_image: Mitsuba variant {mi.variant()!r} is set, not {variant!r} "
            "(call mcdenoise.render.mitsuba_setup.ensure_variant first)"
        )

    plan = plan_effects(job.spec)
    t0 = time.perf_counter()
    scene = _load_scene(job, plan, config, camera)
    load_seconds = time.perf_counter() - t0
    view = camera_metadata(
        camera or job.spec.camera, far=far_clip(job.spec, plan), ao_radius=plan.ao_radius
    )
    common = {
        "mcdenoise:scene": job.spec.name,
        "mcdenoise:image": job.id,
        "mcdenoise:seed": job.seed,
        "mcdenoise:effects": ",".join(job.spec.effects),
        "mcdenoise:plan": plan.describe(),
        "mcdenoise:variant": variant,
        "mitsuba:version": str(mi.__version__),
        "mcdenoise:camera": json.dumps(view),
        **dict(attributes or {}),
    }
    clock = _JitClock(variant)
    try:
        levels, level_records = _render_levels(scene, job, config, plan, clock, common)
        sizes = split_passes(config.ref_spp, config.pass_spp)
        seeds = [reference_seed(job.seed, j) for j in range(len(sizes))]
        ref_total, passes, ref_seconds = _render_passes(
            scene, sizes, seeds, plan.features, clock, None
        )
    finally:
        clock.close()
    assert ref_total is not None
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
