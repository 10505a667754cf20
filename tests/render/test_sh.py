"""Tests for mcdenoise.render.sh: SH basis, lat-long conversion, projection, Mitsuba envmap."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from mcdenoise.errors import InputError
from mcdenoise.render.sh import (
    PAPER_ORDER,
    eval_sh,
    lambert_factors,
    latlong_directions,
    latlong_solid_angles,
    num_coeffs,
    order_of,
    project_latlong_to_sh,
    sh_basis,
    sh_frame_to_world,
    sh_index,
    sh_irradiance,
    sh_to_latlong,
    sh_to_latlong_with_stats,
    world_to_sh_frame,
)

HAS_MITSUBA = importlib.util.find_spec("mitsuba") is not None


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _sphere_quadrature(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre in cos θ × uniform φ: exact for polynomials of degree < 2n on S²."""
    x, w = np.polynomial.legendre.leggauss(n)
    phi = (np.arange(2 * n) + 0.5) * np.pi / n
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    weights = (w[:, None] * np.full(2 * n, np.pi / n)[None, :]).reshape(-1)
    return dirs, weights


def _positive_coeffs(order: int, seed: int = 0) -> np.ndarray:
    """Random colour SH radiance kept positive by a large constant term."""
    rng = np.random.default_rng(seed)
    c = rng.normal(scale=0.1, size=(num_coeffs(order), 3))
    c[0] = 3.0 + rng.uniform(size=3)
    return c


# --------------------------------------------------------------------------- basis


def test_docstring_examples():
    import doctest

    import mcdenoise.render.sh as module

    failed, attempted = doctest.testmod(module)
    assert attempted > 0 and failed == 0


def test_index_layout_and_order():
    assert [sh_index(b, m) for b in range(3) for m in range(-b, b + 1)] == list(range(9))
    assert num_coeffs(PAPER_ORDER) == 36
    assert order_of(np.zeros((36, 3))) == 5
    with pytest.raises(InputError, match="35"):
        order_of(np.zeros((35, 3)))


def test_basis_matches_closed_forms_up_to_order_two():
    d = _unit(np.random.default_rng(1), 50)
    x, y, z = d.T
    expected = np.stack(
        [
            np.full_like(x, 0.282095),
            0.488603 * y,
            0.488603 * z,
            0.488603 * x,
            1.092548 * x * y,
            1.092548 * y * z,
            0.315392 * (3 * z * z - 1),
            1.092548 * x * z,
            0.546274 * (x * x - y * y),
        ],
        axis=1,
    )
    np.testing.assert_allclose(sh_basis(2, d), expected, atol=2e-6)


@pytest.mark.parametrize("order", [PAPER_ORDER, 8])
def test_basis_is_orthonormal_on_the_sphere(order):
    dirs, w = _sphere_quadrature(order + 2)
    y = sh_basis(order, dirs)
    gram = y.T @ (w[:, None] * y)
    np.testing.assert_allclose(gram, np.eye(num_coeffs(order)), atol=1e-10)


def test_basis_normalises_directions_and_rejects_bad_ones():
    d = _unit(np.random.default_rng(2), 10)
    np.testing.assert_allclose(sh_basis(3, 5.0 * d), sh_basis(3, d), atol=1e-12)
    with pytest.raises(InputError):
        sh_basis(2, np.zeros((3, 3)))
    with pytest.raises(InputError):
        sh_basis(2, np.ones((3, 2)))
    with pytest.raises(InputError):
        sh_basis(-1, d)


def test_frame_mapping_is_a_rotation_with_sh_z_up():
    np.testing.assert_allclose(world_to_sh_frame(np.array([0.0, 1.0, 0.0])), [0, 0, 1])
    m = np.stack([world_to_sh_frame(e) for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0)
    d = _unit(np.random.default_rng(3), 5)
    np.testing.assert_allclose(sh_frame_to_world(world_to_sh_frame(d)), d, atol=1e-12)


# --------------------------------------------------------------------------- irradiance


def test_lambert_factors_known_values():
    a = lambert_factors(5)
    np.testing.assert_allclose(
        a, [math.pi, 2 * math.pi / 3, math.pi / 4, 0.0, -math.pi / 24, 0.0], atol=1e-12
    )


def test_sh_irradiance_matches_numerical_integration():
    c = _positive_coeffs(4, seed=4)
    normals = _unit(np.random.default_rng(5), 6)
    dirs, w = _sphere_quadrature(150)  # the clamped cosine is not smooth: many nodes
    radiance = eval_sh(c, dirs)
    cos = np.clip(dirs @ normals.T, 0.0, None)  # (N, K)
    brute = (w[:, None, None] * radiance[:, None, :] * cos[:, :, None]).sum(0)
    np.testing.assert_allclose(sh_irradiance(c, normals), brute, rtol=5e-5)


# --------------------------------------------------------------------------- lat-long


def test_latlong_layout_follows_mitsuba_envmap():
    d = latlong_directions(8, 5)
    assert d.shape == (5, 8, 3)
    np.testing.assert_allclose(d[0, :, 1], 1.0)  # first row: north pole (+Y)
    np.testing.assert_allclose(d[-1, :, 1], -1.0)  # last row: south pole
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    sa = latlong_solid_angles(8, 5)
    assert sa.sum() == pytest.approx(4 * math.pi) and (sa > 0).all()


def test_constant_coefficient_gives_uniform_radiance():
    c = np.zeros((36, 3))
    c[0] = [1.0, 2.0, 3.0]
    img, stats = sh_to_latlong_with_stats(c, 16, 9)
    assert img.dtype == np.float32 and img.shape == (9, 16, 3)
    np.testing.assert_allclose(
        img, np.broadcast_to([1.0, 2.0, 3.0], img.shape) * 0.2820948, rtol=1e-6
    )
    assert stats.texel_fraction == stats.energy_fraction == 0.0


def test_y1_terms_brighten_up_and_plus_x():
    up = np.zeros((4, 3))
    up[0], up[sh_index(1, 0)] = 1.0, 0.5
    img = sh_to_latlong(up, 32, 17).mean(-1)
    rows = img.mean(1)
    assert (np.diff(rows) < 0).all()  # brightest at the zenith (+Y), darkest at the nadir
    side = np.zeros((4, 3))
    side[0], side[sh_index(1, 1)] = 1.0, 0.5
    img = sh_to_latlong(side, 32, 17).mean(-1)
    x = latlong_directions(32, 17)[..., 0]
    assert img[x > 0.5].min() > img[np.abs(x) < 0.1].max() > img[x < -0.5].max()
    minus_z = np.zeros((4, 3))
    minus_z[0], minus_z[sh_index(1, -1)] = 1.0, 0.5  # y_sh = -Z (world)
    img = sh_to_latlong(minus_z, 32, 17).mean(-1)
    z = latlong_directions(32, 17)[..., 2]
    assert img[z < -0.5].min() > img[z > 0.5].max()


def test_negative_radiance_is_clamped_and_reported():
    c = np.zeros((4, 3))
    c[sh_index(1, 0)] = 1.0  # positive above the horizon, negative below
    img, stats = sh_to_latlong_with_stats(c, 64, 33)
    assert img.min() == 0.0
    assert stats.solid_angle_fraction == pytest.approx(0.5, abs=0.03)
    assert stats.energy_fraction == pytest.approx(0.5, abs=0.01)
    assert 0.4 < stats.texel_fraction < 0.6


def test_round_trip_of_a_band_limited_function():
    c = _positive_coeffs(PAPER_ORDER, seed=6)
    img, stats = sh_to_latlong_with_stats(c, 64, 33)
    assert stats.energy_fraction == 0.0
    back = project_latlong_to_sh(img, PAPER_ORDER)
    assert back.shape == (36, 3)
    np.testing.assert_allclose(back, c, atol=2e-5)  # float32 image, exact otherwise
    # Projecting onto fewer bands keeps the low coefficients (orthogonality on the grid).
    low = project_latlong_to_sh(sh_to_latlong(c, 256, 129), 2)
    np.testing.assert_allclose(low, c[:9], atol=2e-3)
    # Single-channel images work too.
    np.testing.assert_allclose(project_latlong_to_sh(img[..., 1], 3)[:, 0], c[:16, 1], atol=1e-3)


def test_projection_of_a_non_band_limited_image_is_close_to_the_integral():
    # f = max(0, up) is not band-limited (kink at the horizon). Exactly,
    # c00 = Y00 ∫ max(0, z) dω = 0.282095 π and c10 = 0.488603 ∫ max(0, z) z dω = 0.488603 · 2π/3.
    d = latlong_directions(256, 129).reshape(-1, 3)
    img = np.maximum(0.0, d[:, 1]).reshape(129, 256)
    c = project_latlong_to_sh(img, 2)[:, 0]
    assert c[0] == pytest.approx(0.2820948 * math.pi, rel=2e-3)
    assert c[sh_index(1, 0)] == pytest.approx(0.4886025 * 2 * math.pi / 3, rel=2e-3)


@pytest.mark.parametrize(
    "call",
    [
        lambda: sh_to_latlong(np.zeros((35, 3)), 8, 5),
        lambda: sh_to_latlong(np.zeros((36, 4)), 8, 5),
        lambda: sh_to_latlong(np.full((4, 3), np.nan), 8, 5),
        lambda: sh_to_latlong(np.zeros((4, 3)), 1, 5),
        lambda: sh_to_latlong(np.zeros((4, 3)), 8, 2),
        lambda: project_latlong_to_sh(np.zeros((5, 8, 3)), -1),
        lambda: project_latlong_to_sh(np.zeros((3, 4)), 5),
        lambda: project_latlong_to_sh(np.full((5, 8), np.inf), 1),
    ],
)
def test_bad_input_raises_input_error(call):
    with pytest.raises(InputError):
        call()


# --------------------------------------------------------------------------- Mitsuba


@pytest.fixture
def mitsuba_variant():
    from mcdenoise.render.integrators import use_variant

    return use_variant()


@pytest.mark.mitsuba
@pytest.mark.skipif(not HAS_MITSUBA, reason="needs mitsuba")
def test_envmap_dict_reproduces_the_sh_radiance_in_mitsuba(mitsuba_variant):
    import drjit as dr
    import mitsuba as mi

    from mcdenoise.render.sh import sh_envmap_dict

    c = _positive_coeffs(3, seed=7) * 0.5
    env = sh_envmap_dict(c, scale=2.0, width=256)
    assert env["type"] == "envmap" and env["bitmap"].width() == 256
    emitter = mi.load_dict(env)
    dirs = _unit(np.random.default_rng(8), 512)
    if dr.is_jit_v(mi.Float):
        si = dr.zeros(mi.SurfaceInteraction3f, len(dirs))
        si.wi = mi.Vector3f(*(-dirs.T.astype(np.float32)))
        got = np.array(emitter.eval(si)).T
    else:
        got = []
        for d in dirs[:64]:
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*(-d))
            got.append(np.array(emitter.eval(si)))
        got, dirs = np.array(got), dirs[:64]
    want = 2.0 * eval_sh(c, world_to_sh_frame(dirs))
    np.testing.assert_allclose(got, want, rtol=0.01)  # bilinear lookup of a smooth map
    with pytest.raises(InputError):
        sh_envmap_dict(c, scale=-1.0)


@pytest.mark.mitsuba
@pytest.mark.skipif(not HAS_MITSUBA, reason="needs mitsuba")
def test_white_sphere_under_order_one_sh_light_has_the_expected_irradiance(mitsuba_variant):
    import mitsuba as mi

    from mcdenoise.render.sh import sh_envmap_dict

    c = np.zeros((4, 3))
    c[0], c[sh_index(1, 0)] = 1.0, 0.5  # sky brighter than ground, radiance >= 0 everywhere
    res, spp = 32, 256  # Mitsuba's C++ path: quick in scalar variants too
    albedo = 0.8
    scene = mi.load_dict(
        {
            "type": "scene",
            "sensor": {
                "type": "perspective",
                "fov": 30,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]
                ),
                "film": {
                    "type": "hdrfilm",
                    "width": res,
                    "height": res,
                    "rfilter": {"type": "box"},
                },
            },
            "ball": {
                "type": "sphere",
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}},
            },
            "sky": sh_envmap_dict(c, width=128),
        }
    )
    integrator = mi.load_dict(
        {"type": "aov", "aovs": "nn:sh_normal", "integrator": {"type": "path", "max_depth": 2}}
    )
    mi.render(scene, integrator=integrator, spp=spp, seed=0)
    ch = {k: np.array(v, dtype=np.float64) for k, v in scene.sensors()[0].film().bitmap().split()}
    rgb, nn = ch["integrator"][..., :3], ch["nn"]
    norm = np.linalg.norm(nn, axis=-1)
    hit = norm > 0.5
    interior = hit[1:-1, 1:-1] & hit[:-2, 1:-1] & hit[2:, 1:-1] & hit[1:-1, :-2] & hit[1:-1, 2:]
    on_ball = np.zeros_like(hit)
    on_ball[1:-1, 1:-1] = interior  # no silhouette pixels (sphere and sky mixed)
    on_ball &= norm > 0.99  # pixel-averaged normals of a curved surface are slightly short
    n = nn[on_ball] / norm[on_ball][:, None]
    predicted = albedo / math.pi * sh_irradiance(c, world_to_sh_frame(n))  # (N, 3)
    measured = rgb[on_ball]
    lit, unlit = n[:, 1] > 0.5, n[:, 1] < -0.5
    assert lit.sum() >= 20 and unlit.sum() >= 20
    ratio = measured[lit].mean() / measured[unlit].mean()
    expected = predicted[lit].mean() / predicted[unlit].mean()
    assert expected > 2.0  # a clearly lit and a clearly unlit side (at the poles: 3.73)
    assert ratio == pytest.approx(expected, rel=0.03)
    assert measured.mean() == pytest.approx(predicted.mean(), rel=0.01)
    assert np.median(np.abs(measured / predicted - 1.0)) < 0.03  # per-pixel noise at 256 spp
