"""Half buffers of ``mcdenoise render --halves`` (issue 24 item 1): two half-sample buffers A
and B per level from disjoint sample streams, ``color == (A + B) / 2`` bit for bit, and the
statistics that say they are independent halves of the samples.

The statistical test (:func:`test_halves_are_independent_and_average_to_the_full_buffer`):
with independent halves, ``E[(A - B)²] = Var A + Var B``, which the halves' own variances of
the mean predict; halves sharing their samples (the negative control, B := A) give 0. The
residuals against a 256-spp reference are uncorrelated across pixels (|r| < 0.1; the
control gives 1).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch
from scene_specs import DOF_SCENE as DOF

from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.generate import generate
from mcdenoise.render.jobs import ImageJob, half_level_passes, jobs_from_specs
from mcdenoise.render.manifest import load_manifest
from mcdenoise.render.moments import Moments, buffers_from_halves
from mcdenoise.render.passes import render_image
from mcdenoise.render.scene_spec import load_spec, parse_spec

VARIANT = "scalar_rgb"

BALL = (
    DOF.replace('effects = ["direct", "dof"]', 'effects = ["direct"]')
    .replace('type = "thinlens"', 'type = "pinhole"')
    .replace("aperture_radius = 0.15\n", "")
)


@pytest.fixture(scope="module")
def variant() -> str:
    pytest.importorskip("mitsuba")
    from mcdenoise.render.mitsuba_setup import ensure_variant

    return ensure_variant(VARIANT)


def _cfg(out: Path, **kw) -> RenderConfig:
    base = {"width": 16, "height": 16, "spp": (2, 8), "ref_spp": 4, "variant": VARIANT}
    return RenderConfig(out=out, **{**base, "halves": True, **kw})


def test_half_passes_split_every_level_evenly() -> None:
    for levels in ([2, 8, 32], [1, 4, 16], [4, 300], [3, 5, 64]):
        cum_a = cum_b = 0
        for level, (a, b) in zip(levels, half_level_passes(levels, 128)):
            cum_a, cum_b = cum_a + sum(a), cum_b + sum(b)
            assert cum_a + cum_b == level and cum_a - cum_b == level % 2
            assert all(0 < n <= 128 for n in a + b)


def test_buffers_from_halves_mean_is_exact_and_odd_counts_have_no_halves() -> None:
    rng = np.random.default_rng(3)

    def moments(spp: int) -> Moments:
        m1 = {"color": rng.lognormal(0, 2, (3, 4, 5)), "albedo": rng.uniform(0, 1, (3, 4, 5))}
        m2 = {k: v * v * 1.5 for k, v in m1.items()}
        return Moments(m1, m2, spp)

    a, b = moments(4), moments(4)
    fb = buffers_from_halves(a, b, ("color", "albedo"))
    for name in ("color", "albedo"):
        assert torch.equal(fb[name], (fb[name + "_a"] + fb[name + "_b"]) / 2)
        assert name + "_a_var" in fb and name + "_b_var" in fb
    pooled = a.merge(b)
    np.testing.assert_allclose(fb["color"].numpy(), pooled.m1["color"], rtol=1e-6)
    assert "color_a" not in buffers_from_halves(a, moments(3))  # 7 samples: no equal halves
    assert buffers_from_halves(a, None).spp == 4


@pytest.mark.mitsuba
def test_halves_are_independent_and_average_to_the_full_buffer(tmp_path, variant) -> None:
    spec = parse_spec(tomllib.loads(DOF), source="<dof>")
    cfg = _cfg(tmp_path, width=32, height=32, spp=(2, 8), ref_spp=256)
    r = render_image(ImageJob(0, "dof", spec, 4242), cfg, variant)
    for part in ("spp2", "spp8"):
        fb = r.levels[part]
        for name in ("color", "albedo", "normal", "depth", "position"):
            assert torch.equal(fb[name], (fb[name + "_a"] + fb[name + "_b"]) / 2), (part, name)
    fb, ref = r.levels["spp8"], r.reference["color"].double()
    a, b = fb["color_a"].double(), fb["color_b"].double()
    predicted = (fb["color_a_var"] + fb["color_b_var"]).double()
    ratio = float(((a - b) ** 2).mean() / predicted.mean())
    assert 0.8 < ratio < 1.25, ratio
    ra, rb = (a - ref).flatten(), (b - ref).flatten()
    noisy = predicted.flatten() > 0
    corr = float(np.corrcoef(ra[noisy].numpy(), rb[noisy].numpy())[0, 1])
    assert abs(corr) < 0.1, corr
    # The negative control: "halves" sharing their samples fail both checks.
    assert float(((a - a) ** 2).mean()) == 0.0
    assert np.corrcoef(ra[noisy].numpy(), ra[noisy].numpy())[0, 1] > 0.99
    # Each half holds half the samples: its predicted variance is about twice the full one.
    half_over_full = float(fb["color_a_var"].mean() / fb["color_var"].mean())
    assert 1.5 < half_over_full < 2.7, half_over_full


@pytest.mark.mitsuba
def test_render_records_disjoint_half_streams_and_refuses_mixing(tmp_path, variant) -> None:
    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "dof.toml").write_text(DOF, encoding="utf-8")
    (folder / "ball.toml").write_text(BALL.replace('"dof"', '"ball"'), encoding="utf-8")
    jobs = jobs_from_specs([load_spec(folder / "dof.toml"), load_spec(folder / "ball.toml")])
    out = tmp_path / "out"
    generate(jobs, _cfg(out, spp=(1, 4, 8)))
    m = load_manifest(out)
    assert m["settings"]["halves"] is True
    for img in m["images"]:
        passes = [p for lv in img["levels"] for p in lv["passes"]]
        seeds = [p["seed"] for p in passes]
        assert len(set(seeds)) == len(seeds)
        assert set(seeds).isdisjoint(p["seed"] for p in img["reference"]["passes"])
        assert sum(p["spp"] for p in passes if p["half"] == "a") == 4
        assert sum(p["spp"] for p in passes if p["half"] == "b") == 4
        assert [lv["increment_spp"] for lv in img["levels"]] == [1, 3, 4]
    from mcdenoise.io import load_buffers

    one = load_buffers(out / "dof.exr", part="spp1")
    assert "color_a" not in one  # one sample cannot be halved
    dof, ball = (load_buffers(out / f, part="spp4") for f in ("dof.exr", "ball.exr"))
    assert {"color_a", "color_b", "color_a_var", "albedo_a", "depth_b_var"} <= set(dof.names())
    # every guide is halved, with a thin lens or without (issue 36: shared guides bias the
    # reference-free estimate)
    assert {"color_a", "color_b_var", "albedo_a", "normal_b", "depth_a_var"} <= set(ball.names())
    with pytest.raises(RenderError, match=r"--halves.*--no-halves"):
        generate(jobs, _cfg(out, spp=(1, 4, 8), halves=False))
