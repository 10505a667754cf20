"""The AO estimators on a real (tiny) AO render, and the ray-traced estimator at the corner.

``ao_contact_48x36.exr`` is ``mcdenoise render data/scenes/ao/ao_contact.toml --res 48x36 --spp 4
--ref-spp 1024`` (part spp4, buffers color/depth/normal/position, the ``mcdenoise:camera`` header kept),
``ao_contact_48x36_ref.exr`` its reference colour. Measured (1 thread): SSIM / relMSE ssao
0.848 / 0.0396, hbao 0.857 / 0.0210, alchemy 0.829 / 0.0128, gtao 0.869 / 0.0204; the 4-spp
render itself 0.849 / 0.0130.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from ao_gbuffers import corner_ao
from click.testing import CliRunner

from mcdenoise.eval.metrics import relmse, ssim
from mcdenoise.io import load_buffers
from mcdenoise.methods.ao import METHODS

HERE = Path(__file__).resolve().parent
RENDER = HERE / "ao_contact_48x36.exr"
REFERENCE = HERE / "ao_contact_48x36_ref.exr"


@pytest.fixture(scope="module")
def scores() -> dict[str, tuple[float, float]]:
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        fb = load_buffers(RENDER)
        ref = load_buffers(REFERENCE)["color"].numpy()
        out = {}
        for m in METHODS:
            x = m.run(fb, m.resolve_params(None), torch.device("cpu")).numpy()
            assert np.isfinite(x).all() and x.min() >= 0 and x.max() <= 1
            out[m.name] = (ssim(x, ref), relmse(x, ref))
        return out
    finally:
        torch.set_num_threads(before)


def test_every_estimator_is_close_to_the_ray_traced_reference(scores):
    for name, (s, e) in scores.items():
        assert s > 0.8 and e < 0.06, (name, s, e)


def test_gtao_is_closer_than_ssao(scores):
    assert scores["gtao"][0] > scores["ssao"][0]
    assert scores["gtao"][1] < scores["ssao"][1]


def test_denoise_command_runs_gtao_on_an_ao_render(tmp_path):
    from mcdenoise_cli.main import main

    out = tmp_path / "ao_gtao.exr"
    res = CliRunner().invoke(
        main, ["denoise", str(RENDER), "--method", "gtao", "-o", str(out)], catch_exceptions=False
    )
    assert res.exit_code == 0, res.output
    x = load_buffers(out)["color"]
    assert x.shape == (3, 36, 48) and torch.equal(x[0], x[2])


@pytest.mark.mitsuba
def test_ray_traced_ao_at_the_inside_corner_matches_the_closed_form():
    mi = pytest.importorskip("mitsuba")
    dr = pytest.importorskip("drjit")
    from mcdenoise.render.integrators import ao_integrator, use_variant

    use_variant()
    t = mi.ScalarTransform4f
    floor = t().rotate([1, 0, 0], -90).scale(100.0)
    wall = t().translate([0, 0, -1]).scale(100.0)  # the plane z = -1, facing +z
    scene = mi.load_dict(
        {
            "type": "scene",
            "floor": {"type": "rectangle", "to_world": floor},
            "wall": {"type": "rectangle", "to_world": wall},
        }
    )
    radius, n = 0.5, 4096
    integ = mi.load_dict(ao_integrator(radius=radius))
    for x in (0.1, 0.3):
        target = (0.0, 0.0, -1.0 + x)  # a floor point x from the wall, seen from above
        origin = (0.0, 2.0, -1.0 + x + 0.5)
        d = np.subtract(target, origin) / np.linalg.norm(np.subtract(target, origin))
        sampler = mi.load_dict({"type": "independent"})
        if dr.is_jit_v(mi.Float):
            sampler.seed(1, n)
            o = mi.Point3f(*(dr.full(mi.Float, float(v), n) for v in origin))
            ray = mi.RayDifferential3f(mi.Ray3f(o, mi.Vector3f(*(float(v) for v in d))))
            ao = np.array(integ.sample(scene, sampler, ray, None, mi.Bool(True))[0])[0]
        else:
            sampler.seed(1)
            ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(*origin), mi.Vector3f(*d)))
            n = 512
            ao = np.array([integ.sample(scene, sampler, ray, None, True)[0][0] for _ in range(n)])
        expected = corner_ao(torch.tensor(x), radius).item()
        assert abs(ao.mean() - expected) < 4.5 * math.sqrt(expected * (1 - expected) / n) + 1e-3
