"""The ``mitsuba`` profile (mcdenoise/io/profiles/mitsuba.py): synthetic files with Mitsuba's
exact channel names, and files rendered with Mitsuba itself (``@pytest.mark.mitsuba``).
"""

from __future__ import annotations

import numpy as np
import pytest
from profile_files import H, W, mitsuba_channels, planes, stack, write

from mcdenoise.io import describe, load_buffers


def test_mitsuba_aov_and_moment_channels(tmp_path, rng):
    spp = 16
    s = rng.uniform(0.0, 0.5, (3, H, W))  # (m2 - m1^2) per XYZ component
    ch = mitsuba_channels(rng, s)
    path = write(tmp_path / "m.exr", ch, {"generatedBy": "Mitsuba version 3.9.1"})
    fb = load_buffers(path, spp=spp)
    assert fb.profile == "mitsuba" and fb.spp == spp
    assert fb.names() == ["color", "albedo", "normal", "depth", "position", "color_var"]
    np.testing.assert_array_equal(fb["color"].numpy(), stack(ch, "RGB"))
    np.testing.assert_array_equal(fb["normal"].numpy(), stack(ch, ["nn.X", "nn.Y", "nn.Z"]))
    np.testing.assert_array_equal(fb["depth"].numpy(), stack(ch, ["dd.T"]))
    np.testing.assert_array_equal(fb["position"].numpy(), stack(ch, ["pp.X", "pp.Y", "pp.Z"]))
    # Luminance variance of the mean from the Y moments, not from the decoy pair.
    assert fb.channels["color_var"] == ["img.path.Y", "img.m2_path.Y"]
    np.testing.assert_allclose(fb["color_var"].numpy()[0], s[1] / (spp - 1), rtol=1e-4, atol=1e-6)
    assert "A" in fb.attributes["_file_channels"]


def test_mitsuba_without_spp_has_no_variance_and_says_why(tmp_path, rng):
    ch = mitsuba_channels(rng, np.zeros((3, H, W)))
    path = write(tmp_path / "m.exr", ch, {"generatedBy": "Mitsuba version 3.9.1"})
    fb = load_buffers(path)
    assert "color_var" not in fb and fb.spp is None
    assert any("color_var not produced" in n and "spp" in n for n in fb.attributes["_notes"])
    info = describe(path)
    assert any("spp" in n for n in info.notes) and "color_var" in info.missing


def test_mitsuba_moment_pair_not_matching_colour_is_rejected(tmp_path, rng):
    ch = mitsuba_channels(rng, np.zeros((3, H, W)))
    ch["img.path.Y"] = ch["img.path.Y"] * 1.5  # no longer the luminance of R,G,B
    fb = load_buffers(write(tmp_path / "m.exr", ch), spp=4)
    assert "color_var" not in fb
    assert any("luminance" in n for n in fb.attributes["_notes"])


def test_mitsuba_nested_aov_under_moment_gives_feature_variances(tmp_path, rng):
    # moment integrator at the top, nesting an aov integrator called "aov" (prefix aov.).
    spp = 8
    ch = planes(rng, ["R", "G", "B"])
    ch.update(planes(rng, ["aov.albedo.R", "aov.albedo.G", "aov.albedo.B", "aov.depth.T"]))
    extra = {n: rng.uniform(0, 0.1, (H, W)).astype(np.float32) for n in list(ch) if "." in n}
    for n, e in extra.items():
        ch["m2_" + n] = ch[n] ** 2 + e
    fb = load_buffers(write(tmp_path / "n.exr", ch), profile="mitsuba", spp=spp)
    assert {"albedo", "depth", "albedo_var", "depth_var"} <= set(fb.names())
    want = stack(extra, ["aov.albedo.R", "aov.albedo.G", "aov.albedo.B"]) / (spp - 1)
    np.testing.assert_allclose(fb["albedo_var"].numpy(), want, rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(
        fb["depth_var"].numpy()[0], extra["aov.depth.T"] / (spp - 1), rtol=1e-4
    )


# --- real Mitsuba output --------------------------------------------------------------------
def _mitsuba_scene(mi, spp: int, w: int = 16, h: int = 12, filt: str = "box"):
    T = mi.ScalarTransform4f
    return mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "aov",
                "aovs": "albedo:albedo,nn:sh_normal,dd:depth,pp:position",
                "img": {"type": "moment", "path": {"type": "path", "max_depth": 3}},
            },
            "sensor": {
                "type": "perspective",
                "to_world": T().look_at(origin=[0, 0, -4], target=[0, 0, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": filt}},
                "sampler": {"type": "independent", "sample_count": spp},
            },
            "sphere": {
                "type": "sphere",
                "bsdf": {
                    "type": "diffuse",
                    "reflectance": {"type": "rgb", "value": [0.8, 0.4, 0.1]},
                },
            },
            "light": {
                "type": "point",
                "position": [2, 2, -2],
                "intensity": {"type": "rgb", "value": [20, 12, 6]},
            },
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.2}},
        }
    )


@pytest.mark.mitsuba
def test_real_mitsuba_file_loads_with_auto_profile(tmp_path):
    mi = pytest.importorskip("mitsuba")
    import drjit as dr

    if dr.thread_count() < 2:  # Mitsuba 3.9.1 hangs in Bitmap.write with a 1-thread pool
        dr.set_thread_count(2)  # (tests/conftest.py restores the pool after the test)
    mi.set_variant("scalar_rgb")
    scene = _mitsuba_scene(mi, spp=8)
    mi.render(scene, seed=3)
    bitmap = scene.sensors()[0].film().bitmap()
    path = tmp_path / "mi.exr"
    bitmap.write(str(path))
    fb = load_buffers(path, spp=8)
    assert fb.profile == "mitsuba"
    assert fb.names() == ["color", "albedo", "normal", "depth", "position", "color_var"]
    raw = np.array(bitmap)
    struct = bitmap.struct_()
    col = {struct[i].name: raw[..., i] for i in range(len(struct))}
    np.testing.assert_array_equal(fb["color"].numpy(), stack(col, "RGB"))
    want = (col["img.m2_path.Y"] - col["img.path.Y"] ** 2).clip(0) / 7
    np.testing.assert_allclose(fb["color_var"].numpy()[0], want, rtol=1e-5, atol=1e-9)
    assert fb.attributes["generatedBy"].startswith("Mitsuba")


@pytest.mark.mitsuba
def test_mitsuba_color_var_matches_variance_over_independent_renders(tmp_path):
    """color_var is an unbiased estimate of the variance of the pixel mean (luminance)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    spp, runs = 4, 80
    scene = _mitsuba_scene(mi, spp=spp)
    lum, est = [], []
    for seed in range(runs):
        mi.render(scene, seed=seed)
        path = tmp_path / "r.exr"
        scene.sensors()[0].film().bitmap().write(str(path))
        fb = load_buffers(path, spp=spp)
        c = fb["color"].numpy()
        lum.append(0.2126729 * c[0] + 0.7151522 * c[1] + 0.0721750 * c[2])
        est.append(fb["color_var"].numpy()[0])
    empirical = np.var(np.stack(lum), axis=0, ddof=1)
    predicted = np.mean(np.stack(est), axis=0)
    mask = empirical > 1e-5
    assert mask.sum() > 20
    ratio = empirical[mask].sum() / predicted[mask].sum()
    # /(spp - 1) is unbiased (ratio ~1); /spp would give ~spp/(spp-1) = 1.33.
    assert 0.85 < ratio < 1.17, ratio


@pytest.mark.mitsuba
def test_real_mitsuba_aov_conventions_are_the_canonical_ones(tmp_path):
    """What the canonical buffers mean is what Mitsuba's ``aov`` writes (the training data's
    renderer): ``sh_normal`` in world space, ``depth`` = distance along the camera ray (not the
    planar camera z), ``position`` in world space, and 0 in all three where the ray escapes."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    T = mi.ScalarTransform4f
    origin, target = np.array([0.5, -5.0, 2.5]), np.array([0.0, 0.0, 1.5])
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "aov",
                "aovs": "albedo:albedo,nn:sh_normal,dd:depth,pp:position",
                "img": {"type": "path", "max_depth": 2},
            },
            "sensor": {
                "type": "perspective",
                "fov": 50,
                "to_world": T().look_at(
                    origin=origin.tolist(), target=target.tolist(), up=[0, 0, 1]
                ),
                "film": {"type": "hdrfilm", "width": 24, "height": 16, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 4},
            },
            "floor": {"type": "rectangle", "to_world": T().scale(20), "bsdf": {"type": "diffuse"}},
            "light": {
                "type": "point",
                "position": [2, -2, 4],
                "intensity": {"type": "rgb", "value": 20},
            },
        }
    )
    mi.render(scene, seed=1)
    path = tmp_path / "aov.exr"
    scene.sensors()[0].film().bitmap().write(str(path))
    fb = load_buffers(path)
    assert fb.profile == "mitsuba"
    pos, n, d = fb["position"].numpy(), fb["normal"].numpy(), fb["depth"].numpy()[0]
    # The bottom half sees only the floor (its far edge is 20 units away, beyond the horizon).
    inner = np.zeros(d.shape, bool)
    inner[d.shape[0] // 2 :] = True
    assert inner.sum() > 50 and np.all(np.abs(pos[2][inner]) < 1e-6)
    np.testing.assert_allclose(n[:, inner], np.array([[0.0], [0.0], [1.0]]).repeat(inner.sum(), 1))
    ray = np.linalg.norm(pos - origin[:, None, None], axis=0)
    fwd = (target - origin) / np.linalg.norm(target - origin)
    planar = np.einsum("i,ihw->hw", fwd, pos - origin[:, None, None])
    # Mean of distances vs distance of the mean position: equal to well under 1 %.
    assert np.max(np.abs(d - ray)[inner] / ray[inner]) < 0.01
    assert np.max(np.abs(d - planar)[inner] / planar[inner]) > 0.05
    # The top row looks over the floor's far edge: no hit, and 0 in every geometric buffer.
    assert np.all(d[0] == 0) and np.all(pos[:, 0] == 0) and np.all(n[:, 0] == 0)
