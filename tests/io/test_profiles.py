"""Tests of mcdenoise.io.profiles: renderer channel conventions, detection, mapping files.

Synthetic files use each renderer's exact channel names (see the profiles module docstring for
where each name was checked); the ``mitsuba`` tests render with Mitsuba itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mcdenoise.errors import InputError
from mcdenoise.io import (
    IncompleteFeatureError,
    MissingFeatureError,
    ProfileError,
    canonical_channels,
    describe,
    detect_profile,
    get_profile,
    load_buffers,
    load_mapping,
)
from mcdenoise.io.exr import write_exr
from mcdenoise.io.profiles import resolve_channels

H, W = 6, 9
# linear sRGB <- CIE XYZ (D65), as Mitsuba's film converts moment colours
SRGB_FROM_XYZ = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)


def planes(rng: np.random.Generator, names, lo=0.0, hi=1.0) -> dict[str, np.ndarray]:
    return {n: rng.uniform(lo, hi, (H, W)).astype(np.float32) for n in names}


def write(path: Path, channels: dict[str, np.ndarray], attributes=None) -> Path:
    # Shuffle the insertion order: nothing may depend on it.
    names = list(channels)[::-1]
    write_exr(path, {n: channels[n] for n in names}, attributes=attributes or {})
    return path


def stack(ch: dict[str, np.ndarray], names) -> np.ndarray:
    return np.stack([ch[n] for n in names])


# --- canonical layout ---------------------------------------------------------------------
def test_canonical_channel_names():
    assert canonical_channels("color") == ("R", "G", "B")
    assert canonical_channels("normal") == ("normal.X", "normal.Y", "normal.Z")
    assert canonical_channels("depth") == ("depth.Z",)
    assert canonical_channels("visibility") == ("visibility.Y",)
    assert canonical_channels("motion") == ("motion.X", "motion.Y")
    assert canonical_channels("color_var") == ("color_var.R", "color_var.G", "color_var.B")
    assert canonical_channels("color_var", 1) == ("color_var.Y",)
    assert canonical_channels("depth_var") == ("depth_var.Z",)
    with pytest.raises(InputError):
        canonical_channels("albedo", 1)


# --- detection ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("channels", "attributes", "expected"),
    [
        (["R", "G", "B", "depth.Z"], {"mcdenoise:layout": "1"}, "mcdenoise"),
        (["R", "G", "B"], {"BlenderMultiChannel": "Blender V2.55.1 and newer"}, "cycles"),
        (["View Layer.Combined.R", "View Layer.Combined.G", "View Layer.Combined.B"], {}, "cycles"),
        (["R", "G", "B", "Albedo.R", "Ns.X", "P.X"], {}, "pbrt"),
        (["R", "G", "B", "Nsx", "Px"], {}, "pbrt"),
        (["R", "G", "B", "colorVariance.Z", "albedo.R"], {}, "tungsten"),
        (["R", "G", "B", "normal.R", "normal.G", "normal.B"], {}, "tungsten"),
        (["R", "G", "B"], {"generatedBy": "Mitsuba version 3.9.1"}, "mitsuba"),
        (["R", "G", "B", "dd.T"], {}, "mitsuba"),
        (["R", "G", "B", "img.m2_path.X"], {}, "mitsuba"),
        (["R", "G", "B", "sh_normal.X"], {}, "mitsuba"),
        (["B", "G", "R"], {}, "mcdenoise"),
    ],
)
def test_detect_profile(channels, attributes, expected):
    assert detect_profile(channels, attributes).name == expected


def test_undetectable_file_names_its_channels():
    with pytest.raises(ProfileError, match=r"cannot tell.*Y, foo\.bar.*profile="):
        detect_profile(["Y", "foo.bar"], {})


def test_get_profile():
    assert get_profile("PBRT").name == "pbrt"
    assert get_profile("cycles:My.Layer").layer == "My.Layer"
    with pytest.raises(ProfileError, match="unknown profile 'vray'"):
        get_profile("vray")
    with pytest.raises(ProfileError, match="takes no option"):
        get_profile("pbrt:x")


# --- renderer round trips -----------------------------------------------------------------
def mitsuba_channels(rng, spp_var_y):
    """Channels as Mitsuba's aov integrator nesting a moment integrator writes them."""
    xyz = rng.uniform(0.1, 2.0, (3, H, W))
    rgb = np.einsum("ij,jhw->ihw", SRGB_FROM_XYZ, xyz)
    ch = {c: rgb[i].astype(np.float32) for i, c in enumerate("RGB")}
    ch["A"] = np.ones((H, W), np.float32)
    for i, s in enumerate("XYZ"):
        ch[f"img.path.{s}"] = xyz[i].astype(np.float32)
        ch[f"img.m2_path.{s}"] = (xyz[i] ** 2 + spp_var_y[i]).astype(np.float32)
    ch.update({f"img.{c}": ch[c] for c in "RGB"})
    ch["img.A"] = ch["A"]
    ch.update(planes(rng, ["albedo.R", "albedo.G", "albedo.B"]))
    ch.update(planes(rng, ["nn.X", "nn.Y", "nn.Z"], -1, 1))
    ch.update(planes(rng, ["dd.T"], 1, 5))
    ch.update(planes(rng, ["pp.X", "pp.Y", "pp.Z"], -3, 3))
    # A decoy moment pair whose first moment is not the colour.
    ch.update(planes(rng, ["decoy.X", "decoy.Y", "decoy.Z"]))
    ch.update(planes(rng, ["m2_decoy.X", "m2_decoy.Y", "m2_decoy.Z"], 2, 3))
    return ch


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


def cycles_channels(rng):
    ch = {}
    for layer in ("Composite", "View Layer.001"):
        ch.update(planes(rng, [f"{layer}.Combined.{c}" for c in "RGBA"]))
    L = "View Layer.001"
    ch.update(planes(rng, [f"{L}.Noisy Image.{c}" for c in "RGBA"]))
    ch.update(planes(rng, [f"{L}.Denoising Albedo.{c}" for c in "RGB"]))
    ch.update(planes(rng, [f"{L}.Denoising Normal.{c}" for c in "XYZ"], -1, 1))
    ch.update(planes(rng, [f"{L}.Denoising Depth.Z", f"{L}.Depth.Z"], 1, 9))
    ch.update(planes(rng, [f"{L}.Position.{c}" for c in "XYZ"], -5, 5))
    ch.update(planes(rng, [f"{L}.Diffuse Color.{c}" for c in "RGB"]))
    return ch


def test_cycles_multilayer(tmp_path, rng):
    ch = cycles_channels(rng)
    attrs = {
        "BlenderMultiChannel": "Blender V2.55.1 and newer",
        "cycles.View Layer.001.samples": "64",
    }
    path = write(tmp_path / "c.exr", ch, attrs)
    fb = load_buffers(path)
    L = "View Layer.001"
    assert fb.profile == f"cycles:{L}" and fb.spp == 64
    assert fb.names() == ["color", "albedo", "normal", "depth", "position"]
    np.testing.assert_array_equal(
        fb["color"].numpy(), stack(ch, [f"{L}.Noisy Image.{c}" for c in "RGB"])
    )
    np.testing.assert_array_equal(fb["depth"].numpy()[0], ch[f"{L}.Denoising Depth.Z"])
    np.testing.assert_array_equal(
        fb["normal"].numpy(), stack(ch, [f"{L}.Denoising Normal.{c}" for c in "XYZ"])
    )
    # Another layer by name: only what it has (its Combined pass).
    comp = load_buffers(path, profile="cycles:Composite")
    assert comp.names() == ["color"]
    np.testing.assert_array_equal(
        comp["color"].numpy(), stack(ch, [f"Composite.Combined.{c}" for c in "RGB"])
    )
    with pytest.raises(ProfileError, match="no Cycles view layer 'Nope'"):
        load_buffers(path, profile="cycles:Nope")


def test_pbrt_gbuffer(tmp_path, rng):
    names = ["R", "G", "B", "Albedo.R", "Albedo.G", "Albedo.B", "P.X", "P.Y", "P.Z", "dzdx",
             "dzdy", "N.X", "N.Y", "N.Z", "Ns.X", "Ns.Y", "Ns.Z", "u", "v", "Variance.R",
             "Variance.G", "Variance.B", "RelativeVariance.R", "RelativeVariance.G",
             "RelativeVariance.B"]  # fmt: skip
    ch = planes(rng, names)
    path = write(tmp_path / "p.exr", ch, {"samplesPerPixel": 16})
    fb = load_buffers(path)
    assert fb.profile == "pbrt" and fb.spp == 16
    assert fb.names() == ["color", "albedo", "normal", "depth", "position", "color_var"]
    np.testing.assert_array_equal(fb["normal"].numpy(), stack(ch, ["Ns.X", "Ns.Y", "Ns.Z"]))
    np.testing.assert_array_equal(fb["depth"].numpy()[0], ch["P.Z"])
    # Per-sample variance (of luminance: pbrt's sensor space is XYZ) -> variance of the mean.
    np.testing.assert_allclose(fb["color_var"].numpy()[0], ch["Variance.G"] / 16, rtol=1e-6)
    info = describe(path)
    assert {"N.X", "u", "Variance.R", "RelativeVariance.G"} <= set(info.unmapped)
    with pytest.raises(InputError, match="conflicting sample counts"):
        load_buffers(path, spp=32)


def test_tungsten_kpcn(tmp_path, rng):
    ch = planes(rng, ["R", "G", "B", "colorA.R", "colorA.G", "colorA.B", "colorVariance.Z"])
    for layer, sfx in [("albedo", "RGB"), ("normal", "RGB"), ("diffuse", "RGB"),
                       ("specular", "RGB"), ("depth", "Z"), ("visibility", "Z")]:  # fmt: skip
        ch.update(planes(rng, [f"{layer}.{c}" for c in sfx]))
        ch.update(planes(rng, [f"{layer}A.{c}" for c in sfx]))
        ch.update(planes(rng, [f"{layer}Variance.Z"], 0, 0.01))
    fb = load_buffers(write(tmp_path / "t.exr", ch))
    assert fb.profile == "tungsten"
    feats = ["color", "albedo", "normal", "depth", "diffuse", "specular", "visibility"]
    assert set(fb.names()) == set(feats) | {f + "_var" for f in feats}
    np.testing.assert_array_equal(
        fb["normal"].numpy(), stack(ch, ["normal.R", "normal.G", "normal.B"])
    )
    np.testing.assert_array_equal(fb["visibility"].numpy()[0], ch["visibility.Z"])
    np.testing.assert_array_equal(fb["color_var"].numpy()[0], ch["colorVariance.Z"])  # copied
    np.testing.assert_array_equal(fb["diffuse_var"].numpy()[0], ch["diffuseVariance.Z"])


# --- completeness (HARD_CASES 4) ----------------------------------------------------------
def test_incomplete_feature_is_an_error_listing_missing_and_present(tmp_path, rng):
    ch = planes(rng, ["R", "G", "B", "albedo.R", "albedo.G", "depth.Z"])
    path = write(tmp_path / "i.exr", ch, {"mcdenoise:layout": "1"})
    with pytest.raises(IncompleteFeatureError) as exc:
        load_buffers(path)
    msg = str(exc.value)
    assert "albedo is incomplete" in msg and "albedo.B" in msg and "albedo.R, albedo.G" in msg
    assert "file channels:" in msg and "depth.Z" in msg and str(path) in msg
    assert isinstance(exc.value, MissingFeatureError) and "\n" not in msg


def test_missing_colour_is_an_error_optional_features_may_be_absent(tmp_path, rng):
    only_features = write(tmp_path / "f.exr", planes(rng, ["albedo.R", "albedo.G", "albedo.B"]))
    with pytest.raises(MissingFeatureError, match=r"missing color.*albedo\.R"):
        load_buffers(only_features, profile="mcdenoise")
    fb = load_buffers(write(tmp_path / "c.exr", planes(rng, "RGB")))
    assert fb.names() == ["color"]
    with pytest.raises(MissingFeatureError, match=r"needs albedo.*file channels: R, G, B"):
        fb.require(["albedo"], needed_by="kpcn")


# --- mapping files ------------------------------------------------------------------------
def test_mapping_file_toml_and_json(tmp_path, rng):
    ch = planes(rng, ["beauty.R", "beauty.G", "beauty.B", "alb.R", "alb.G", "alb.B", "var.Y"])
    path = write(tmp_path / "u.exr", ch)
    (tmp_path / "map.toml").write_text(
        'color = ["beauty.R", "beauty.G", "beauty.B"]\n'
        'albedo = ["alb.R", "alb.G", "alb.B"]\n'
        'color_var = ["var.Y"]\nspp = 8\nvariance = "sample"\n'
    )
    fb = load_buffers(path, mapping=tmp_path / "map.toml")
    assert fb.profile == "mapping" and fb.spp == 8
    np.testing.assert_array_equal(fb["albedo"].numpy(), stack(ch, ["alb.R", "alb.G", "alb.B"]))
    np.testing.assert_allclose(fb["color_var"].numpy()[0], ch["var.Y"] / 8, rtol=1e-6)
    (tmp_path / "map.json").write_text(json.dumps({"color": ["beauty.R", "beauty.G", "beauty.B"]}))
    assert load_buffers(path, mapping=tmp_path / "map.json").names() == ["color"]


def test_mapping_overrides_a_detected_profile(tmp_path, rng):
    ch = mitsuba_channels(rng, np.zeros((3, H, W)))
    ch.update(planes(rng, ["alb2.R", "alb2.G", "alb2.B"]))
    path = write(tmp_path / "m.exr", ch, {"generatedBy": "Mitsuba version 3.9.1"})
    fb = load_buffers(path, mapping={"albedo": ["alb2.R", "alb2.G", "alb2.B"]})
    assert fb.profile == "mitsuba" and fb.channels["albedo"] == ["alb2.R", "alb2.G", "alb2.B"]
    np.testing.assert_array_equal(fb["normal"].numpy(), stack(ch, ["nn.X", "nn.Y", "nn.Z"]))
    with pytest.raises(MissingFeatureError, match=r"mapping needs depth \(z\.A\)"):
        load_buffers(path, mapping={"depth": ["z.A"]})


@pytest.mark.parametrize(
    ("text", "suffix", "words"),
    [
        ('colour = ["R", "G", "B"]', ".toml", "unknown key 'colour'"),
        ('albedo = ["a.R", "a.G"]', ".toml", r"albedo needs 3 channel name\(s\), got 2"),
        ('color_var = ["a", "b"]', ".toml", r"color_var needs 3 or 1 channel"),
        ('color = ["R", "G", "B"]\nspp = 0', ".toml", "spp must be a positive integer"),
        ('color = ["R", "G", "B"]\nvariance = "biased"', ".toml", "variance must be"),
        ('color = "R"', ".toml", "must be a list of channel names"),
        ("color = [", ".toml", "invalid TOML"),
        ('{"color": ["R", "G", "B"],}', ".json", "invalid JSON"),
        ("spp = 4", ".toml", "names no buffer"),
    ],
)
def test_invalid_mapping_files(tmp_path, text, suffix, words):
    path = tmp_path / f"bad{suffix}"
    path.write_text(text)
    with pytest.raises(ProfileError, match=words) as exc:
        load_mapping(path)
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(ProfileError, match="not found"):
        load_mapping(tmp_path / "missing.toml")


def test_non_strict_resolution_collects_problems():
    cmap = resolve_channels(["albedo.R", "normal.X"], {}, profile="mcdenoise", strict=False)
    assert len(cmap.problems) == 3  # normal and albedo incomplete, color missing
    assert "color" not in cmap.sources


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
