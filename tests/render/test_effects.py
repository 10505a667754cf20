"""Effect plans: every effect switch changes what is simulated; mismatches are errors."""

from __future__ import annotations

import copy

import pytest

from mcdenoise.render.effects import AO_FEATURES, DIRECT_DEPTH, plan_effects
from mcdenoise.render.scene_spec import SpecError, parse_spec

DIFFUSE = {"type": "diffuse", "reflectance": [0.7, 0.7, 0.7]}
GLASS = {"type": "dielectric"}
ROUGH = {"type": "roughconductor", "conductor": "Au", "roughness": 0.2}


def scene(effects, *, materials=(DIFFUSE,), camera=None, light=True, ao_radius=None):
    objs = [
        {"shape": "sphere", "center": [i, 0, 0], "radius": 0.4, "material": m}
        for i, m in enumerate(materials)
    ]
    if light:
        objs.append(
            {
                "shape": "disk",
                "transform": {"translate": [0, 3, 0], "rotate": [90, 0, 0]},
                "emission": [4, 4, 4],
            }
        )
    d = {
        "name": "s",
        "effects": list(effects),
        "objects": objs,
        "camera": camera or {"origin": [0, 0, 4], "target": [0, 0, 0]},
    }
    if ao_radius is not None:
        d["render"] = {"ao_radius": ao_radius}
    return parse_spec(copy.deepcopy(d))


THINLENS = {"type": "thinlens", "origin": [0, 0, 4], "target": [0, 0, 0], "aperture_radius": 0.1}


def test_direct_only_is_one_bounce():
    p = plan_effects(scene(["direct"]))
    assert (p.integrator, p.max_depth) == ("path", DIRECT_DEPTH)


def test_indirect_is_full_paths():
    p = plan_effects(scene(["direct", "indirect"]))
    assert (p.integrator, p.max_depth) == ("path", 8)
    assert p.integrator_dict() == {"type": "path", "max_depth": 8, "rr_depth": 5}


def test_specular_object_without_caustics_uses_the_cutting_integrator():
    p = plan_effects(scene(["direct", "indirect"], materials=(DIFFUSE, GLASS)))
    assert p.integrator == "mcd_path" and not p.caustics
    assert p.integrator_dict()["caustics"] is False
    q = plan_effects(scene(["direct", "indirect", "caustics"], materials=(DIFFUSE, GLASS)))
    assert q.integrator == "path" and q.caustics


def test_dof_switches_the_lens():
    assert plan_effects(scene(["direct", "dof"], camera=THINLENS)).thinlens
    assert not plan_effects(scene(["direct"])).thinlens


def test_ao_plan():
    p = plan_effects(scene(["ao"], light=False, ao_radius=0.5))
    assert p.integrator == "mcd_ao" and p.ao_radius == 0.5 and p.features == AO_FEATURES
    assert p.integrator_dict() == {"type": "mcd_ao", "radius": 0.5}


@pytest.mark.parametrize(
    "kwargs,fragment",
    [
        ({"effects": ["direct", "dof"]}, "thin-lens camera"),
        ({"effects": ["direct"], "camera": THINLENS}, "'dof' is not declared"),
        ({"effects": ["ao"], "light": False}, "ao_radius"),
        ({"effects": ["ao", "direct"], "ao_radius": 1.0}, "excludes direct"),
        ({"effects": ["indirect"]}, "needs 'direct'"),
        ({"effects": ["direct"], "light": False}, "needs a light"),
        ({"effects": ["direct", "glossy"]}, "no object has a glossy material"),
        ({"effects": ["direct"], "materials": (ROUGH,)}, "'glossy' is not declared"),
        ({"effects": ["direct", "caustics"], "materials": (GLASS,)}, "needs 'indirect'"),
        ({"effects": ["direct", "indirect", "caustics"]}, "smooth specular object"),
    ],
)
def test_effect_and_content_must_agree(kwargs, fragment):
    effects = kwargs.pop("effects")
    with pytest.raises(SpecError, match="effects: ") as info:
        plan_effects(scene(effects, **kwargs))
    assert fragment in str(info.value)
