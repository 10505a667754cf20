"""The camera in the file (mcdenoise.io.camera) and the registry methods on FeatureBuffers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from ao_gbuffers import planes_gbuffer

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.io.camera import CameraInfo, camera_from_attributes, camera_from_record, look_at
from mcdenoise.methods.ao import METHODS
from mcdenoise.render.scene_spec import Camera
from mcdenoise.render.scenes import camera_metadata, camera_to_world


def test_io_look_at_is_the_renderers():
    cam = Camera(origin=(2.6, 2.0, 3.6), target=(-0.2, 0.45, -0.2), fov=50)
    np.testing.assert_allclose(
        look_at(cam.origin, cam.target, cam.up), camera_to_world(cam), atol=1e-12
    )


def test_metadata_round_trips_through_the_header():
    cam = Camera(origin=(0.0, 1.0, 4.0), target=(0.0, 0.5, 0.0), fov=35)
    attrs = {"mcdenoise:camera": json.dumps(camera_metadata(cam, ao_radius=0.75))}
    info = camera_from_attributes(attrs)
    assert info is not None
    assert info.fov == 35 and info.fov_axis == "x" and info.ao_radius == 0.75
    assert info.near == 0.01 and info.far == 1e4
    np.testing.assert_allclose(info.to_world, camera_to_world(cam))
    # a sequence frame's older record (spec camera only) gives the same matrix
    old = {k: v for k, v in camera_metadata(cam).items() if k not in ("to_world", "near", "far")}
    np.testing.assert_allclose(camera_from_record(old).to_world, camera_to_world(cam))
    assert camera_from_attributes({}) is None


def test_world_to_view_maps_the_view_direction_to_plus_z():
    cam = Camera(origin=(1.0, 2.0, 3.0), target=(0.0, 0.0, 0.0), fov=40)
    info = camera_from_record(camera_metadata(cam))
    forward = -np.asarray(cam.origin) / np.linalg.norm(cam.origin)
    np.testing.assert_allclose(info.world_to_view() @ forward, [0, 0, 1], atol=1e-12)
    # world up appears pointing up the image: view y (down) negative
    assert (info.world_to_view() @ np.array([0.0, 1.0, 0.0]))[1] < 0
    assert CameraInfo(fov=90).focal_pixels(100, 50) == pytest.approx(50.0)


@pytest.mark.parametrize(
    "bad", ['{"fov": 200}', "not json", '{"origin": [0, 0, 0]}', '{"fov": 40, "to_world": 3}']
)
def test_bad_camera_records_raise_one_line_errors(bad):
    with pytest.raises(InputError) as err:
        camera_from_attributes({"mcdenoise:camera": bad}, "x.exr")
    assert "\n" not in str(err.value)


def _ao_buffers(with_camera: bool) -> FeatureBuffers:
    """An AO-render-like FeatureBuffers of a floor, camera pitched 30° down (world y up)."""
    g, _ = planes_gbuffer([((0, 1, 0), 1.0)], pitch=30, height=24, width=32)
    depth = g.position.norm(dim=0, keepdim=True)
    # the synthetic world is y-down; the renderer's is y-up: camera looking down -z, tilted
    cam = Camera(
        origin=(0.0, 1.0, 0.0),
        target=(0.0, 1.0 - math.sin(math.radians(30)), -math.cos(math.radians(30))),
        fov=60,
    )
    info = camera_from_record(camera_metadata(cam))
    view_normal = g.normal
    world_normal = torch.einsum(
        "ji,jhw->ihw", torch.as_tensor(info.world_to_view(), dtype=torch.float32), view_normal
    )
    attrs = (
        {"mcdenoise:camera": json.dumps(camera_metadata(cam, ao_radius=0.5))} if with_camera else {}
    )
    return FeatureBuffers(
        {"color": torch.rand(3, 24, 32), "depth": depth, "normal": world_normal}, attributes=attrs
    )


@pytest.mark.parametrize("method", METHODS, ids=lambda m: m.name)
def test_methods_read_the_camera_and_output_grey_ao(method):
    fb = _ao_buffers(with_camera=True)
    assert method.accepts(fb) is None
    out = method.run(fb, method.resolve_params(None), torch.device("cpu"))
    assert out.shape == (3, 24, 32)
    assert torch.equal(out[0], out[1]) and torch.equal(out[1], out[2])
    assert out.min() > 0.9  # an open floor: unoccluded


def test_inputs_without_a_camera_need_fov_and_radius():
    fb = _ao_buffers(with_camera=False)
    gtao = next(m for m in METHODS if m.name == "gtao")
    reason = gtao.accepts(fb)
    assert reason is not None and "-p fov=" in reason
    assert "radius" in (gtao.accepts(fb, {"fov": "60"}) or "")
    out = gtao.run(fb, gtao.resolve_params({"fov": "60", "radius": "0.5"}), torch.device("cpu"))
    assert out.min() > 0.9  # normals rebuilt from depth


def test_view_space_conventions_match_the_renderers_positions():
    # The fixture is a real mcdenoise render (tests/ao/test_ao_render.py): its world positions
    # must be what depth + camera rebuild (fov axis, Mitsuba's x-left camera frame, y down,
    # depth along the ray). A pixel's buffers average its samples, so the rebuilt point of
    # a pixel-centre ray lies within about a pixel footprint (z / f, here ~0.08) of it.
    from pathlib import Path

    from mcdenoise.ao.geometry import view_gbuffer
    from mcdenoise.io import load_buffers

    fb = load_buffers(Path(__file__).resolve().parent / "ao_contact_48x36.exr")
    cam = camera_from_attributes(fb.attributes)
    assert cam is not None and cam.ao_radius == 0.6
    h, w = fb.shape
    rot = torch.as_tensor(cam.world_to_view(), dtype=torch.float32)
    g = view_gbuffer(fb["depth"], cam.focal_pixels(w, h))
    world = torch.einsum("ji,jhw->ihw", rot, g.position) + torch.as_tensor(
        cam.to_world[:3, 3], dtype=torch.float32
    ).view(3, 1, 1)
    err = (world - fb["position"]).norm(dim=0)[g.valid]
    assert err.median() < 0.03 and err.quantile(0.9) < 0.06
    # the renderer's normals, rotated into view space, agree with those rebuilt from depth
    g2 = view_gbuffer(fb["depth"], g.focal, normal=fb["normal"], world_to_view=rot)
    assert (g2.normal * g.normal).sum(0)[g.valid].median() > 0.98


def test_fov_axis_option_for_a_vertical_field_of_view():
    fb = _ao_buffers(with_camera=False)  # 32 wide, 24 high, horizontal fov 60
    gtao = next(m for m in METHODS if m.name == "gtao")
    vertical = 2 * math.degrees(math.atan(math.tan(math.radians(30)) * 24 / 32))
    a = gtao.run(fb, gtao.resolve_params({"fov": "60", "radius": "0.5"}), torch.device("cpu"))
    b = gtao.run(
        fb,
        gtao.resolve_params({"fov": str(vertical), "fov_axis": "y", "radius": "0.5"}),
        torch.device("cpu"),
    )
    assert torch.allclose(a, b, atol=1e-4)
    with pytest.raises(InputError):
        gtao.run(fb, gtao.resolve_params({"fov": "60", "fov_axis": "z", "radius": "0.5"}), "cpu")
