"""Materials and textures of the random scenes (subjects, floors), in the spec schema."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from mcdenoise.render.random_scenes.assets import texture_files
from mcdenoise.render.random_scenes.distribution import Distribution
from mcdenoise.render.random_scenes.sampling import (
    LUMINANCE,
    choose,
    colour,
    rounded,
    rounded_vec,
)


def texture(
    rng: np.random.Generator, d: Distribution, kind: str, *, extent: float | None = None
) -> Any:
    """A texture value of the spec schema. ``extent``: the uv range's world size (a large
    surface, where periods are chosen in world units), else per-uv periods for objects."""
    m, f = d.materials, d.floors
    if kind == "constant":
        return colour(rng, m, m.value)
    c0, c1 = colour(rng, m, m.dark_value), colour(rng, m, m.light_value)
    if kind == "checkerboard":
        scale = extent / f.checker_size.draw(rng) if extent else m.checker_periods.draw(rng)
        return {"checkerboard": {"color0": c0, "color1": c1, "scale": rounded(scale, 3)}}
    if kind == "noise":
        scale = extent / f.noise_size.draw(rng) if extent else m.noise_cells.draw(rng)
        seed = int(rng.integers(0, 2**31 - 1))
        return {"noise": {"color0": c0, "color1": c1, "scale": rounded(scale, 3), "seed": seed}}
    if kind == "image":
        files = texture_files()
        scale = extent / f.image_size.draw(rng) if extent else m.image_repeats.draw(rng)
        return {"image": {"file": files[int(rng.integers(len(files)))], "scale": rounded(scale, 3)}}
    raise ValueError(f"unknown texture kind {kind!r}")


def material(rng: np.random.Generator, d: Distribution, typ: str, base: Any) -> dict[str, Any]:
    """A material of type ``typ``; ``base`` is the base colour of diffuse/plastics."""
    m = d.materials
    if typ == "diffuse":
        return {"type": "diffuse", "reflectance": base}
    if typ in ("plastic", "roughplastic"):
        out: dict[str, Any] = {"type": typ, "diffuse": base, "ior": rounded(m.ior.draw(rng))}
        if typ == "roughplastic":
            out["roughness"] = rounded(m.roughness.draw(rng))
        return out
    if typ in ("conductor", "roughconductor"):
        out = {"type": typ}
        if rng.random() < m.conductor_preset_prob:
            out["conductor"] = m.conductors[int(rng.integers(len(m.conductors)))]
        else:
            out["eta"] = rounded_vec(m.eta.draw(rng, 3))
            out["k"] = rounded_vec(m.k.draw(rng, 3))
        if rng.random() >= m.white_specular_prob:
            out["specular"] = rounded_vec(m.specular_tint.draw(rng, 3))
        if typ == "roughconductor":
            out["roughness"] = rounded(m.roughness.draw(rng))
        return out
    if typ == "dielectric":
        out = {"type": "dielectric", "ior": rounded(m.ior.draw(rng))}
        if rng.random() < m.rough_dielectric_prob:
            out["roughness"] = rounded(m.dielectric_roughness.draw(rng))
        return out
    raise ValueError(f"unknown material type {typ!r}")


def subject_material(rng: np.random.Generator, d: Distribution, *, textured: bool) -> dict:
    """A subject's material; ``textured``: its base colour may be a texture (not meshes)."""
    typ = choose(rng, d.materials.types)
    kind = choose(rng, d.materials.textures) if textured else "constant"
    return material(rng, d, typ, texture(rng, d, kind))


def floor_material(rng: np.random.Generator, d: Distribution, extent: float) -> dict[str, Any]:
    """The material of a floor, ground, table or support plane of world size ``extent``."""
    typ = "diffuse" if rng.random() < d.floors.diffuse_prob else "roughplastic"
    kind = choose(rng, d.floors.textures)
    return material(rng, d, typ, texture(rng, d, kind, extent=extent))


def albedo(value: Any) -> float:
    """Mean luminance of a texture value (images: their approximate mean, 0.2)."""
    if isinstance(value, Mapping):
        kind, p = next(iter(value.items()))
        if kind == "image":
            return 0.2
        return float((np.asarray(p["color0"]) + np.asarray(p["color1"])) / 2 @ LUMINANCE)
    return float(np.asarray(value) @ LUMINANCE)


def is_glossy(m: Mapping[str, Any]) -> bool:
    return m["type"] in ("roughplastic", "roughconductor") or (
        m["type"] == "dielectric" and m.get("roughness", 0) > 0
    )


def is_specular(m: Mapping[str, Any]) -> bool:
    return m["type"] in ("plastic", "conductor") or (
        m["type"] == "dielectric" and m.get("roughness", 0) == 0
    )
