"""Tests for mcdenoise.render.integrators: ``mcd_ao`` and ``mcd_path`` (tiny Mitsuba renders)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from mcdenoise.errors import InputError  # noqa: E402
from mcdenoise.render.integrators import (  # noqa: E402
    ao_integrator,
    path_integrator,
    register_integrators,
    use_variant,
)

pytestmark = pytest.mark.mitsuba


def T():  # Mitsuba's T() idiom, resolved after a variant is set
    return mi.ScalarTransform4f()


@pytest.fixture(autouse=True)
def variant() -> str:
    """llvm_ad_rgb where the LLVM backend works, else scalar_rgb; integrators registered."""
    return use_variant()


# --------------------------------------------------------------------------- helpers


def _film(res: int) -> dict:
    return {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}


def _camera(origin, target, res: int, up=(0, 1, 0), fov: float = 40.0) -> dict:
    return {
        "type": "perspective",
        "fov": fov,
        "to_world": T().look_at(origin=list(origin), target=list(target), up=list(up)),
        "film": _film(res),
        "sampler": {"type": "independent"},
    }


def _plane(y: float, size: float = 1000.0, facing_up: bool = True) -> dict:
    angle = -90 if facing_up else 90
    return {
        "type": "rectangle",
        "to_world": T().translate([0, y, 0]).rotate([1, 0, 0], angle).scale(size),
        "bsdf": {"type": "diffuse"},
    }


def render_channels(scene, integrator: dict, spp: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Render and return the film's channel groups by name (``<root>`` = RGB, AOV prefixes)."""
    mi.render(scene, integrator=mi.load_dict(integrator), spp=spp, seed=seed)
    bitmap = scene.sensors()[0].film().bitmap()
    return {name: np.array(b, dtype=np.float64) for name, b in bitmap.split()}


def ao_at(scene, origin, target, n: int, seed: int = 0, **params) -> np.ndarray:
    """``n`` mcd_ao estimates (one per sample) for the camera ray ``origin → target``."""
    integ = mi.load_dict(ao_integrator(**params))
    d = np.asarray(target, float) - np.asarray(origin, float)
    d /= np.linalg.norm(d)
    sampler = mi.load_dict({"type": "independent"})
    if dr.is_jit_v(mi.Float):
        sampler.seed(seed, n)
        o = mi.Point3f(*(dr.full(mi.Float, float(v), n) for v in origin))
        ray = mi.RayDifferential3f(mi.Ray3f(o, mi.Vector3f(*(float(v) for v in d))))
        value, _valid, aovs = integ.sample(scene, sampler, ray, None, mi.Bool(True))
        assert aovs == []
        return np.array(value)[0]
    sampler.seed(seed)
    out = np.empty(n)
    ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(*origin), mi.Vector3f(*d)))
    for k in range(n):
        out[k] = integ.sample(scene, sampler, ray, None, True)[0][0]
    return out


def _eroded(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 4-neighbours are in ``mask`` too (no partial-coverage edge pixels)."""
    m = mask.copy()
    m[1:] &= mask[:-1]
    m[:-1] &= mask[1:]
    m[:, 1:] &= mask[:, :-1]
    m[:, :-1] &= mask[:, 1:]
    m[0] = m[-1] = False
    m[:, 0] = m[:, -1] = False
    return m


# --------------------------------------------------------------------------- parameters


@pytest.mark.parametrize(
    ("factory", "kwargs", "word"),
    [
        (ao_integrator, {"radius": 0.0}, "radius"),
        (ao_integrator, {"radius": -1.0}, "radius"),
        (ao_integrator, {"radius": float("nan")}, "radius"),
        (ao_integrator, {"rays": 0}, "rays"),
        (ao_integrator, {"rays": 1.5}, "rays"),
        (ao_integrator, {"radius": True}, "radius"),
        (ao_integrator, {"background": 2.0}, "background"),
        (path_integrator, {"max_depth": -2}, "max_depth"),
        (path_integrator, {"rr_depth": 0}, "rr_depth"),
    ],
)
def test_bad_parameters_raise_one_line_input_error(factory, kwargs, word):
    with pytest.raises(InputError, match=word) as info:
        factory(**kwargs)
    assert "\n" not in str(info.value)


def test_docstring_examples():
    import doctest

    import mcdenoise.render.integrators as module

    failed, attempted = doctest.testmod(module)
    assert attempted > 0 and failed == 0


def test_parameters_accept_numpy_scalars():
    d = ao_integrator(radius=np.float32(0.5), rays=np.int64(3))
    assert d["rays"] == 3 and type(d["rays"]) is int
    assert mi.load_dict(d) is not None


def test_plugin_constructor_checks_parameters_too():
    with pytest.raises(RuntimeError, match="radius must be > 0"):
        mi.load_dict({"type": "mcd_ao", "radius": -1.0})
    with pytest.raises(RuntimeError, match="unreferenced"):
        mi.load_dict({"type": "mcd_path", "max_depht": 3})


def test_register_is_idempotent_and_plugins_describe_themselves():
    register_integrators()
    register_integrators()
    assert "radius=0.5" in str(mi.load_dict(ao_integrator(radius=0.5)))
    assert "caustics=False" in str(mi.load_dict(path_integrator(caustics=False)))


# --------------------------------------------------------------------------- mcd_ao


def test_ao_open_plane_seen_from_above_is_one():
    scene = mi.load_dict(
        {"type": "scene", "sensor": _camera((0, 2, 0.5), (0, 0, 0), 16), "floor": _plane(0.0)}
    )
    for radius in (0.5, math.inf):
        rgb = render_channels(scene, ao_integrator(radius=radius, rays=2), spp=4)["<root>"]
        assert rgb.shape == (16, 16, 3)
        np.testing.assert_array_equal(rgb, 1.0)


def test_ao_camera_miss_gives_background():
    scene = mi.load_dict(
        {"type": "scene", "sensor": _camera((0, 1, 0), (0, 5, 1), 8), "floor": _plane(0.0)}
    )
    rgb = render_channels(scene, ao_integrator(background=0.25), spp=2)["<root>"]
    np.testing.assert_allclose(rgb, 0.25)


def test_ao_between_parallel_planes_matches_cosine_weighted_formula():
    # Floor point under a ceiling at height h: a cosine-distributed ray is unoccluded within
    # radius r iff cos θ < h / r, so AO = (h / r)² (uniform hemisphere sampling would give h/r).
    scene = mi.load_dict({"type": "scene", "floor": _plane(0.0), "ceiling": _plane(1.0)})
    n = 8192 if dr.is_jit_v(mi.Float) else 2048
    for r in (1.25, 2.0, 4.0):
        ao = ao_at(scene, (0, 0.5, 0), (0, 0, 0), n, radius=r)
        expected = (1.0 / r) ** 2
        assert set(np.unique(ao)) <= {0.0, 1.0}  # rays=1: every sample is 0 or 1
        assert abs(ao.mean() - expected) < 4.5 * math.sqrt(expected * (1 - expected) / n)
    assert ao_at(scene, (0, 0.5, 0), (0, 0, 0), 256, radius=0.9).min() == 1.0
    assert ao_at(scene, (0, 0.5, 0), (0, 0, 0), 256).max() == 0.0  # unbounded radius


def test_ao_flips_the_hemisphere_towards_the_viewer():
    # Floor (normal +Y) seen from below, an occluder 0.5 below it, the ceiling 1 above it:
    # the hemisphere must face down, AO = (0.5 / r)²; facing up would give (1 / r)².
    scene = mi.load_dict(
        {
            "type": "scene",
            "floor": _plane(0.0),
            "ceiling": _plane(1.0),
            "below": _plane(-0.5),
        }
    )
    n = 4096 if dr.is_jit_v(mi.Float) else 1024
    ao = ao_at(scene, (0, -0.25, 0), (0, 0, 0), n, radius=2.0, rays=4)
    assert abs(ao.mean() - 0.0625) < 0.02
    ao_top = ao_at(scene, (0, 0.5, 0), (0, 0, 0), n, radius=2.0, rays=4)
    assert abs(ao_top.mean() - 0.25) < 0.03


def test_ao_closed_box_corner_darker_than_face_centre_and_monotone_in_radius():
    # Seen from inside a closed cube [-1, 1]^3 (outward normals: the flip matters here too).
    scene = mi.load_dict({"type": "scene", "box": {"type": "cube", "bsdf": {"type": "diffuse"}}})
    n = 2048 if dr.is_jit_v(mi.Float) else 512
    centre, corner = (0.0, -1.0, 0.0), (0.9, -1.0, 0.9)
    face = ao_at(scene, (0, 0, 0), centre, n, radius=0.5)
    near_corner = ao_at(scene, (0, 0, 0), corner, n, radius=0.5)
    assert face.min() == 1.0  # every other wall is >= 1 away from the face centre
    assert 0.05 < near_corner.mean() < face.mean() - 0.2

    radii = (0.5, 1.2, 1.6, 2.0, 2.5)  # the farthest wall point is sqrt(6) = 2.45 away
    runs = [ao_at(scene, (0, 0, 0), centre, n, seed=3, radius=r) for r in radii]
    means = [run.mean() for run in runs]
    assert means[0] == 1.0 and means[-1] == 0.0
    assert all(a > b for a, b in itertools.pairwise(means))
    # Same seed → same directions: occluded within r implies occluded within any r' > r.
    for a, b in itertools.pairwise(runs):
        assert (b <= a).all()


# --------------------------------------------------------------------------- mcd_path


def _glass_box_scene(res: int):
    """Cornell box with a glass sphere (delta BSDF) and a rough metal sphere (glossy)."""
    d = mi.cornell_box()
    d["sensor"]["film"] = _film(res)
    del d["small-box"], d["large-box"]
    d["glass"] = {
        "type": "sphere",
        "center": [0.35, -0.65, 0.3],
        "radius": 0.3,
        "bsdf": {"type": "dielectric"},
    }
    d["metal"] = {
        "type": "sphere",
        "center": [-0.4, -0.7, -0.2],
        "radius": 0.25,
        "bsdf": {"type": "roughconductor", "alpha": 0.2},
    }
    return mi.load_dict(d)


def _mean_and_var(scene, integrator: dict, spp: int, seed: int):
    """Per-pixel mean and variance of the mean, from Mitsuba's ``moment`` integrator."""
    ch = render_channels(scene, {"type": "moment", "nested": integrator}, spp, seed)
    m1, m2 = ch["nested"], ch["m2_nested"]
    return m1, np.maximum(m2 - m1 * m1, 0.0) / spp


def test_mcd_path_with_caustics_agrees_with_mitsuba_path():
    if not dr.is_jit_v(mi.Float):
        pytest.skip("needs a JIT variant to be quick (scalar is covered below)")
    scene = _glass_box_scene(32)
    spp = 256
    ref, ref_var = _mean_and_var(scene, {"type": "path", "max_depth": 8}, spp, seed=0)
    out, out_var = _mean_and_var(scene, path_integrator(max_depth=8), spp, seed=1)
    alt, alt_var = _mean_and_var(scene, path_integrator(max_depth=8, caustics=False), spp, 2)

    def z_of_means(a, va, b, vb):
        return (a.mean() - b.mean()) / math.sqrt((va.sum() + vb.sum()) / a.size**2)

    def chi2_per_pixel(a, va, b, vb):
        v = va + vb
        keep = v > 0
        return float(((a - b)[keep] ** 2 / v[keep]).mean())

    def relmse(a, b):
        return float(((a - b) ** 2 / (b * b + 0.01)).mean())

    assert abs(z_of_means(out, out_var, ref, ref_var)) < 4.0
    chi2 = chi2_per_pixel(out, out_var, ref, ref_var)
    assert 0.8 < chi2 < 1.2, chi2  # differences are pure noise
    assert relmse(out, ref) < 0.025
    # The test can tell a biased integrator apart: no caustics is visibly different.
    assert chi2_per_pixel(alt, alt_var, ref, ref_var) > 1.3


@pytest.mark.skipif(
    tuple(int(v) for v in mi.__version__.split(".")[:2]) != (3, 9),
    reason="relies on Mitsuba 3.9's order of random numbers in path; the statistical test "
    "above is the version-independent contract",
)
@pytest.mark.parametrize("scalar", [False, True])
def test_same_seed_reproduces_mitsuba_path_sample_for_sample(scalar):
    # mcd_path draws its random numbers in the order of Mitsuba's path, so with caustics on
    # and the same seed the two images agree to float rounding (a strong regression test).
    if scalar:
        use_variant("scalar_rgb")
    try:
        scene = _glass_box_scene(10 if scalar else 24)
        spp = 4 if scalar else 16
        for depth, hide in ((-1, False), (3, True)):
            ref = {"type": "path", "max_depth": depth, "hide_emitters": hide}
            a = render_channels(scene, ref, spp, seed=7)["<root>"]
            b = render_channels(scene, path_integrator(max_depth=depth, hide_emitters=hide), spp, 7)
            np.testing.assert_allclose(b["<root>"], a, rtol=1e-5, atol=1e-6)
    finally:
        use_variant()


def _caustic_scene(res: int):
    return mi.load_dict(
        {
            "type": "scene",
            "sensor": _camera((0, 3.5, 3.5), (0, 0, 0), res),
            "floor": {
                "type": "rectangle",
                "to_world": T().rotate([1, 0, 0], -90).scale(3),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.8}},
            },
            "ball": {
                "type": "sphere",
                "center": [0, 0.75, 0],
                "radius": 0.5,
                "bsdf": {"type": "dielectric"},
            },
            "lamp": {
                "type": "sphere",
                "center": [0, 3.0, 0],
                "radius": 0.4,
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 10.0}},
            },
        }
    )


def test_no_caustics_darkens_the_floor_under_a_glass_ball_only():
    jit = dr.is_jit_v(mi.Float)
    res, spp = (32, 256) if jit else (12, 16)
    scene = _caustic_scene(res)
    pos = render_channels(scene, {"type": "aov", "aovs": "pp:position"}, spp=4)["pp"]
    on = render_channels(scene, path_integrator(max_depth=8), spp, seed=1)["<root>"].mean(-1)
    off = render_channels(scene, path_integrator(max_depth=8, caustics=False), spp, 2)
    off = off["<root>"].mean(-1)

    r = np.hypot(pos[..., 0], pos[..., 2])
    floor = np.abs(pos[..., 1]) < 1e-4  # every position sample in the pixel on the floor
    under, far = floor & (r < 0.3), _eroded(floor) & (r > 1.2)
    ball = _eroded(pos[..., 1] > 0.3)
    assert under.sum() >= 4 and far.sum() >= 20 and ball.sum() >= 4
    # The focused caustic under the ball is gone ...
    assert off[under].mean() < 0.2 * on[under].mean()
    # ... directly lit floor is unchanged within noise (3 % at these sample counts) ...
    tolerance = 0.03 if jit else 0.15
    assert abs(off[far].mean() / on[far].mean() - 1.0) < tolerance
    # ... and the ball itself is still rendered (camera → glass paths are kept).
    assert off[ball].mean() > 0.3 * on[ball].mean() > 0


def test_max_depth_two_is_direct_light_only():
    # Cornell box: the light faces down, so the ceiling next to it gets only indirect light.
    d = mi.cornell_box()
    d["sensor"]["film"] = _film(32)
    scene = mi.load_dict(d)
    spp = 64 if dr.is_jit_v(mi.Float) else 4
    pos = render_channels(scene, {"type": "aov", "aovs": "pp:position"}, spp=16)["pp"]
    ceiling = _eroded(pos[..., 1] > 1.0 - 1e-5)
    assert ceiling.sum() >= 10
    direct = render_channels(scene, path_integrator(max_depth=2), spp)["<root>"]
    bounce = render_channels(scene, path_integrator(max_depth=3), spp)["<root>"]
    assert (direct[ceiling] == 0.0).all()
    assert (bounce[ceiling].mean(-1) > 0).mean() > 0.9
    floor = _eroded(np.abs(pos[..., 1] + 1.0) < 1e-5)
    assert direct[floor].mean() > 0.05  # the directly lit floor is not black


def test_hide_emitters_hides_the_area_light_and_environment():
    d = mi.cornell_box()
    d["sensor"]["film"] = _film(32)
    scene = mi.load_dict(d)
    shown = render_channels(scene, path_integrator(max_depth=2), 4)["<root>"]
    hidden = render_channels(scene, path_integrator(max_depth=2, hide_emitters=True), 4)
    assert shown.max() > 5.0  # the light (radiance ~18) is visible ...
    assert hidden["<root>"].max() < 2.0  # ... and gone when hidden
    sky = mi.load_dict(
        {
            "type": "scene",
            "sensor": _camera((0, 1, 0), (0, 5, 1), 8),
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.5}},
        }
    )
    np.testing.assert_allclose(render_channels(sky, path_integrator(), 2)["<root>"], 0.5)
    np.testing.assert_array_equal(
        render_channels(sky, path_integrator(hide_emitters=True), 2)["<root>"], 0.0
    )


# --------------------------------------------------------------------------- nesting


def test_nested_in_moment_and_aov_gives_sensible_moments():
    d = mi.cornell_box()
    d["sensor"]["film"] = _film(16)
    scene = mi.load_dict(d)
    spp = 64 if dr.is_jit_v(mi.Float) else 8
    aovs = "albedo:albedo,nn:sh_normal,dd:depth"

    def moment_aov(inner: dict) -> dict:
        return {"type": "moment", "nested": {"type": "aov", "aovs": aovs, "integrator": inner}}

    ao = render_channels(scene, moment_aov(ao_integrator(radius=0.5)), spp)
    m1, m2 = ao["nested.integrator"], ao["m2_nested.integrator"]
    assert m1.shape == (16, 16, 4)  # R, G, B and alpha of the nested integrator
    assert 0.0 <= m1[..., :3].min() and m1[..., :3].max() <= 1.0
    assert 0.2 < m1[..., :3].mean() < 1.0
    # rays = 1: each sample is 0 or 1, so the second moment equals the first.
    np.testing.assert_allclose(m2[..., :3], m1[..., :3], atol=1e-5)
    assert set(ao) >= {"nested.albedo", "nested.nn", "nested.dd", "m2_nested.dd"}

    pt = render_channels(scene, moment_aov(path_integrator(max_depth=8)), spp, seed=5)
    m1, m2 = pt["nested.integrator"][..., :3], pt["m2_nested.integrator"][..., :3]
    assert (m2 >= m1 * m1 * (1 - 1e-4) - 1e-7).all()  # variance >= 0
    var_of_mean = (m2 - m1 * m1) / spp
    plain = render_channels(scene, path_integrator(max_depth=8), spp, seed=6)["<root>"]
    z = (m1.mean() - plain.mean()) / math.sqrt(2 * var_of_mean.sum() / m1.size**2)
    assert abs(z) < 4.0
    # The AOVs next to it are the same first-hit features as next to Mitsuba's own path.
    ref = render_channels(
        scene, {"type": "aov", "aovs": aovs, "integrator": {"type": "path"}}, spp, 5
    )
    for name in ("albedo", "nn", "dd"):
        np.testing.assert_allclose(pt[f"nested.{name}"], ref[name], atol=1e-5)


# --------------------------------------------------------------------------- scalar fallback


def test_scalar_variant_runs_both_integrators():
    use_variant("scalar_rgb")
    try:
        plane = mi.load_dict(
            {"type": "scene", "sensor": _camera((0, 2, 0.5), (0, 0, 0), 6), "floor": _plane(0.0)}
        )
        np.testing.assert_array_equal(
            render_channels(plane, ao_integrator(radius=1.0), 2)["<root>"], 1.0
        )
        sky = mi.load_dict(
            {"type": "scene", "sensor": _camera((0, 1, 0), (0, 5, 1), 4), "floor": _plane(0.0)}
        )
        rgb = render_channels(sky, ao_integrator(radius=1.0, rays=2, background=0.5), 2)
        np.testing.assert_array_equal(rgb["<root>"], 0.5)
        d = mi.cornell_box()
        d["sensor"]["film"] = _film(8)
        scene = mi.load_dict(d)
        ref, ref_var = _mean_and_var(scene, {"type": "path", "max_depth": 4}, 16, seed=0)
        out, out_var = _mean_and_var(scene, path_integrator(max_depth=4), 16, seed=1)
        z = (out.mean() - ref.mean()) / math.sqrt((ref_var.sum() + out_var.sum()) / out.size**2)
        assert abs(z) < 4.0
        assert out.max() > 1.0 and ref.max() > 1.0  # the light is visible (and brightest)
    finally:
        use_variant()
