"""Procedural random scenes (the package mcdenoise/render/random_scenes/).

Specs are plain data, so most checks need no renderer: determinism (and a pinned hash of the
specs of one seed), schema round trip, effect plans, the geometry promises (camera outside
every object, every subject in frame, thin lens focused on a subject), non-negative SH
lighting, that the documented distribution is exactly the data the generator draws from, and
that the empirical frequencies over many specs match it. A few tiny renders
(``@pytest.mark.mitsuba``, ``scalar_rgb``, 16×16 at 2 spp) check that Mitsuba accepts the
specs and lit scenes are finite and not black.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import importlib.util
import json
import math
import random
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from mcdenoise.errors import InputError, McdenoiseError
from mcdenoise.render import random_scenes as rs
from mcdenoise.render.effects import plan_effects
from mcdenoise.render.random_scenes import distribution as dist_module
from mcdenoise.render.scene_spec import EFFECTS, LIGHTS, MATERIALS, SHAPES, TEXTURES, parse_spec
from mcdenoise.render.sh import sh_to_latlong_with_stats

N_FREQ = 500  # specs for the frequency checks (about 1.5 s to generate)
SEED = 20240611


@pytest.fixture(scope="module")
def scenes() -> list[rs.RandomScene]:
    return [rs.random_scene(SEED, i) for i in range(N_FREQ)]


# ------------------------------------------------------------------------- determinism


def test_same_seed_and_index_give_equal_specs():
    a, b = rs.random_spec(3, 17), rs.random_spec(3, 17)
    assert a == b
    assert json.dumps(a.to_dict(), sort_keys=True) == json.dumps(b.to_dict(), sort_keys=True)


def test_index_and_seed_change_the_spec():
    base = rs.random_spec(3, 17).to_dict()
    for other in (rs.random_spec(3, 18), rs.random_spec(4, 17)):
        d = other.to_dict()
        assert d["name"] != base["name"]
        del d["name"], d["description"]
        assert d != {k: v for k, v in base.items() if k not in ("name", "description")}


def test_global_random_state_is_not_used():
    first = rs.random_spec(9, 2)
    np.random.seed(123)  # noqa: NPY002 - the legacy global state is what is tested
    random.seed(123)
    np.random.random(1000)  # noqa: NPY002 - move the global generator on
    assert rs.random_spec(9, 2) == first


def test_index_does_not_depend_on_what_was_generated_before():
    later = rs.random_specs(3, seed=5, start=40)
    assert later == [rs.random_spec(5, i) for i in (40, 41, 42)]


def test_specs_of_seed_0_are_pinned():
    """The generator's output for a fixed seed never changes unnoticed (refactors included).

    The hash was recorded from the single-module generator before it was split into the
    package (``sha256`` of the sorted-key JSON of specs 0..19 of seed 0, asset folder replaced
    by ``<assets>``). A deliberate change of the distribution changes it: record the new one.
    """
    root = str(rs.asset_dir().resolve())
    text = "\n".join(
        json.dumps(rs.random_spec(0, i).to_dict(), sort_keys=True).replace(root, "<assets>")
        for i in range(20)
    )
    first = rs.random_scene(0, 0)
    assert (first.archetype, first.variant, first.subjects) == (
        "tabletop",
        "spot",
        (1, 2, 3, 4, 5, 6),
    )
    assert first.spec.camera.fov == 45.11 and first.spec.camera.origin == (3.0532, 3.1606, -0.1696)
    digest = hashlib.sha256(text.encode()).hexdigest()
    assert digest == "fe34426b2bc688f10aece573443d8da3221ce17ee3ad8c94a6dbdb41062f02ae"


@pytest.mark.parametrize("seed,index", [(-1, 0), (0, -3), (1.5, 0), (True, 0), ("1", 0)])
def test_bad_seed_or_index_is_a_one_line_user_error(seed, index):
    with pytest.raises(InputError) as err:
        rs.random_spec(seed, index)
    assert isinstance(err.value, McdenoiseError) and "\n" not in str(err.value)


# ------------------------------------------------------------------------- validity


def test_200_specs_round_trip_and_plan():
    for i in range(200):
        spec = rs.random_spec(11, i)
        d = spec.to_dict()
        assert parse_spec(d) == spec, i
        assert parse_spec(json.loads(json.dumps(d))) == spec, i  # as a manifest stores it
        plan = plan_effects(spec)
        assert plan.thinlens == (spec.camera.type == "thinlens")


def test_effects_are_exactly_what_the_content_implies(scenes):
    for sc in scenes:
        spec, eff = sc.spec, set(sc.spec.effects)
        mats = [o.material for o in spec.objects]
        assert list(spec.effects) == [e for e in EFFECTS if e in eff]
        assert ("dof" in eff) == (spec.camera.type == "thinlens")
        if sc.archetype == "ao":
            assert eff == {"ao"} and spec.render.ao_radius and spec.camera.type == "pinhole"
            continue
        assert "direct" in eff and spec.has_lights
        assert ("glossy" in eff) == any(m.glossy for m in mats)
        if "caustics" in eff:
            assert "indirect" in eff and any(m.specular_lobe for m in mats)
        if sc.archetype == "interior":
            assert "indirect" in eff
        if any(m.type == "dielectric" for m in mats) and "indirect" in eff:
            assert spec.render.max_depth >= 8


def _unit_box(o) -> tuple[np.ndarray, np.ndarray]:
    """World-to-local matrix of an object and its local box half-extents / kind."""
    if o.shape == "sphere":
        m = np.diag([o.radius] * 3 + [1.0])
        m[:3, 3] = o.center
        return np.linalg.inv(np.asarray(o.transform.matrix()) @ m), np.ones(3)
    m = np.asarray(o.transform.matrix())
    if o.shape == "mesh":
        asset = {a.file: a for a in rs.mesh_assets()}[o.file]
        return np.linalg.inv(m), np.asarray(asset.half_extents)
    return np.linalg.inv(m), np.ones(3)


def _inside(o, point: np.ndarray) -> bool:
    inv, half = _unit_box(o)
    p = (inv @ np.append(point, 1.0))[:3]
    if o.shape == "sphere":
        return bool(np.linalg.norm(p) <= 1.0)
    if o.shape == "cylinder":
        return bool(math.hypot(p[0], p[1]) <= 1.0 and 0.0 <= p[2] <= 1.0)
    if o.shape in ("cube", "mesh"):
        return bool(np.all(np.abs(p) <= half))
    return bool(abs(p[2]) < 1e-4 and np.all(np.abs(p[:2]) <= 1.0))  # on a rectangle / disk


def _centre(o) -> np.ndarray:
    if o.shape == "sphere":
        return np.asarray(o.center)
    local = np.array([0.0, 0.0, 0.5, 1.0]) if o.shape == "cylinder" else np.array([0, 0, 0, 1.0])
    return (np.asarray(o.transform.matrix()) @ local)[:3]


def _camera_frame(cam) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    o = np.asarray(cam.origin)
    f = np.asarray(cam.target) - o
    f /= np.linalg.norm(f)
    right = np.cross(f, cam.up)
    right /= np.linalg.norm(right)
    return o, f, right, np.cross(right, f)


def test_camera_is_outside_every_object_and_frames_every_subject(scenes):
    for sc in scenes:
        spec = sc.spec
        cam = spec.camera
        origin, f, right, up = _camera_frame(cam)
        for i, o in enumerate(spec.objects):
            assert not _inside(o, origin), (spec.name, i, o.shape)
        assert sc.subjects, spec.name
        half = math.tan(math.radians(cam.fov) / 2)  # square images: same both ways
        for i in sc.subjects:
            d = _centre(spec.objects[i]) - origin
            depth = d @ f
            assert depth > 0, (spec.name, i)
            assert abs(d @ right) / depth <= half and abs(d @ up) / depth <= half, (spec.name, i)


def test_subjects_are_the_placed_objects_not_room_or_lights(scenes):
    for sc in scenes:
        objs = sc.spec.objects
        assert len(sc.subjects) <= 8
        for i in sc.subjects:
            assert objs[i].emission is None
            assert objs[i].shape != "mesh" or objs[i].file in {a.file for a in rs.mesh_assets()}
        if sc.archetype == "interior" or sc.variant == "room":  # floor, ceiling, walls
            rooms = [o for i, o in enumerate(objs) if i not in sc.subjects]
            assert sum(o.shape == "rectangle" and o.emission is None for o in rooms) >= 6


def test_thin_lens_focuses_on_a_subject(scenes):
    lens = [sc for sc in scenes if sc.spec.camera.type == "thinlens"]
    assert lens
    for sc in lens:
        cam = sc.spec.camera
        origin, f, _, _ = _camera_frame(cam)
        depths = [(_centre(sc.spec.objects[i]) - origin) @ f for i in sc.subjects]
        assert min(abs(cam.focus_distance - d) for d in depths) < 2e-3 * cam.focus_distance
        assert 0.005 * cam.focus_distance <= cam.aperture_radius <= 0.045 * cam.focus_distance


def test_sh_lighting_is_non_negative_so_nothing_is_clamped(scenes):
    lights = [lt for sc in scenes for lt in sc.spec.lights if lt.type == "sh"]
    assert len(lights) > 20
    for lt in lights:
        coeffs = np.asarray(lt.params["coefficients"])
        img, stats = sh_to_latlong_with_stats(coeffs, 128, 65)  # what sh_envmap_dict bakes
        assert stats.texel_fraction == 0.0
        assert img.mean() > 0.1  # and it is not dark


def test_random_sh_coefficients_mean_radiance_and_positivity():
    for k in range(20):
        rng = np.random.default_rng([1, k])
        coeffs = rs.random_sh_coefficients(rng, mean_radiance=0.7)
        assert coeffs.shape == (36, 3)
        img, stats = sh_to_latlong_with_stats(coeffs, 128, 65)
        assert stats.texel_fraction == 0.0
        y00 = 0.5 / math.sqrt(math.pi)
        lum = coeffs[0] * y00 @ np.array([0.2126, 0.7152, 0.0722])
        assert lum == pytest.approx(0.7, rel=0.02)
        assert np.std(img.mean(axis=2)) > 0.05  # directional, not a constant environment


# ------------------------------------------------------------------------- distribution


def _variants(value, path=""):
    """(path, value with one parameter changed) for every parameter inside ``value``."""
    if dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            for sub, changed in _variants(getattr(value, f.name), f"{path}.{f.name}"):
                yield sub, dataclasses.replace(value, **{f.name: changed})
    elif isinstance(value, dict):
        for key, item in value.items():
            for sub, changed in _variants(item, f"{path}[{key}]"):
                yield sub, {**value, key: changed}
    elif isinstance(value, tuple):
        for i, item in enumerate(value):
            for sub, changed in _variants(item, f"{path}[{i}]"):
                yield sub, (*value[:i], changed, *value[i + 1 :])
    elif isinstance(value, str):
        yield path, value + "x"
    elif isinstance(value, int):
        yield path, value + 1
    else:
        yield path, value * 0.5 + 0.013


def test_the_documented_distribution_is_the_data():
    """One source of truth: the text is rendered from DISTRIBUTION, writes no number of its
    own, and shows every parameter (changing any one changes the text)."""
    text = rs.describe_distribution()
    assert dist_module.template_numbers() == []
    assert text in dist_module.__doc__
    seen = 0
    for path, changed in _variants(rs.DISTRIBUTION):
        assert rs.describe_distribution(changed) != text, f"{path} is not in the text"
        seen += 1
    assert seen > 150  # every leaf of the nested data was tried


def test_the_generator_draws_from_the_data():
    """Changing the data changes the scenes: the code has no second copy of these numbers."""
    d = rs.DISTRIBUTION
    replace = dataclasses.replace
    only_tabletop = replace(
        d,
        archetypes={"tabletop": 1.0},
        subjects=replace(d.subjects, shapes={"cube": 1.0}),
        materials=replace(d.materials, types={"dielectric": 1.0}),
        camera=replace(d.camera, thinlens_prob=1.0),
        lights=replace(d.lights, warm=(1.0, 1.0, 1.0), cool=(1.0, 1.0, 1.0)),
        effects=replace(d.effects, rr_depth=3, dielectric_min_depth=11),
    )
    for i in range(15):
        sc = rs.random_scene(4, i, distribution=only_tabletop)
        spec = sc.spec
        assert sc.archetype == "tabletop" and spec.camera.type == "thinlens"
        assert spec.render.rr_depth == 3
        assert all(spec.objects[j].shape == "cube" for j in sc.subjects)
        assert all(spec.objects[j].material.type == "dielectric" for j in sc.subjects)
        if "indirect" in spec.effects:
            assert spec.render.max_depth >= 11
        for lt in spec.lights:  # white lights of luminance 1
            if lt.type in ("point", "spot"):
                rgb = np.asarray(lt.params["intensity"])
                assert np.allclose(rgb, rgb[0], rtol=1e-3), rgb
    assert rs.random_scene(4, 0) == rs.random_scene(4, 0, distribution=d)


def _share(counter: collections.Counter, key: str) -> float:
    return counter[key] / sum(counter.values())


def test_archetype_frequencies_match_the_documented_probabilities(scenes):
    counts = collections.Counter(sc.archetype for sc in scenes)
    for name, p in rs.ARCHETYPES.items():
        assert abs(_share(counts, name) - p) < 0.06, (name, counts)
    variants = {sc.variant for sc in scenes}
    for v in ("ceiling", "window+panel", "window+sun", "door+panel", "room", "ground", "sh+sun"):
        assert v in variants, v


def test_every_shape_material_texture_light_and_effect_occurs(scenes):
    shapes, mats, textures, lights, effects, meshes, counts = (
        collections.Counter() for _ in range(7)
    )
    for sc in scenes:
        spec = sc.spec
        counts[len(sc.subjects)] += 1
        effects.update(spec.effects)
        lights.update(lt.type for lt in spec.lights)
        lights.update("area" for o in spec.objects if o.emission is not None)
        for o in spec.objects:
            m = o.material
            textures.update(
                t.kind
                for t in (m.reflectance, m.diffuse)
                if m.type in ("diffuse", "plastic", "roughplastic")
            )
        for i in sc.subjects:
            o = spec.objects[i]
            shapes[o.shape] += 1
            if sc.archetype != "ao":
                mats[o.material.type] += 1
            if o.shape == "mesh":
                meshes[Path(o.file).name] += 1
    assert set(shapes) == set(SHAPES)
    assert set(mats) == set(MATERIALS)
    assert set(TEXTURES) | {"constant"} <= set(textures)
    assert set(LIGHTS) | {"area"} == set(lights)
    assert set(effects) == set(EFFECTS)
    assert set(meshes) == {a.name for a in rs.mesh_assets()}
    assert set(counts) == set(range(1, 9))
    # loose bounds around the documented probabilities (occlusion culling and retries shift
    # them a little)
    for name, p in rs.MATERIAL_WEIGHTS.items():
        assert abs(_share(mats, name) - p) < 0.05, (name, mats)
    for name, p in rs.SHAPE_WEIGHTS.items():
        assert abs(_share(shapes, name) - p) < 0.07, (name, shapes)
    rough_glass = sum(
        sc.spec.objects[i].material.roughness > 0
        for sc in scenes
        for i in sc.subjects
        if sc.spec.objects[i].material.type == "dielectric" and sc.archetype != "ao"
    )
    assert 0.15 < rough_glass / mats["dielectric"] < 0.45


def test_effect_switch_frequencies(scenes):
    lit = [sc for sc in scenes if sc.archetype != "ao"]
    thin = sum(sc.spec.camera.type == "thinlens" for sc in lit) / len(lit)
    assert abs(thin - rs.THINLENS_PROB) < 0.06
    eligible = [
        sc
        for sc in lit
        if "indirect" in sc.spec.effects and any(o.material.specular_lobe for o in sc.spec.objects)
    ]
    caustic = sum("caustics" in sc.spec.effects for sc in eligible) / len(eligible)
    assert abs(caustic - rs.CAUSTICS_PROB) < 0.1  # and the rest exercise the cutting integrator
    for arch in ("outdoor", "tabletop", "sh"):
        group = [sc for sc in lit if sc.archetype == arch]
        share = sum("indirect" in sc.spec.effects for sc in group) / len(group)
        assert abs(share - rs.INDIRECT_PROB[arch]) < 0.15, arch
    fireflies = sum(
        any(o.emission is not None and o.shape == "sphere" for o in sc.spec.objects) for sc in lit
    )
    assert fireflies > 0.05 * len(lit)  # small bright bulbs


# ------------------------------------------------------------------------- assets


def test_assets_are_small_and_reproducible_by_their_script(tmp_path):
    folder = rs.asset_dir()
    shipped = sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix != ".py")
    assert sum(p.stat().st_size for p in shipped) < 400_000
    made = _make_assets_script().make_assets(tmp_path)
    assert sorted(p.relative_to(tmp_path) for p in made) == sorted(
        p.relative_to(folder) for p in shipped
    )
    for p in made:
        ours = folder / p.relative_to(tmp_path)
        if p.suffix == ".exr":  # OpenImageIO stamps a DateTime: compare the pixels
            import OpenImageIO as oiio

            a = oiio.ImageBuf(str(p)).get_pixels(oiio.FLOAT)
            b = oiio.ImageBuf(str(ours)).get_pixels(oiio.FLOAT)
            assert np.array_equal(a, b)
        else:
            assert p.read_bytes() == ours.read_bytes(), p.name


def test_mesh_assets_are_closed_outward_and_indexed():
    make_assets = _make_assets_script()
    for asset in rs.mesh_assets():
        v, f = _read_mesh(Path(asset.file))
        assert make_assets.signed_volume(v, f) > 0.05, asset.name
        assert np.allclose(np.abs(v).max(0), asset.half_extents, atol=1e-4), asset.name
        assert np.linalg.norm(v, axis=1).max() == pytest.approx(asset.radius, abs=1e-4)
        # closed and consistently oriented: every directed edge is matched by its reverse
        # (faceted meshes repeat vertices per face, so weld them by position first)
        welded = _weld(v, f)
        directed = collections.Counter()
        for tri in welded:
            for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
                if a != b:
                    directed[(a, b)] += 1
        assert all(directed[(b, a)] == n for (a, b), n in directed.items()), asset.name


def _make_assets_script() -> ModuleType:
    """The asset script as a module (loaded by path: it is package data, not a package)."""
    path = rs.asset_dir() / "make_assets.py"
    spec = importlib.util.spec_from_file_location("make_assets", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _weld(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    _, inverse = np.unique(np.round(v, 5), axis=0, return_inverse=True)
    return inverse.reshape(-1)[f]


def _read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Positions and triangles of the packaged OBJ / binary PLY files."""
    if path.suffix == ".obj":
        v, f = [], []
        for line in path.read_text().splitlines():
            if line.startswith("v "):
                v.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                f.append([int(x.split("/")[0]) - 1 for x in line.split()[1:4]])
        return np.asarray(v), np.asarray(f)
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    lines = head.decode().splitlines()
    nv = int(next(x for x in lines if x.startswith("element vertex")).split()[-1])
    nf = int(next(x for x in lines if x.startswith("element face")).split()[-1])
    v = np.frombuffer(body[: 12 * nv], dtype="<f4").reshape(nv, 3).astype(np.float64)
    faces = np.frombuffer(body[12 * nv :], dtype=np.dtype([("n", "u1"), ("i", "<i4", 3)]))
    assert len(faces) == nf and np.all(faces["n"] == 3)
    return v, faces["i"].astype(np.int64)


# ------------------------------------------------------------------------- renders


def _render_indices() -> list[int]:
    """Six indices of seed 0 covering every archetype (plus a window-lit interior)."""
    want = ["interior", "outdoor", "tabletop", "sh", "ao"]
    picked: list[int] = []
    window = None
    for i in range(200):
        sc = rs.random_scene(0, i)
        if sc.archetype in want:
            want.remove(sc.archetype)
            picked.append(i)
        elif window is None and sc.variant.startswith(("window", "door")):
            window = i
        if not want and window is not None:
            break
    return [*picked, window]


@pytest.mark.mitsuba
@pytest.mark.parametrize("index", _render_indices())
def test_random_specs_render_finite_and_lit(index):
    mi = pytest.importorskip("mitsuba")
    from mcdenoise.render.mitsuba_setup import ensure_variant
    from mcdenoise.render.scenes import scene_dict

    ensure_variant("scalar_rgb")
    sc = rs.random_scene(0, index)
    plan = plan_effects(sc.spec)
    scene = mi.load_dict(scene_dict(sc.spec, plan, width=16, height=16))
    img = np.asarray(mi.render(scene, spp=2, seed=index), dtype=np.float64)
    assert img.shape == (16, 16, 3)
    assert np.isfinite(img).all() and (img >= 0).all()
    assert img.mean() > 1e-3, (sc.archetype, sc.variant)  # not black
    if sc.archetype == "ao":
        assert img.max() <= 1.0 + 1e-6 and img.min() < 1.0  # occlusion somewhere
