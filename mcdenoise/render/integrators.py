"""Custom Mitsuba 3 integrators: ambient occlusion (``mcd_ao``) and a path tracer that can
leave out caustics (``mcd_path``).

Both are Python subclasses of ``mi.SamplingIntegrator`` written with ``@dr.syntax`` loops, so
in the JIT variants (``llvm_ad_rgb``, ``cuda_ad_rgb``) a whole render is traced into one
compiled kernel; in ``scalar_*`` variants the same code runs once per sample in the
interpreter (correct, but slow: see ``benchmarks/bench_integrators.py``). They return no
AOVs of their own and nest in Mitsuba's ``aov`` and ``moment`` integrators like any C++
integrator (``moment`` → ``aov`` → ``mcd_path`` is what the data generator renders).
Unpolarized variants only (``*_rgb``, ``*_mono``, ``*_spectral``).

Call :func:`register_integrators` after ``mi.set_variant(...)`` (again after every variant
change: the classes are built against the variant active at that moment). Then use the
plugin dicts from :func:`ao_integrator` / :func:`path_integrator`, which check their
arguments and raise :class:`~mcdenoise.errors.InputError` with a one-line message (the plugin
constructors check the same things, but Mitsuba's parser wraps their errors in a
``RuntimeError`` with a traceback).

``mcd_ao`` — ambient occlusion within a radius
    Output: grey RGB in [0, 1], ``AO(p) = 1/π ∫_Ω V_r(p, ω) cos θ dω`` at the first visible
    surface point ``p``, where ``V_r = 0`` when a surface is hit within distance ``radius``
    (scene units) along ``ω`` and 1 otherwise (a ray that escapes or hits beyond the radius is
    unoccluded). This is the cosine-weighted AO of Zhukov/Landis; it is estimated by ``rays``
    cosine-weighted hemisphere rays per camera sample, so each estimate is the fraction of
    unoccluded rays and, with ``rays = 1``, each sample is exactly 0 or 1. The hemisphere is
    centred on the shading normal flipped towards the viewer (two-sided surfaces); occlusion
    rays start at ``si.spawn_ray`` (offset along the geometric normal to the side the ray
    leaves by). Emitter shapes occlude like any other shape. Camera rays that miss every
    shape return ``background`` (default 1, i.e. "open sky": a pixel that sees nothing is
    fully unoccluded; use 0 for a black background) and are marked invalid (alpha 0).

``mcd_path`` — path tracer with a ``caustics`` switch
    The same estimator as Mitsuba's ``path`` (unidirectional, next-event estimation combined
    with BSDF sampling by the power heuristic, Russian roulette from ``rr_depth`` on,
    ``max_depth`` counted as in ``path``: 1 = emitters seen directly, 2 = direct light only,
    -1 = unbounded; ``hide_emitters`` skips area emitters and the environment for camera
    rays). With ``caustics = false``, a path that has already scattered off a non-delta
    (diffuse or glossy) lobe is terminated as soon as it samples a delta (smooth specular)
    reflection or transmission: light along diffuse → specular → … chains is not simulated,
    the usual "no caustics" regularisation (paths camera → specular → diffuse → light, e.g.
    a floor seen through glass, are kept; passing through ``null`` interfaces does not count
    as specular). With ``caustics = true`` (default) it agrees with ``path`` in distribution;
    it even draws its random numbers in ``path``'s order, so with Mitsuba 3.9 and the same seed
    both render the same image up to float rounding (tested). No participating media.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

from mcdenoise.errors import InputError, McdenoiseError

try:  # the optional 'render' extra; @dr.syntax needs `dr` and `mi` as module globals
    import drjit as dr
    import mitsuba as mi
except ImportError:  # pragma: no cover - exercised only without mitsuba
    dr = mi = None  # type: ignore[assignment]

#: Registered plugin names.
AO_PLUGIN = "mcd_ao"
PATH_PLUGIN = "mcd_path"

_UINT32_MAX = 2**32 - 1


# --------------------------------------------------------------------------- validation


def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _check_ao(radius: float, rays: int, background: float) -> None:
    if not (_is_real(radius) and radius > 0):  # NaN fails the comparison
        raise InputError(f"{AO_PLUGIN}: radius must be > 0 (scene units), got {radius!r}")
    if not (_is_int(rays) and rays >= 1):
        raise InputError(f"{AO_PLUGIN}: rays must be an integer >= 1, got {rays!r}")
    if not (_is_real(background) and 0.0 <= background <= 1.0):
        raise InputError(f"{AO_PLUGIN}: background must be in [0, 1], got {background!r}")


def _check_path(max_depth: int, rr_depth: int) -> None:
    if not (_is_int(max_depth) and max_depth >= -1):
        raise InputError(
            f"{PATH_PLUGIN}: max_depth must be -1 (unbounded) or >= 0, got {max_depth!r}"
        )
    if not (_is_int(rr_depth) and rr_depth >= 1):
        raise InputError(f"{PATH_PLUGIN}: rr_depth must be an integer >= 1, got {rr_depth!r}")


def ao_integrator(
    radius: float = math.inf, rays: int = 1, background: float = 1.0
) -> dict[str, Any]:
    """Mitsuba plugin dict for ``mcd_ao`` (see the module docstring), arguments checked.

    ``radius`` is in scene units (``inf``: unbounded occlusion distance), ``rays`` the number
    of occlusion rays per camera sample, ``background`` the value of pixels that see nothing.

    >>> ao_integrator(radius=0.5, rays=4)
    {'type': 'mcd_ao', 'radius': 0.5, 'rays': 4, 'background': 1.0}
    """
    _check_ao(radius, rays, background)
    return {
        "type": AO_PLUGIN,
        "radius": float(radius),
        "rays": int(rays),
        "background": float(background),
    }


def path_integrator(
    max_depth: int = -1,
    rr_depth: int = 5,
    hide_emitters: bool = False,
    caustics: bool = True,
) -> dict[str, Any]:
    """Mitsuba plugin dict for ``mcd_path`` (see the module docstring), arguments checked.

    >>> path_integrator(max_depth=8, caustics=False)["caustics"]
    False
    """
    _check_path(max_depth, rr_depth)
    return {
        "type": PATH_PLUGIN,
        "max_depth": int(max_depth),
        "rr_depth": int(rr_depth),
        "hide_emitters": bool(hide_emitters),
        "caustics": bool(caustics),
    }


# --------------------------------------------------------------------------- plugins


def _not(mask: Any) -> Any:
    """Logical not for a Dr.Jit mask or a Python ``bool`` (scalar variants; ``~True == -2``)."""
    return mask ^ True


def _mis_weight(pdf_a: Any, pdf_b: Any) -> Any:
    """Power heuristic ``a² / (a² + b²)``, 0 where undefined (both pdfs 0 or infinite)."""
    a2 = pdf_a * pdf_a
    denom = a2 + pdf_b * pdf_b
    w = a2 / dr.select(denom > 0, denom, 1.0)  # no 0/0 (Python floats raise in scalar mode)
    return dr.select((denom > 0) & dr.isfinite(w), w, 0.0)


def _build_classes() -> tuple[type, type]:
    """Define the integrator classes against the Mitsuba variant active now."""
    if mi.is_polarized:
        raise InputError(
            f"{AO_PLUGIN}/{PATH_PLUGIN} support unpolarized variants only, not {mi.variant()!r}"
        )

    class AmbientOcclusionIntegrator(mi.SamplingIntegrator):
        """``mcd_ao``: radius-limited cosine-weighted ambient occlusion (grey, [0, 1])."""

        def __init__(self, props: mi.Properties) -> None:
            super().__init__(props)
            radius = props.get("radius", math.inf)
            rays = props.get("rays", 1)
            background = props.get("background", 1.0)
            _check_ao(radius, rays, background)
            self.radius = float(radius)
            self.rays = int(rays)
            self.background = float(background)

        @dr.syntax
        def sample(
            self,
            scene: mi.Scene,
            sampler: mi.Sampler,
            ray: mi.RayDifferential3f,
            medium: mi.Medium | None = None,
            active: mi.Bool = True,
        ) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
            ray = mi.Ray3f(ray)
            si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True, active=active)
            valid = mi.Bool(active) & si.is_valid()

            # Two-sided shading: the hemisphere faces the viewer.
            n = mi.Vector3f(si.sh_frame.n)
            n = dr.select(dr.dot(n, ray.d) > 0, -n, n)
            frame = mi.Frame3f(n)

            unoccluded = mi.Float(0.0)
            i = mi.UInt32(0)
            while dr.hint(valid & (i < self.rays), label="mcd_ao"):
                wo = frame.to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
                occ_ray = si.spawn_ray(wo)
                if dr.hint(math.isfinite(self.radius), mode="scalar"):
                    occ_ray.maxt = self.radius
                hit = scene.ray_test(occ_ray, valid)
                unoccluded += dr.select(hit, 0.0, 1.0)
                i += 1

            ao = dr.select(valid, unoccluded / self.rays, self.background)
            return mi.Spectrum(ao), valid, []

        def aov_names(self) -> list[str]:
            return []

        def to_string(self) -> str:
            return (
                f"AmbientOcclusionIntegrator[radius={self.radius}, rays={self.rays}, "
                f"background={self.background}]"
            )

    class PathIntegrator(mi.SamplingIntegrator):
        """``mcd_path``: Mitsuba's ``path`` estimator plus a ``caustics`` switch."""

        def __init__(self, props: mi.Properties) -> None:
            super().__init__(props)  # reads hide_emitters
            max_depth = props.get("max_depth", -1)
            rr_depth = props.get("rr_depth", 5)
            _check_path(max_depth, rr_depth)
            self.max_depth_param = int(max_depth)
            self.max_depth = _UINT32_MAX if max_depth == -1 else int(max_depth)
            self.rr_depth = int(rr_depth)
            self.caustics = bool(props.get("caustics", True))

        @dr.syntax
        def sample(
            self,
            scene: mi.Scene,
            sampler: mi.Sampler,
            ray: mi.RayDifferential3f,
            medium: mi.Medium | None = None,
            active: mi.Bool = True,
        ) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
            # In scalar variants the loop runs per sample in Python, where a null BSDF or
            # shape pointer is None and must not be called: `jit or ...` guards below are
            # constant True when tracing a JIT kernel (null entries there evaluate to 0).
            jit = dr.is_jit_v(mi.Float)
            if dr.hint(self.max_depth == 0, mode="scalar"):
                return mi.Spectrum(0.0), mi.Bool(False), []

            bsdf_ctx = mi.BSDFContext()
            ray = mi.Ray3f(ray)
            active = mi.Bool(active)
            depth = mi.UInt32(0)
            result = mi.Spectrum(0.0)
            throughput = mi.Spectrum(1.0)
            eta = mi.Float(1.0)
            valid_ray = mi.Bool((not self.hide_emitters) and scene.environment() is not None)
            prev_si = dr.zeros(mi.SurfaceInteraction3f)
            prev_bsdf_pdf = mi.Float(1.0)
            prev_bsdf_delta = mi.Bool(True)
            had_smooth = mi.Bool(False)  # any diffuse/glossy bounce so far?

            pi = scene.ray_intersect_preliminary(ray, coherent=True, active=active)
            if dr.hint(self.hide_emitters and (jit or (active and pi.is_valid())), mode="scalar"):
                # Camera rays pass through area emitters, as in Mitsuba's path.
                skip = active & pi.is_valid() & (pi.shape.emitter() != None)  # noqa: E711
                si_skip = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal, skip)
                pi_after = self.skip_area_emitters(scene, si_skip.spawn_ray(ray.d), True, skip)
                pi = dr.select(skip, pi_after, pi)

            while dr.hint(active, label="mcd_path"):
                si = pi.compute_surface_interaction(ray, mi.RayFlags.All)
                active_next = mi.Bool(active)
                if dr.hint(self.hide_emitters, mode="scalar"):
                    active_next &= _not((depth == 0) & _not(si.is_valid()))  # hide environment

                # ---- emission found by BSDF sampling (or seen directly), MIS-weighted
                ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
                if dr.hint(jit or ds.emitter is not None, mode="scalar"):
                    # (explicit selects: scalar variants do not honour `active` masks)
                    em_pdf = dr.select(
                        prev_bsdf_delta,
                        0.0,
                        scene.pdf_emitter_direction(prev_si, ds, _not(prev_bsdf_delta)),
                    )
                    mis_bsdf = _mis_weight(prev_bsdf_pdf, em_pdf)
                    em_active = active_next & (prev_bsdf_pdf > 0)
                    emitted = dr.select(em_active, ds.emitter.eval(si, em_active), 0.0)
                    result += throughput * mis_bsdf * emitted

                active_next &= (depth + 1 < self.max_depth) & si.is_valid()
                # Alpha: a surface was hit (continuing paths refine this below: null events).
                valid_ray |= active & si.is_valid() & _not(active_next)

                if dr.hint(jit or active_next, mode="scalar"):
                    bsdf = si.bsdf(ray)

                    # ---- emitter sampling (next-event estimation)
                    active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                    # (like path in scalar variants: no emitter sample at a purely delta BSDF)
                    sample_em = jit or active_em
                    wo = mi.Vector3f(0.0, 0.0, 1.0)  # scalar, no emitter sample: unused
                    if dr.hint(sample_em, mode="scalar"):
                        ds, em_weight = scene.sample_emitter_direction(
                            si, sampler.next_2d(), True, active_em
                        )
                        active_em &= ds.pdf != 0.0
                        wo = si.to_local(ds.d)

                    # ---- BSDF value for the emitter sample, and a new direction
                    sample_1 = sampler.next_1d()
                    sample_2 = sampler.next_2d()
                    bsdf_val, bsdf_pdf, bsdf_sample, bsdf_weight = bsdf.eval_pdf_sample(
                        bsdf_ctx, si, wo, sample_1, sample_2, active_next
                    )
                    if dr.hint(sample_em, mode="scalar"):
                        mis_em = dr.select(ds.delta, 1.0, _mis_weight(ds.pdf, bsdf_pdf))
                        contribution = throughput * bsdf_val * em_weight * mis_em
                        result = dr.select(active_em, result + contribution, result)

                    # ---- continue the path
                    sampled = bsdf_sample.sampled_type
                    ray = si.spawn_ray(si.to_world(bsdf_sample.wo))
                    throughput *= bsdf_weight
                    eta *= bsdf_sample.eta
                    valid_ray |= active_next & _not(mi.has_flag(sampled, mi.BSDFFlags.Null))
                    prev_si = si
                    prev_bsdf_pdf = bsdf_sample.pdf
                    prev_bsdf_delta = mi.has_flag(sampled, mi.BSDFFlags.Delta)

                    if dr.hint(not self.caustics, mode="scalar"):
                        specular = mi.has_flag(sampled, mi.BSDFFlags.DeltaReflection) | mi.has_flag(
                            sampled, mi.BSDFFlags.DeltaTransmission
                        )
                        active_next &= _not(had_smooth & specular)
                        had_smooth |= mi.has_flag(sampled, mi.BSDFFlags.Smooth)

                    # ---- stopping criterion (Russian roulette as in Mitsuba's path)
                    depth = dr.select(si.is_valid(), depth + 1, depth)
                    throughput_max = dr.max(mi.unpolarized_spectrum(throughput))
                    rr_prob = dr.minimum(throughput_max * eta * eta, 0.95)
                    rr_active = depth >= self.rr_depth
                    rr_continue = sampler.next_1d() < rr_prob
                    throughput = dr.select(rr_active, throughput * dr.rcp(rr_prob), throughput)
                    active_next &= (_not(rr_active) | rr_continue) & (throughput_max != 0.0)

                    pi = scene.ray_intersect_preliminary(ray, coherent=False, active=active_next)
                active = active_next

            return dr.select(valid_ray, result, 0.0), valid_ray, []

        def aov_names(self) -> list[str]:
            return []

        def to_string(self) -> str:
            return (
                f"PathIntegrator[max_depth={self.max_depth_param}, rr_depth={self.rr_depth}, "
                f"hide_emitters={self.hide_emitters}, caustics={self.caustics}]"
            )

    return AmbientOcclusionIntegrator, PathIntegrator


def use_variant(variant: str | None = None) -> str:
    """Set a Mitsuba variant and register the integrators for it; return the variant name.

    ``None`` picks ``llvm_ad_rgb`` when Dr.Jit's LLVM backend is usable (it needs a working
    ``libLLVM``) and falls back to ``scalar_rgb`` otherwise.
    """
    if mi is None:
        raise McdenoiseError("mcdenoise render needs mitsuba: pip install 'mcdenoise[render]'")
    if variant is None:
        llvm = "llvm_ad_rgb" in mi.variants() and dr.has_backend(dr.JitBackend.LLVM)
        variant = "llvm_ad_rgb" if llvm else "scalar_rgb"
    if variant not in mi.variants():
        raise InputError(f"unknown Mitsuba variant {variant!r}; available: {mi.variants()}")
    mi.set_variant(variant)
    register_integrators()
    return variant


def register_integrators() -> None:
    """Register ``mcd_ao`` and ``mcd_path`` for the Mitsuba variant that is set now.

    Idempotent: calling it again (for the same or another variant, after
    ``mi.set_variant``) re-registers the plugins against the current variant's classes.
    Raises :class:`InputError` when no variant is set or the variant is polarized.
    """
    if mi is None:
        raise McdenoiseError("mcdenoise render needs mitsuba: pip install 'mcdenoise[render]'")
    if mi.variant() is None:
        raise InputError("register_integrators: call mi.set_variant(...) first")
    ao_cls, path_cls = _build_classes()
    mi.register_integrator(AO_PLUGIN, lambda props: ao_cls(props))
    mi.register_integrator(PATH_PLUGIN, lambda props: path_cls(props))
