"""The out-of-distribution scene set (data/scenes/ood), its plain Mitsuba ``aov`` copies
(benchmarks/render_ood.py) and scene loading with one Dr.Jit thread.

The OOD specs must parse, plan and build a Mitsuba scene that renders (8×8, 1 spp,
``scalar_rgb``), be distinct from the curated specs that the held-out benchmark renders, and
be read by no training recipe. The plain copies must hold exactly the channels Mitsuba's
``aov`` integrator writes, read back through the ``mitsuba`` profile without variances.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from scene_specs import BALL_SCENE

from mcdenoise.render.effects import plan_effects
from mcdenoise.render.scene_spec import collect_specs, load_spec

mi = pytest.importorskip("mitsuba")
from mcdenoise.render import mitsuba_setup, scenes  # noqa: E402  (after the importorskip)

pytestmark = pytest.mark.mitsuba

ROOT = Path(__file__).resolve().parents[2]
OOD = ROOT / "data" / "scenes" / "ood"
OOD_SPECS = sorted(OOD.glob("*.toml"))


def _render_ood_module():
    spec = importlib.util.spec_from_file_location(
        "render_ood", ROOT / "benchmarks" / "render_ood.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_dozen_specs_with_distinct_names():
    assert len(OOD_SPECS) >= 12
    names = [load_spec(p).name for p in OOD_SPECS]
    assert len(set(names)) == len(names)
    curated = {load_spec(p).name for p in collect_specs([ROOT / "data" / "scenes"])}
    assert not set(names) & curated
    assert all(n.startswith("ood_") for n in names)


def test_the_curated_folder_does_not_include_them():
    # `mcdenoise render data/scenes` (the held-out recipe) must not pick up the OOD set
    assert not any(p.parent == OOD for p in collect_specs([ROOT / "data" / "scenes"]))


def test_no_training_recipe_or_generator_reads_the_folder():
    # the recipes that render evaluation sets; every other recipe makes training data
    evaluation = {"ood.md", "heldout-halves.md"}
    recipes = (ROOT / "data" / "recipes").glob("*.md")
    texts = [p.read_text() for p in recipes if p.name not in evaluation]
    texts += [p.read_text() for p in (ROOT / "mcdenoise").rglob("*.py")]
    assert not [t for t in texts if "scenes/ood" in t]


def test_the_set_covers_what_the_issue_asks():
    specs = [load_spec(p) for p in OOD_SPECS]
    effects = {e for s in specs for e in s.effects}
    assert {"dof", "ao", "glossy", "indirect"} <= effects
    lights = {lt.type for s in specs for lt in s.lights}
    assert {"sun", "envmap"} <= lights
    materials = {o.material.type for s in specs for o in s.objects}
    assert {"roughconductor", "conductor"} <= materials
    textures = {o.material.reflectance.kind for s in specs for o in s.objects}
    assert {"checkerboard", "noise", "image"} <= textures


@pytest.mark.parametrize("path", OOD_SPECS, ids=lambda p: p.stem)
def test_spec_builds_a_scene_that_renders(path):
    mitsuba_setup.ensure_variant("scalar_rgb")
    from mcdenoise.render.integrators import register_integrators

    register_integrators()
    spec = load_spec(path)
    plan = plan_effects(spec)
    d = scenes.scene_dict(spec, plan, width=8, height=8)
    image = np.array(mi.render(mitsuba_setup.load_scene(d), spp=1, seed=0), dtype=np.float64)
    assert image.shape == (8, 8, 3)
    assert np.isfinite(image).all() and image.max() > 0


def test_plain_aov_copies_are_what_mitsuba_writes(tmp_path):
    from mcdenoise.io import load_buffers
    from mcdenoise.io.exr import probe_exr
    from mcdenoise.render.config import RenderConfig
    from mcdenoise.render.generate import render_dataset

    ro = _render_ood_module()
    spec = tmp_path / "plain.toml"
    spec.write_text(BALL_SCENE.format(name="plain"), encoding="utf-8")
    canon = tmp_path / "r"
    config = RenderConfig(out=canon, width=8, height=6, spp=ro.LEVELS, ref_spp=8,
                          variant="scalar_rgb")  # fmt: skip
    render_dataset([spec], config)
    written = ro.render_plain(canon, tmp_path / "aov", threads=2)
    assert sorted(p.name for p in written) == [f"plain_spp{s}.exr" for s in (16, 4, 64)]
    (part,) = probe_exr(tmp_path / "aov" / "plain_spp4.exr")
    channels = {c.name for c in part.channels}
    want = ["R", "G", "B"] + [f"albedo.{c}" for c in "RGB"] + [f"normal.{c}" for c in "XYZ"]
    want += ["depth.T"] + [f"position.{c}" for c in "XYZ"]
    assert set(want) <= channels
    # besides them only the named nested integrator's own copy of the colour
    assert channels - set(want) <= {f"integrator.{c}" for c in "RGBA"}
    assert str(part.attributes.get("generatedBy", "")).startswith("Mitsuba version")
    b = load_buffers(tmp_path / "aov" / "plain_spp4.exr")
    assert b.profile == "mitsuba"
    assert sorted(b.buffers) == ["albedo", "color", "depth", "normal", "position"]
    assert (b.height, b.width) == (6, 8)
    ref = load_buffers(canon / "ref" / "plain.exr")
    # same scene, same film: the floor's albedo is exactly the reference's where both see it
    assert np.allclose(b["albedo"].numpy()[:, -1], ref["albedo"].numpy()[:, -1], atol=1e-6)
    # a second run renders nothing (resume)
    assert ro.render_plain(canon, tmp_path / "aov", threads=2) == []


def test_envmap_file_loads_with_one_drjit_thread():
    """Mitsuba 3.9.1 (llvm) never returns from loading an envmap file with one Dr.Jit thread;
    mitsuba_setup.load_scene loads with two. Run in a child, so a regression fails instead of hanging."""
    code = textwrap.dedent(
        f"""
        import drjit as dr
        from mcdenoise.render import mitsuba_setup, scenes
        mitsuba_setup.ensure_variant("auto")
        dr.set_thread_count(1)
        s = mitsuba_setup.load_scene({{
            "type": "scene",
            "e": {{"type": "envmap", "filename": {str(ROOT / "data/scenes/envmaps/studio.exr")!r}}},
            "s": {{"type": "sphere"}},
        }})
        assert dr.thread_count() == 1, dr.thread_count()
        print("loaded", len(s.emitters()))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=240, check=False
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "loaded 1" in out.stdout
