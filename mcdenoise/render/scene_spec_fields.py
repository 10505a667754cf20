"""The checked readers of a scene spec's tables: each reads one table (material, texture, object,
light, camera, animation), checks every key and value and names the key in its
``SpecError``. :func:`mcdenoise.render.scene_spec.parse_spec` puts them together.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mcdenoise.render.scene_spec_types import (
    CAMERA_PATHS,
    LIGHTS,
    MATERIAL_KEYS,
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
    SceneObject,
    SpecError,
    Texture,
    Transform,
    Vec3,
)


class _Ctx:
    """Where we are in the spec, for error messages."""

    def __init__(self, source: str, base: Path | None) -> None:
        self.source = source
        self.base = base

    def error(self, key: str, msg: str) -> SpecError:
        where = f"{key}: " if key else ""
        return SpecError(f"{self.source}: {where}{msg}")

    def path(self, key: str, value: Any, suffixes: Sequence[str] | None = None) -> str:
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a file name, got {value!r}")
        p = Path(value)
        if not p.is_absolute() and self.base is not None:
            p = self.base / p
        if not p.is_file():
            raise self.error(key, f"file {value!r} not found (looked at {p})")
        if suffixes and p.suffix.lower() not in suffixes:
            raise self.error(key, f"{value!r} must be one of {', '.join(suffixes)}")
        return str(p.resolve())


def _table(ctx: _Ctx, key: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ctx.error(key, f"must be a table, got {type(value).__name__}")
    return value


def _check_keys(ctx: _Ctx, key: str, table: Mapping[str, Any], allowed: Sequence[str]) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise ctx.error(key, f"unknown key(s) {', '.join(unknown)} (allowed: {', '.join(allowed)})")


def _num(
    ctx: _Ctx,
    key: str,
    value: Any,
    *,
    lo: float | None = None,
    lo_open: bool = False,
    hi: float | None = None,
) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ctx.error(key, f"must be a finite number, got {value!r}")
    v = float(value)
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise ctx.error(key, f"must be {'>' if lo_open else '>='} {lo:g}, got {v:g}")
    if hi is not None and v > hi:
        raise ctx.error(key, f"must be <= {hi:g}, got {v:g}")
    return v


def _int(ctx: _Ctx, key: str, value: Any, *, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ctx.error(key, f"must be an integer >= {lo}, got {value!r}")
    return int(value)


def _vec3(ctx: _Ctx, key: str, value: Any, *, nonneg: bool = False) -> Vec3:
    if isinstance(value, int | float) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != 3:
        raise ctx.error(key, f"must be [x, y, z] (3 numbers), got {value!r}")
    out = tuple(
        _num(ctx, f"{key}[{i}]", v, lo=0.0 if nonneg else None) for i, v in enumerate(value)
    )
    return out  # type: ignore[return-value]


def _texture(ctx: _Ctx, key: str, value: Any) -> Texture:
    if isinstance(value, int | float | Sequence) and not isinstance(value, str | Mapping):
        return Texture(kind="constant", color=_vec3(ctx, key, value, nonneg=True))
    t = _table(ctx, key, value)
    if len(t) != 1 or next(iter(t)) not in TEXTURES:
        raise ctx.error(
            key,
            f"a texture is [r, g, b] or one of {{{', '.join(TEXTURES)} = {{...}}}}, got {dict(t)!r}",
        )
    kind, params = next(iter(t.items()))
    k = f"{key}.{kind}"
    p = _table(ctx, k, params)
    if kind == "image":
        _check_keys(ctx, k, p, ("file", "scale"))
        return Texture(
            kind="image",
            file=ctx.path(f"{k}.file", p.get("file"), (".png", ".jpg", ".jpeg", ".exr")),
            scale=_num(ctx, f"{k}.scale", p.get("scale", 1.0), lo=0, lo_open=True),
        )
    _check_keys(ctx, k, p, ("color0", "color1", "scale", "seed"))
    return Texture(
        kind=kind,
        color0=_vec3(ctx, f"{k}.color0", p.get("color0", (0.2, 0.2, 0.2)), nonneg=True),
        color1=_vec3(ctx, f"{k}.color1", p.get("color1", (0.8, 0.8, 0.8)), nonneg=True),
        scale=_num(ctx, f"{k}.scale", p.get("scale", 8.0), lo=0, lo_open=True),
        seed=_int(ctx, f"{k}.seed", p.get("seed", 0), lo=0),
    )


def _material(ctx: _Ctx, key: str, value: Any) -> Material:
    m = _table(ctx, key, value)
    typ = m.get("type")
    if typ not in MATERIALS:
        raise ctx.error(f"{key}.type", f"must be one of {', '.join(MATERIALS)}, got {typ!r}")
    _check_keys(ctx, key, m, MATERIAL_KEYS[typ])
    kw: dict[str, Any] = {"type": typ}
    if "reflectance" in m:
        kw["reflectance"] = _texture(ctx, f"{key}.reflectance", m["reflectance"])
    if "diffuse" in m:
        kw["diffuse"] = _texture(ctx, f"{key}.diffuse", m["diffuse"])
    if "specular" in m:
        kw["specular"] = _texture(ctx, f"{key}.specular", m["specular"])
    if typ in ("roughplastic", "roughconductor"):
        kw["roughness"] = _num(
            ctx, f"{key}.roughness", m.get("roughness", 0.1), lo=0, lo_open=True, hi=1.0
        )
    if typ == "dielectric" and "roughness" in m:
        kw["roughness"] = _num(ctx, f"{key}.roughness", m["roughness"], lo=0.0, hi=1.0)
    if "ior" in m:
        kw["ior"] = _num(ctx, f"{key}.ior", m["ior"], lo=1.0, lo_open=True, hi=4.0)
    if typ in ("conductor", "roughconductor"):
        if "conductor" in m and ("eta" in m or "k" in m):
            raise ctx.error(key, 'give either conductor = "Au" or eta and k, not both')
        if ("eta" in m) != ("k" in m):
            raise ctx.error(key, "eta and k go together")
        if "eta" in m:
            kw["eta"] = _vec3(ctx, f"{key}.eta", m["eta"], nonneg=True)
            kw["k"] = _vec3(ctx, f"{key}.k", m["k"], nonneg=True)
        else:
            name = m.get("conductor", "Al")
            if not isinstance(name, str) or not name:
                raise ctx.error(
                    f"{key}.conductor", f"must be a material name like 'Au', got {name!r}"
                )
            kw["conductor"] = name
    return Material(**kw)


_SHAPE_KEYS = (
    "shape",
    "material",
    "transform",
    "center",
    "radius",
    "file",
    "emission",
    "motion",
)


def _transform(ctx: _Ctx, key: str, value: Any) -> Transform:
    t = _table(ctx, key, value)
    _check_keys(ctx, key, t, ("translate", "rotate", "scale"))
    scale = _vec3(ctx, f"{key}.scale", t.get("scale", 1.0))
    if any(s == 0 for s in scale):
        raise ctx.error(f"{key}.scale", "must not be 0 on any axis")
    return Transform(
        translate=_vec3(ctx, f"{key}.translate", t.get("translate", 0.0)),
        rotate=_vec3(ctx, f"{key}.rotate", t.get("rotate", 0.0)),
        scale=scale,
    )


def _object(ctx: _Ctx, key: str, value: Any, materials: Mapping[str, Material]) -> SceneObject:
    o = _table(ctx, key, value)
    _check_keys(ctx, key, o, _SHAPE_KEYS)
    shape = o.get("shape")
    if shape not in SHAPES:
        raise ctx.error(f"{key}.shape", f"must be one of {', '.join(SHAPES)}, got {shape!r}")
    mat_value = o.get("material", {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]})
    mat_name = None
    if isinstance(mat_value, str):
        if mat_value not in materials:
            known = ", ".join(sorted(materials)) or "none defined"
            raise ctx.error(f"{key}.material", f"unknown material {mat_value!r} (known: {known})")
        mat, mat_name = materials[mat_value], mat_value
    else:
        mat = _material(ctx, f"{key}.material", mat_value)
    kw: dict[str, Any] = {"shape": shape, "material": mat, "material_name": mat_name}
    if "transform" in o:
        kw["transform"] = _transform(ctx, f"{key}.transform", o["transform"])
    if shape == "sphere":
        if ("center" in o or "radius" in o) and "transform" in o:
            raise ctx.error(key, "a sphere takes center/radius or a transform, not both")
        kw["center"] = _vec3(ctx, f"{key}.center", o.get("center", 0.0))
        kw["radius"] = _num(ctx, f"{key}.radius", o.get("radius", 1.0), lo=0, lo_open=True)
    elif "center" in o or "radius" in o:
        raise ctx.error(key, f"center/radius are for spheres; place a {shape} with a transform")
    if shape == "mesh":
        kw["file"] = ctx.path(f"{key}.file", o.get("file"), MESH_SUFFIXES)
    elif "file" in o:
        raise ctx.error(f"{key}.file", "only meshes take a file")
    if "emission" in o:
        em = _vec3(ctx, f"{key}.emission", o["emission"], nonneg=True)
        if max(em) <= 0:
            raise ctx.error(f"{key}.emission", "must be positive (omit it for a non-emitter)")
        kw["emission"] = em
    if "motion" in o:
        m = _table(ctx, f"{key}.motion", o["motion"])
        _check_keys(ctx, f"{key}.motion", m, ("translate",))
        if "translate" not in m:
            raise ctx.error(f"{key}.motion", "needs translate = [dx, dy, dz]")
        kw["motion"] = _vec3(ctx, f"{key}.motion.translate", m["translate"])
    return SceneObject(**kw)


_LIGHT_KEYS = {
    "point": ("type", "position", "intensity"),
    "spot": ("type", "position", "target", "intensity", "cutoff", "beam_width"),
    "constant": ("type", "radiance"),
    "envmap": ("type", "file", "procedural", "scale", "rotate"),
    "sun": ("type", "direction", "irradiance", "angular_diameter"),
    "sh": ("type", "coefficients", "scale"),
}


def _light(ctx: _Ctx, key: str, value: Any) -> Light:
    lt = _table(ctx, key, value)
    typ = lt.get("type")
    if typ not in LIGHTS:
        raise ctx.error(f"{key}.type", f"must be one of {', '.join(LIGHTS)}, got {typ!r}")
    _check_keys(ctx, key, lt, _LIGHT_KEYS[typ])
    p: dict[str, Any] = {}
    if typ in ("point", "spot"):
        p["position"] = _vec3(ctx, f"{key}.position", lt.get("position"))
        p["intensity"] = _vec3(ctx, f"{key}.intensity", lt.get("intensity"), nonneg=True)
    if typ == "spot":
        p["target"] = _vec3(ctx, f"{key}.target", lt.get("target"))
        p["cutoff"] = _num(ctx, f"{key}.cutoff", lt.get("cutoff", 20.0), lo=0, lo_open=True, hi=90)
        p["beam_width"] = _num(
            ctx,
            f"{key}.beam_width",
            lt.get("beam_width", 0.75 * p["cutoff"]),
            lo=0,
            lo_open=True,
            hi=p["cutoff"],
        )
    if typ == "constant":
        p["radiance"] = _vec3(ctx, f"{key}.radiance", lt.get("radiance"), nonneg=True)
    if typ == "envmap":
        if ("file" in lt) == ("procedural" in lt):
            raise ctx.error(key, "an envmap takes exactly one of file or procedural")
        if "file" in lt:
            p["file"] = ctx.path(f"{key}.file", lt["file"], (".exr", ".hdr", ".png", ".jpg"))
        elif lt["procedural"] != "sky":
            raise ctx.error(f"{key}.procedural", f"must be 'sky', got {lt['procedural']!r}")
        else:
            p["procedural"] = "sky"
        p["scale"] = _num(ctx, f"{key}.scale", lt.get("scale", 1.0), lo=0, lo_open=True)
        p["rotate"] = _vec3(ctx, f"{key}.rotate", lt.get("rotate", 0.0))
    if typ == "sun":
        d = _vec3(ctx, f"{key}.direction", lt.get("direction"))
        n = math.sqrt(sum(c * c for c in d))
        if n == 0:
            raise ctx.error(f"{key}.direction", "must not be zero")
        # Normalise once: a direction that is already unit length is kept bit for bit, so
        # parse -> to_dict -> parse round trips exactly.
        p["direction"] = d if abs(n - 1.0) <= 1e-12 else tuple(c / n for c in d)
        p["irradiance"] = _vec3(ctx, f"{key}.irradiance", lt.get("irradiance"), nonneg=True)
        p["angular_diameter"] = _num(
            ctx, f"{key}.angular_diameter", lt.get("angular_diameter", 0.53), lo=0.0, hi=30.0
        )
    if typ == "sh":
        co = lt.get("coefficients")
        if not isinstance(co, Sequence) or len(co) != SH_COEFFS:
            got = len(co) if isinstance(co, Sequence) else co
            raise ctx.error(
                f"{key}.coefficients",
                f"must be {SH_COEFFS} rows of [r, g, b] (order 5), got {got!r}",
            )
        p["coefficients"] = tuple(
            _vec3(ctx, f"{key}.coefficients[{i}]", c) for i, c in enumerate(co)
        )
        p["scale"] = _num(ctx, f"{key}.scale", lt.get("scale", 1.0), lo=0, lo_open=True)
    return Light(type=typ, params=p)


def _camera(ctx: _Ctx, value: Any) -> Camera:
    c = _table(ctx, "camera", value)
    _check_keys(
        ctx,
        "camera",
        c,
        ("type", "origin", "target", "up", "fov", "aperture_radius", "focus_distance"),
    )
    typ = c.get("type", "pinhole")
    if typ not in ("pinhole", "thinlens"):
        raise ctx.error("camera.type", f"must be pinhole or thinlens, got {typ!r}")
    origin = _vec3(ctx, "camera.origin", c.get("origin", (0.0, 1.0, 4.0)))
    target = _vec3(ctx, "camera.target", c.get("target", (0.0, 1.0, 0.0)))
    if origin == target:
        raise ctx.error("camera", "origin and target must differ")
    kw: dict[str, Any] = {
        "type": typ,
        "origin": origin,
        "target": target,
        "up": _vec3(ctx, "camera.up", c.get("up", (0.0, 1.0, 0.0))),
        "fov": _num(ctx, "camera.fov", c.get("fov", 40.0), lo=0, lo_open=True, hi=179),
    }
    if typ == "pinhole" and ("aperture_radius" in c or "focus_distance" in c):
        raise ctx.error("camera", 'aperture_radius/focus_distance need type = "thinlens"')
    if typ == "thinlens":
        if "aperture_radius" not in c:
            raise ctx.error("camera.aperture_radius", "a thinlens camera needs an aperture radius")
        kw["aperture_radius"] = _num(
            ctx, "camera.aperture_radius", c["aperture_radius"], lo=0, lo_open=True
        )
        dist = math.dist(origin, target)
        kw["focus_distance"] = _num(
            ctx, "camera.focus_distance", c.get("focus_distance", dist), lo=0, lo_open=True
        )
    return Camera(**kw)


_ANIMATION_KEYS = {
    "orbit": ("camera_path", "angle"),
    "dolly": ("camera_path", "fraction"),
    "keyframes": ("camera_path", "keyframes"),
    "static": ("camera_path",),
}


def _animation(ctx: _Ctx, value: Any) -> Animation:
    a = _table(ctx, "animation", value)
    path = a.get("camera_path", "orbit")
    if path not in CAMERA_PATHS:
        raise ctx.error(
            "animation.camera_path", f"must be one of {', '.join(CAMERA_PATHS)}, got {path!r}"
        )
    _check_keys(ctx, "animation", a, _ANIMATION_KEYS[path])
    if path == "orbit":
        return Animation("orbit", angle=_num(ctx, "animation.angle", a.get("angle", 10.0)))
    if path == "dolly":
        frac = _num(ctx, "animation.fraction", a.get("fraction", 0.1))
        if frac >= 1.0:
            raise ctx.error(
                "animation.fraction", f"must be < 1 (1 reaches the target), got {frac:g}"
            )
        return Animation("dolly", fraction=frac)
    if path == "static":
        return Animation("static")
    keys = a.get("keyframes")
    if not isinstance(keys, Sequence) or isinstance(keys, str) or len(keys) < 2:
        raise ctx.error("animation.keyframes", "must be a list of at least 2 {origin, target}")
    frames: list[Keyframe] = []
    for i, k in enumerate(keys):
        where = f"animation.keyframes[{i}]"
        kt = _table(ctx, where, k)
        _check_keys(ctx, where, kt, ("origin", "target"))
        if i == 0 and not ("origin" in kt and "target" in kt):
            raise ctx.error(where, "the first keyframe needs both origin and target")
        origin = (
            _vec3(ctx, f"{where}.origin", kt["origin"]) if "origin" in kt else frames[-1].origin
        )
        target = (
            _vec3(ctx, f"{where}.target", kt["target"]) if "target" in kt else frames[-1].target
        )
        if origin == target:
            raise ctx.error(where, "origin and target must differ")
        frames.append(Keyframe(origin, target))
    return Animation("keyframes", keyframes=tuple(frames))
