"""From a scene spec to a Mitsuba 3 scene: the ``mi.load_dict`` dictionary, and the variant.

:func:`scene_dict` maps every spec feature (:mod:`mcdenoise.render.scene_spec`) onto Mitsuba 3.9
plugins; what is *simulated* (integrator, path depth, lens) comes from the effect plan
(:mod:`mcdenoise.render.effects`). :func:`ensure_variant` picks and sets the Mitsuba variant
and registers the project's integrators; call it before :func:`scene_dict`.

Conventions (spec → Mitsuba):

Camera
    ``perspective`` (pinhole) or, when the plan has ``thinlens`` (effect ``dof``), ``thinlens``
    with ``aperture_radius`` and ``focus_distance``. ``fov`` is the **horizontal** field of
    view in degrees (``fov_axis = "x"``), whatever the aspect ratio. ``to_world`` is
    :func:`camera_to_world` (Mitsuba's look-at: the camera looks along its local +Z, local +X
    points to the image's left). Film: ``hdrfilm`` of the requested size, float32 RGB, ``box``
    reconstruction filter (each sample lands in one pixel with weight 1, as the variance
    estimate needs); sampler ``independent`` (i.i.d. samples).
Shapes
    ``sphere`` → ``sphere`` (``center``, ``radius``; or a transform with a uniform scale).
    ``cube`` ([-1, 1]³), ``rectangle`` ([-1, 1]² at z = 0, facing +z), ``disk`` (unit disk
    at z = 0 facing +z) → the plugins of the same name with ``to_world`` =
    ``Transform.matrix()``. ``cylinder`` (radius 1, z in [0, 1]) → Mitsuba's open
    ``cylinder`` plus two ``disk`` caps, so it is a closed solid (glass cylinders refract
    correctly, no hollow look from above). ``mesh`` → ``obj`` / ``ply`` by suffix.
Materials
    ``diffuse`` → ``diffuse``; ``plastic`` → ``plastic`` (``int_ior`` = ior);
    ``roughplastic`` → ``roughplastic`` (GGX, ``alpha`` = roughness); ``conductor`` →
    ``conductor`` (``material`` = a name Mitsuba ships, or RGB ``eta``/``k``;
    ``specular_reflectance`` = specular); ``roughconductor`` likewise with GGX ``alpha``;
    ``dielectric`` → ``dielectric`` or, with roughness > 0, ``roughdielectric`` (GGX), both
    with ``int_ior`` = ior and ``ext_ior`` = 1 (vacuum). Every opaque material is wrapped in
    ``twosided`` (a sheet like a rectangle wall looks the same from both sides; Mitsuba's
    BSDFs are black from the back); dielectrics are not (they need the inside/outside).
Textures
    constant → ``rgb``; ``checkerboard`` → ``checkerboard`` with ``to_uv`` scaled by
    ``scale``: ``scale`` periods (``2·scale`` squares) per uv unit along u and v; ``image``
    → ``bitmap`` from the file, repeated ``scale`` times per uv unit; ``noise`` → seeded,
    tileable value noise (:func:`mcdenoise.render.procedural.noise_image`) baked into an
    in-memory ``mi.Bitmap``, ``scale`` = noise cells per uv unit.
Lights
    emissive objects → an ``area`` emitter on the shape (one-sided: it emits on the side
    its normal faces; for a rectangle or disk that is local +z). ``point`` → ``point``;
    ``spot`` → ``spot`` aimed by a look-at at ``target``, ``cutoff_angle`` = cutoff,
    ``beam_width``. ``constant`` → ``constant``; ``envmap`` → ``envmap`` from the file or
    from the procedural sky (:func:`mcdenoise.render.procedural.sky_image`, baked into a
    bitmap), ``to_world`` = the ``rotate`` rotation, ``scale``. ``sh`` →
    :func:`mcdenoise.render.sh.sh_envmap_dict`. At most one environment light (constant,
    envmap, sh) per scene: Mitsuba supports one.
Sun
    a finite sun (``angular_diameter`` > 0) is a black ``disk`` carrying a uniform ``area``
    emitter, placed far along ``direction`` at ``SUN_DISTANCE_FACTOR`` (10⁴) × the scene's
    radius (:func:`scene_bounds`) from its centre and facing it, with the radius that subtends
    the given angular diameter and the radiance ``L = E / (π sin² α)`` (``α`` the angular
    radius) that gives irradiance ``E`` on a surface facing it (exact at the scene's centre,
    within 0.02 % across it). A disk rather than a sphere because Mitsuba samples a sphere
    by its cone of directions, whose pdf loses float32 precision for tiny angles (a 0.1°
    sphere sun is 10 % too bright), while a disk is sampled by area. Next-event estimation
    samples it, so diffuse surfaces converge; glossy and specular bounces that hit it by
    BSDF sampling carry ``L`` (about 45 000 × E for the real sun's 0.53°): fireflies, as real
    suns make. With ``angular_diameter = 0`` it is a delta
    ``directional`` emitter (hard shadows, no fireflies, invisible to BSDF sampling).

In an AO plan (effect ``ao``) the ``[[lights]]`` are left out (the AO integrator ignores
light); the objects and their materials are kept.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.render.effects import EffectPlan
from mcdenoise.render.mitsuba_setup import _mi
from mcdenoise.render.procedural import NOISE_CELLS, noise_image, sky_image
from mcdenoise.render.scene_spec import (
    Camera,
    Light,
    Material,
    SceneObject,
    SceneSpec,
    SpecError,
    Texture,
    Transform,
)

#: A finite sun sits this many scene radii from the scene's centre: across the scene its
#: direction varies by at most 1e-4 rad and its irradiance (inverse square) by at most 0.02 %.
SUN_DISTANCE_FACTOR = 1e4
#: Environment lights: Mitsuba takes at most one per scene.
ENVIRONMENT_LIGHTS = ("constant", "envmap", "sh")
#: The sensor's near clip plane (Mitsuba's default, set explicitly so the file can record it).
NEAR_CLIP = 0.01
#: The sensor's far clip plane unless a light needs a farther one (a distant sun disk).
FAR_CLIP = 1e4


# --------------------------------------------------------------------------------------------
# Camera
# --------------------------------------------------------------------------------------------
def look_at(origin: Sequence[float], target: Sequence[float], up: Sequence[float]) -> np.ndarray:
    """Mitsuba's look-at matrix, 4×4 float64: columns ``left, up', forward, origin``.

    The frame looks along local +Z (``forward = normalize(target - origin)``), local +X is
    ``normalize(up × forward)`` and local +Y ``forward × left``.

    Raises:
        InputError: ``origin == target`` or ``up`` parallel to the viewing direction.
    """
    o = np.asarray(origin, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - o
    if np.linalg.norm(f) == 0:
        raise InputError(f"look-at: origin and target are both {tuple(o)}")
    f /= np.linalg.norm(f)
    left = np.cross(np.asarray(up, dtype=np.float64), f)
    if np.linalg.norm(left) < 1e-9:
        raise InputError(f"look-at: up {tuple(up)} is parallel to the view direction {tuple(f)}")
    left /= np.linalg.norm(left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(f, left), f, o
    return m


def camera_to_world(camera: Camera) -> np.ndarray:
    """The camera's 4×4 camera-to-world matrix (float64), exactly what the sensor gets.

    Camera space is Mitsuba's: the camera looks along +Z, +Y is up in the image and +X
    points to the image's *left*. Sequences project world points with its inverse.
    """
    return look_at(camera.origin, camera.target, camera.up)


def camera_metadata(
    camera: Camera, *, far: float = FAR_CLIP, ao_radius: float | None = None
) -> dict[str, Any]:
    """What screen-space methods need to rebuild view-space positions, as plain JSON values.

    The ``mcdenoise:camera`` header attribute of a render (JSON) and the ``camera`` of its
    manifest record (:func:`mcdenoise.io.camera.camera_from_attributes` reads it back). Keys:
    the spec's camera (``type``, ``origin``, ``target``, ``up``, ``fov``, ``aperture_radius``,
    ``focus_distance``), ``fov_axis`` (``"x"``: ``fov`` is horizontal), ``to_world`` (the 4×4
    camera-to-world matrix of :func:`camera_to_world`, rows), ``near`` and ``far`` (the clip
    planes the sensor got) and, for an AO render, ``ao_radius`` (the ``mcd_ao`` occlusion
    distance, scene units). The image size is the file's own.

    >>> m = camera_metadata(Camera(origin=(0, 0, 5), target=(0, 0, 0)), ao_radius=0.5)
    >>> m["fov_axis"], m["near"], m["to_world"][2], m["ao_radius"]
    ('x', 0.01, [0.0, 0.0, -1.0, 5.0], 0.5)
    """
    d: dict[str, Any] = {
        "type": camera.type,
        "origin": [float(v) for v in camera.origin],
        "target": [float(v) for v in camera.target],
        "up": [float(v) for v in camera.up],
        "fov": float(camera.fov),
        "fov_axis": "x",
        "aperture_radius": camera.aperture_radius,
        "focus_distance": camera.focus_distance,
        "to_world": camera_to_world(camera).tolist(),
        "near": NEAR_CLIP,
        "far": float(far),
    }
    if ao_radius is not None:
        d["ao_radius"] = float(ao_radius)
    return d


def far_clip(spec: SceneSpec, plan: EffectPlan) -> float:
    """The sensor's far clip distance for ``spec`` rendered as ``plan``: :data:`FAR_CLIP`, or
    twice the distance to the far edge of a finite sun's disk when that is farther
    (:func:`sun_geometry`; AO plans have no lights)."""
    lights = () if plan.integrator == "mcd_ao" else spec.lights
    suns = [lt for lt in lights if lt.type == "sun" and lt.params["angular_diameter"] > 0]
    far = FAR_CLIP
    if suns:
        _, radius = scene_bounds(spec)
        dist = SUN_DISTANCE_FACTOR * radius
        for lt in suns:
            alpha = math.radians(lt.params["angular_diameter"]) / 2.0
            far = max(far, 2.0 * (dist + dist * math.tan(alpha)))
    return far


def _sensor(
    camera: Camera, plan: EffectPlan, width: int, height: int, far: float, where: str
) -> dict[str, Any]:
    mi = _mi()
    if plan.thinlens != (camera.type == "thinlens"):
        want = "thin-lens" if plan.thinlens else "pinhole"
        raise SpecError(
            f"{where}: camera: the effect plan needs a {want} camera, got a {camera.type} one"
        )
    try:
        to_world = mi.ScalarTransform4f(camera_to_world(camera).tolist())
    except InputError as err:
        raise SpecError(f"{where}: camera: {err}") from None
    d: dict[str, Any] = {
        "type": "thinlens" if plan.thinlens else "perspective",
        "fov": float(camera.fov),
        "fov_axis": "x",
        "to_world": to_world,
        "near_clip": NEAR_CLIP,
        "far_clip": float(far),
        "film": {
            "type": "hdrfilm",
            "width": int(width),
            "height": int(height),
            "pixel_format": "rgb",
            "component_format": "float32",
            "rfilter": {"type": "box"},
        },
        "sampler": {"type": "independent", "sample_count": 4},
    }
    if plan.thinlens:
        d["aperture_radius"] = float(camera.aperture_radius or 0.0)
        d["focus_distance"] = float(
            camera.focus_distance or math.dist(camera.origin, camera.target)
        )
    return d


# --------------------------------------------------------------------------------------------
# Textures and materials
# --------------------------------------------------------------------------------------------
def _rgb(c: Sequence[float]) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(x) for x in c]}


def _uv_scale(s: float) -> Any:
    return _mi().ScalarTransform4f().scale([float(s), float(s), 1.0])


def texture_dict(t: Texture) -> dict[str, Any]:
    """The Mitsuba texture (or ``rgb`` spectrum) of a spec texture (see the module table)."""
    mi = _mi()
    if t.kind == "constant":
        return _rgb(t.color)
    if t.kind == "checkerboard":
        return {
            "type": "checkerboard",
            "color0": _rgb(t.color0),
            "color1": _rgb(t.color1),
            "to_uv": _uv_scale(t.scale),
        }
    if t.kind == "image":
        return {"type": "bitmap", "filename": str(t.file), "to_uv": _uv_scale(t.scale)}
    if t.kind == "noise":
        return {
            "type": "bitmap",
            "bitmap": mi.Bitmap(noise_image(t.color0, t.color1, t.seed)),
            "to_uv": _uv_scale(t.scale / NOISE_CELLS),
        }
    raise SpecError(f"unknown texture kind {t.kind!r}")


@functools.cache
def conductor_names() -> frozenset[str]:
    """Conductor presets of the installed Mitsuba (``Au``, ``Ag``, ``Cu``, ..., ``none``)."""
    import mitsuba  # lazy: Mitsuba is optional and slow to import

    folder = Path(mitsuba.__file__).parent / "data" / "ior"
    return frozenset({p.name.split(".")[0] for p in folder.glob("*.eta.spd")} | {"none"})


def bsdf_dict(m: Material, where: str = "material") -> dict[str, Any]:
    """The Mitsuba BSDF of a spec material (see the module table); ``where`` names it in
    errors (an unknown conductor preset is a :class:`SpecError`)."""
    typ = m.type
    if typ == "diffuse":
        bsdf: dict[str, Any] = {"type": "diffuse", "reflectance": texture_dict(m.reflectance)}
    elif typ in ("plastic", "roughplastic"):
        bsdf = {
            "type": typ,
            "diffuse_reflectance": texture_dict(m.diffuse),
            "int_ior": float(m.ior),
            "ext_ior": 1.0,
        }
        if typ == "roughplastic":
            bsdf.update(distribution="ggx", alpha=float(m.roughness))
    elif typ in ("conductor", "roughconductor"):
        bsdf = {"type": typ, "specular_reflectance": texture_dict(m.specular)}
        if m.eta is not None and m.k is not None:
            bsdf.update(eta=_rgb(m.eta), k=_rgb(m.k))
        else:
            name = m.conductor or "Al"
            if name not in conductor_names():
                raise SpecError(
                    f"{where}: unknown conductor {name!r} (Mitsuba has e.g. Au, Ag, Al, Cu, Cr, "
                    "W, none)"
                )
            bsdf["material"] = name
        if typ == "roughconductor":
            bsdf.update(distribution="ggx", alpha=float(m.roughness))
    elif typ == "dielectric":
        bsdf = {"type": "dielectric", "int_ior": float(m.ior), "ext_ior": 1.0}
        if m.roughness > 0:
            bsdf.update(type="roughdielectric", distribution="ggx", alpha=float(m.roughness))
        return bsdf
    else:
        raise SpecError(f"{where}: unknown material type {typ!r}")
    return {"type": "twosided", "bsdf": bsdf}


# --------------------------------------------------------------------------------------------
# Shapes
# --------------------------------------------------------------------------------------------
def _matrix(t: Transform) -> np.ndarray:
    return np.asarray(t.matrix(), dtype=np.float64)


def _transform(m: np.ndarray) -> Any:
    return _mi().ScalarTransform4f(np.asarray(m, dtype=np.float64).tolist())


def _sphere_matrix(o: SceneObject) -> np.ndarray:
    """Unit sphere -> world for a sphere (``center``/``radius`` and/or a transform)."""
    m = np.diag([o.radius or 1.0] * 3 + [1.0])
    m[:3, 3] = o.center or (0.0, 0.0, 0.0)
    return _matrix(o.transform) @ m


def _object_shapes(o: SceneObject, where: str, bsdf: dict[str, Any]) -> list[dict[str, Any]]:
    """The Mitsuba shapes of one spec object (a cylinder gives three), with ``bsdf``."""
    if o.shape == "sphere":
        s = np.abs(o.transform.scale)
        if not np.allclose(s, s[0], rtol=1e-6):
            raise SpecError(
                f"{where}.transform: a sphere needs a uniform scale, got {o.transform.scale} "
                "(use a mesh for an ellipsoid)"
            )
        shapes = [{"type": "sphere", "to_world": _transform(_sphere_matrix(o))}]
    elif o.shape in ("cube", "rectangle", "disk"):
        shapes = [{"type": o.shape, "to_world": _transform(_matrix(o.transform))}]
    elif o.shape == "cylinder":
        m = _matrix(o.transform)
        top = np.eye(4)
        top[2, 3] = 1.0
        bottom = np.diag([1.0, -1.0, -1.0, 1.0])  # disk turned to face -z, at z = 0
        shapes = [
            {"type": "cylinder", "to_world": _transform(m)},
            {"type": "disk", "to_world": _transform(m @ top)},
            {"type": "disk", "to_world": _transform(m @ bottom)},
        ]
    elif o.shape == "mesh":
        suffix = Path(str(o.file)).suffix.lower().lstrip(".")
        shapes = [
            {"type": suffix, "filename": str(o.file), "to_world": _transform(_matrix(o.transform))}
        ]
    else:
        raise SpecError(f"{where}.shape: unknown shape {o.shape!r}")
    for s in shapes:
        s["bsdf"] = bsdf
        if o.emission is not None:
            s["emitter"] = {"type": "area", "radiance": _rgb(o.emission)}
    return shapes


_UNIT_CORNERS = np.array([[x, y, z, 1.0] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])


def scene_bounds(spec: SceneSpec) -> tuple[np.ndarray, float]:
    """Centre and radius of a sphere around the spec's objects and camera (scene units).

    Each object counts by the transformed corners of its unit shape's box ([-1, 1]³; a
    mesh by its own bounding box, read from the file). Used to place a finite sun.
    """
    points = [np.asarray(spec.camera.origin), np.asarray(spec.camera.target)]
    for o in spec.objects:
        if o.shape == "sphere":
            m = _sphere_matrix(o)
        elif o.shape == "mesh":
            lo, hi = _mesh_box(str(o.file))
            box = np.diag([*((hi - lo) / 2), 1.0])
            box[:3, 3] = (hi + lo) / 2
            m = _matrix(o.transform) @ box
        else:
            m = _matrix(o.transform)
        points.extend((_UNIT_CORNERS @ m.T)[:, :3])
    pts = np.asarray(points, dtype=np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    center = (lo + hi) / 2
    return center, float(max(np.linalg.norm(pts - center, axis=1).max(), 1e-3))


def _mesh_box(file: str) -> tuple[np.ndarray, np.ndarray]:
    mi = _mi()
    bbox = mi.load_dict({"type": Path(file).suffix.lower().lstrip("."), "filename": file}).bbox()
    return np.array(bbox.min, dtype=np.float64), np.array(bbox.max, dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Lights
# --------------------------------------------------------------------------------------------
def sun_geometry(
    direction: Sequence[float],
    irradiance: Sequence[float],
    angular_diameter: float,
    center: Sequence[float],
    distance: float,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Position, radius and radiance of a disk sun of ``angular_diameter`` degrees, facing
    ``center`` from ``distance`` along ``direction``, that gives ``irradiance`` there.

    ``radius = distance · tan α`` (α the angular radius), so the disk subtends exactly α, and
    ``radiance = E / (π sin² α)``: a uniform disk of angular radius α seen face-on has
    projected solid angle ``π sin² α``.
    """
    alpha = math.radians(angular_diameter) / 2.0
    sin_a = math.sin(alpha)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    position = np.asarray(center, dtype=np.float64) + distance * d
    radiance = np.asarray(irradiance, dtype=np.float64) / (math.pi * sin_a * sin_a)
    return position, distance * math.tan(alpha), radiance


def _light(
    light: Light, where: str, bounds: tuple[np.ndarray, float] | None
) -> tuple[dict[str, Any], float]:
    """The Mitsuba emitter (or emitting shape) of one light, and the camera far-clip distance
    it needs (0: the default suffices). ``bounds``: :func:`scene_bounds`, needed by a sun."""
    mi = _mi()
    p = light.params
    typ = light.type
    if typ == "point":
        return {
            "type": "point",
            "position": list(p["position"]),
            "intensity": _rgb(p["intensity"]),
        }, 0
    if typ == "spot":
        pos, tgt = np.asarray(p["position"]), np.asarray(p["target"])
        if np.allclose(pos, tgt):
            raise SpecError(f"{where}: position and target must differ")
        f = (tgt - pos) / np.linalg.norm(tgt - pos)
        up = (0.0, 1.0, 0.0) if abs(f[1]) < 0.99 else (1.0, 0.0, 0.0)
        return {
            "type": "spot",
            "to_world": _transform(look_at(pos, tgt, up)),
            "intensity": _rgb(p["intensity"]),
            "cutoff_angle": float(p["cutoff"]),
            "beam_width": float(p["beam_width"]),
        }, 0
    if typ == "constant":
        return {"type": "constant", "radiance": _rgb(p["radiance"])}, 0
    if typ == "envmap":
        d: dict[str, Any] = {
            "type": "envmap",
            "scale": float(p["scale"]),
            "to_world": _transform(_matrix(Transform(rotate=tuple(p["rotate"])))),
        }
        if "file" in p:
            d["filename"] = str(p["file"])
        else:
            d["bitmap"] = mi.Bitmap(sky_image())
        return d, 0
    if typ == "sh":
        try:
            from mcdenoise.render.sh import (  # lazy: optional, see except
                sh_envmap_dict,
            )
        except ImportError as err:
            raise SpecError(f"{where}: SH environments need mcdenoise.render.sh ({err})") from None
        return sh_envmap_dict(np.asarray(p["coefficients"], dtype=np.float64), scale=p["scale"]), 0
    if typ == "sun":
        if p["angular_diameter"] == 0:
            return {
                "type": "directional",
                "direction": [-float(c) for c in p["direction"]],
                "irradiance": _rgb(p["irradiance"]),
            }, 0
        assert bounds is not None
        center, radius = bounds
        dist = SUN_DISTANCE_FACTOR * radius
        pos, r, radiance = sun_geometry(
            p["direction"], p["irradiance"], p["angular_diameter"], center, dist
        )
        d = np.asarray(p["direction"], dtype=np.float64)
        up = (0.0, 1.0, 0.0) if abs(d[1]) < 0.99 else (1.0, 0.0, 0.0)
        # The disk's +z (its emitting side) faces the scene's centre.
        to_world = look_at(pos, center, up) @ np.diag([r, r, r, 1.0])
        return {
            "type": "disk",
            "to_world": _transform(to_world),
            "bsdf": {"type": "diffuse", "reflectance": _rgb((0.0, 0.0, 0.0))},
            "emitter": {"type": "area", "radiance": _rgb(radiance)},
        }, dist + r
    raise SpecError(f"{where}.type: unknown light type {typ!r}")


# --------------------------------------------------------------------------------------------
# The scene
# --------------------------------------------------------------------------------------------
def scene_dict(
    spec: SceneSpec,
    plan: EffectPlan,
    *,
    width: int,
    height: int,
    integrator: dict[str, Any] | None = None,
    camera: Camera | None = None,
) -> dict[str, Any]:
    """The full ``mi.load_dict`` dictionary of ``spec`` rendered as ``plan`` says.

    Args:
        spec: a parsed spec; ``plan``: ``plan_effects(spec)``.
        width, height: film size in pixels.
        integrator: the integrator dict (e.g. ``moment`` → ``aov`` → the radiance
            integrator); default ``plan.integrator_dict()``.
        camera: overrides ``spec.camera`` (camera paths of sequences); its type must match
            the plan (thin lens iff ``dof``).

    Keys: ``sensor``, ``integrator``, ``obj_<i>`` (``obj_<i>_side``/``_top``/``_bottom`` for
    a cylinder), ``light_<i>``, and ``mat_<name>`` for each named material in use (defined
    once, referenced by its objects, so a noise texture is baked once). Needs a variant (:func:`ensure_variant`).

    Raises:
        SpecError: what Mitsuba would reject with a traceback (unknown conductor preset,
            non-uniformly scaled sphere, two environment lights, bad camera).
        InputError: bad size, or no variant set.
    """
    _mi()
    if int(width) < 1 or int(height) < 1:
        raise InputError(f"film size must be >= 1x1, got {width}x{height}")
    where = spec.source or spec.name
    envs = [lt.type for lt in spec.lights if lt.type in ENVIRONMENT_LIGHTS]
    lights = () if plan.integrator == "mcd_ao" else spec.lights
    if len(envs) > 1 and lights:
        raise SpecError(
            f"{where}: lights: at most one environment light (constant, envmap, sh), "
            f"got {', '.join(envs)}"
        )
    d: dict[str, Any] = {"type": "scene"}
    for i, o in enumerate(spec.objects):
        if o.material_name is not None:  # a named material: one BSDF (and texture) shared
            key = f"mat_{o.material_name}"
            if key not in d:
                d[key] = bsdf_dict(o.material, f"{where}: materials.{o.material_name}")
            bsdf = {"type": "ref", "id": key}
        else:
            bsdf = bsdf_dict(o.material, f"{where}: objects[{i}].material")
        shapes = _object_shapes(o, f"{where}: objects[{i}]", bsdf)
        if len(shapes) == 1:
            d[f"obj_{i:03d}"] = shapes[0]
        else:
            for part, s in zip(("side", "top", "bottom"), shapes):
                d[f"obj_{i:03d}_{part}"] = s
    bounds = scene_bounds(spec) if any(lt.type == "sun" for lt in lights) else None
    for i, lt in enumerate(lights):
        d[f"light_{i:03d}"], _ = _light(lt, f"{where}: lights[{i}]", bounds)
    far = far_clip(spec, plan)
    d["sensor"] = _sensor(camera or spec.camera, plan, width, height, far, where)
    d["integrator"] = integrator if integrator is not None else plan.integrator_dict()
    return d
