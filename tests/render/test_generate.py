"""Tests of ``mcdenoise.render.generate`` and the modules it runs (``render.passes``,
``render.layout``), and of the moment maths of ``render.moments``.

Renders are tiny (16×16 to 32×32 pixels, a few spp) in ``scalar_rgb``, which needs no JIT
compilation; the scenes plan to Mitsuba's own ``path`` integrator except the AO test.
The heart is :func:`test_predicted_variance_matches_the_spread_over_seeds`: the per-pixel
variance of the mean written next to each buffer must agree with the variance of the pixel
means observed over independent renders.
"""

from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from scene_specs import DOF_SCENE as DOF

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers, probe_exr, read_exr
from mcdenoise.render import generate as gen
from mcdenoise.render import jobs as jobs_module
from mcdenoise.render import moments as moments_module
from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.generate import generate
from mcdenoise.render.jobs import ImageJob, image_seed, jobs_from_specs
from mcdenoise.render.manifest import load_manifest, merge_manifests
from mcdenoise.render.moments import (
    Moments,
    buffers_from_moments,
    film_channels,
    moment_integrator,
    moments_from_film,
)
from mcdenoise.render.passes import render_image
from mcdenoise.render.scene_spec import SpecError, load_spec, parse_spec

VARIANT = "scalar_rgb"
LIT_BUFFERS = {
    *(b for f in ("color", "albedo", "normal", "depth", "position") for b in (f, f + "_var"))
}

# A floor, a sphere, a point light and a dim sky: direct light only (Mitsuba's `path`, depth 2).
BALL = """
name = "{name}"
effects = ["direct"]
[camera]
origin = [0, 1, 4]
target = [0, 0.5, 0]
fov = 40
[[objects]]
shape = "rectangle"
transform = {{ rotate = [-90, 0, 0], scale = [3, 3, 1] }}
material = {{ type = "diffuse", reflectance = {{ checkerboard = {{ color0 = [0.2, 0.2, 0.2], color1 = [0.8, 0.8, 0.8], scale = 4 }} }} }}
[[objects]]
shape = "sphere"
center = [0, 0.5, 0]
radius = {radius}
material = {{ type = "diffuse", reflectance = [0.7, 0.3, 0.2] }}
[[lights]]
type = "point"
position = [1, 3, 2]
intensity = [20, 20, 20]
[[lights]]
type = "constant"
radiance = [0.2, 0.2, 0.25]
"""


AO = """
name = "ao"
effects = ["ao"]
[render]
ao_radius = 1.0
[camera]
origin = [0, 1, 4]
target = [0, 0.5, 0]
[[objects]]
shape = "rectangle"
transform = { rotate = [-90, 0, 0], scale = [3, 3, 1] }
[[objects]]
shape = "sphere"
center = [0, 0.5, 0]
radius = 0.5
"""


def write_spec(folder: Path, text: str, name: str = "ball", radius: float = 0.5) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(text).format(name=name, radius=radius), encoding="utf-8")
    return path


def spec_text(text: str, source: str = "<test>"):
    import tomllib

    return parse_spec(tomllib.loads(text), source=source)


def config(out: Path, **kw) -> RenderConfig:
    base = {"width": 16, "height": 16, "spp": (2, 8), "ref_spp": 16, "variant": VARIANT}
    base.update(kw)
    return RenderConfig(out=out, **base)


@pytest.fixture(scope="module")
def variant() -> str:
    pytest.importorskip("mitsuba")
    from mcdenoise.render.mitsuba_setup import ensure_variant

    return ensure_variant(VARIANT)


def channels(path: Path, part: str | int) -> dict[str, np.ndarray]:
    return read_exr(path, part=part).pixels


# --- settings, seeds and passes (no Mitsuba) -------------------------------------------------
def test_config_refuses_bad_values() -> None:
    with pytest.raises(RenderError, match="unknown Mitsuba variant 'gpu'"):
        RenderConfig(out=Path("x"), variant="gpu")
    with pytest.raises(RenderError, match="ref_spp"):
        RenderConfig(out=Path("x"), ref_spp=0)
    with pytest.raises(RenderError, match="strictly increasing"):
        RenderConfig(out=Path("x"), spp=(16, 4))
    with pytest.raises(RenderError, match="shard 3/2"):
        RenderConfig(out=Path("x"), shard=(3, 2))


def test_job_ids_are_unique_and_file_safe() -> None:
    specs = [spec_text(BALL.format(name=n, radius=0.5)) for n in ("box", "box", "a b/c", "x_ref")]
    jobs = jobs_from_specs(specs, seed=3)
    assert [j.id for j in jobs] == ["box", "box_2", "a_b_c", "x_ref"]
    assert [j.index for j in jobs] == [0, 1, 2, 3]
    assert jobs[0].seed != jobs[1].seed  # same scene twice: two different images


def test_variance_of_mean_from_moments_is_unbiased() -> None:
    rng = np.random.default_rng(0)
    spp = 4
    samples = rng.exponential(2.0, size=(spp, 3, 5, 7))
    m = Moments({"color": samples.mean(0)}, {"color": (samples**2).mean(0)}, spp)
    fb = buffers_from_moments(m)
    want = samples.var(axis=0, ddof=1) / spp
    np.testing.assert_allclose(fb["color_var"].numpy(), want, rtol=1e-5)
    assert fb.spp == spp and fb["color"].dtype == torch.float32
    # Pooled moments of two sample sets = moments of the union.
    more = rng.exponential(2.0, size=(12, 3, 5, 7))
    both = m.merge(Moments({"color": more.mean(0)}, {"color": (more**2).mean(0)}, 12))
    pooled = np.concatenate([samples, more])
    np.testing.assert_allclose(both.m1["color"], pooled.mean(0), rtol=1e-12)
    np.testing.assert_allclose(
        buffers_from_moments(both)["color_var"].numpy(), pooled.var(0, ddof=1) / 16, rtol=1e-5
    )


def test_round_off_negative_variance_is_clamped_and_one_sample_gives_zero() -> None:
    m1 = np.full((3, 2, 2), 3.0)
    m2 = m1 * m1 - 1e-7  # what float32 round-off does to a constant pixel
    assert (
        float(buffers_from_moments(Moments({"color": m1}, {"color": m2}, 16))["color_var"].min())
        == 0.0
    )
    one = Moments({"color": m1}, {"color": m1 * m1 + 5}, 1)
    assert not buffers_from_moments(one)["color_var"].any()


def test_film_channels_are_found_by_name_not_position() -> None:
    chans = film_channels(["depth", "normal"])
    names = [c for cs in chans.values() for c in cs]
    names = names + ["m2_" + c for c in names]
    order = np.random.default_rng(1).permutation(len(names))
    shuffled = [names[i] for i in order]
    pixels = np.stack([np.full((2, 3), float(i)) for i in order], axis=-1).astype(np.float32)
    m = moments_from_film(shuffled, pixels, ["depth", "normal"], 4)
    assert m.m1["depth"][0, 0, 0] == names.index("inner.depth.T")
    assert m.m2["normal"][2, 0, 0] == names.index("m2_inner.normal.Z")
    keep = [i for i, n in enumerate(shuffled) if n != "m2_inner.depth.T"]
    with pytest.raises(InputError, match=r"no channel\(s\) m2_inner\.depth\.T; it has "):
        moments_from_film([shuffled[i] for i in keep], pixels[..., keep], ["depth"], 4)
    d = moment_integrator({"type": "path"}, ["albedo"])
    assert d["inner"]["aovs"] == "albedo:albedo"


# --- rendering ---------------------------------------------------------------------------------
@pytest.mark.mitsuba
def test_outputs_are_read_back_with_every_feature(tmp_path: Path, variant: str) -> None:
    spec = write_spec(tmp_path, BALL)
    out = tmp_path / "out"
    result = generate(jobs_from_specs([load_spec(spec)]), config(out, spp=(2, 8, 32)))
    assert result.rendered == ["ball"] and result.variant == variant
    noisy, ref = out / "ball.exr", out / "ref" / "ball.exr"
    assert [p.name for p in probe_exr(noisy)] == ["spp2", "spp8", "spp32"]
    seconds = []
    for spp in (2, 8, 32):
        fb = load_buffers(noisy, part=f"spp{spp}")
        assert set(fb.names()) == LIT_BUFFERS and fb.shape == (16, 16) and fb.spp == spp
        a = fb.attributes
        assert a["mcdenoise:scene"] == "ball" and a["mcdenoise:variant"] == variant
        assert a["mcdenoise:effects"] == "direct" and a["mcdenoise:seed"] == image_seed(0, "ball")
        seconds.append(a["mcdenoise:render_seconds"])
        assert all(bool(fb[n].isfinite().all()) for n in fb.names())
        assert all(float(fb[n].min()) >= 0 for n in fb.names() if n.endswith("_var"))
    assert seconds == sorted(seconds) and seconds[0] > 0  # cumulative
    first = load_buffers(noisy)  # no part: the first (lowest spp)
    assert first.spp == 2
    assert torch.equal(first["color"], load_buffers(noisy, part="spp2")["color"])
    r = load_buffers(ref)
    assert set(r.names()) == LIT_BUFFERS and r.spp == 16
    assert r.attributes["mcdenoise:passes"] == 1
    # More samples, less predicted noise: variance of the mean falls about as 1/spp.
    v2 = float(load_buffers(noisy, part="spp2")["color_var"].mean())
    v32 = float(load_buffers(noisy, part="spp32")["color_var"].mean())
    assert 6 < v2 / v32 < 40

    m = load_manifest(out)
    assert m["settings"] == {"width": 16, "height": 16, "spp": [2, 8, 32], "ref_spp": 16,
                             "pass_spp": 128}  # fmt: skip
    (img,) = m["images"]
    assert img["files"] == {"noisy": "ball.exr", "reference": "ref/ball.exr"}
    assert parse_spec(img["spec"]) == parse_spec(load_spec(spec).to_dict() | {"source": None})
    assert [lv["spp"] for lv in img["levels"]] == [2, 8, 32]
    assert [lv["increment_spp"] for lv in img["levels"]] == [2, 6, 24]
    assert [lv["render_seconds"] for lv in img["levels"]] == pytest.approx(seconds, abs=1e-5)
    assert img["reference"]["spp"] == 16 and img["variant"] == variant
    assert img["plan"].startswith("path direct only")
    noisy_seeds = {p["seed"] for lv in img["levels"] for p in lv["passes"]}
    assert noisy_seeds.isdisjoint(p["seed"] for p in img["reference"]["passes"])


@pytest.mark.mitsuba
def test_a_level_pools_the_samples_of_the_levels_below(tmp_path: Path, variant: str) -> None:
    """Level 8 = the 2 samples of level 2 plus 6 more: (2·c2 + 6·c6) / 8, where c6 is a
    6-spp render with the seed of the second noisy pass."""
    spec = spec_text(BALL.format(name="ball", radius=0.5))
    job = ImageJob(0, "ball", spec, 1000)
    two_levels = render_image(job, config(tmp_path, spp=(2, 8)), variant)
    alone = render_image(ImageJob(0, "ball", spec, 1002), config(tmp_path, spp=(6,)), variant)
    only_first = render_image(job, config(tmp_path, spp=(2,)), variant)
    c2, c8 = two_levels.levels["spp2"]["color"], two_levels.levels["spp8"]["color"]
    c6 = alone.levels["spp6"]["color"]
    assert torch.equal(c2, only_first.levels["spp2"]["color"])
    torch.testing.assert_close(c8, (2 * c2 + 6 * c6) / 8, rtol=1e-5, atol=1e-6)
    assert not torch.equal(c8, c6)


@pytest.mark.mitsuba
def test_same_seed_same_pixels_other_seed_other_pixels(tmp_path: Path, variant: str) -> None:
    spec = write_spec(tmp_path, BALL)
    jobs = jobs_from_specs([load_spec(spec)])
    for name in ("a", "b"):
        generate(jobs, config(tmp_path / name))
    generate(jobs_from_specs([load_spec(spec)], seed=1), config(tmp_path / "c"))
    for f, part in (("ball.exr", "spp2"), ("ball.exr", "spp8"), ("ref/ball.exr", 0)):
        a, b, c = (channels(tmp_path / d / f, part) for d in "abc")
        assert a.keys() == b.keys()
        assert all(np.array_equal(a[k], b[k]) for k in a), f
        assert not np.array_equal(a["R"], c["R"]), f


@pytest.mark.mitsuba
def test_predicted_variance_matches_the_spread_over_seeds(tmp_path: Path, variant: str) -> None:
    """K independent renders of a 32×32 thin-lens scene at 4 spp: the empirical variance of
    the pixel means matches the mean predicted variance of the mean (image-mean ratio within
    15 % for colour and albedo, 20 % for normals, 25 % for depth and position, whose few
    silhouette pixels dominate; per-pixel correlation > 0.7). Dividing by spp instead of
    spp − 1 gives 0.76 and fails; so does reading a wrong channel."""
    spec = spec_text(DOF)
    k, spp = 16, 4
    cfg = config(tmp_path, width=32, height=32, spp=(spp,), ref_spp=1)
    runs = [
        render_image(ImageJob(0, "dof", spec, 7919 * i + 11), cfg, variant).levels[f"spp{spp}"]
        for i in range(k)
    ]
    tolerance = {"color": 0.15, "albedo": 0.15, "normal": 0.2, "depth": 0.25, "position": 0.25}
    for name, tol in tolerance.items():
        means = torch.stack([r[name] for r in runs]).double().numpy()
        empirical = means.var(axis=0, ddof=1)
        predicted = torch.stack([r[name + "_var"] for r in runs]).double().mean(0).numpy()
        assert (empirical > 0).mean() > 0.2, f"{name}: too few pixels with variance"
        ratio = predicted.mean() / empirical.mean()
        assert abs(ratio - 1.0) < tol, f"{name}: predicted/empirical variance = {ratio:.3f}"
        corr = np.corrcoef(empirical.ravel(), predicted.ravel())[0, 1]
        assert corr > 0.7, f"{name}: per-pixel correlation {corr:.3f}"


@pytest.mark.mitsuba
def test_ao_plan_writes_only_geometric_features(tmp_path: Path, variant: str) -> None:
    spec = spec_text(AO)
    r = render_image(ImageJob(0, "ao", spec, 5), config(tmp_path, spp=(2,), ref_spp=4), variant)
    fb = r.levels["spp2"]
    assert set(fb.names()) == {"color", "color_var", "normal", "normal_var", "depth",
                               "depth_var", "position", "position_var"}  # fmt: skip
    c = fb["color"]
    assert float(c.min()) >= 0 and float(c.max()) <= 1
    assert torch.equal(c[0], c[1]) and torch.equal(c[1], c[2])  # grey
    assert r.level_records[0]["passes"][0]["spp"] == 2


@pytest.mark.mitsuba
def test_rerun_skips_finished_images_and_redoes_half_finished(tmp_path: Path, variant: str) -> None:
    specs = [load_spec(write_spec(tmp_path, BALL, n, 0.3 + 0.1 * i)) for i, n in enumerate("abc")]
    jobs = jobs_from_specs(specs)
    out = tmp_path / "out"
    cfg = config(out)
    assert generate(jobs, cfg).rendered == ["a", "b", "c"]
    stamp = (out / "a.exr").stat().st_mtime_ns
    again = generate(jobs, cfg)
    assert again.rendered == [] and again.skipped == ["a", "b", "c"] and again.variant is None
    assert (out / "a.exr").stat().st_mtime_ns == stamp
    (out / "ref" / "b.exr").unlink()  # as if killed while rendering b's reference
    assert generate(jobs, cfg).rendered == ["b"]
    # A changed spec under the same id is a different image: rendered again.
    changed = jobs_from_specs([load_spec(write_spec(tmp_path, BALL, "c", 0.9))])
    changed = [ImageJob(2, "c", changed[0].spec, jobs[2].seed)]
    assert generate(changed, cfg).rendered == ["c"]
    # Other settings in the same folder: refused, nothing touched.
    with pytest.raises(RenderError, match=r"--spp 2,8 .*--spp 2,4,8.*another output folder"):
        generate(jobs, config(out, spp=(2, 4, 8)))
    assert [r["id"] for r in load_manifest(out)["images"]] == ["a", "b", "c"]


@pytest.mark.mitsuba
def test_interrupt_leaves_finished_images_and_a_valid_manifest(
    tmp_path: Path, variant: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    specs = [load_spec(write_spec(tmp_path, BALL, n)) for n in ("a", "b")]
    jobs = jobs_from_specs(specs)
    out = tmp_path / "out"
    real_save = gen.write_image

    def killed_during_b(rendered, cfg):
        if rendered.job.id == "b":
            from mcdenoise.io.buffer_files import save_buffers_parts

            # b's noisy file lands, then Ctrl-C arrives before its reference is written.
            save_buffers_parts(out / "b.exr", rendered.levels)
            raise KeyboardInterrupt
        return real_save(rendered, cfg)

    monkeypatch.setattr(gen, "write_image", killed_during_b)
    with pytest.raises(KeyboardInterrupt):
        generate(jobs, config(out))
    m = json.loads((out / "manifest.json").read_text())
    assert [r["id"] for r in m["images"]] == ["a"]
    assert load_buffers(out / "ref" / "a.exr").spp == 16
    assert not [p for p in os.listdir(out) if p.startswith(".mcdenoise-tmp-")]
    monkeypatch.setattr(gen, "write_image", real_save)
    resumed = generate(jobs, config(out))
    assert resumed.skipped == ["a"] and resumed.rendered == ["b"]
    assert [r["id"] for r in load_manifest(out)["images"]] == ["a", "b"]


@pytest.mark.mitsuba
def test_two_shards_render_everything_once_into_one_manifest(tmp_path: Path, variant: str) -> None:
    specs = [load_spec(write_spec(tmp_path, BALL, f"s{i}", 0.2 + 0.1 * i)) for i in range(5)]
    jobs = jobs_from_specs(specs)
    out = tmp_path / "shared"
    first = generate(jobs, config(out, shard=(1, 2)))
    after_one = load_manifest(out)
    second = generate(jobs, config(out, shard=(2, 2)))
    assert first.rendered == ["s0", "s2", "s4"] and second.rendered == ["s1", "s3"]
    assert [r["id"] for r in after_one["images"]] == ["s0", "s2", "s4"]
    m = load_manifest(out)
    assert m["shards"] == ["manifest.shard-1-of-2.json", "manifest.shard-2-of-2.json"]
    assert [r["id"] for r in m["images"]] == [f"s{i}" for i in range(5)]
    assert m["image_count"] == 5 and m["variants"] == [variant]
    shard_ids = [
        [r["id"] for r in json.loads((out / name).read_text())["images"]] for name in m["shards"]
    ]
    assert sorted(shard_ids[0] + shard_ids[1]) == [f"s{i}" for i in range(5)]
    # Unsharded re-run over the merged folder: nothing left to render.
    assert generate(jobs, config(out)).skipped == [f"s{i}" for i in range(5)]
    (out / "manifest.json").unlink()
    assert merge_manifests(out)["image_count"] == 5


@pytest.mark.mitsuba
def test_spec_errors_stop_the_run_before_rendering(tmp_path: Path, variant: str) -> None:
    bad = spec_text(BALL.format(name="x", radius=0.5).replace('["direct"]', '["direct", "dof"]'))
    good = spec_text(BALL.format(name="y", radius=0.5))
    with pytest.raises(SpecError, match="'dof' needs a thin-lens camera"):
        generate([ImageJob(0, "y", good, 1), ImageJob(1, "x", bad, 2)], config(tmp_path / "o"))
    assert not (tmp_path / "o" / "y.exr").exists()


def test_unwritable_or_occupied_output_is_refused(tmp_path: Path) -> None:
    spec = spec_text(BALL.format(name="x", radius=0.5))
    (tmp_path / "file").write_text("x")
    with pytest.raises(RenderError, match="exists and is not a folder"):
        generate([ImageJob(0, "x", spec, 1)], config(tmp_path / "file"))
    if Path("/proc/self").is_dir():  # Linux: nobody, root included, can create files there
        with pytest.raises(RenderError, match="cannot create the output folder"):
            generate([ImageJob(0, "x", spec, 1)], config(Path("/proc/self/mcdenoise-out")))


def test_missing_mitsuba_is_one_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "mitsuba", None)
    spec = spec_text(BALL.format(name="x", radius=0.5))
    with pytest.raises(RenderError, match=r"pip install 'mcdenoise\[render\]'"):
        generate([ImageJob(0, "x", spec, 1)], config(tmp_path / "o"))


@pytest.mark.slow
@pytest.mark.mitsuba
def test_llvm_variant_is_deterministic_too(tmp_path: Path, variant: str) -> None:
    """Same spec, seed and settings in ``llvm_ad_rgb``: identical pixels, variant recorded."""
    from mcdenoise.render.mitsuba_setup import ensure_variant, variant_works

    if not variant_works("llvm_ad_rgb"):
        pytest.skip("llvm_ad_rgb does not work here (libllvm19 missing?)")
    spec = write_spec(tmp_path, BALL)
    try:
        for name in ("a", "b"):
            cfg = config(tmp_path / name, variant="llvm_ad_rgb", spp=(4, 16), ref_spp=64)
            assert generate(jobs_from_specs([load_spec(spec)]), cfg).variant == "llvm_ad_rgb"
    finally:
        ensure_variant(VARIANT)
    for f, part in (("ball.exr", "spp4"), ("ball.exr", "spp16"), ("ref/ball.exr", 0)):
        a, b = (channels(tmp_path / d / f, part) for d in "ab")
        assert all(np.array_equal(a[k], b[k]) for k in a), f
    assert load_manifest(tmp_path / "a")["variants"] == ["llvm_ad_rgb"]


@pytest.mark.parametrize("module", [jobs_module, moments_module])
def test_docstring_examples(module) -> None:
    import doctest

    failed, attempted = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0
