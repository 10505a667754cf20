"""Seeded procedural scene specs for training data (``mcdenoise render --random N --seed S``).

:func:`random_spec` ``(seed, index)`` builds one :class:`~mcdenoise.render.scene_spec.SceneSpec`
from ``numpy.random.default_rng([seed, index])`` alone (no global state): the same pair gives
the same spec in every process, and scene ``index`` of a data set does not depend on how many
scenes were generated before it (shards are independent). Every spec survives
``parse_spec(spec.to_dict())`` unchanged and declares exactly the effects its content calls
for (:func:`~mcdenoise.render.effects.plan_effects` accepts it). Meshes, image textures and
the studio envmap are package assets (:mod:`.assets`), referred to by absolute path.
:func:`random_scene` also returns the archetype, its variant and which objects are the placed
"subjects".

The distribution the scenes are drawn from is data, :data:`DISTRIBUTION`
(:mod:`.distribution`); :func:`describe_distribution` writes it out as text, which is also
that module's docstring. The rest, by concern: :mod:`.materials` (materials, textures),
:mod:`.placement` (subjects, cameras), :mod:`.lights` (lights, SH environments) and
:mod:`.archetypes` (one builder per archetype).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcdenoise.errors import InputError
from mcdenoise.render.effects import plan_effects
from mcdenoise.render.random_scenes.archetypes import BUILDERS, Build
from mcdenoise.render.random_scenes.assets import (
    MeshAsset,
    asset_dir,
    envmap_file,
    mesh_assets,
    texture_files,
)
from mcdenoise.render.random_scenes.distribution import (
    DISTRIBUTION,
    Distribution,
    describe_distribution,
)
from mcdenoise.render.random_scenes.lights import random_sh_coefficients
from mcdenoise.render.random_scenes.materials import is_glossy, is_specular
from mcdenoise.render.random_scenes.placement import make_thinlens, unhidden
from mcdenoise.render.random_scenes.sampling import choose
from mcdenoise.render.scene_spec import EFFECTS, SceneSpec, parse_spec

#: Scene archetypes and their probabilities.
ARCHETYPES: Mapping[str, float] = DISTRIBUTION.archetypes
#: Shapes of the subjects and their probabilities.
SHAPE_WEIGHTS: Mapping[str, float] = DISTRIBUTION.subjects.shapes
#: Material types of the subjects and their probabilities.
MATERIAL_WEIGHTS: Mapping[str, float] = DISTRIBUTION.materials.types
#: Texture kinds of the diffuse/plastic base colour of non-mesh subjects.
TEXTURE_WEIGHTS: Mapping[str, float] = DISTRIBUTION.materials.textures
#: Texture kinds of floors and ground planes.
FLOOR_TEXTURE_WEIGHTS: Mapping[str, float] = DISTRIBUTION.floors.textures
#: Weights of the number of subjects 1..8.
COUNT_WEIGHTS: tuple[float, ...] = DISTRIBUTION.subjects.count_weights
#: Mitsuba conductor presets drawn from (all metallic; Mitsuba ships more).
CONDUCTORS: tuple[str, ...] = DISTRIBUTION.materials.conductors
#: Share of lit scenes with a thin-lens camera (effect ``dof``).
THINLENS_PROB: float = DISTRIBUTION.camera.thinlens_prob
#: Share of scenes with ``indirect`` and a smooth specular object that declare ``caustics``.
CAUSTICS_PROB: float = DISTRIBUTION.effects.caustics_prob
#: Share of scenes of each lit archetype that declare ``indirect``.
INDIRECT_PROB: Mapping[str, float] = DISTRIBUTION.effects.indirect_prob
#: ``render.max_depth`` choices (with ``indirect``) and their probabilities.
MAX_DEPTHS: tuple[tuple[int, float], ...] = DISTRIBUTION.effects.max_depths

__all__ = [
    "ARCHETYPES",
    "CAUSTICS_PROB",
    "CONDUCTORS",
    "COUNT_WEIGHTS",
    "DISTRIBUTION",
    "FLOOR_TEXTURE_WEIGHTS",
    "INDIRECT_PROB",
    "MATERIAL_WEIGHTS",
    "MAX_DEPTHS",
    "SHAPE_WEIGHTS",
    "TEXTURE_WEIGHTS",
    "THINLENS_PROB",
    "Distribution",
    "MeshAsset",
    "RandomScene",
    "asset_dir",
    "describe_distribution",
    "envmap_file",
    "mesh_assets",
    "random_scene",
    "random_sh_coefficients",
    "random_spec",
    "random_specs",
    "texture_files",
]


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


def _check_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise InputError(f"random scenes: {name} must be an integer >= 0, got {value!r}")
    return int(value)


def random_scene(
    seed: int, index: int, *, distribution: Distribution = DISTRIBUTION
) -> RandomScene:
    """The ``index``-th random scene of data set ``seed``, with its archetype and subjects.

    Deterministic in ``(seed, index)`` alone (``numpy.random.default_rng([seed, index])``);
    ``distribution`` is what it draws from (default :data:`DISTRIBUTION`).

    Raises:
        InputError: ``seed`` or ``index`` is not an integer >= 0.
    """
    seed, index = _check_int("seed", seed), _check_int("index", index)
    d = distribution
    rng = np.random.default_rng([seed, index])
    archetype = choose(rng, d.archetypes)
    b = Build(rng=rng, dist=d, archetype=archetype)
    BUILDERS[archetype](b)
    b.subjects = unhidden(d, b.camera["origin"], b.subjects)
    lit = archetype != "ao"
    if lit:
        b.indirect = rng.random() < d.effects.indirect_prob[archetype]
        if rng.random() < d.camera.thinlens_prob:
            make_thinlens(rng, d, b.camera, b.subjects)
    mats = b.all_materials()
    effects: set[str] = set()
    render: dict[str, Any] = {"rr_depth": d.effects.rr_depth}
    if lit:
        effects.add("direct")
        if b.indirect:
            effects.add("indirect")
            depths, p = zip(*d.effects.max_depths)
            depth = int(rng.choice(depths, p=np.asarray(p) / sum(p)))
            if any(m["type"] == "dielectric" for m in mats):
                depth = max(depth, d.effects.dielectric_min_depth)
            render["max_depth"] = depth
            if any(is_specular(m) for m in mats) and rng.random() < d.effects.caustics_prob:
                effects.add("caustics")
        if any(is_glossy(m) for m in mats):
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
    """The ``index``-th random scene spec of data set ``seed`` (see :data:`DISTRIBUTION`)."""
    return random_scene(seed, index).spec


def random_specs(count: int, seed: int, start: int = 0) -> list[SceneSpec]:
    """Specs ``start .. start + count - 1`` of data set ``seed``."""
    count, start = _check_int("count", count), _check_int("start", start)
    return [random_spec(seed, i) for i in range(start, start + count)]
