"""Scene specs: a small TOML schema for the scenes ``mcdenoise render`` renders.

A spec describes geometry, materials, lights and a camera, and **declares its light-transport
effects**; the renderer simulates (and pays for) only those (see :mod:`mcdenoise.render.effects`).
Specs are plain data: this module parses and validates them (:func:`parse_spec`,
:func:`load_spec`), finds the spec files of folders (:func:`collect_specs`) and knows nothing
of Mitsuba; the typed result (:class:`SceneSpec` and its pieces) is defined in
:mod:`mcdenoise.render.scene_spec_types` and re-exported here.

Schema (every length in scene units, every angle in degrees, colours linear RGB)::

    name = "cornell"                      # default: the file's stem
    description = "..."                   # optional
    effects = ["direct", "indirect"]      # required: subset of EFFECTS

    [render]                              # optional
    max_depth = 8                         # longest path with "indirect" (Mitsuba convention:
                                          # 2 = direct light only); ignored without it
    rr_depth = 5                          # Russian roulette from this depth
    ao_radius = 1.0                       # with "ao": occlusion distance (required then)

    [camera]
    type = "pinhole"                      # or "thinlens" (needs aperture_radius, focus_distance)
    origin = [0, 1, 4]
    target = [0, 1, 0]
    up = [0, 1, 0]                        # default [0, 1, 0]
    fov = 40                              # horizontal field of view
    aperture_radius = 0.05                # thinlens
    focus_distance = 4.0                  # thinlens; default: |target - origin|

    [materials.floor]                     # a named material; types and parameters below
    type = "roughplastic"
    diffuse = { checkerboard = { color0 = [0.2, 0.2, 0.2], color1 = [0.8, 0.8, 0.8], scale = 8 } }
    roughness = 0.2

    [[objects]]
    shape = "sphere"                      # sphere, cube, cylinder, rectangle, disk, mesh
    center = [0, 1, 0]                    # sphere: center + radius (or a transform)
    radius = 0.5
    material = "floor"                    # a name from [materials] or an inline table
    emission = [10, 10, 10]               # optional: makes the object an area light

    [[objects]]
    shape = "cube"                        # unit shapes: cube [-1,1]³, rectangle/disk in the
    transform = { translate = [0, 0.5, 0], rotate = [0, 30, 0], scale = [0.5, 0.5, 0.5] }
                                          # z = 0 plane facing +z, cylinder radius 1 z in [0,1]
    [[objects]]
    shape = "mesh"
    file = "meshes/bunny.obj"             # .obj or .ply, relative to the spec file
    material = { type = "diffuse", reflectance = [0.7, 0.7, 0.7] }

    [[lights]]
    type = "point"                        # point, spot, constant, envmap, sun, sh
    position = [0, 3, 0]
    intensity = [10, 10, 10]

    [animation]                           # optional: used by sequences (--frames N)
    camera_path = "orbit"                 # orbit, dolly, keyframes or static
    angle = 20                            # orbit: degrees about the camera's up axis through
                                          # the target over the whole sequence (default 10;
                                          # positive: counter-clockwise seen from above)
    # fraction = 0.2                      # dolly: the origin moves this fraction of the way to
                                          # the target (< 1; negative: away; default 0.1)
    # keyframes = [{ origin = [0, 1, 4], target = [0, 1, 0] }, { origin = [1, 1, 4] }]
                                          # keyframes: >= 2, evenly spaced over the sequence,
                                          # linearly interpolated; a key without target (or
                                          # origin) keeps the previous key's

    [[objects]]                           # any object may move (linearly over the sequence):
    shape = "sphere"
    motion = { translate = [0.5, 0, 0] }  # world-space displacement from first to last frame

Materials (``type`` and its parameters; ``<texture>`` is a colour ``[r, g, b]``, a scalar, or
``{ checkerboard = {color0, color1, scale} }``, ``{ image = "file.png", scale = 1 }`` or
``{ noise = {color0, color1, scale, seed} }`` — procedural value noise):

=================  =========================================================================
diffuse            reflectance = <texture>
plastic            diffuse = <texture>, ior = 1.5 (smooth coating)
roughplastic       diffuse = <texture>, roughness (GGX alpha, > 0), ior = 1.5
conductor          conductor = "Au" (Mitsuba's names: Au, Ag, Cu, Al, ...) or eta/k = [r,g,b],
                   specular = <texture> (tint, default 1)
roughconductor     as conductor, plus roughness (> 0)
dielectric         ior = 1.5 (smooth glass); roughness > 0 makes it rough glass
=================  =========================================================================

Glossy = roughplastic, roughconductor, rough dielectric; specular (delta) = plastic's coating,
conductor, smooth dielectric.

Lights (besides emissive objects):

=========  ========================================================================
point      position, intensity = [r, g, b]
spot       position, target, intensity, cutoff = 20 (degrees), beam_width = cutoff * 0.75
constant   radiance = [r, g, b] (uniform environment)
envmap     file = "sky.exr" (lat-long, relative to the spec), scale = 1, or
           procedural = "sky" (a built-in gradient sky), rotate = [0, y, 0]
sun        direction = [x, y, z] (towards the sun), irradiance = [r, g, b] (on a surface
           facing the sun), angular_diameter = 0.53 (degrees; small and bright: fireflies)
sh         coefficients = 36 rows of [r, g, b] (real SH up to order 5, see
           :mod:`mcdenoise.render.sh`), scale = 1
=========  ========================================================================

Effects (:data:`EFFECTS`): ``direct`` (light reaching a visible surface straight from a light),
``indirect`` (light after more bounces), ``glossy`` (glossy materials are present and
simulated), ``caustics`` (light through specular chains onto diffuse/glossy surfaces), ``dof``
(thin-lens depth of field), ``ao`` (ambient occlusion instead of lighting). Whether a spec's
effects and its content agree is checked by :func:`mcdenoise.render.effects.plan_effects`.

Animation (``[animation]`` and ``objects[i].motion``) describes a sequence as a function of
the sequence time ``s`` in [0, 1] (first to last frame); the frame count comes from the
renderer (``mcdenoise render --frames N``), and :mod:`mcdenoise.render.animation` samples the
path at ``s = f / (N - 1)``. A still image (no ``--frames``) ignores it. A thin-lens camera's
focus keeps its offset from the target (``focus_distance - |target - origin|``) along the path.

Errors are :class:`SpecError` with the file and the key path, e.g.
``cornell.toml: objects[2].material: unknown material 'gld' (known: floor, red, white)``.
"""

from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.render.scene_spec_fields import (
    _animation,
    _camera,
    _check_keys,
    _Ctx,
    _int,
    _light,
    _material,
    _num,
    _object,
    _table,
)
from mcdenoise.render.scene_spec_types import (
    CAMERA_PATHS,
    EFFECTS,
    LIGHTS,
    MATERIALS,
    MESH_SUFFIXES,
    SH_COEFFS,
    SHAPES,
    TEXTURES,
    Animation,
    Camera,
    Keyframe,
    Light,
    Material,
    RenderSettings,
    SceneObject,
    SceneSpec,
    SpecError,
    Texture,
    Transform,
)

__all__ = [
    "CAMERA_PATHS",
    "EFFECTS",
    "LIGHTS",
    "MATERIALS",
    "MESH_SUFFIXES",
    "SHAPES",
    "SH_COEFFS",
    "TEXTURES",
    "Animation",
    "Camera",
    "Keyframe",
    "Light",
    "Material",
    "RenderSettings",
    "SceneObject",
    "SceneSpec",
    "SpecError",
    "Texture",
    "Transform",
    "collect_specs",
    "load_spec",
    "parse_spec",
]


# --- parsing ------------------------------------------------------------------------------


_TOP_KEYS = (
    "name",
    "description",
    "effects",
    "render",
    "camera",
    "materials",
    "objects",
    "lights",
    "animation",
)


def parse_spec(
    data: Mapping[str, Any], *, source: str = "<spec>", base: str | os.PathLike[str] | None = None
) -> SceneSpec:
    """Validate a spec given as a mapping (a parsed TOML file, or :meth:`SceneSpec.to_dict`).

    ``base`` is the folder relative file names (meshes, images) are resolved against.
    """
    ctx = _Ctx(source, Path(base) if base is not None else None)
    top = _table(ctx, "", data)
    _check_keys(ctx, "", top, (*_TOP_KEYS, "source"))
    name = top.get("name") or (Path(source).stem if source != "<spec>" else None)
    if not isinstance(name, str) or not name:
        raise ctx.error("name", f"must be a non-empty string, got {name!r}")
    effects = top.get("effects")
    if not isinstance(effects, Sequence) or isinstance(effects, str) or not effects:
        raise ctx.error("effects", f"must be a non-empty list from {', '.join(EFFECTS)}")
    bad = [e for e in effects if e not in EFFECTS]
    if bad:
        raise ctx.error(
            "effects",
            f"unknown effect(s) {', '.join(map(repr, bad))} (known: {', '.join(EFFECTS)})",
        )
    if len(set(effects)) != len(effects):
        raise ctx.error("effects", "lists an effect twice")
    r = _table(ctx, "render", top.get("render", {}))
    _check_keys(ctx, "render", r, ("max_depth", "rr_depth", "ao_radius"))
    render = RenderSettings(
        max_depth=_int(ctx, "render.max_depth", r.get("max_depth", 8), lo=2),
        rr_depth=_int(ctx, "render.rr_depth", r.get("rr_depth", 5), lo=1),
        ao_radius=(
            _num(ctx, "render.ao_radius", r["ao_radius"], lo=0, lo_open=True)
            if "ao_radius" in r
            else None
        ),
    )
    mats_t = _table(ctx, "materials", top.get("materials", {}))
    materials = {str(n): _material(ctx, f"materials.{n}", m) for n, m in mats_t.items()}
    objs = top.get("objects", [])
    if not isinstance(objs, Sequence) or isinstance(objs, str) or not objs:
        raise ctx.error("objects", "must be a non-empty list of [[objects]] tables")
    objects = tuple(_object(ctx, f"objects[{i}]", o, materials) for i, o in enumerate(objs))
    lts = top.get("lights", [])
    if not isinstance(lts, Sequence) or isinstance(lts, str):
        raise ctx.error("lights", "must be a list of [[lights]] tables")
    lights = tuple(_light(ctx, f"lights[{i}]", lt) for i, lt in enumerate(lts))
    desc = top.get("description", "")
    if not isinstance(desc, str):
        raise ctx.error("description", "must be a string")
    return SceneSpec(
        name=name,
        effects=tuple(effects),
        camera=_camera(ctx, top.get("camera", {})),
        objects=objects,
        lights=lights,
        materials=materials,
        render=render,
        description=desc,
        source=top.get("source") if source == "<spec>" else source,
        animation=_animation(ctx, top["animation"]) if "animation" in top else None,
    )


def load_spec(path: str | os.PathLike[str]) -> SceneSpec:
    """Read and validate a scene spec (``.toml``, or ``.json`` as written by
    :meth:`SceneSpec.to_dict`); file names in it are relative to its folder."""
    p = Path(path)
    if not p.is_file():
        raise SpecError(f"{p}: scene spec not found" if not p.exists() else f"{p}: not a file")
    try:
        text = p.read_text(encoding="utf-8")
        data = json.loads(text) if p.suffix.lower() == ".json" else tomllib.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as err:
        kind = "JSON" if p.suffix.lower() == ".json" else "TOML"
        raise SpecError(f"{p}: not valid {kind}: {' '.join(str(err).split())}") from None
    return parse_spec(data, source=str(p), base=p.parent)


def collect_specs(
    paths: Sequence[str | os.PathLike[str]], *, base: str | os.PathLike[str] | None = None
) -> list[Path]:
    """The scene spec files named by ``paths``, in order: a folder stands for its ``*.toml``
    files (sorted by name), a file for itself. Relative paths are taken from ``base`` (default:
    the working directory). A file named twice is listed twice (it renders as two images).

    Raises:
        SpecError: a folder holds no ``*.toml`` (``<path>: folder holds no *.toml scene
            spec``) or a path does not exist (``<path>: scene spec not found``).
    """
    files: list[Path] = []
    for item in paths:
        p = Path(item).expanduser()
        if base is not None and not p.is_absolute():
            p = Path(base) / p
        if p.is_dir():
            found = sorted(p.glob("*.toml"))
            if not found:
                raise SpecError(f"{p}: folder holds no *.toml scene spec")
            files.extend(found)
        elif p.exists():
            files.append(p)
        else:
            raise SpecError(f"{p}: scene spec not found")
    return files
