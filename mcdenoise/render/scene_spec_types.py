"""The typed scene spec: the dataclasses :func:`mcdenoise.render.scene_spec.parse_spec` returns.

Plain frozen data, no Mitsuba: :class:`SceneSpec` and its pieces (camera, objects,
materials, textures, lights, animation), the names the schema accepts (:data:`EFFECTS`,
:data:`SHAPES`, ...), and :meth:`SceneSpec.to_dict`, which writes a spec back in the schema
users write (the schema itself: :mod:`mcdenoise.render.scene_spec`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mcdenoise.errors import McdenoiseError

EFFECTS: tuple[str, ...] = ("direct", "indirect", "glossy", "caustics", "dof", "ao")
SHAPES: tuple[str, ...] = ("sphere", "cube", "cylinder", "rectangle", "disk", "mesh")
MATERIALS: tuple[str, ...] = (
    "diffuse",
    "plastic",
    "roughplastic",
    "conductor",
    "roughconductor",
    "dielectric",
)
LIGHTS: tuple[str, ...] = ("point", "spot", "constant", "envmap", "sun", "sh")
TEXTURES: tuple[str, ...] = ("checkerboard", "image", "noise")
#: Number of SH coefficients of order 5 ((5 + 1)²).
SH_COEFFS = 36
MESH_SUFFIXES = (".obj", ".ply")


class SpecError(McdenoiseError, ValueError):
    """A scene spec is malformed; the message names the file and the key."""


Vec3 = tuple[float, float, float]

#: Keys each material type takes (the schema's material table).
MATERIAL_KEYS = {
    "diffuse": ("type", "reflectance"),
    "plastic": ("type", "diffuse", "ior"),
    "roughplastic": ("type", "diffuse", "roughness", "ior"),
    "conductor": ("type", "conductor", "eta", "k", "specular"),
    "roughconductor": ("type", "conductor", "eta", "k", "specular", "roughness"),
    "dielectric": ("type", "ior", "roughness"),
}


# --- small typed pieces -------------------------------------------------------------------


@dataclass(frozen=True)
class Texture:
    """A colour source: ``kind`` is ``constant``, ``checkerboard``, ``image`` or ``noise``.

    ``color`` for constant; ``color0``/``color1``/``scale`` for checkerboard and noise (+``seed``
    for noise); ``file`` (absolute after loading) and ``scale`` for image.
    """

    kind: str = "constant"
    color: Vec3 = (0.5, 0.5, 0.5)
    color0: Vec3 = (0.2, 0.2, 0.2)
    color1: Vec3 = (0.8, 0.8, 0.8)
    scale: float = 1.0
    file: str | None = None
    seed: int = 0


@dataclass(frozen=True)
class Transform:
    """Scale, then rotate (degrees about X, then Y, then Z), then translate."""

    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate: Vec3 = (0.0, 0.0, 0.0)
    scale: Vec3 = (1.0, 1.0, 1.0)

    def matrix(self) -> list[list[float]]:
        """The 4×4 row-major matrix ``T · Rz · Ry · Rx · S``."""
        rx, ry, rz = (math.radians(a) for a in self.rotate)
        cx, sx, cy, sy, cz, sz = (
            math.cos(rx),
            math.sin(rx),
            math.cos(ry),
            math.sin(ry),
            math.cos(rz),
            math.sin(rz),
        )
        r = [
            [cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx],
            [sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx],
            [-sy, cy * sx, cy * cx],
        ]
        m = [[r[i][j] * self.scale[j] for j in range(3)] + [self.translate[i]] for i in range(3)]
        return [*m, [0.0, 0.0, 0.0, 1.0]]


@dataclass(frozen=True)
class Camera:
    type: str = "pinhole"
    origin: Vec3 = (0.0, 1.0, 4.0)
    target: Vec3 = (0.0, 1.0, 0.0)
    up: Vec3 = (0.0, 1.0, 0.0)
    fov: float = 40.0
    aperture_radius: float | None = None
    focus_distance: float | None = None


@dataclass(frozen=True)
class Material:
    """A material; unused parameters keep their defaults (see the module table)."""

    type: str = "diffuse"
    reflectance: Texture = field(default_factory=Texture)  # diffuse
    diffuse: Texture = field(default_factory=Texture)  # (rough)plastic
    specular: Texture = field(default_factory=lambda: Texture(color=(1.0, 1.0, 1.0)))
    roughness: float = 0.0
    ior: float = 1.5
    conductor: str | None = None
    eta: Vec3 | None = None
    k: Vec3 | None = None

    @property
    def glossy(self) -> bool:
        """Has a glossy (rough, non-diffuse) lobe."""
        return self.type in ("roughplastic", "roughconductor") or (
            self.type == "dielectric" and self.roughness > 0
        )

    @property
    def specular_lobe(self) -> bool:
        """Has a delta (perfectly specular) lobe: the start of a caustic chain."""
        return self.type in ("plastic", "conductor") or (
            self.type == "dielectric" and self.roughness == 0
        )


@dataclass(frozen=True)
class SceneObject:
    shape: str
    material: Material
    material_name: str | None = None
    transform: Transform = field(default_factory=Transform)
    center: Vec3 | None = None  # sphere
    radius: float | None = None  # sphere
    file: str | None = None  # mesh, absolute after loading
    emission: Vec3 | None = None
    motion: Vec3 | None = None  # world-space translation over a sequence (first -> last frame)


#: Camera paths of ``[animation]``.
CAMERA_PATHS: tuple[str, ...] = ("orbit", "dolly", "keyframes", "static")


@dataclass(frozen=True)
class Keyframe:
    """One camera key of a ``keyframes`` path (origin and target, world space)."""

    origin: Vec3
    target: Vec3


@dataclass(frozen=True)
class Animation:
    """How the camera moves over a sequence (``s`` in [0, 1], first to last frame).

    ``orbit``: the origin turns by ``angle`` degrees about the camera's ``up`` axis through the
    target. ``dolly``: the origin moves ``fraction`` of the way to the target. ``keyframes``:
    origin and target interpolated linearly between evenly spaced keys. ``static``: the camera
    stays (only objects move).
    """

    camera_path: str = "orbit"
    angle: float = 10.0
    fraction: float = 0.1
    keyframes: tuple[Keyframe, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"camera_path": self.camera_path}
        if self.camera_path == "orbit":
            d["angle"] = self.angle
        elif self.camera_path == "dolly":
            d["fraction"] = self.fraction
        elif self.camera_path == "keyframes":
            d["keyframes"] = [
                {"origin": list(k.origin), "target": list(k.target)} for k in self.keyframes
            ]
        return d


@dataclass(frozen=True)
class Light:
    """A light; ``params`` holds the type's parameters, already validated."""

    type: str
    params: Mapping[str, Any]


@dataclass(frozen=True)
class RenderSettings:
    max_depth: int = 8
    rr_depth: int = 5
    ao_radius: float | None = None


@dataclass(frozen=True)
class SceneSpec:
    """A parsed, structurally valid scene spec (effects vs content: see ``effects.py``)."""

    name: str
    effects: tuple[str, ...]
    camera: Camera
    objects: tuple[SceneObject, ...]
    lights: tuple[Light, ...] = ()
    materials: Mapping[str, Material] = field(default_factory=dict)
    render: RenderSettings = field(default_factory=RenderSettings)
    description: str = ""
    source: str | None = None  # the spec file, when loaded from one
    animation: Animation | None = None  # camera path of sequences (``[animation]``)

    def to_dict(self) -> dict[str, Any]:
        """The spec in the schema users write (JSON-serialisable): ``parse_spec`` reads it back
        to an equal spec, so a manifest that records it can be rendered again."""
        d: dict[str, Any] = {"name": self.name, "effects": list(self.effects)}
        if self.description:
            d["description"] = self.description
        r = self.render
        d["render"] = {"max_depth": r.max_depth, "rr_depth": r.rr_depth}
        if r.ao_radius is not None:
            d["render"]["ao_radius"] = r.ao_radius
        d["camera"] = _camera_dict(self.camera)
        if self.materials:
            d["materials"] = {n: _material_dict(m) for n, m in self.materials.items()}
        d["objects"] = [_object_dict(o) for o in self.objects]
        if self.lights:
            d["lights"] = [{"type": lt.type, **_jsonable(dict(lt.params))} for lt in self.lights]
        if self.animation is not None:
            d["animation"] = self.animation.to_dict()
        if self.source:
            d["source"] = self.source
        return d

    @property
    def emissive_objects(self) -> tuple[SceneObject, ...]:
        return tuple(o for o in self.objects if o.emission is not None)

    @property
    def has_lights(self) -> bool:
        return bool(self.lights or self.emissive_objects)


def _texture_value(t: Texture) -> Any:
    if t.kind == "constant":
        return list(t.color)
    if t.kind == "image":
        return {"image": {"file": t.file, "scale": t.scale}}
    return {
        t.kind: {
            "color0": list(t.color0),
            "color1": list(t.color1),
            "scale": t.scale,
            "seed": t.seed,
        }
    }


def _material_dict(m: Material) -> dict[str, Any]:
    keys = MATERIAL_KEYS[m.type]
    d: dict[str, Any] = {"type": m.type}
    for k in ("reflectance", "diffuse", "specular"):
        if k in keys:
            d[k] = _texture_value(getattr(m, k))
    if "roughness" in keys and (m.type != "dielectric" or m.roughness > 0):
        d["roughness"] = m.roughness
    if "ior" in keys:
        d["ior"] = m.ior
    if m.type in ("conductor", "roughconductor"):
        if m.eta is not None and m.k is not None:
            d["eta"], d["k"] = list(m.eta), list(m.k)
        else:
            d["conductor"] = m.conductor
    return d


def _object_dict(o: SceneObject) -> dict[str, Any]:
    d: dict[str, Any] = {"shape": o.shape}
    d["material"] = o.material_name if o.material_name else _material_dict(o.material)
    if o.shape == "sphere" and o.transform == Transform():
        d["center"], d["radius"] = list(o.center or (0.0, 0.0, 0.0)), o.radius
    elif o.transform != Transform():  # (a sphere placed by a transform has center 0, radius 1)
        t = o.transform
        d["transform"] = {
            "translate": list(t.translate),
            "rotate": list(t.rotate),
            "scale": list(t.scale),
        }
    if o.file:
        d["file"] = o.file
    if o.emission is not None:
        d["emission"] = list(o.emission)
    if o.motion is not None:
        d["motion"] = {"translate": list(o.motion)}
    return d


def _camera_dict(c: Camera) -> dict[str, Any]:
    d: dict[str, Any] = {
        "type": c.type,
        "origin": list(c.origin),
        "target": list(c.target),
        "up": list(c.up),
        "fov": c.fov,
    }
    if c.type == "thinlens":
        d["aperture_radius"], d["focus_distance"] = c.aperture_radius, c.focus_distance
    return d


def _jsonable(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, tuple | list):
        return [_jsonable(v) for v in x]
    return x
