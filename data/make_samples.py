"""Render the small sample scenes shipped in ``data/samples/`` with Mitsuba 3.

Usage (the files in ``data/samples/`` were made with exactly this)::

    python data/make_samples.py --out data/samples

For every scene it writes

* ``<scene>_spp4.exr`` and ``<scene>_spp16.exr``: noisy colour plus the feature buffers
  ``albedo``, ``normal`` (shading normal, world space), ``depth`` (distance along the camera
  ray), ``position`` (world space) and, for each of these and for ``color``, the per-pixel
  variance of the MEAN (``<name>_var``);
* ``ref/<scene>.exr``: a high-spp reference (colour only, float32; >= 4096 spp, 16384 for
  the caustic), rendered in passes of at most ``--pass-spp`` samples with distinct seeds and
  averaged, so memory stays bounded;

and ``README.md`` describing the scenes, seeds, spp, the command line, the Mitsuba version and
variant and the render times.

All buffers come from ONE render per image: a ``moment`` integrator nests an ``aov``
integrator (albedo, shading normal, depth, position) which nests a ``path`` integrator, on a
film with a ``box`` reconstruction filter, so every sample lands in exactly one pixel with
weight 1 and the film's first and second moments ``m1``, ``m2`` are plain per-pixel sample
means. The variance of the mean is then estimated without bias as
``(m2 - m1**2) / (spp - 1)`` (the sample variance ``n/(n-1) * (m2 - m1**2)`` divided by ``n``;
dividing by ``spp`` instead underestimates it by the factor ``(spp - 1) / spp``, 25 % at 4 spp),
clamped at 0 where float32 round-off makes it slightly negative.

The module is importable (``tests/data/test_samples.py`` uses :func:`build_scene`,
:func:`render_buffers` and :func:`select_variant` for the statistical check of the variance).
Arrays are numpy float32 of layout ``(C, H, W)``; colour is linear HDR sRGB/Rec.709 primaries.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Side of the square images shipped in ``data/samples/``.
DEFAULT_SIZE = 128
#: Samples per pixel of the noisy images.
NOISY_SPP = (4, 16)
#: Largest spp of one render call (reference passes), bounding memory.
DEFAULT_PASS_SPP = 128
#: Variants tried in order when ``--variant`` is not given.
VARIANTS = ("llvm_ad_rgb", "scalar_rgb")

#: Feature buffers of every sample image (their Mitsuba AOVs: ``mcdenoise.render.moments``).
FEATURES = ("albedo", "normal", "depth", "position")
#: Buffer names of :func:`render_buffers` (colour first).
CHANNELS = ("color", *FEATURES)
#: Mitsuba AOV string of the nested ``aov`` integrator, for the README.
AOVS = "albedo:albedo,normal:sh_normal,depth:depth,position:position"
#: Buffers written to the reference files. Colour only: noisy float32 colour is nearly
#: incompressible, and with the features (or ``color_var``) the folder exceeds its 5 MB budget.
REF_BUFFERS = ("color",)
#: Buffers stored as float32; everything else is written as half.
FLOAT32_BUFFERS = ("color", "color_var")


# --------------------------------------------------------------------------------------------
# Variant selection
# --------------------------------------------------------------------------------------------
def select_variant(requested: str | None = None) -> str:
    """Set and return the Mitsuba variant: ``requested``, else the best that works here
    (:func:`mcdenoise.render.scenes.ensure_variant`: cuda, then llvm, then scalar)."""
    from mcdenoise.render.scenes import ensure_variant

    return ensure_variant(requested or "auto")


# --------------------------------------------------------------------------------------------
# Scenes (mi.load_dict dictionaries, no external assets)
# --------------------------------------------------------------------------------------------
def _rgb(r: float, g: float, b: float) -> dict[str, Any]:
    return {"type": "rgb", "value": [r, g, b]}


def _checker(c0: Sequence[float], c1: Sequence[float], scale: float) -> dict[str, Any]:
    import mitsuba as mi

    return {
        "type": "checkerboard",
        "color0": _rgb(*c0),
        "color1": _rgb(*c1),
        "to_uv": mi.ScalarTransform4f().scale([scale, scale, 1.0]),
    }


def _floor(size: float, bsdf: dict[str, Any], y: float = 0.0) -> dict[str, Any]:
    """A square of side ``2 * size`` in the plane ``y``, normal +Y."""
    import mitsuba as mi

    to_world = mi.ScalarTransform4f().translate([0.0, y, 0.0]).rotate([1, 0, 0], -90).scale(size)
    return {"type": "rectangle", "to_world": to_world, "bsdf": bsdf}


def _integrator(max_depth: int) -> dict[str, Any]:
    from mcdenoise.render.moments import moment_integrator

    return moment_integrator({"type": "path", "max_depth": max_depth}, FEATURES)


def _film(size: int) -> dict[str, Any]:
    return {
        "type": "hdrfilm",
        "width": size,
        "height": size,
        "pixel_format": "rgb",
        "component_format": "float32",
        "rfilter": {"type": "box"},
    }


def _sampler() -> dict[str, Any]:
    # Independent sampler: the spp samples of a pixel are i.i.d., so the variance of their
    # mean is the sample variance / spp (a stratified sampler would break that estimate).
    return {"type": "independent", "sample_count": 4}


def _perspective(
    origin: Sequence[float], target: Sequence[float], fov: float, size: int
) -> dict[str, Any]:
    import mitsuba as mi

    return {
        "type": "perspective",
        "fov": fov,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
        "film": _film(size),
        "sampler": _sampler(),
    }


def sky_envmap(width: int = 128, height: int = 64) -> np.ndarray:
    """A procedural sky in Mitsuba's lat-long layout, ``(height, width, 3)`` linear RGB.

    Blue zenith fading to a bright horizon, a dim brown ground and a soft sun (Gaussian lobe
    of about 4 degrees) in direction ``(0.45, 0.55, 0.70)`` (up is +Y, the cameras look
    along -Z), so objects are lit from the front-right-top. Mitsuba maps texel ``(u, v)`` to
    ``theta = pi v``, ``phi = 2 pi u`` and direction ``(sin phi sin theta, cos theta,
    -cos phi sin theta)``.
    """
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    theta = np.pi * v[:, None]
    phi = 2.0 * np.pi * u[None, :]
    d = np.stack(
        np.broadcast_arrays(
            np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)
        ),
        axis=-1,
    )
    up = d[..., 1:2]
    zenith = np.array([0.18, 0.32, 0.75])
    horizon = np.array([0.85, 0.88, 0.95])
    ground = np.array([0.20, 0.16, 0.12])
    t = np.sqrt(np.clip(up, 0.0, 1.0))
    sky = np.where(up > 0, horizon * (1 - t) + zenith * t, ground)
    sun_dir = np.array([0.45, 0.55, 0.70])
    sun_dir /= np.linalg.norm(sun_dir)
    cos_sun = np.clip(d @ sun_dir, -1.0, 1.0)
    angle = np.arccos(cos_sun)
    width_rad = math.radians(4.0)
    sun = 60.0 * np.exp(-0.5 * (angle / width_rad) ** 2)[..., None] * np.array([1.0, 0.93, 0.8])
    return (sky + sun).astype(np.float32)


def scene_cornell(size: int) -> dict[str, Any]:
    """Mitsuba's Cornell box: a small ceiling light, mostly indirect illumination."""
    import mitsuba as mi

    scene = mi.cornell_box()
    scene["integrator"] = _integrator(max_depth=16)
    scene["sensor"]["film"] = _film(size)
    scene["sensor"]["sampler"] = _sampler()
    return scene


def scene_materials(size: int) -> dict[str, Any]:
    """Smooth silver, rough gold and checker-textured plastic spheres on a checker
    rough-plastic floor, lit by a procedural sky with a soft sun."""
    import mitsuba as mi

    return {
        "type": "scene",
        "integrator": _integrator(max_depth=8),
        "sensor": _perspective([0.0, 1.3, 5.6], [0.0, 0.5, 0.0], 40.0, size),
        "sky": {"type": "envmap", "bitmap": mi.Bitmap(sky_envmap()), "scale": 1.0},
        "floor": _floor(
            60.0,
            {
                "type": "roughplastic",
                "distribution": "ggx",
                "alpha": 0.15,
                "diffuse_reflectance": _checker((0.75, 0.75, 0.72), (0.12, 0.12, 0.14), 120.0),
            },
        ),
        "silver": {
            "type": "sphere",
            "center": [-1.25, 0.55, 0.0],
            "radius": 0.55,
            "bsdf": {"type": "conductor", "material": "Ag"},
        },
        "gold": {
            "type": "sphere",
            "center": [0.0, 0.55, -0.35],
            "radius": 0.55,
            "bsdf": {"type": "roughconductor", "material": "Au", "alpha": 0.18},
        },
        "plastic": {
            "type": "sphere",
            "center": [1.25, 0.55, 0.0],
            "radius": 0.55,
            "bsdf": {
                "type": "plastic",
                "int_ior": 1.5,
                "diffuse_reflectance": _checker((0.7, 0.08, 0.06), (0.9, 0.85, 0.7), 8.0),
            },
        },
    }


def scene_caustic(size: int) -> dict[str, Any]:
    """A glass sphere on a diffuse floor lit by a small, very bright spherical light:
    a caustic that unidirectional path tracing finds only by chance (fireflies)."""
    return {
        "type": "scene",
        "integrator": _integrator(max_depth=16),
        "sensor": _perspective([0.0, 1.7, 4.2], [0.0, 0.45, 0.0], 40.0, size),
        "fill": {"type": "constant", "radiance": _rgb(0.04, 0.045, 0.05)},
        "floor": _floor(4.0, {"type": "diffuse", "reflectance": _rgb(0.7, 0.7, 0.68)}),
        "wall": {
            "type": "rectangle",
            "to_world": _wall_transform(),
            "bsdf": {"type": "diffuse", "reflectance": _rgb(0.55, 0.6, 0.7)},
        },
        "glass": {
            "type": "sphere",
            "center": [-0.1, 0.6, 0.0],
            "radius": 0.6,
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
        },
        "block": {
            "type": "cube",
            "to_world": _cube_transform([1.5, 0.3, -1.0], 0.3, 25.0),
            "bsdf": {"type": "diffuse", "reflectance": _rgb(0.65, 0.25, 0.1)},
        },
        "bulb": {
            "type": "sphere",
            "center": [-2.2, 2.4, -0.6],
            "radius": 0.15,
            "emitter": {"type": "area", "radiance": _rgb(220.0, 205.0, 180.0)},
        },
    }


def _wall_transform() -> Any:
    import mitsuba as mi

    return mi.ScalarTransform4f().translate([0.0, 2.0, -2.2]).scale([4.0, 2.0, 1.0])


def _cube_transform(center: Sequence[float], half: float, yaw_deg: float) -> Any:
    import mitsuba as mi

    return mi.ScalarTransform4f().translate(list(center)).rotate([0, 1, 0], yaw_deg).scale(half)


def scene_dof(size: int) -> dict[str, Any]:
    """Depth of field (thin lens focused on the middle object) over finely checkered
    objects and floor: defocus blur, texture detail and features that vary inside a pixel."""
    import mitsuba as mi

    origin = np.array([0.0, 1.2, 4.5])
    focus_target = np.array([0.0, 0.45, 0.0])
    return {
        "type": "scene",
        "integrator": _integrator(max_depth=8),
        "sensor": {
            "type": "thinlens",
            "fov": 40.0,
            "aperture_radius": 0.12,
            "focus_distance": float(np.linalg.norm(origin - focus_target)),
            "to_world": mi.ScalarTransform4f().look_at(
                origin=origin.tolist(), target=[0.0, 0.55, 0.0], up=[0, 1, 0]
            ),
            "film": _film(size),
            "sampler": _sampler(),
        },
        "fill": {"type": "constant", "radiance": _rgb(0.25, 0.27, 0.3)},
        "light": {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f()
            .translate([1.0, 3.5, 1.5])
            .rotate([1, 0, 0], 90)
            .scale(0.8),
            "emitter": {"type": "area", "radiance": _rgb(9.0, 8.5, 7.5)},
        },
        "floor": _floor(
            8.0,
            {"type": "diffuse", "reflectance": _checker((0.8, 0.8, 0.8), (0.1, 0.1, 0.1), 40.0)},
        ),
        "near": {
            "type": "sphere",
            "center": [-0.9, 0.45, 2.2],
            "radius": 0.45,
            "bsdf": {
                "type": "diffuse",
                "reflectance": _checker((0.9, 0.75, 0.1), (0.1, 0.2, 0.6), 16.0),
            },
        },
        "middle": {
            "type": "cube",
            "to_world": _cube_transform([0.0, 0.45, 0.0], 0.45, 30.0),
            "bsdf": {
                "type": "diffuse",
                "reflectance": _checker((0.85, 0.85, 0.85), (0.6, 0.05, 0.05), 6.0),
            },
        },
        "far": {
            "type": "sphere",
            "center": [1.3, 0.7, -3.0],
            "radius": 0.7,
            "bsdf": {
                "type": "roughplastic",
                "alpha": 0.2,
                "diffuse_reflectance": _checker((0.1, 0.55, 0.2), (0.9, 0.9, 0.85), 20.0),
            },
        },
    }


@dataclass(frozen=True)
class SceneSpec:
    """One sample scene: how to build it, what it stresses, and its reference spp."""

    name: str
    build: Callable[[int], dict[str, Any]]
    description: str
    ref_spp: int


SCENES: dict[str, SceneSpec] = {
    s.name: s
    for s in (
        SceneSpec(
            "cornell",
            scene_cornell,
            "Cornell box (Mitsuba's `mi.cornell_box()`): diffuse walls and boxes lit by a "
            "small ceiling light; mostly indirect light, colour bleeding, soft shadows.",
            4096,
        ),
        SceneSpec(
            "materials",
            scene_materials,
            "Smooth silver, rough gold and checker-textured smooth-plastic spheres on a "
            "checkered rough-plastic floor under a procedural sky with a soft sun "
            "(environment light): glossy reflections, texture edges, albedo vs. specular.",
            4096,
        ),
        SceneSpec(
            "caustic",
            scene_caustic,
            "Glass sphere, a diffuse block and a floor lit by a small, very bright spherical "
            "light plus a dim constant fill: refraction, a caustic on the floor and fireflies "
            "(the caustic is found only by BSDF sampling hitting the small light).",
            16384,
        ),
        SceneSpec(
            "dof",
            scene_dof,
            "Depth of field (`thinlens`, focused on the middle cube) over finely checkered "
            "spheres, cube and floor, area light plus constant fill: defocus noise, fine "
            "texture detail and features (normal, depth, position) that vary inside a pixel.",
            4096,
        ),
    )
}


def build_scene(name: str, size: int = DEFAULT_SIZE) -> dict[str, Any]:
    """The ``mi.load_dict`` dictionary of sample scene ``name`` at ``size`` x ``size`` pixels.

    Needs a Mitsuba variant to be set (:func:`select_variant`).
    """
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    if size < 1:
        raise ValueError(f"image size must be >= 1, got {size}")
    return SCENES[name].build(size)


def load_scene(name: str, size: int = DEFAULT_SIZE) -> Any:
    """``mi.load_dict(build_scene(name, size))``."""
    import mitsuba as mi

    return mi.load_dict(build_scene(name, size))


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------
def _as_arrays(moments: Any) -> dict[str, np.ndarray]:
    from mcdenoise.render.moments import buffers_from_moments

    fb = buffers_from_moments(moments)
    return {name: fb[name].numpy() for name in fb.names()}


def render_buffers(scene: Any, spp: int, seed: int) -> dict[str, np.ndarray]:
    """One render of ``scene``: ``color``, ``albedo``, ``normal``, ``depth``, ``position`` and
    their ``_var`` (variance of the mean), float32 ``(C, H, W)``; colour in linear HDR RGB.
    The estimator is the library's (:mod:`mcdenoise.render.moments`)."""
    from mcdenoise.render.moments import render_moments

    return _as_arrays(render_moments(scene, spp, seed, FEATURES))


def reference_seeds(first_seed: int, spp: int, pass_spp: int) -> list[tuple[int, int]]:
    """``(seed, spp)`` of each reference pass: consecutive seeds, at most ``pass_spp`` each."""
    if spp < 1 or pass_spp < 1:
        raise ValueError(f"spp and pass_spp must be >= 1, got {spp} and {pass_spp}")
    full, rest = divmod(spp, pass_spp)
    counts = [pass_spp] * full + ([rest] if rest else [])
    return [(first_seed + i, n) for i, n in enumerate(counts)]


def render_reference(
    scene: Any, spp: int, first_seed: int, pass_spp: int = DEFAULT_PASS_SPP
) -> dict[str, np.ndarray]:
    """A high-spp render averaged from passes of at most ``pass_spp`` (distinct seeds).

    Returns the same buffers as :func:`render_buffers`, with variances over all ``spp``
    samples (merged moments accumulated in float64).
    """
    from mcdenoise.render.moments import render_moments

    total = None
    for seed, n in reference_seeds(first_seed, spp, pass_spp):
        m = render_moments(scene, n, seed, FEATURES)
        total = m if total is None else total.merge(m)
    assert total is not None
    return _as_arrays(total)


# --------------------------------------------------------------------------------------------
# Metrics and previews
# --------------------------------------------------------------------------------------------
def relmse(x: np.ndarray, ref: np.ndarray, eps: float = 0.01) -> float:
    """mean((x - r)^2 / (r^2 + eps)) over all pixels and channels (linear HDR colour)."""
    x64 = x.astype(np.float64)
    r64 = ref.astype(np.float64)
    return float(np.mean((x64 - r64) ** 2 / (r64 * r64 + eps)))


def relmse_of_noise(mean: np.ndarray, var: np.ndarray, eps: float = 0.01) -> float:
    """Expected relMSE of an unbiased estimate ``mean`` against the truth, from its variance of
    the mean: ``mean(var / (mean^2 + eps))`` (used to show how converged a reference is)."""
    m64 = mean.astype(np.float64)
    return float(np.mean(var.astype(np.float64) / (m64 * m64 + eps)))


def _tonemap(rgb: np.ndarray) -> np.ndarray:
    """Linear ``(3, H, W)`` -> sRGB-encoded ``(H, W, 3)`` in [0, 1] (clamped, no exposure)."""
    x = np.clip(np.moveaxis(rgb, 0, -1), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _normalise(img: np.ndarray) -> np.ndarray:
    """``(C, H, W)`` -> ``(H, W, 3)`` scaled to [0, 1] by its 1st..99th percentile range."""
    lo, hi = np.percentile(img, [1, 99])
    x = np.clip((img - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    if x.shape[0] == 1:
        x = np.repeat(x, 3, axis=0)
    return np.moveaxis(x, 0, -1)


def write_preview(path: Path, images: dict[str, dict[str, np.ndarray]]) -> None:
    """A contact sheet PNG: 4 spp, 16 spp, reference colour; albedo, normal, depth, position,
    sqrt(color_var) of the 16 spp image."""
    import OpenImageIO as oiio

    from mcdenoise.io.atomic import atomic_path

    b16 = images["spp16"]
    tiles = [
        _tonemap(images["spp4"]["color"]),
        _tonemap(b16["color"]),
        _tonemap(images["ref"]["color"]),
        _tonemap(b16["albedo"]),
        np.moveaxis(np.clip(0.5 * b16["normal"] + 0.5, 0, 1), 0, -1),
        _normalise(b16["depth"]),
        _normalise(b16["position"]),
        _normalise(np.sqrt(b16["color_var"].mean(axis=0, keepdims=True))),
    ]
    h, w = tiles[0].shape[:2]
    sheet = np.ones((2 * h + 2, 4 * w + 6, 3), dtype=np.float32)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, 4)
        sheet[r * (h + 2) : r * (h + 2) + h, c * (w + 2) : c * (w + 2) + w] = tile
    pixels = (np.clip(sheet, 0, 1) * 255 + 0.5).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        out.open(str(tmp), oiio.ImageSpec(sheet.shape[1], sheet.shape[0], 3, "uint8"))
        out.write_image(pixels)
        out.close()


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------
def _save(
    path: Path,
    buffers: dict[str, np.ndarray],
    *,
    spp: int,
    attributes: dict[str, Any],
    keep: Sequence[str] | None = None,
) -> None:
    """Write ``buffers`` through :func:`mcdenoise.io.save_buffers` (ZIP; colour float32,
    the rest half)."""
    from mcdenoise.io import FeatureBuffers, save_buffers

    names = [n for n in buffers if keep is None or n in keep]
    fb = FeatureBuffers({n: buffers[n] for n in names}, spp=spp)
    half = [n for n in names if n not in FLOAT32_BUFFERS]
    path.parent.mkdir(parents=True, exist_ok=True)
    report = save_buffers(path, fb, half=half, compression="zip", attributes=attributes)
    if report.total_clamped:
        raise RuntimeError(f"{path}: half overflow clamped in {report.clamped}")


def _readme(
    *,
    size: int,
    variant: str,
    version: str,
    command: str,
    rows: list[dict[str, Any]],
    total_seconds: float,
    pass_spp: int,
    exr_bytes: int,
) -> str:
    lines = [
        "# Sample renders",
        "",
        "Small Mitsuba 3 renders for tests, demos and quick experiments. Made by "
        "`data/make_samples.py`; do not edit by hand, re-run the command below.",
        "",
        f"- resolution: {size}x{size} pixels (width x height)",
        f"- renderer: Mitsuba {version}, variant `{variant}`",
        f"- command: `{command}`",
        f"- total time: {total_seconds:.0f} s (wall clock, 2 shared CPU cores)",
        f"- size of the EXR files: {exr_bytes / 2**20:.2f} MiB (ZIP compression)",
        "- files: `<scene>_spp4.exr`, `<scene>_spp16.exr` (noisy), `ref/<scene>.exr` (reference)",
        "",
        "## Buffers",
        "",
        "Noisy files: `color` (R,G,B, float32, linear HDR), `albedo`, `normal` (shading normal, "
        "world space), `depth` (distance along the camera ray, 0 where the ray escapes), "
        "`position` (world space), and for each of them `<buffer>_var`, the per-pixel variance "
        "of the MEAN (float32 for `color_var`, half for the features). All come from one render: "
        "a `moment` integrator nesting an `aov` integrator "
        f"(`{AOVS}`) nesting a `path` integrator, box reconstruction filter, independent "
        "sampler. Variance of the mean = max(0, (m2 - m1^2) / (spp - 1)) (unbiased; "
        "`/ spp` would be low by (spp-1)/spp).",
        "",
        f"References: `color` only (float32), the mean over passes of <= {pass_spp} spp with "
        "consecutive distinct seeds, rendered with the same integrator. Their own remaining "
        "noise (expected relMSE from the variance of their mean) is listed below.",
        "",
        "`albedo` is Mitsuba's `eval_diffuse_reflectance`: the diffuse reflectance of diffuse "
        "and plastic surfaces, 0 for smooth conductors and glass, and pi * f(wi, n) for rough "
        "conductors, which exceeds 1 on glossy lobes (largest albedo per scene below). That is "
        "what the renderer gives; albedo demodulation has to cope with it.",
        "",
        "Header attributes: `mcdenoise:spp`, `mcdenoise:scene`, `mcdenoise:seed` (first seed; "
        "references also `mcdenoise:passes`), `mcdenoise:variant`, "
        "`mcdenoise:render_seconds`, `mitsuba:version`.",
        "",
        "## Scenes",
        "",
    ]
    for row in rows:
        lines.append(
            f"- `{row['scene']}`: {row['description']} Largest albedo: {row['albedo_max']:.3g}."
        )
    lines += [
        "",
        "## Spp, seeds, time, error",
        "",
        "relMSE = mean((x - r)^2 / (r^2 + 0.01)) of `color` vs the reference, linear RGB.",
        "",
        "| scene | spp | seed | seconds | relMSE vs ref |",
        "|---|---|---|---|---|",
    ]
    for row in rows:
        for item in row["images"]:
            if item["relmse"] is not None:
                err = f"{item['relmse']:.4g}"
            else:  # the reference itself: its expected error from its own variance
                err = f"~{item['own_relmse']:.2g} (its own noise)"
            lines.append(
                f"| {row['scene']} | {item['spp']} | {item['seed']} | "
                f"{item['seconds']:.1f} | {err} |"
            )
    lines.append("")
    return "\n".join(lines)


def make_samples(
    out: Path,
    *,
    scenes: Sequence[str],
    size: int,
    variant: str,
    seed: int,
    ref_scale: float,
    pass_spp: int,
    preview: Path | None,
    command: str,
) -> list[dict[str, Any]]:
    """Render every scene of ``scenes`` into ``out``; return per-scene records (seeds, spp,
    seconds, relMSE) that also go into ``out/README.md``."""
    import mitsuba as mi

    from mcdenoise.io.atomic import write_text_atomic

    t_all = time.perf_counter()
    rows: list[dict[str, Any]] = []
    written: list[Path] = []
    for name in scenes:
        spec = SCENES[name]
        base = seed + 1000 * (list(SCENES).index(name) + 1)
        scene = load_scene(name, size)
        images: dict[str, dict[str, np.ndarray]] = {}
        records: list[dict[str, Any]] = []
        common = {
            "mcdenoise:scene": name,
            "mcdenoise:variant": variant,
            "mitsuba:version": mi.__version__,
        }

        ref_spp = max(1, round(spec.ref_spp * ref_scale))
        ref_first = base + 100
        t0 = time.perf_counter()
        ref = render_reference(scene, ref_spp, ref_first, pass_spp)
        ref_seconds = time.perf_counter() - t0
        passes = len(reference_seeds(ref_first, ref_spp, pass_spp))
        images["ref"] = ref
        written.append(out / "ref" / f"{name}.exr")
        _save(
            written[-1],
            ref,
            spp=ref_spp,
            keep=REF_BUFFERS,
            attributes={
                **common,
                "mcdenoise:seed": ref_first,
                "mcdenoise:passes": passes,
                "mcdenoise:render_seconds": round(ref_seconds, 3),
            },
        )
        for i, spp in enumerate(NOISY_SPP):
            s = base + 1 + i
            t0 = time.perf_counter()
            bufs = render_buffers(scene, spp, s)
            seconds = time.perf_counter() - t0
            images[f"spp{spp}"] = bufs
            written.append(out / f"{name}_spp{spp}.exr")
            _save(
                written[-1],
                bufs,
                spp=spp,
                attributes={
                    **common,
                    "mcdenoise:seed": s,
                    "mcdenoise:render_seconds": round(seconds, 3),
                },
            )
            records.append(
                {
                    "spp": spp,
                    "seed": s,
                    "seconds": seconds,
                    "relmse": relmse(bufs["color"], ref["color"]),
                }
            )
        records.append(
            {
                "spp": ref_spp,
                "seed": f"{ref_first}..{ref_first + passes - 1}",
                "seconds": ref_seconds,
                "relmse": None,
                "own_relmse": relmse_of_noise(ref["color"], ref["color_var"]),
            }
        )
        rows.append(
            {
                "scene": name,
                "description": spec.description,
                "images": records,
                "albedo_max": float(images[f"spp{NOISY_SPP[-1]}"]["albedo"].max()),
            }
        )
        if preview is not None:
            preview.mkdir(parents=True, exist_ok=True)
            write_preview(preview / f"{name}.png", images)
    total = time.perf_counter() - t_all
    write_text_atomic(
        out / "README.md",
        _readme(
            size=size,
            variant=variant,
            version=mi.__version__,
            command=command,
            rows=rows,
            total_seconds=total,
            pass_spp=pass_spp,
            exr_bytes=sum(p.stat().st_size for p in written),
        ),
    )
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("data/samples"), help="output folder")
    parser.add_argument(
        "--variant",
        default=None,
        help="Mitsuba variant (default: the best that works: cuda, llvm, scalar)",
    )
    parser.add_argument("--scenes", nargs="+", choices=list(SCENES), default=list(SCENES))
    parser.add_argument("--size", type=int, default=DEFAULT_SIZE, help="image width = height")
    parser.add_argument("--seed", type=int, default=0, help="offset added to every seed")
    parser.add_argument(
        "--ref-scale",
        type=float,
        default=1.0,
        help="multiplies each scene's reference spp (quick runs)",
    )
    parser.add_argument(
        "--pass-spp", type=int, default=DEFAULT_PASS_SPP, help="max spp per reference pass"
    )
    parser.add_argument("--preview", type=Path, default=None, help="folder for PNG contact sheets")
    args = parser.parse_args(argv)
    if args.size < 1 or args.pass_spp < 1 or args.ref_scale <= 0:
        parser.error("--size and --pass-spp must be >= 1 and --ref-scale > 0")
    try:
        variant = select_variant(args.variant)
    except ValueError as err:
        parser.error(str(err))
    command = shlex.join(
        ["python", "data/make_samples.py", *(sys.argv[1:] if argv is None else argv)]
    )
    rows = make_samples(
        args.out,
        scenes=args.scenes,
        size=args.size,
        variant=variant,
        seed=args.seed,
        ref_scale=args.ref_scale,
        pass_spp=args.pass_spp,
        preview=args.preview,
        command=command,
    )
    for row in rows:
        errs = ", ".join(
            f"{r['spp']} spp {r['relmse']:.4g}" for r in row["images"] if r["relmse"] is not None
        )
        print(f"{row['scene']}: relMSE {errs}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
