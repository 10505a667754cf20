"""Scene spec parsing and validation (mcdenoise/render/scene_spec.py)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from mcdenoise.render.scene_spec import SH_COEFFS, SpecError, Transform, load_spec, parse_spec

BASE = {
    "name": "t",
    "effects": ["direct", "indirect"],
    "camera": {"origin": [0, 1, 4], "target": [0, 1, 0], "fov": 45},
    "materials": {
        "white": {"type": "diffuse", "reflectance": [0.7, 0.7, 0.7]},
        "floor": {
            "type": "roughplastic",
            "diffuse": {"checkerboard": {"color0": [0.1, 0.1, 0.1], "scale": 4}},
            "roughness": 0.3,
        },
    },
    "objects": [
        {"shape": "sphere", "center": [0, 1, 0], "radius": 0.5, "material": "white"},
        {
            "shape": "cube",
            "transform": {"translate": [1, 0.5, 0], "rotate": [0, 30, 0], "scale": 0.5},
            "material": {"type": "dielectric"},
        },
        {
            "shape": "rectangle",
            "transform": {"rotate": [-90, 0, 0], "scale": 5},
            "material": "floor",
        },
        {
            "shape": "disk",
            "transform": {"translate": [0, 3, 0], "rotate": [90, 0, 0]},
            "emission": [5, 5, 5],
        },
    ],
    "lights": [
        {"type": "point", "position": [0, 3, 0], "intensity": [1, 1, 1]},
        {"type": "spot", "position": [0, 3, 0], "target": [0, 0, 0], "intensity": [1, 1, 1]},
        {"type": "constant", "radiance": [0.1, 0.1, 0.1]},
        {"type": "envmap", "procedural": "sky", "scale": 0.5},
        {"type": "sun", "direction": [0, 2, 0], "irradiance": [2, 2, 2]},
        {"type": "sh", "coefficients": [[0.5, 0.5, 0.5]] + [[0, 0, 0]] * (SH_COEFFS - 1)},
    ],
}


def spec_with(path: str, value):
    """BASE with one key (dotted path, list indices as ints) replaced (None deletes it)."""
    d = copy.deepcopy(BASE)
    keys = path.split(".")
    node = d
    for k in keys[:-1]:
        node = node[int(k)] if k.isdigit() else node[k]
    last = int(keys[-1]) if keys[-1].isdigit() else keys[-1]
    if value is None:
        del node[last]
    else:
        node[last] = value
    return d


def test_valid_spec_parses_every_kind():
    s = parse_spec(BASE)
    assert s.effects == ("direct", "indirect")
    assert [o.shape for o in s.objects] == ["sphere", "cube", "rectangle", "disk"]
    assert s.objects[0].material_name == "white"
    assert s.objects[1].material.specular_lobe and not s.objects[1].material.glossy
    assert s.objects[2].material.glossy
    assert s.objects[2].material.diffuse.kind == "checkerboard"
    assert s.emissive_objects[0].emission == (5.0, 5.0, 5.0)
    sun = s.lights[4]
    assert sun.params["direction"] == pytest.approx((0.0, 1.0, 0.0))  # normalised
    assert [lt.type for lt in s.lights] == ["point", "spot", "constant", "envmap", "sun", "sh"]


def test_to_dict_round_trips_and_is_json():
    s = parse_spec(BASE)
    d = json.loads(json.dumps(s.to_dict()))
    assert parse_spec(d) == s


def test_transform_matrix_order_scale_rotate_translate():
    t = Transform(translate=(1, 2, 3), rotate=(0, 90, 0), scale=(2, 1, 1))
    m = t.matrix()
    # x axis scaled by 2, then rotated 90 deg about y: (1,0,0) -> (0,0,-2), then translated
    x = [sum(m[i][j] * v for j, v in enumerate((1, 0, 0, 1))) for i in range(3)]
    assert x == pytest.approx([1, 2, 1])


@pytest.mark.parametrize(
    "path,value,fragment",
    [
        ("effects", ["direct", "subsurface"], "unknown effect"),
        ("effects", [], "non-empty"),
        ("effects", ["direct", "direct"], "twice"),
        ("objects.0.material", "gold", "unknown material 'gold'"),
        ("objects.0.shape", "torus", "must be one of"),
        ("objects.1.center", [0, 0, 0], "center/radius are for spheres"),
        ("objects.0.radius", -1, "must be >"),
        ("objects.2.transform", {"scale": [1, 0, 1]}, "must not be 0"),
        ("objects.2.colour", [1, 0, 0], "unknown key(s) colour"),
        ("objects.3.emission", [0, 0, 0], "must be positive"),
        ("materials.floor.roughness", 0, "must be >"),
        ("materials.white.reflectance", {"plaid": {}}, "a texture is"),
        ("materials.white.type", "velvet", "must be one of"),
        ("camera.type", "fisheye", "pinhole or thinlens"),
        ("camera.aperture_radius", 0.1, 'need type = "thinlens"'),
        ("camera.target", [0, 1, 4], "must differ"),
        ("lights.5.coefficients", [[1, 1, 1]] * 9, "must be 36 rows"),
        ("lights.4.direction", [0, 0, 0], "must not be zero"),
        ("lights.3.procedural", "desert", "must be 'sky'"),
        ("lights.0.intensity", [1, -1, 1], "must be >= 0"),
        ("render", {"max_depth": 1}, "render.max_depth"),
        ("objects", [], "non-empty list"),
    ],
)
def test_invalid_specs_name_the_key(path, value, fragment):
    with pytest.raises(SpecError) as info:
        parse_spec(spec_with(path, value), source="scene.toml")
    msg = str(info.value)
    assert msg.startswith("scene.toml: ")
    assert fragment in msg
    assert "\n" not in msg


def test_thinlens_needs_aperture_and_defaults_focus_to_target_distance():
    d = spec_with("camera.type", "thinlens")
    with pytest.raises(SpecError, match="aperture"):
        parse_spec(d)
    d["camera"]["aperture_radius"] = 0.05
    assert parse_spec(d).camera.focus_distance == pytest.approx(4.0)


def test_files_resolve_relative_to_the_spec(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    d = spec_with("objects.0", {"shape": "mesh", "file": "meshes/tri.obj"})
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps(d))
    s = load_spec(spec)
    assert s.objects[0].file == str((tmp_path / "meshes" / "tri.obj").resolve())
    d["objects"][0]["file"] = "meshes/missing.obj"
    spec.write_text(json.dumps(d))
    with pytest.raises(SpecError, match=r"missing\.obj"):
        load_spec(spec)


def test_load_spec_errors(tmp_path):
    with pytest.raises(SpecError, match="not found"):
        load_spec(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("effects = [direct")
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(bad)


def test_name_defaults_to_file_stem(tmp_path):
    p = tmp_path / "my_scene.toml"
    p.write_text('effects = ["direct"]\n[[objects]]\nshape = "sphere"\nemission = [1, 1, 1]\n')
    assert load_spec(p).name == "my_scene"


# --- [animation] and objects[i].motion (sequences) -------------------------------------------
@pytest.mark.parametrize(
    "animation",
    [
        {"camera_path": "orbit", "angle": -25},
        {"camera_path": "dolly", "fraction": 0.4},
        {"camera_path": "static"},
        {
            "camera_path": "keyframes",
            "keyframes": [
                {"origin": [0, 1, 4], "target": [0, 1, 0]},
                {"origin": [2, 1, 4]},
                {"target": [1, 0, 0]},
            ],
        },
    ],
)
def test_animation_parses_and_round_trips(animation):
    d = spec_with("animation", animation)
    d["objects"][1]["motion"] = {"translate": [0.5, 0, -1]}
    s = parse_spec(d)
    assert s.animation is not None and s.animation.camera_path == animation["camera_path"]
    assert s.objects[1].motion == (0.5, 0.0, -1.0) and s.objects[0].motion is None
    assert parse_spec(json.loads(json.dumps(s.to_dict()))) == s
    if animation["camera_path"] == "keyframes":  # a key without origin/target keeps the last
        assert [k.origin for k in s.animation.keyframes] == [(0, 1, 4), (2, 1, 4), (2, 1, 4)]
        assert [k.target for k in s.animation.keyframes] == [(0, 1, 0), (0, 1, 0), (1, 0, 0)]


def test_animation_defaults_and_absence():
    assert parse_spec(BASE).animation is None
    assert "animation" not in parse_spec(BASE).to_dict()
    assert parse_spec(spec_with("animation", {})).animation.angle == 10.0  # an orbit
    assert parse_spec(spec_with("animation", {"camera_path": "dolly"})).animation.fraction == 0.1


def test_a_sphere_placed_by_a_transform_round_trips():
    d = spec_with("objects.0", {"shape": "sphere", "transform": {"translate": [1, 2, 3]}})
    s = parse_spec(d)
    assert parse_spec(json.loads(json.dumps(s.to_dict()))) == s


@pytest.mark.parametrize(
    "path,value,fragment",
    [
        ("animation", {"camera_path": "crane"}, "must be one of orbit, dolly"),
        ("animation", {"camera_path": "dolly", "fraction": 1.0}, "must be < 1"),
        ("animation", {"camera_path": "dolly", "angle": 3}, "unknown key(s) angle"),
        ("animation", {"camera_path": "orbit", "angle": "a lot"}, "animation.angle"),
        ("animation", {"camera_path": "keyframes"}, "at least 2"),
        (
            "animation",
            {"camera_path": "keyframes", "keyframes": [{"origin": [0, 0, 1]}, {}]},
            "first keyframe needs both",
        ),
        (
            "animation",
            {
                "camera_path": "keyframes",
                "keyframes": [{"origin": [0, 0, 1], "target": [0, 0, 1]}] * 2,
            },
            "keyframes[0]: origin and target must differ",
        ),
        ("animation", [1, 2], "must be a table"),
        ("objects.1.motion", {"rotate": [0, 1, 0]}, "unknown key(s) rotate"),
        ("objects.1.motion", {}, "needs translate"),
        ("objects.1.motion", {"translate": [1, 2]}, "objects[1].motion.translate"),
    ],
)
def test_invalid_animation_names_the_key(path, value, fragment):
    with pytest.raises(SpecError) as info:
        parse_spec(spec_with(path, value), source="scene.toml")
    msg = str(info.value)
    assert msg.startswith("scene.toml: ") and fragment in msg and "\n" not in msg


def test_sun_direction_round_trips_bit_for_bit():
    d = copy.deepcopy(BASE)
    d["lights"] = [{"type": "sun", "direction": [0.3, 0.7, 0.2], "irradiance": [1, 1, 1]}]
    s1 = parse_spec(d)
    s2 = parse_spec(s1.to_dict())
    s3 = parse_spec(s2.to_dict())
    assert s1 == s2 == s3


def test_collect_specs_expands_folders_in_name_order(tmp_path: Path) -> None:
    from mcdenoise.render.scene_spec import collect_specs

    (tmp_path / "d").mkdir()
    for name in ("b.toml", "a.toml", "c.json"):
        (tmp_path / "d" / name).write_text("", encoding="utf-8")
    (tmp_path / "x.toml").write_text("", encoding="utf-8")
    got = collect_specs(["x.toml", "d", "x.toml"], base=tmp_path)
    assert [p.relative_to(tmp_path).as_posix() for p in got] == [
        "x.toml",
        "d/a.toml",
        "d/b.toml",
        "x.toml",  # named twice: listed twice (two images)
    ]
    (tmp_path / "empty").mkdir()
    with pytest.raises(SpecError, match=r"empty: folder holds no \*\.toml scene spec"):
        collect_specs([tmp_path / "empty"])
    with pytest.raises(SpecError, match=r"nope\.toml: scene spec not found"):
        collect_specs(["nope.toml"], base=tmp_path)
