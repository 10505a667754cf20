"""Seeded procedural scene specs for training data (``mcdenoise render --random N --seed S``).

:func:`random_spec` ``(seed, index)`` builds one :class:`~mcdenoise.render.spec.SceneSpec`
from ``numpy.random.default_rng([seed, index])`` alone (no global state): the same pair gives
the same spec in every process, and scene ``index`` of a data set does not depend on how many
scenes were generated before it (shards are independent). Every spec survives
``parse_spec(spec.to_dict())`` unchanged and declares exactly the effects its content calls
for (:func:`~mcdenoise.render.effects.plan_effects` accepts it). Meshes, image textures and
the studio envmap are package assets (``mcdenoise/render/assets/``, made by
``assets/make_assets.py``), referred to by absolute path. :func:`random_scene` also returns
the archetype, its variant and which objects are the placed "subjects".

Distribution
============
Scene units ≈ metres, angles in degrees, colours linear RGB; ``U(a, b)`` uniform,
``logU`` log-uniform. Light powers are derived from a target irradiance ``E`` at the
subjects (point/spot intensity ``E·d²``, emitter radiance ``E·d²/A``), so exposure does not
depend on a light's distance or size; in rooms, ``E`` is multiplied by ``1 − ρ`` (``ρ`` the
area-weighted reflectance of floor, walls and ceiling) because interreflection adds about
``1 / (1 − ρ)``.

**Archetypes** (probability):

=========  =====  =========================================================================
interior   0.30   closed room: W, D ``U(4, 7)``, H ``U(2.6, 3.4)``; camera inside (below).
                  Floor: see "floors"; walls: constant ``value U(0.4, 0.85)`` (15 %: brick or
                  wood image); ceiling: grey ``U(0.6, 0.85)``. Light (variant):
                  ``ceiling`` 65 %: emissive panel under the ceiling, half sizes
                  ``U(0.2, 0.6)``, ``E U(3, 6)`` at the floor. ``window``/``door`` 35 %:
                  an opening in the back or a side wall (door 30 %, half width
                  ``U(0.4, 0.6)``, height ``U(1.9, 2.2)``; window half width ``U(0.4, 0.9)``,
                  sill ``U(0.6, 1)``, top ``U(1.6, 2.3)``) with outside either ``+panel``
                  (60 %: emissive panel ``U(1.3, 2.5)``× the opening, ``U(0.2, 1)`` behind
                  it, ``E U(6, 14)`` at the room's centre) or ``+sun`` (40 %: a sun at
                  elevation ``U(15, 45)`` within ±35° of the wall's normal, bright enough
                  that the light entering gives an average ``E U(1, 3)`` inside, plus a sky
                  or constant environment of radiance ≈ 0.1× the sun's irradiance):
                  nearly all light indirect. Extras: point light (20 %,
                  ``E U(1, 3)``), spot (15 %, ``E U(1, 4)``), 1–3 bulbs (25 %). Always
                  ``indirect``.
outdoor    0.25   ground: rectangle (60 %) or disk of half size ``U(15, 40)``; one
                  environment: procedural sky envmap 45 % (scale ``U(0.5, 1.3)``), studio
                  envmap file 25 % (scale ``U(0.2, 0.6)``), constant 30 % (``U(0.2, 0.7)``),
                  × 1.6 when there is no sun; sun 70 % (elevation ``U(15, 70)``, azimuth
                  uniform, irradiance ``U(1.5, 4)``); 1–2 bulbs (15 %).
tabletop   0.20   subjects of size ``U(0.15, 0.42)`` on a table slab (half ``U(1.4, 2.4)``
                  × ``U(1, 1.8)``, floor-like material), a floor 0.75 below (75 %), a
                  backdrop facing the camera (50 %). Key light at elevation ``U(35, 75)``,
                  azimuth within ±120° of the camera's, ``U(1.8, 3.5)`` away, ``E U(2, 6)``:
                  spot 55 % (cutoff = the subjects' angular radius + ``U(5, 15)``, in
                  [12, 60]; beam width ``U(0.5, 0.9)``× cutoff) or point 45 %. Fill:
                  constant ``U(0.05, 0.3)`` (75 %) and/or a second point light opposite
                  the key (``E U(0.3, 1)``, 25 %); 1–2 bulbs (20 %).
sh         0.15   subjects on a support plane (rectangle or disk, half ``U(3, 8)``) lit by an
                  order-5 SH environment as in the AR-lighting paper
                  (:func:`random_sh_coefficients`, mean radiance ``U(0.3, 0.9)``), plus, in
                  50 %, a main directional light (a sun along the SH sky's brightest
                  direction above 8.6° elevation, irradiance ``U(0.5, 2)``).
ao         0.10   effects ``["ao"]``, ``ao_radius U(0.3, 2)``, white diffuse geometry
                  (reflectance 0.8): 60 % subjects on an open ground, 40 % in a closed room
                  (as interiors); no lights; always a pinhole.
=========  =====  =========================================================================

**Bulbs** (fireflies): emissive spheres of radius ``U(0.02, 0.06)`` and radiance giving
``E U(0.3, 1.5)`` at 1.5 units, away from subjects and camera. Suns have angular diameter
``U(0.5, 3)`` (85 %) or 0 (a delta ``directional`` light, 15 %); every sun and light colour
is a white between warm ``(1, 0.78, 0.55)`` and cool ``(0.8, 0.9, 1)``, luminance 1.

**Subjects**: count 1–8 with weights 8, 14, 17, 17, 15, 12, 9, 8 %, placed on the floor,
ground or table with non-overlapping footprints (a subject that does not fit in 40 tries is
left out); size ``s U(0.25, 0.7)``. Shapes: sphere 20 % (radius ``s``; 15 % float
``U(0.1, 0.8)`` above the ground), cube 17 % (half extents ``U(0.5, 1)·s``, yaw
``U(0, 90)``), cylinder 15 % (upright, radius ``U(0.4, 0.9)·s``, height ``U(0.8, 2.5)·s``),
rectangle 9 % (standing panel, half sizes ``U(0.6, 1.2)·s`` × ``U(0.6, 1.4)·s``), disk 9 %
(radius ``U(0.6, 1.2)·s``, lying on the ground 50 %, else standing), mesh 30 % (one of the
seven assets, uniform scale ``U(0.8, 1.3)·s``, yaw uniform). Standing panels, disks and the
star mesh face the camera ±40°. A scene whose subjects all lie flat is redrawn, and a
subject standing in front of another one's centre (closer than 0.7 of its bounding radius
to the line of sight) is removed, so no standing subject is hidden.

**Materials** of the subjects: diffuse 25 %, plastic 12 %, roughplastic 18 %, conductor
12 %, roughconductor 18 %, dielectric 15 %. GGX roughness ``logU(0.03, 0.5)`` (plastic,
conductor); 30 % of dielectrics are rough, ``logU(0.02, 0.3)``; IOR ``U(1.3, 1.8)``
(plastic, dielectric). Conductors: 80 % a Mitsuba preset from :data:`CONDUCTORS`, else RGB
``eta U(0.05, 1.5)``, ``k U(1.5, 5)``; specular tint 1 (75 %) or ``U(0.6, 1)`` per channel.
Colours: uniform hue, saturation ``U(0.2, 0.9)`` (25 %: grey, ``U(0, 0.1)``), value
``U(0.05, 0.85)``; two-colour textures use values ``U(0.05, 0.5)`` and ``U(0.3, 0.85)``.
Base-colour texture of diffuse and plastic non-mesh subjects: constant 50 %, checkerboard
20 % (``U(1, 6)`` periods per uv unit), noise 20 % (``U(4, 16)`` cells per uv unit), image
10 % (bricks or wood, ``U(1, 3)`` repeats); meshes carry no UVs and get constant colours.
**Floors**, grounds, tables: diffuse 60 % / roughplastic 40 %, texture constant 25 %,
checkerboard 35 %, noise 25 %, image 15 %, with world-size periods ``U(0.6, 2.5)`` (checks),
``U(0.3, 1.2)`` (noise cells), ``U(1, 3)`` (image tiles).

**Camera** (square images; ``fov`` horizontal = vertical): open scenes orbit the subjects'
bounding sphere at azimuth ``U(0, 360)``, elevation ``U(5, 45)`` (tabletop ``U(15, 55)``,
sh ``U(10, 40)``), fov ``U(30, 60)``, at ``U(1, 1.3)``× the distance at which the sphere
just fits, aimed at its centre ± 0.1 of its radius. Interiors: at ``U(0.3, 0.7)`` from the
front wall, ``x U(−W/4, W/4)``, height ``U(0.9, 1.9)``, aimed at the subjects' centroid,
fov the larger of ``U(40, 65)`` and what frames every subject (≤ 85). Every subject's centre
is in frame and the camera is outside every object. Thin lens (``dof``) in 20 % of lit
scenes: focused on a random subject (``focus_distance`` = its depth along the view axis),
``aperture_radius U(0.01, 0.04)``× the focus distance.

**Effects**: lit scenes declare ``direct``; ``indirect`` in every interior, 80 % of
outdoor and tabletop, 70 % of sh scenes; ``glossy`` iff a glossy material is present;
``caustics`` in 60 % of the scenes with ``indirect`` and a smooth specular material
(plastic, conductor, smooth dielectric), so 40 % exercise the integrator that cuts those
paths; ``dof`` iff thin lens. ``render.max_depth`` (with ``indirect``): 6, 8, 10, 12 with
probabilities 15, 50, 20, 15 % (at least 8 with a dielectric); ``rr_depth`` 5.
"""

from __future__ import annotations

import colorsys
import functools
import itertools
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.render.effects import plan_effects
from mcdenoise.render.sh import (
    PAPER_ORDER,
    latlong_directions,
    latlong_solid_angles,
    sh_basis,
    world_to_sh_frame,
)
from mcdenoise.render.spec import EFFECTS, SceneSpec, parse_spec

#: Scene archetypes and their probabilities.
ARCHETYPES: Mapping[str, float] = {
    "interior": 0.30,
    "outdoor": 0.25,
    "tabletop": 0.20,
    "sh": 0.15,
    "ao": 0.10,
}
#: Shapes of the subjects and their probabilities.
SHAPE_WEIGHTS: Mapping[str, float] = {
    "sphere": 0.20,
    "cube": 0.17,
    "cylinder": 0.15,
    "rectangle": 0.09,
    "disk": 0.09,
    "mesh": 0.30,
}
#: Material types of the subjects and their probabilities.
MATERIAL_WEIGHTS: Mapping[str, float] = {
    "diffuse": 0.25,
    "plastic": 0.12,
    "roughplastic": 0.18,
    "conductor": 0.12,
    "roughconductor": 0.18,
    "dielectric": 0.15,
}
#: Texture kinds of the diffuse/plastic base colour of non-mesh subjects.
TEXTURE_WEIGHTS: Mapping[str, float] = {
    "constant": 0.50,
    "checkerboard": 0.20,
    "noise": 0.20,
    "image": 0.10,
}
#: Texture kinds of floors and ground planes.
FLOOR_TEXTURE_WEIGHTS: Mapping[str, float] = {
    "constant": 0.25,
    "checkerboard": 0.35,
    "noise": 0.25,
    "image": 0.15,
}
#: Weights of the number of subjects 1..8.
COUNT_WEIGHTS: tuple[float, ...] = (0.08, 0.14, 0.17, 0.17, 0.15, 0.12, 0.09, 0.08)
#: Mitsuba conductor presets drawn from (all metallic; Mitsuba ships more).
CONDUCTORS: tuple[str, ...] = (
    "Ag", "Al", "Au", "Be", "Cr", "Cu", "Hg", "Ir", "Li", "Mo", "Nb", "Rh", "Ta", "TiN", "VN", "W",
)  # fmt: skip
#: Share of lit scenes with a thin-lens camera (effect ``dof``).
THINLENS_PROB = 0.2
#: Share of scenes with ``indirect`` and a smooth specular object that declare ``caustics``.
CAUSTICS_PROB = 0.6
#: Share of scenes of each lit archetype that declare ``indirect``.
INDIRECT_PROB: Mapping[str, float] = {"interior": 1.0, "outdoor": 0.8, "tabletop": 0.8, "sh": 0.7}
#: ``render.max_depth`` choices (with ``indirect``) and their probabilities.
MAX_DEPTHS: tuple[tuple[int, float], ...] = ((6, 0.15), (8, 0.50), (10, 0.20), (12, 0.15))

_ASSETS = "assets"
_UP = np.array([0.0, 1.0, 0.0])
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class MeshAsset:
    """A packaged mesh: absolute ``file``, bounding-box ``half_extents`` (centred at the
    origin) and ``radius`` (largest vertex distance from the origin), in mesh units."""

    name: str
    file: str
    half_extents: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class RandomScene:
    """A generated spec plus how it was made.

    ``archetype``: a key of :data:`ARCHETYPES`; ``variant``: the archetype's sub-kind (e.g.
    ``"window"``); ``subjects``: indices into ``spec.objects`` of the placed objects (not the
    room, ground, table or emitters), all of which are in the camera's view.
    """

    spec: SceneSpec
    archetype: str
    variant: str
    subjects: tuple[int, ...]


def asset_dir() -> Path:
    """Folder of the packaged assets (``meshes/``, ``textures/``, ``envmaps/``)."""
    return Path(str(resources.files("mcdenoise.render").joinpath(_ASSETS)))


@functools.cache
def mesh_assets() -> tuple[MeshAsset, ...]:
    """The packaged meshes, from ``assets/meshes/index.json`` (sorted by name)."""
    folder = asset_dir() / "meshes"
    index = json.loads((folder / "index.json").read_text(encoding="utf-8"))
    return tuple(
        MeshAsset(
            name=name,
            file=str((folder / name).resolve()),
            half_extents=tuple(float(x) for x in entry["half_extents"]),  # type: ignore[arg-type]
            radius=float(entry["radius"]),
        )
        for name, entry in sorted(index.items())
    )


def texture_files() -> tuple[str, ...]:
    """Absolute paths of the packaged image textures (sorted)."""
    return tuple(str(p.resolve()) for p in sorted((asset_dir() / "textures").glob("*.png")))


def envmap_file() -> str:
    """Absolute path of the packaged studio environment map."""
    return str((asset_dir() / "envmaps" / "studio.exr").resolve())


# --------------------------------------------------------------------------------- sampling


def _choice(rng: np.random.Generator, weights: Mapping[str, float]) -> str:
    keys = list(weights)
    p = np.asarray([weights[k] for k in keys], dtype=np.float64)
    return keys[int(rng.choice(len(keys), p=p / p.sum()))]


def _r(x: float, nd: int = 4) -> float:
    """Round for a compact, readable spec (and manifest)."""
    return float(round(float(x), nd))


def _v(x: Sequence[float] | np.ndarray, nd: int = 4) -> list[float]:
    return [_r(c, nd) for c in x]


def _logu(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _color(rng: np.random.Generator, lo: float = 0.05, hi: float = 0.85) -> list[float]:
    """A reflectance: uniform hue, mostly saturated (25 % grey), value in [lo, hi]."""
    h = rng.uniform()
    s = rng.uniform(0.0, 0.1) if rng.random() < 0.25 else rng.uniform(0.2, 0.9)
    v = rng.uniform(lo, hi)
    return _v(colorsys.hsv_to_rgb(h, s, v))


def _tint(rng: np.random.Generator) -> np.ndarray:
    """A light colour between warm and cool white, luminance 1."""
    t = rng.uniform()
    c = (1 - t) * np.array([1.0, 0.78, 0.55]) + t * np.array([0.8, 0.9, 1.0])
    return c / float(c @ _LUMINANCE)


def _texture(rng: np.random.Generator, kind: str, *, extent: float | None = None) -> Any:
    """A texture value of the spec schema. ``extent``: the uv range's world size (a large
    surface, where periods are chosen in world units), else per-uv periods for objects."""
    if kind == "constant":
        return _color(rng)
    c0, c1 = _color(rng, 0.05, 0.5), _color(rng, 0.3, 0.85)
    if kind == "checkerboard":
        scale = extent / rng.uniform(0.6, 2.5) if extent else rng.uniform(1, 6)
        return {"checkerboard": {"color0": c0, "color1": c1, "scale": _r(scale, 3)}}
    if kind == "noise":
        scale = extent / rng.uniform(0.3, 1.2) if extent else rng.uniform(4, 16)
        seed = int(rng.integers(0, 2**31 - 1))
        return {"noise": {"color0": c0, "color1": c1, "scale": _r(scale, 3), "seed": seed}}
    if kind == "image":
        files = texture_files()
        scale = extent / rng.uniform(1.0, 3.0) if extent else rng.uniform(1, 3)
        return {"image": {"file": files[int(rng.integers(len(files)))], "scale": _r(scale, 3)}}
    raise ValueError(f"unknown texture kind {kind!r}")


def _material(rng: np.random.Generator, typ: str, texture: Any) -> dict[str, Any]:
    """A material of type ``typ``; ``texture`` is the base colour of diffuse/plastics."""
    if typ == "diffuse":
        return {"type": "diffuse", "reflectance": texture}
    if typ in ("plastic", "roughplastic"):
        m: dict[str, Any] = {"type": typ, "diffuse": texture, "ior": _r(rng.uniform(1.3, 1.8))}
        if typ == "roughplastic":
            m["roughness"] = _r(_logu(rng, 0.03, 0.5))
        return m
    if typ in ("conductor", "roughconductor"):
        m = {"type": typ}
        if rng.random() < 0.8:
            m["conductor"] = CONDUCTORS[int(rng.integers(len(CONDUCTORS)))]
        else:
            m["eta"] = _v(rng.uniform(0.05, 1.5, 3))
            m["k"] = _v(rng.uniform(1.5, 5.0, 3))
        if rng.random() >= 0.75:
            m["specular"] = _v(rng.uniform(0.6, 1.0, 3))
        if typ == "roughconductor":
            m["roughness"] = _r(_logu(rng, 0.03, 0.5))
        return m
    if typ == "dielectric":
        m = {"type": "dielectric", "ior": _r(rng.uniform(1.3, 1.8))}
        if rng.random() < 0.3:
            m["roughness"] = _r(_logu(rng, 0.02, 0.3))
        return m
    raise ValueError(f"unknown material type {typ!r}")


def _subject_material(rng: np.random.Generator, *, textured: bool) -> dict[str, Any]:
    typ = _choice(rng, MATERIAL_WEIGHTS)
    kind = _choice(rng, TEXTURE_WEIGHTS) if textured else "constant"
    return _material(rng, typ, _texture(rng, kind))


def _floor_material(rng: np.random.Generator, extent: float) -> dict[str, Any]:
    typ = "diffuse" if rng.random() < 0.6 else "roughplastic"
    return _material(rng, typ, _texture(rng, _choice(rng, FLOOR_TEXTURE_WEIGHTS), extent=extent))


def _albedo(texture: Any) -> float:
    """Mean luminance of a texture value (images: their approximate mean, 0.2)."""
    if isinstance(texture, Mapping):
        kind, p = next(iter(texture.items()))
        if kind == "image":
            return 0.2
        return float((np.asarray(p["color0"]) + np.asarray(p["color1"])) / 2 @ _LUMINANCE)
    return float(np.asarray(texture) @ _LUMINANCE)


def _glossy(m: Mapping[str, Any]) -> bool:
    return m["type"] in ("roughplastic", "roughconductor") or (
        m["type"] == "dielectric" and m.get("roughness", 0) > 0
    )


def _specular(m: Mapping[str, Any]) -> bool:
    return m["type"] in ("plastic", "conductor") or (
        m["type"] == "dielectric" and m.get("roughness", 0) == 0
    )


# --------------------------------------------------------------------------------- objects


@dataclass
class _Solid:
    """A subject built at the origin (x = z = 0, resting on y = 0), then moved."""

    obj: dict[str, Any]
    centre: np.ndarray  # of the bounding sphere
    radius: float  # of the bounding sphere
    foot: float  # footprint radius in the xz plane
    can_hide: bool = True  # False: lies flat on the ground, hides nothing

    def moved(self, x: float, y: float, z: float) -> _Solid:
        obj = json.loads(json.dumps(self.obj))  # a deep copy
        shift = np.array([x, y, z])
        if obj["shape"] == "sphere":
            obj["center"] = _v(np.asarray(obj["center"]) + shift)
        else:
            obj["transform"]["translate"] = _v(np.asarray(obj["transform"]["translate"]) + shift)
        return _Solid(obj, self.centre + shift, self.radius, self.foot, self.can_hide)


def _xform(translate: Sequence[float], rotate: Sequence[float], scale: Sequence[float]) -> dict:
    return {"translate": _v(translate), "rotate": _v(rotate, 3), "scale": _v(scale)}


def _solid(
    rng: np.random.Generator, shape: str, s: float, face_yaw: float, material: dict[str, Any]
) -> _Solid:
    """One subject of ``shape`` and size ``s`` at the origin; flat ones face ``face_yaw``."""
    o: dict[str, Any] = {"shape": shape, "material": material}
    facing = face_yaw + rng.uniform(-40, 40)
    if shape == "sphere":
        lift = rng.uniform(0.1, 0.8) if rng.random() < 0.15 else 0.0
        o["center"], o["radius"] = [0.0, _r(s + lift), 0.0], _r(s)
        return _Solid(o, np.array([0.0, s + lift, 0.0]), s, s)
    if shape == "cube":
        h = s * rng.uniform(0.5, 1.0, 3)
        o["transform"] = _xform([0, h[1], 0], [0, rng.uniform(0, 90), 0], h)
        return _Solid(
            o, np.array([0.0, h[1], 0.0]), float(np.linalg.norm(h)), math.hypot(h[0], h[2])
        )
    if shape == "cylinder":
        rad, height = s * rng.uniform(0.4, 0.9), s * rng.uniform(0.8, 2.5)
        o["transform"] = _xform([0, 0, 0], [-90, rng.uniform(0, 360), 0], [rad, rad, height])
        return _Solid(o, np.array([0.0, height / 2, 0.0]), math.hypot(rad, height / 2), rad)
    if shape == "rectangle":
        w, h = s * rng.uniform(0.6, 1.2), s * rng.uniform(0.6, 1.4)
        o["transform"] = _xform([0, h, 0], [0, facing, 0], [w, h, 1])
        return _Solid(o, np.array([0.0, h, 0.0]), math.hypot(w, h), w)
    if shape == "disk":
        rad = s * rng.uniform(0.6, 1.2)
        if rng.random() < 0.5:  # lying on the ground, facing up
            o["transform"] = _xform([0, 0.003, 0], [-90, 0, 0], [rad, rad, 1])
            return _Solid(o, np.array([0.0, 0.003, 0.0]), rad, rad, can_hide=False)
        o["transform"] = _xform([0, rad, 0], [0, facing, 0], [rad, rad, 1])
        return _Solid(o, np.array([0.0, rad, 0.0]), rad, rad)
    if shape == "mesh":
        meshes = mesh_assets()
        mesh = meshes[int(rng.integers(len(meshes)))]
        k = s * rng.uniform(0.8, 1.3)
        yaw = facing if mesh.name.startswith("star") else rng.uniform(0, 360)
        hx, hy, hz = mesh.half_extents
        o["file"] = mesh.file
        o["transform"] = _xform([0, k * hy, 0], [0, yaw, 0], [k, k, k])
        return _Solid(o, np.array([0.0, k * hy, 0.0]), k * mesh.radius, k * math.hypot(hx, hz))
    raise ValueError(f"unknown shape {shape!r}")


def _place_subjects(
    rng: np.random.Generator,
    count: int,
    sample_xz: Callable[[float], tuple[float, float] | None],
    size: tuple[float, float],
    face_yaw: float,
    *,
    textured: bool = True,
    material: Callable[[], dict[str, Any]] | None = None,
) -> list[_Solid]:
    """``count`` subjects with non-overlapping footprints; ``sample_xz(foot)`` draws a
    position whose footprint of radius ``foot`` fits the region (``None``: cannot fit)."""
    placed: list[_Solid] = []
    for _ in range(count):
        shape = _choice(rng, SHAPE_WEIGHTS)
        mat = material() if material else _subject_material(rng, textured=shape != "mesh")
        s = rng.uniform(*size)
        for _attempt in range(40):
            solid = _solid(rng, shape, s, face_yaw, mat)
            xz = sample_xz(solid.foot)
            if xz is not None and all(
                math.dist(xz, (p.centre[0], p.centre[2])) > solid.foot + p.foot + 0.05
                for p in placed
            ):
                placed.append(solid.moved(xz[0], 0.0, xz[1]))
                break
            s *= 0.95
    # a scene whose only subjects lie flat on the ground shows nothing: the caller retries
    return placed if any(p.can_hide for p in placed) else []


def _count(rng: np.random.Generator) -> int:
    return 1 + int(rng.choice(len(COUNT_WEIGHTS), p=np.asarray(COUNT_WEIGHTS) / sum(COUNT_WEIGHTS)))


def _in_box(
    rng: np.random.Generator, x: tuple[float, float], z: tuple[float, float]
) -> Callable[[float], tuple[float, float] | None]:
    def sample(foot: float) -> tuple[float, float] | None:
        lo_x, hi_x, lo_z, hi_z = x[0] + foot, x[1] - foot, z[0] + foot, z[1] - foot
        if lo_x > hi_x or lo_z > hi_z:
            return None
        return float(rng.uniform(lo_x, hi_x)), float(rng.uniform(lo_z, hi_z))

    return sample


def _in_disk(
    rng: np.random.Generator, radius: float
) -> Callable[[float], tuple[float, float] | None]:
    def sample(foot: float) -> tuple[float, float] | None:
        r = radius - foot
        if r <= 0:
            return None
        rr, a = r * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        return rr * math.cos(a), rr * math.sin(a)

    return sample


# --------------------------------------------------------------------------------- camera


def _basis(origin: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f = target - origin
    f = f / np.linalg.norm(f)
    right = np.cross(f, _UP)
    right /= np.linalg.norm(right)
    return f, right, np.cross(right, f)


def _needed_tan(origin: np.ndarray, target: np.ndarray, solids: Sequence[_Solid]) -> float:
    """tan of the half field of view that holds every subject's centre (plus half its
    bounding radius) in a square image; inf when a subject is behind or around the camera."""
    f, right, up = _basis(origin, target)
    worst = 0.0
    for sld in solids:
        d = sld.centre - origin
        depth = float(d @ f)
        if depth <= sld.radius:
            return math.inf
        pad = 0.5 * sld.radius / depth
        worst = max(worst, abs(float(d @ right)) / depth + pad, abs(float(d @ up)) / depth + pad)
    return worst


def _outside(point: np.ndarray, solids: Sequence[_Solid], margin: float) -> bool:
    return all(np.linalg.norm(point - s.centre) > s.radius + margin for s in solids)


def _bounding(solids: Sequence[_Solid]) -> tuple[np.ndarray, float]:
    lo = np.min([s.centre - s.radius for s in solids], axis=0)
    hi = np.max([s.centre + s.radius for s in solids], axis=0)
    c = (lo + hi) / 2
    return c, max(float(np.linalg.norm(s.centre - c)) + s.radius for s in solids)


def _orbit_camera(
    rng: np.random.Generator, solids: Sequence[_Solid], azimuth: float, elevation: tuple
) -> dict[str, Any]:
    """A camera on a sphere around the subjects that frames all of them."""
    c, radius = _bounding(solids)
    fov = rng.uniform(30, 60)
    e, a = math.radians(rng.uniform(*elevation)), math.radians(azimuth)
    direction = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    target = c + rng.uniform(-0.1, 0.1, 3) * radius
    dist = radius / math.sin(math.radians(fov) / 2) * rng.uniform(1.0, 1.3)
    half_tan = math.tan(math.radians(fov) / 2)
    for _ in range(50):
        origin = target + dist * direction
        origin[1] = max(origin[1], 0.2)
        if _needed_tan(origin, target, solids) < 0.95 * half_tan and _outside(origin, solids, 0.1):
            break
        dist *= 1.1
    return {"origin": _v(origin), "target": _v(target), "fov": _r(fov, 2)}


def _room_camera(
    rng: np.random.Generator, solids: list[_Solid], w: float, d: float, h: float
) -> dict[str, Any] | None:
    """A camera inside a room (x in ±w/2, z up to d/2, y below h) that frames ``solids``."""
    for _ in range(60):
        origin = np.array(
            [
                rng.uniform(-w / 4, w / 4),
                rng.uniform(0.9, min(1.9, h - 0.5)),
                d / 2 - rng.uniform(0.3, 0.7),
            ]
        )
        target = np.mean([s.centre for s in solids], axis=0) + rng.uniform(-0.2, 0.2, 3)
        target[1] = max(target[1], 0.3)
        if not _outside(origin, solids, 0.1):
            continue
        need = math.degrees(2 * math.atan(1.08 * _needed_tan(origin, target, solids)))
        fov = max(need, rng.uniform(40, 65))
        if fov <= 85:
            return {"origin": _v(origin), "target": _v(target), "fov": _r(fov, 2)}
    return None


def _seg_dist(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> float:
    """Distance from ``p`` to the segment ``a``–``b``."""
    ab = b - a
    t = float(np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0))
    return float(np.linalg.norm(a + t * ab - p))


def _unhidden(origin: Sequence[float], solids: Sequence[_Solid]) -> list[_Solid]:
    """Drop subjects that stand in front of another standing subject's centre (within 0.7 of
    their bounding radius of the line of sight), nearest first, so no kept standing subject
    is hidden behind another (objects lying flat on the ground hide nothing)."""
    o = np.asarray(origin, dtype=np.float64)
    keep = sorted(solids, key=lambda s: float(np.linalg.norm(s.centre - o)))
    i = 0
    while i < len(keep):
        a = keep[i]
        da = float(np.linalg.norm(a.centre - o))
        hides = a.can_hide and any(
            c.can_hide
            and float(np.linalg.norm(c.centre - o)) > da
            and _seg_dist(o, c.centre, a.centre) < 0.7 * a.radius
            for c in keep[i + 1 :]
        )
        if hides:
            del keep[i]
        else:
            i += 1
    return keep


def _thinlens(rng: np.random.Generator, cam: dict[str, Any], solids: Sequence[_Solid]) -> None:
    """Make ``cam`` a thin lens focused on a random subject."""
    origin, target = np.asarray(cam["origin"]), np.asarray(cam["target"])
    f = (target - origin) / np.linalg.norm(target - origin)
    focus = float((solids[int(rng.integers(len(solids)))].centre - origin) @ f)
    cam.update(
        type="thinlens",
        focus_distance=_r(focus),
        aperture_radius=_r(focus * rng.uniform(0.01, 0.04), 5),
    )


# --------------------------------------------------------------------------------- lights


def _bulbs(
    rng: np.random.Generator,
    count: int,
    region: Callable[[], np.ndarray],
    avoid: Sequence[_Solid],
    camera_origin: np.ndarray,
) -> list[dict[str, Any]]:
    """Small very bright emissive spheres (fireflies) at ``region()`` positions."""
    out = []
    for _ in range(count):
        r = rng.uniform(0.02, 0.06)
        for _attempt in range(20):
            p = region()
            if (
                p[1] > r + 0.1  # above the ground or table
                and _outside(p, avoid, r + 0.1)
                and np.linalg.norm(p - camera_origin) > r + 0.5
            ):
                radiance = rng.uniform(0.3, 1.5) * 1.5**2 / (math.pi * r * r) * _tint(rng)
                out.append(
                    {
                        "shape": "sphere",
                        "center": _v(p),
                        "radius": _r(r, 5),
                        "material": {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]},
                        "emission": _v(radiance, 2),
                    }
                )
                break
    return out


def _point(position: np.ndarray, target: np.ndarray, irradiance: float, tint: np.ndarray) -> dict:
    d2 = float(np.sum((position - target) ** 2))
    return {"type": "point", "position": _v(position), "intensity": _v(irradiance * d2 * tint, 3)}


def _spot(
    rng: np.random.Generator,
    position: np.ndarray,
    target: np.ndarray,
    radius: float,
    irradiance: float,
    tint: np.ndarray,
) -> dict:
    dist = float(np.linalg.norm(position - target))
    cutoff = min(max(math.degrees(math.atan(1.3 * radius / dist)) + rng.uniform(5, 15), 12), 60)
    return {
        "type": "spot",
        "position": _v(position),
        "target": _v(target),
        "intensity": _v(irradiance * dist * dist * tint, 3),
        "cutoff": _r(cutoff, 2),
        "beam_width": _r(cutoff * rng.uniform(0.5, 0.9), 2),
    }


#: Offsets in units in the last place tried by :func:`_unit`, smallest first.
_ULP_STEPS = sorted(itertools.product(range(-4, 5), repeat=3), key=lambda t: (sum(map(abs, t)), t))


def _unit(direction: Sequence[float]) -> list[float]:
    """A unit vector whose float norm is exactly 1.0, so :func:`~mcdenoise.render.spec.parse_spec`
    (which divides by the norm again) keeps it bit for bit and specs round-trip exactly: the
    normalised ``direction`` moved by at most a few ulps per component."""
    norm = math.sqrt(sum(float(c) ** 2 for c in direction))
    d = [float(c) / norm for c in direction]
    for steps in _ULP_STEPS:
        e = list(d)
        for i, n in enumerate(steps):
            for _ in range(abs(n)):
                e[i] = float(np.nextafter(e[i], math.copysign(math.inf, n)))
        if math.sqrt(sum(c * c for c in e)) == 1.0:
            return e
    raise AssertionError(f"no unit vector of norm exactly 1.0 near {direction}")


def _sun(rng: np.random.Generator, direction: np.ndarray, irradiance: float) -> dict[str, Any]:
    return {
        "type": "sun",
        "direction": _unit(_v(direction / np.linalg.norm(direction))),
        "irradiance": _v(irradiance * _tint(rng), 3),
        "angular_diameter": _r(rng.uniform(0.5, 3.0) if rng.random() < 0.85 else 0.0, 3),
    }


def _sky(rng: np.random.Generator, *, studio: float = 0.25, gain: float = 1.0) -> dict[str, Any]:
    """One environment light: procedural sky (45 %), the studio envmap (``studio``) or a
    constant, its brightness times ``gain``."""
    u = rng.random()
    if u < 0.45:
        return {
            "type": "envmap",
            "procedural": "sky",
            "scale": _r(gain * rng.uniform(0.5, 1.3)),
            "rotate": [0.0, _r(rng.uniform(0, 360), 2), 0.0],
        }
    if u < 0.45 + studio:
        return {
            "type": "envmap",
            "file": envmap_file(),
            "scale": _r(gain * rng.uniform(0.2, 0.6)),
            "rotate": [0.0, _r(rng.uniform(0, 360), 2), 0.0],
        }
    return {"type": "constant", "radiance": _v(gain * rng.uniform(0.2, 0.7) * _tint(rng))}


@functools.cache
def _sh_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World directions ``(N, 3)``, solid angles ``(N,)`` and order-5 SH basis ``(N, 36)``
    of Mitsuba's lat-long texel samples (read-only arrays)."""
    dirs = latlong_directions(width, height).reshape(-1, 3)
    weights = latlong_solid_angles(width, height).reshape(-1)
    basis = sh_basis(PAPER_ORDER, world_to_sh_frame(dirs))
    for a in (dirs, weights, basis):
        a.flags.writeable = False
    return dirs, weights, basis


def random_sh_coefficients(rng: np.random.Generator, mean_radiance: float = 0.8) -> np.ndarray:
    """Order-5 SH radiance ``(36, 3)`` (module :mod:`mcdenoise.render.sh` convention) of a
    random environment: a gradient sky (brighter above) plus 1–3 coloured lobes of sharpness
    ``U(3, 25)``, projected on SH; then the constant term is raised until the radiance is
    ≥ 0 at every texel of the lat-long :func:`~mcdenoise.render.sh.sh_envmap_dict` bakes (so
    nothing is clamped), and everything is scaled to ``mean_radiance`` (luminance averaged
    over the sphere)."""
    dirs, weights, basis = _sh_grid(64, 33)
    up = dirs[:, 1:2]
    top, bottom = np.array(_color(rng, 0.4, 1.0)), np.array(_color(rng, 0.05, 0.4))
    radiance = top * np.clip(up, 0, 1) ** rng.uniform(0.5, 2.0) + bottom * np.clip(-up, 0, 1)
    radiance = radiance + 0.05
    for _ in range(int(rng.integers(1, 4))):
        mu = rng.normal(size=3)
        mu[1] = abs(mu[1]) * rng.choice([1.0, -0.3])  # mostly from above
        mu /= np.linalg.norm(mu)
        lobe = np.exp(rng.uniform(3, 25) * (dirs @ mu - 1))[:, None]
        radiance = radiance + rng.uniform(1, 6) * lobe * _tint(rng)
    coeffs = basis.T @ (radiance * weights[:, None])  # (36, 3): ∫ L Y_i dω by quadrature
    y00 = 0.5 / math.sqrt(math.pi)
    lowest = (_sh_grid(128, 65)[2] @ coeffs).min(axis=0)  # the texels sh_envmap_dict bakes
    coeffs[0] += np.maximum(0.0, -lowest) / y00
    mean = coeffs[0] * y00  # mean radiance per channel
    coeffs *= mean_radiance / float(mean @ _LUMINANCE)
    coeffs[0] += 2e-4 / y00  # keeps the coefficients non-negative after rounding
    return coeffs


# --------------------------------------------------------------------------------- archetypes


@dataclass
class _Build:
    """The scene being assembled, in the user-facing schema."""

    rng: np.random.Generator
    archetype: str
    variant: str = ""
    objects: list[dict[str, Any]] = field(default_factory=list)
    subjects: list[_Solid] = field(default_factory=list)
    materials: dict[str, dict[str, Any]] = field(default_factory=dict)
    lights: list[dict[str, Any]] = field(default_factory=list)
    camera: dict[str, Any] = field(default_factory=dict)
    indirect: bool = True
    ao_radius: float | None = None
    room_albedo: float = 0.5  # mean reflectance of a room's floor, walls and ceiling

    def all_materials(self) -> list[dict[str, Any]]:
        out = []
        for o in self.objects + [s.obj for s in self.subjects]:
            m = o.get("material")
            out.append(self.materials[m] if isinstance(m, str) else m)
        return [m for m in out if m is not None]


def _rect(translate: Sequence[float], rotate: Sequence[float], half: Sequence[float]) -> dict:
    return {"shape": "rectangle", "transform": _xform(translate, rotate, [half[0], half[1], 1])}


def _room(b: _Build, w: float, d: float, h: float, *, ao: bool) -> None:
    """Floor, ceiling and four walls; with variant ``window`` one of the back and side walls
    gets an opening (window or door) with a light outside (:func:`_opening_light`)."""
    rng = b.rng
    if ao:
        white = {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]}
        b.materials.update(floor=white, wall=white, ceiling=white)
    else:
        b.materials["floor"] = _floor_material(rng, max(w, d))
        wall_tex = _texture(rng, "image", extent=max(w, d)) if rng.random() < 0.15 else None
        b.materials["wall"] = {"type": "diffuse", "reflectance": wall_tex or _color(rng, 0.4, 0.85)}
        b.materials["ceiling"] = {
            "type": "diffuse",
            "reflectance": _v([rng.uniform(0.6, 0.85)] * 3),
        }
    floor, wall, ceiling = (
        _albedo(b.materials[k].get("reflectance", b.materials[k].get("diffuse")))
        for k in ("floor", "wall", "ceiling")
    )
    b.room_albedo = (w * d * (floor + ceiling) + 2 * (w + d) * h * wall) / (
        2 * w * d + 2 * (w + d) * h
    )
    b.objects.append({**_rect([0, 0, 0], [-90, 0, 0], [w / 2, d / 2]), "material": "floor"})
    b.objects.append({**_rect([0, h, 0], [90, 0, 0], [w / 2, d / 2]), "material": "ceiling"})
    # wall: (centre of its base line, yaw so the rectangle's +z faces inward, half width)
    walls = {
        "back": (np.array([0.0, 0.0, -d / 2]), 0.0, w / 2),
        "left": (np.array([-w / 2, 0.0, 0.0]), 90.0, d / 2),
        "right": (np.array([w / 2, 0.0, 0.0]), -90.0, d / 2),
        "front": (np.array([0.0, 0.0, d / 2]), 180.0, w / 2),
    }
    opening = ""
    if b.variant == "window":
        opening = ("back", "left", "right")[int(rng.integers(3))]
    for name, (base, yaw, half_w) in walls.items():
        u = np.array([math.cos(math.radians(yaw)), 0.0, -math.sin(math.radians(yaw))])
        if name != opening:
            b.objects.append(
                {
                    **_rect(base + np.array([0, h / 2, 0]), [0, yaw, 0], [half_w, h / 2]),
                    "material": "wall",
                }
            )
            continue
        door = rng.random() < 0.3
        hw = min(rng.uniform(0.4, 0.9) if not door else rng.uniform(0.4, 0.6), half_w - 0.3)
        v0, v1 = (
            (0.0, min(rng.uniform(1.9, 2.2), h - 0.3))
            if door
            else (
                rng.uniform(0.6, 1.0),
                min(rng.uniform(1.6, 2.3), h - 0.3),
            )
        )
        c = rng.uniform(-half_w + hw + 0.3, half_w - hw - 0.3)
        pieces = [(-half_w, c - hw, 0.0, h), (c + hw, half_w, 0.0, h), (c - hw, c + hw, v1, h)]
        if v0 > 0:
            pieces.append((c - hw, c + hw, 0.0, v0))
        for a0, a1, b0, b1 in pieces:
            centre = base + u * (a0 + a1) / 2 + np.array([0, (b0 + b1) / 2, 0])
            b.objects.append(
                {**_rect(centre, [0, yaw, 0], [(a1 - a0) / 2, (b1 - b0) / 2]), "material": "wall"}
            )
        hole_centre = base + u * c + np.array([0, (v0 + v1) / 2, 0])
        hole_half = np.array([hw, (v1 - v0) / 2])
        b.variant = "door" if door else "window"
        inward = np.array([math.sin(math.radians(yaw)), 0.0, math.cos(math.radians(yaw))])
        _opening_light(b, hole_centre, hole_half, inward, yaw, (w, d, h))


def _opening_light(
    b: _Build,
    centre: np.ndarray,
    half: np.ndarray,
    inward: np.ndarray,
    yaw: float,
    room: tuple[float, float, float],
) -> None:
    """Light outside an opening: an emissive panel facing in, or a sun shining in + a sky.

    The sun's irradiance is set so that the power entering through the opening, spread over
    the room's surfaces and multiplied by interreflection (≈ 1 / (1 − albedo)), gives an
    average irradiance ``U(1, 3)`` inside: the sunlit patch is then tens of times brighter
    than the rest, as in real rooms. The sky's gain is ``U(0.1, 0.3)``× the sun's irradiance
    (a radiance of roughly 0.1× the sun's irradiance).
    """
    rng = b.rng
    w, d, h = room
    reach = (w if abs(inward[0]) > 0.5 else d) / 2  # opening -> room centre
    if rng.random() < 0.6:
        area = 4 * half[0] * half[1]
        # the room multiplies light by about 1 / (1 - albedo) through interreflection
        radiance = rng.uniform(6, 14) * (1 - b.room_albedo) * reach**2 / area * _tint(rng)
        grow = rng.uniform(1.3, 2.5)
        panel = _rect(centre - inward * rng.uniform(0.2, 1.0), [0, yaw, 0], half * grow)
        panel["material"] = {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]}
        panel["emission"] = _v(radiance, 3)
        b.objects.append(panel)
        b.variant += "+panel"
        return
    elev = math.radians(rng.uniform(15, 45))
    turn = math.radians(rng.uniform(-35, 35))
    out = -inward
    horiz = np.array(
        [
            out[0] * math.cos(turn) + out[2] * math.sin(turn),
            0.0,
            -out[0] * math.sin(turn) + out[2] * math.cos(turn),
        ]
    )
    room_area = 2 * w * d + 2 * (w + d) * h
    hole_area = 4 * half[0] * half[1]
    sun = rng.uniform(1, 3) * room_area * (1 - b.room_albedo) / hole_area
    b.lights.append(_sun(rng, horiz * math.cos(elev) + _UP * math.sin(elev), sun))
    b.lights.append(_sky(rng, studio=0.0, gain=sun * rng.uniform(0.05, 0.15) / 0.5))
    b.variant += "+sun"


def _interior(b: _Build, ao: bool = False) -> None:
    rng = b.rng
    w, d, h = rng.uniform(4, 7), rng.uniform(4, 7), rng.uniform(2.6, 3.4)
    if not ao:
        b.variant = "window" if rng.random() < 0.35 else "ceiling"
    subjects: list[_Solid] = []
    cam = None
    count = _count(rng)
    white = {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]}
    while cam is None:
        subjects = _place_subjects(
            rng,
            count,
            _in_box(rng, (-w / 2 + 0.4, w / 2 - 0.4), (-d / 2 + 0.4, d / 2 - 1.8)),
            (0.25, 0.7),
            rng.uniform(-30, 30),
            material=(lambda: dict(white)) if ao else None,
        )
        cam = _room_camera(rng, subjects, w, d, h) if subjects else None
        count = max(1, count - 1)
    b.subjects = subjects
    b.camera = cam
    _room(b, w, d, h, ao=ao)
    if ao:
        return
    centre = np.mean([s.centre for s in subjects], axis=0)
    if b.variant == "ceiling":
        half = rng.uniform(0.2, 0.6, 2)
        x = rng.uniform(-w / 4, w / 4)
        z = rng.uniform(-d / 4, d / 4)
        e = rng.uniform(3, 6) * (1 - b.room_albedo)  # interreflection adds ~ 1 / (1 - albedo)
        radiance = e * h * h / (4 * half[0] * half[1]) * _tint(rng)
        panel = _rect([x, h - 0.005, z], [90, 0, 0], half)
        panel["material"] = {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]}
        panel["emission"] = _v(radiance, 3)
        b.objects.append(panel)
    origin = np.asarray(cam["origin"])
    if rng.random() < 0.2:
        pos = np.array(
            [rng.uniform(-w / 3, w / 3), h - rng.uniform(0.3, 0.6), rng.uniform(-d / 3, d / 3)]
        )
        b.lights.append(_point(pos, centre, rng.uniform(1, 3) * (1 - b.room_albedo), _tint(rng)))
    if rng.random() < 0.15:
        pos = np.array([rng.uniform(-w / 3, w / 3), h - 0.3, rng.uniform(-d / 3, d / 3)])
        _, rad = _bounding(subjects)
        b.lights.append(
            _spot(rng, pos, centre, rad, rng.uniform(1, 4) * (1 - b.room_albedo), _tint(rng))
        )
    if rng.random() < 0.25:

        def region() -> np.ndarray:
            return np.array(
                [
                    rng.uniform(-w / 2 + 0.2, w / 2 - 0.2),
                    rng.uniform(h / 2, h - 0.2),
                    rng.uniform(-d / 2 + 0.2, d / 2 - 0.2),
                ]
            )

        b.objects += _bulbs(rng, int(rng.integers(1, 4)), region, subjects, origin)


def _ground(b: _Build, white: bool = False) -> None:
    rng = b.rng
    g = rng.uniform(15, 40)
    mat = (
        {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]}
        if white
        else _floor_material(rng, 2 * g)
    )
    if rng.random() < 0.6:
        ground = _rect([0, 0, 0], [-90, 0, 0], [g, g])
    else:
        ground = {"shape": "disk", "transform": _xform([0, 0, 0], [-90, 0, 0], [g, g, 1])}
    b.objects.append({**ground, "material": mat})


def _open_subjects(
    b: _Build, size: tuple[float, float], region: float, azimuth: float, **kw: Any
) -> None:
    rng = b.rng
    count = _count(rng)
    subjects: list[_Solid] = []
    while not subjects:
        subjects = _place_subjects(rng, count, _in_disk(rng, region), size, azimuth, **kw)
    b.subjects = subjects


def _outdoor(b: _Build) -> None:
    rng = b.rng
    azimuth = rng.uniform(0, 360)
    _open_subjects(b, (0.25, 0.7), rng.uniform(1.2, 2.5), azimuth)
    b.camera = _orbit_camera(rng, b.subjects, azimuth, (5, 45))
    _ground(b)
    sun = rng.random() < 0.7
    b.lights.append(_sky(rng, gain=1.0 if sun else 1.6))  # overcast: a brighter sky
    b.variant = b.lights[-1].get("procedural") or (
        "studio" if "file" in b.lights[-1] else "constant"
    )
    if sun:
        e, a = math.radians(rng.uniform(15, 70)), rng.uniform(0, 2 * math.pi)
        direction = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
        b.lights.append(_sun(rng, direction, rng.uniform(1.5, 4)))
        b.variant += "+sun"
    if rng.random() < 0.15:
        c, rad = _bounding(b.subjects)

        def region() -> np.ndarray:
            return c + rng.uniform(-1, 1, 3) * (rad + 0.5) + np.array([0, rad, 0])

        b.objects += _bulbs(
            rng, int(rng.integers(1, 3)), region, b.subjects, np.asarray(b.camera["origin"])
        )


def _tabletop(b: _Build) -> None:
    rng = b.rng
    azimuth = rng.uniform(0, 360)
    tw, td = rng.uniform(1.4, 2.4), rng.uniform(1.0, 1.8)
    count = _count(rng)
    subjects: list[_Solid] = []
    while not subjects:
        subjects = _place_subjects(
            rng,
            count,
            _in_box(rng, (-tw + 0.1, tw - 0.1), (-td + 0.1, td - 0.1)),
            (0.15, 0.42),
            azimuth,
        )
    b.subjects = subjects
    b.camera = _orbit_camera(rng, subjects, azimuth, (15, 55))
    b.objects.append(
        {
            "shape": "cube",
            "transform": _xform([0, -0.04, 0], [0, 0, 0], [tw, 0.04, td]),
            "material": _floor_material(rng, 2 * max(tw, td)),
        }
    )
    if rng.random() < 0.75:
        b.objects.append(
            {
                **_rect([0, -0.75, 0], [-90, 0, 0], [12, 12]),
                "material": {"type": "diffuse", "reflectance": _color(rng, 0.1, 0.6)},
            }
        )
    if rng.random() < 0.5:
        a = math.radians(azimuth)
        back = -np.array([math.sin(a), 0.0, math.cos(a)]) * (math.hypot(tw, td) + 0.3)
        b.objects.append(
            {
                **_rect(back + np.array([0, 1.0, 0]), [0, azimuth, 0], [4.0, 1.8]),
                "material": {"type": "diffuse", "reflectance": _color(rng, 0.2, 0.8)},
            }
        )
    c, rad = _bounding(subjects)
    key_az = math.radians(azimuth + rng.uniform(-120, 120))
    e = math.radians(rng.uniform(35, 75))
    dist = rng.uniform(1.8, 3.5)
    pos = c + dist * np.array(
        [math.cos(e) * math.sin(key_az), math.sin(e), math.cos(e) * math.cos(key_az)]
    )
    if rng.random() < 0.55:
        b.lights.append(_spot(rng, pos, c, rad, rng.uniform(2, 6), _tint(rng)))
        b.variant = "spot"
    else:
        b.lights.append(_point(pos, c, rng.uniform(2, 6), _tint(rng)))
        b.variant = "point"
    if rng.random() < 0.75:
        b.lights.append({"type": "constant", "radiance": _v(rng.uniform(0.05, 0.3) * _tint(rng))})
        b.variant += "+fill"
    if rng.random() < 0.25:
        fill_az = key_az + math.pi + rng.uniform(-0.8, 0.8)
        fpos = c + rng.uniform(2, 4) * np.array(
            [math.sin(fill_az), rng.uniform(0.3, 0.8), math.cos(fill_az)]
        )
        b.lights.append(_point(fpos, c, rng.uniform(0.3, 1.0), _tint(rng)))
        b.variant += "+point"
    if rng.random() < 0.2:

        def region() -> np.ndarray:
            return c + rng.uniform(-1, 1, 3) * (rad + 0.6) + np.array([0, rad + 0.2, 0])

        b.objects += _bulbs(
            rng, int(rng.integers(1, 3)), region, subjects, np.asarray(b.camera["origin"])
        )


def _sh_scene(b: _Build) -> None:
    rng = b.rng
    azimuth = rng.uniform(0, 360)
    _open_subjects(b, (0.25, 0.7), rng.uniform(1.0, 2.2), azimuth)
    b.camera = _orbit_camera(rng, b.subjects, azimuth, (10, 40))
    g = rng.uniform(3, 8)
    plane = (
        _rect([0, 0, 0], [-90, 0, 0], [g, g])
        if rng.random() < 0.5
        else {"shape": "disk", "transform": _xform([0, 0, 0], [-90, 0, 0], [g, g, 1])}
    )
    b.objects.append({**plane, "material": _floor_material(rng, 2 * g)})
    coeffs = random_sh_coefficients(rng, rng.uniform(0.3, 0.9))
    b.lights.append({"type": "sh", "coefficients": [_v(c, 5) for c in coeffs], "scale": 1.0})
    b.variant = "sh"
    if rng.random() < 0.5:
        # the main directional light: the brightest direction of the (non-negative) SH sky
        dirs, _, basis = _sh_grid(64, 33)
        lum = basis @ coeffs @ _LUMINANCE
        best = dirs[int(np.argmax(np.where(dirs[:, 1] > 0.15, lum, -np.inf)))]
        b.lights.append(_sun(rng, best, rng.uniform(0.5, 2)))
        b.variant += "+sun"


def _ao(b: _Build) -> None:
    rng = b.rng
    b.ao_radius = _r(rng.uniform(0.3, 2.0), 3)
    b.indirect = False
    white = {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]}
    if rng.random() < 0.4:
        b.variant = "room"
        _interior(b, ao=True)
        return
    b.variant = "ground"
    azimuth = rng.uniform(0, 360)
    _open_subjects(b, (0.25, 0.7), rng.uniform(1.2, 2.5), azimuth, material=lambda: dict(white))
    b.camera = _orbit_camera(rng, b.subjects, azimuth, (5, 45))
    _ground(b, white=True)


_BUILDERS: dict[str, Callable[[_Build], None]] = {
    "interior": _interior,
    "outdoor": _outdoor,
    "tabletop": _tabletop,
    "sh": _sh_scene,
    "ao": _ao,
}


# --------------------------------------------------------------------------------- public


def _check_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise InputError(f"random scenes: {name} must be an integer >= 0, got {value!r}")
    return int(value)


def random_scene(seed: int, index: int) -> RandomScene:
    """The ``index``-th random scene of data set ``seed``, with its archetype and subjects.

    Deterministic in ``(seed, index)`` alone (``numpy.random.default_rng([seed, index])``).

    Raises:
        InputError: ``seed`` or ``index`` is not an integer >= 0.
    """
    seed, index = _check_int("seed", seed), _check_int("index", index)
    rng = np.random.default_rng([seed, index])
    archetype = _choice(rng, ARCHETYPES)
    b = _Build(rng=rng, archetype=archetype)
    _BUILDERS[archetype](b)
    b.subjects = _unhidden(b.camera["origin"], b.subjects)
    lit = archetype != "ao"
    if lit:
        b.indirect = rng.random() < INDIRECT_PROB[archetype]
        if rng.random() < THINLENS_PROB:
            _thinlens(rng, b.camera, b.subjects)
    mats = b.all_materials()
    effects: set[str] = set()
    render: dict[str, Any] = {"rr_depth": 5}
    if lit:
        effects.add("direct")
        if b.indirect:
            effects.add("indirect")
            depths, p = zip(*MAX_DEPTHS)
            depth = int(rng.choice(depths, p=np.asarray(p) / sum(p)))
            if any(m["type"] == "dielectric" for m in mats):
                depth = max(depth, 8)
            render["max_depth"] = depth
            if any(_specular(m) for m in mats) and rng.random() < CAUSTICS_PROB:
                effects.add("caustics")
        if any(_glossy(m) for m in mats):
            effects.add("glossy")
        if b.camera.get("type") == "thinlens":
            effects.add("dof")
    else:
        effects.add("ao")
        render["ao_radius"] = b.ao_radius
    n_subj = len(b.subjects)
    first = len(b.objects)
    objects = b.objects + [s.obj for s in b.subjects]
    light_kinds = sorted(
        {lt["type"] for lt in b.lights}
        | ({"area"} if any("emission" in o for o in objects) else set())
    )
    desc = (
        f"random scene (seed {seed}, index {index}): {archetype}/{b.variant}, "
        f"{n_subj} object{'s' * (n_subj != 1)}, lights: {', '.join(light_kinds) or 'none'}"
    )
    data: dict[str, Any] = {
        "name": f"random-{seed}-{index:06d}",
        "description": desc,
        "effects": [e for e in EFFECTS if e in effects],
        "render": render,
        "camera": {"type": "pinhole", "up": [0.0, 1.0, 0.0], **b.camera},
        "materials": b.materials,
        "objects": objects,
        "lights": b.lights,
    }
    spec = parse_spec(data)
    plan_effects(spec)  # the generator's own contract: raises if content and effects disagree
    return RandomScene(
        spec=spec,
        archetype=archetype,
        variant=b.variant,
        subjects=tuple(range(first, first + n_subj)),
    )


def random_spec(seed: int, index: int) -> SceneSpec:
    """The ``index``-th random scene spec of data set ``seed`` (see the module docstring)."""
    return random_scene(seed, index).spec


def random_specs(count: int, seed: int, start: int = 0) -> list[SceneSpec]:
    """Specs ``start .. start + count - 1`` of data set ``seed``."""
    count, start = _check_int("count", count), _check_int("start", start)
    return [random_spec(seed, i) for i in range(start, start + count)]
