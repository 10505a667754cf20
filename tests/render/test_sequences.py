"""Tests of ``mcdenoise.render.animation`` and of sequences in ``generate`` / ``mcdenoise render``.

Camera paths are checked as geometry (no Mitsuba). Motion vectors are checked against
analytic values on a plane (pure camera translation, dolly), a moving object under a static
camera, and by the warp test: frame t−1's reference, backward-warped by frame t's vectors,
reproduces frame t's reference to within its own Monte Carlo noise where the mask says the
history is valid, and clearly does not when the vectors are zeroed. Renders are tiny
(16×16 to 32×32, 3 frames) in ``scalar_rgb``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import torch

from mcdenoise.errors import InputError
from mcdenoise.io import load_buffers, probe_exr, read_exr
from mcdenoise.render import animation as sq
from mcdenoise.render import generate as gen
from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.effects import plan_effects
from mcdenoise.render.generate import generate
from mcdenoise.render.jobs import jobs_from_specs
from mcdenoise.render.layout import export_samples, frame_file, frame_reference_file
from mcdenoise.render.manifest import load_manifest
from mcdenoise.render.scene_spec import SpecError, parse_spec

VARIANT = "scalar_rgb"

# A plane facing the camera (+z), the camera on the z axis looking down -z: every centre ray
# hits the plane at distance D = 4 (camera-space depth), so the motion is analytic.
PLANE = """
name = "plane"
effects = ["direct"]
[camera]
origin = [0, 0, 4]
target = [0, 0, 0]
fov = 40
{animation}
[[objects]]
shape = "rectangle"
transform = {{ scale = [20, 20, 1] }}
[[lights]]
type = "constant"
radiance = [1, 1, 1]
"""

# A sphere moving right in front of a floor, static camera looking along -z at its height.
MOVING = """
name = "moving"
effects = ["direct"]
[camera]
origin = [0, 0.5, 4]
target = [0, 0.5, 0]
fov = 40
[animation]
camera_path = "static"
[[objects]]
shape = "rectangle"
transform = { rotate = [-90, 0, 0], scale = [4, 4, 1] }
[[objects]]
shape = "sphere"
center = [-0.3, 0.5, 0]
radius = 0.5
motion = { translate = [0.6, 0, 0] }
[[lights]]
type = "constant"
radiance = [1, 1, 1]
"""

# Diffuse, smoothly textured (value noise), lit by a uniform sky: view-independent shading
# that varies at the scale of a few pixels, so a wrong motion shows and bilinear resampling
# does not. The camera looks down on the floor (no grazing horizon).
WARP = """
name = "{name}"
effects = ["direct"]
[camera]
origin = [0, 2.5, 3.5]
target = [0, 0.3, 0]
fov = 45
[animation]
camera_path = "orbit"
angle = 20
[[objects]]
shape = "rectangle"
transform = {{ rotate = [-90, 0, 0], scale = [4, 4, 1] }}
material = {{ type = "diffuse", reflectance = {{ noise = {{ color0 = [0.1, 0.1, 0.1], color1 = [0.9, 0.8, 0.6], scale = 3, seed = 3 }} }} }}
[[objects]]
shape = "sphere"
center = [0.2, 0.5, 0]
radius = 0.5
material = {{ type = "diffuse", reflectance = {{ noise = {{ color0 = [0.8, 0.2, 0.1], color1 = [0.1, 0.3, 0.8], scale = 3, seed = 1 }} }} }}
[[lights]]
type = "constant"
radiance = [1, 1, 1]
"""

# The small ball scene of the still-image tests, for the file, resume and shard tests.
BALL = """
name = "{name}"
effects = ["direct"]
[camera]
origin = [0, 1, 4]
target = [0, 0.5, 0]
[[objects]]
shape = "rectangle"
transform = {{ rotate = [-90, 0, 0], scale = [3, 3, 1] }}
[[objects]]
shape = "sphere"
center = [0, 0.5, 0]
radius = {radius}
material = {{ type = "diffuse", reflectance = [0.7, 0.3, 0.2] }}
motion = {{ translate = [0.2, 0, 0] }}
[[lights]]
type = "point"
position = [1, 3, 2]
intensity = [20, 20, 20]
"""


def spec_of(text: str, **fmt):
    return parse_spec(tomllib.loads(text.format(**fmt) if fmt else text), source="test.toml")


def plane_spec(animation: str):
    return spec_of(PLANE, animation=animation)


def film_scale(fov: float, width: int) -> float:
    return 0.5 * width / math.tan(math.radians(fov) / 2)


@pytest.fixture(scope="module")
def variant() -> str:
    pytest.importorskip("mitsuba")
    from mcdenoise.render.mitsuba_setup import ensure_variant

    return ensure_variant(VARIANT)


def geometry(spec, frames: int, width: int, height: int) -> list[sq.GeometryBuffer]:
    plan = plan_effects(spec)
    cams = sq.frame_cameras(spec, frames)
    return [
        sq.render_geometry(sq.spec_at(spec, s), plan, c, width, height)
        for s, c in zip(sq.frame_times(frames), cams)
    ]


def config(out: Path, **kw) -> RenderConfig:
    base = {"width": 16, "height": 16, "spp": (1, 4), "ref_spp": 8, "variant": VARIANT, "frames": 3}
    base.update(kw)
    return RenderConfig(out=out, **base)


# --- camera paths (no Mitsuba) ----------------------------------------------------------------
def test_orbit_turns_about_the_target_by_the_angle_counter_clockwise() -> None:
    spec = plane_spec('[animation]\ncamera_path = "orbit"\nangle = 30')
    cams = sq.frame_cameras(spec, 4)
    target = np.array(spec.camera.target)
    offsets = [np.array(c.origin) - target for c in cams]
    assert all(c.target == spec.camera.target and c.fov == spec.camera.fov for c in cams)
    assert cams[0].origin == pytest.approx(spec.camera.origin)
    for a, b in itertools.pairwise(offsets):
        assert np.linalg.norm(b) == pytest.approx(4.0)
        cos = float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
        assert math.degrees(math.acos(min(cos, 1.0))) == pytest.approx(10.0)
    # Right-handed about up = +y: from +z towards +x (counter-clockwise seen from above).
    assert offsets[-1] == pytest.approx(
        [4 * math.sin(math.radians(30)), 0, 4 * math.cos(math.radians(30))]
    )


def test_dolly_keyframes_static_and_the_default_orbit() -> None:
    dolly = sq.frame_cameras(plane_spec('[animation]\ncamera_path = "dolly"\nfraction = 0.5'), 3)
    assert [c.origin[2] for c in dolly] == pytest.approx([4.0, 3.0, 2.0])
    keys = """[animation]
camera_path = "keyframes"
keyframes = [{ origin = [0, 0, 4], target = [0, 0, 0] }, { origin = [2, 0, 4], target = [2, 0, 0] },
             { origin = [2, 2, 4] }]"""
    cams = sq.frame_cameras(plane_spec(keys), 5)  # keys at s = 0, 0.5, 1; frames at 0, .25, ...
    assert np.array([c.origin for c in cams]) == pytest.approx(
        np.array([(0, 0, 4), (1, 0, 4), (2, 0, 4), (2, 1, 4), (2, 2, 4)])
    )
    assert np.array([c.target for c in cams]) == pytest.approx(
        np.array([(0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 0, 0), (2, 0, 0)])
    )
    static = sq.frame_cameras(plane_spec('[animation]\ncamera_path = "static"'), 3)
    assert all(c == static[0] for c in static)
    # No [animation]: 1 degree per frame about the target.
    spec = plane_spec("")
    default = sq.frame_cameras(spec, 6)
    assert sq.sequence_animation(spec, 6).angle == pytest.approx(5.0)
    end = np.array(default[-1].origin)
    assert math.degrees(math.atan2(end[0], end[2])) == pytest.approx(5.0)


def test_thin_lens_keeps_its_focus_offset_and_bad_paths_are_errors() -> None:
    text = PLANE.replace(
        "fov = 40", 'fov = 40\ntype = "thinlens"\naperture_radius = 0.1\nfocus_distance = 3.5'
    )
    text = text.replace('effects = ["direct"]', 'effects = ["direct", "dof"]')
    cams = sq.frame_cameras(
        spec_of(text, animation='[animation]\ncamera_path = "dolly"\nfraction = 0.5'), 3
    )
    assert [c.focus_distance for c in cams] == pytest.approx([3.5, 2.5, 1.5])  # focus plane stays
    assert all(c.type == "thinlens" and c.aperture_radius == 0.1 for c in cams)
    with pytest.raises(SpecError, match="focus behind the camera"):
        sq.frame_cameras(
            spec_of(text, animation='[animation]\ncamera_path = "dolly"\nfraction = 0.9'), 3
        )
    through = """[animation]
camera_path = "keyframes"
keyframes = [{ origin = [0, 0, 4], target = [0, 0, 0] }, { origin = [0, 0, -4] }]"""
    with pytest.raises(SpecError, match=r"s = 0.5: the camera origin reaches its target"):
        sq.frame_cameras(plane_spec(through), 3)
    with pytest.raises(InputError, match="frames must be an integer >= 2"):
        sq.frame_cameras(plane_spec(""), 1)


def test_moving_objects_are_placed_at_each_time() -> None:
    spec = spec_of(MOVING)
    assert sq.object_offsets(spec, 0.5).tolist() == [[0, 0, 0], [0.3, 0, 0]]
    moved = sq.spec_at(spec, 1.0)
    assert moved.objects[1].center == pytest.approx((0.3, 0.5, 0.0))
    assert moved.objects[0] == spec.objects[0] and moved.camera == spec.camera
    cube = spec_of(
        MOVING.replace(
            'shape = "sphere"\ncenter = [-0.3, 0.5, 0]\nradius = 0.5',
            'shape = "cube"\ntransform = { translate = [1, 0, 0], rotate = [0, 30, 0] }',
        )
    )
    t = sq.spec_at(cube, 0.5).objects[1].transform
    assert t.translate == pytest.approx((1.3, 0, 0)) and t.rotate == (0, 30, 0)
    still = plane_spec("")
    assert sq.spec_at(still, 0.7) is still  # nothing moves: the same spec


def test_projection_round_trips_pixel_centres() -> None:
    spec = plane_spec('[animation]\ncamera_path = "orbit"\nangle = 40')
    cam = sq.frame_cameras(spec, 2)[1]
    d = sq.pixel_directions(cam, 24, 16)
    assert np.linalg.norm(d, axis=-1) == pytest.approx(np.ones((16, 24)))
    for pts, fn in (
        (np.array(cam.origin) + 3.7 * d, sq.project_points),
        (d, sq.project_directions),
    ):
        q, z = fn(pts, cam, 24, 16)
        centres = np.stack(np.meshgrid(np.arange(24) + 0.5, np.arange(16) + 0.5), axis=-1)
        assert np.abs(q - centres).max() < 1e-9 and (z > 0).all()


def test_warp_previous_shifts_by_whole_pixels_and_checks_shapes() -> None:
    img = torch.arange(2 * 6 * 7, dtype=torch.float64).reshape(1, 2, 6, 7)
    motion = torch.zeros(1, 2, 6, 7, dtype=torch.float64)
    torch.testing.assert_close(sq.warp_previous(img, motion), img)
    motion[:, 0], motion[:, 1] = 2.0, -1.0  # prev = p + (2, -1): two right, one up
    out = sq.warp_previous(img, motion)
    torch.testing.assert_close(out[:, :, 1:, :5], img[:, :, :5, 2:])
    motion[:, 0] = 0.5  # halfway between two columns: their mean
    torch.testing.assert_close(
        sq.warp_previous(img, motion)[:, :, 1:, :6], (img[:, :, :5, :6] + img[:, :, :5, 1:]) / 2
    )
    with pytest.raises(InputError, match="does not fit"):
        sq.warp_previous(img, motion[:, :, :5])
    with pytest.raises(InputError, match=r"\(B, 2, H, W\)"):
        sq.warp_previous(img[0], motion[0])


def plane_geometry(camera, w: int, h: int) -> sq.GeometryBuffer:
    """Hits of the pixel-centre rays of ``camera`` on the plane z = 0 (object 0)."""
    d = sq.pixel_directions(camera, w, h)
    o = np.array(camera.origin)
    pos = o + (-o[2] / d[..., 2])[..., None] * d
    return sq.GeometryBuffer(pos, np.zeros((h, w), dtype=np.int64), camera)


def test_each_condition_of_the_validity_mask_counts() -> None:
    """Synthetic geometry: a static camera over a plane (q = p, one tap per pixel), with the
    previous frame edited so that exactly one condition fails in each case."""
    spec = plane_spec('[animation]\ncamera_path = "static"')
    cam = spec.camera
    w, h = 12, 10
    cur = plane_geometry(cam, w, h)
    motion, valid = sq.motion_vectors(cur, plane_geometry(cam, w, h))
    assert float(motion.abs().max()) < 1e-9 and bool(valid.all())

    # Another object at the same place (same depth) over a block: its inside is invalid.
    prev = plane_geometry(cam, w, h)
    prev.object[2:8, 2:8] = 1
    v = sq.motion_vectors(cur, prev)[1][0].numpy()
    assert not v[2:8, 2:8].any()
    # ... and the one-pixel band around it, whose taps' footprints cross the edge.
    assert not v[1, 2:8].any() and not v[2:8, 8].any()
    assert v[0].all() and v[:, 10:].all()

    # One pixel of another object: its 3×3 neighbourhood is not pure in the previous frame.
    prev = plane_geometry(cam, w, h)
    prev.object[5, 5] = 1
    v = sq.motion_vectors(cur, prev)[1][0].numpy()
    assert not v[4:7, 4:7].any() and v.sum() == w * h - 9

    # The same object, but closer to the camera than the point (it was hidden): invalid.
    prev = plane_geometry(cam, w, h)
    prev.position[3, 4] = 0.5 * (prev.position[3, 4] + np.array(cam.origin))
    v = sq.motion_vectors(cur, prev)[1][0].numpy()
    assert not v[3, 4] and v.sum() == w * h - 1

    # An edge in the current frame (object 1 appeared on the left): the column beside it is
    # invalid although its tap, inside object 1 in the previous frame, is pure.
    two = plane_geometry(cam, w, h)
    two.object[:, :6] = 1
    prev = plane_geometry(cam, w, h)
    prev.object[:] = 1
    v = sq.motion_vectors(two, prev)[1][0].numpy()
    assert v[:, :5].all() and not v[:, 5:].any()

    # A pixel whose point left the previous film: a narrow camera turned by 0.7°, the distance
    # test alone cannot tell the clamped border tap from the point.
    narrow = dataclasses.replace(cam, fov=10.0)
    turned = dataclasses.replace(narrow, target=(0.05, 0.0, 0.0))
    m, v = sq.motion_vectors(plane_geometry(turned, w, h), plane_geometry(narrow, w, h))
    gone = (np.arange(w) + 0.5 + m[0].numpy() > w) | (np.arange(w) + 0.5 + m[0].numpy() < 0)
    assert gone.any() and not v[0].numpy()[gone].any() and v[0].numpy()[~gone].all()


# --- geometry pass and motion vectors (Mitsuba) -----------------------------------------------
@pytest.mark.mitsuba
@pytest.mark.parametrize("thinlens", [False, True])
def test_geometry_pass_hits_through_pixel_centres(variant: str, thinlens: bool) -> None:
    text = MOVING
    if thinlens:
        text = text.replace("fov = 40", 'fov = 40\ntype = "thinlens"\naperture_radius = 0.3')
        text = text.replace('effects = ["direct"]', 'effects = ["direct", "dof"]')
    spec = spec_of(text)
    g = geometry(spec, 2, 24, 16)[0]
    q, _ = sq.project_points(g.position, spec.camera, 24, 16)
    centres = np.stack(np.meshgrid(np.arange(24) + 0.5, np.arange(16) + 0.5), axis=-1)
    assert np.abs(q - centres)[g.hit].max() < 2e-3  # the lens centre: no defocus offset
    assert (
        g.object[8, 10] == 1 and g.object[15, 12] == 0 and g.object[0, 0] == -1
    )  # ball, floor, sky
    assert (g.position[~g.hit] == 0).all()


@pytest.mark.mitsuba
def test_camera_translation_over_a_plane_gives_the_analytic_motion(variant: str) -> None:
    keys = """[animation]
camera_path = "keyframes"
keyframes = [{ origin = [0, 0, 4], target = [0, 0, 0] }, { origin = [1, 0, 4], target = [1, 0, 0] }]"""
    w, h = 32, 24
    g = geometry(plane_spec(keys), 3, w, h)
    motion, valid = sq.motion_vectors(g[2], g[1])
    # The camera moved 0.5 to the right (+x is image right): points moved f * 0.5 / 4 to the left.
    shift = film_scale(40, w) * 0.5 / 4
    torch.testing.assert_close(motion[0], torch.full((h, w), shift), atol=2e-3, rtol=0)
    torch.testing.assert_close(motion[1], torch.zeros(h, w), atol=2e-3, rtol=0)
    inside = torch.from_numpy(np.arange(w) + 0.5 + shift <= w).expand(h, w)
    assert torch.equal(valid[0] > 0, inside)  # valid unless the point left the previous film
    m0, v0 = sq.motion_vectors(g[0], None)
    assert not m0.any() and not v0.any()  # frame 0: no history


@pytest.mark.mitsuba
def test_dolly_towards_a_plane_scales_about_the_centre(variant: str) -> None:
    w, h = 24, 16
    g = geometry(plane_spec('[animation]\ncamera_path = "dolly"\nfraction = 0.5'), 3, w, h)
    motion, valid = sq.motion_vectors(g[2], g[1])  # distance 3 -> 2
    centres = torch.from_numpy(np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)))
    centre = torch.tensor([w / 2, h / 2], dtype=torch.float64).view(2, 1, 1)
    want = (centres - centre) * (2.0 / 3.0 - 1.0)
    torch.testing.assert_close(motion.double(), want, atol=2e-3, rtol=0)
    assert bool(valid.all())  # zooming in: everything was on the previous film


@pytest.mark.mitsuba
def test_moving_object_uses_its_own_motion_and_marks_what_it_uncovers(variant: str) -> None:
    spec = spec_of(MOVING)
    w, h = 32, 24
    g = geometry(spec, 3, w, h)
    disp = sq.object_offsets(spec, 1.0) - sq.object_offsets(spec, 0.5)
    motion, valid = sq.motion_vectors(g[2], g[1], disp)
    ball, floor = g[2].object == 1, g[2].object == 0
    # The ball moved 0.3 right at camera depth z = 4 - X.z: its points came from the left.
    z = 4.0 - g[2].position[..., 2]
    want = -film_scale(40, w) * 0.3 / z
    assert np.abs(motion[0].numpy() - want)[ball].max() < 2e-3
    assert np.abs(motion[1].numpy())[ball].max() < 2e-3
    # The static floor (static camera) does not move; where the ball was, it was hidden.
    assert float(motion[:, torch.from_numpy(floor)].abs().max()) < 1e-4  # float32 positions
    uncovered = floor & (g[1].object == 1)
    assert uncovered.sum() >= 4 and not valid[0][torch.from_numpy(uncovered)].any()
    far = torch.from_numpy(floor & (g[1].object == 0))
    assert float(valid[0][far].mean()) > 0.8  # floor seen in both frames: mostly valid
    # Without the object's own motion, the ball's vectors are wrong (0 here).
    wrong, _ = sq.motion_vectors(g[2], g[1])
    assert np.abs(wrong[0].numpy() - want)[ball].min() > 1.0


ORBIT_KEYS = """[animation]
camera_path = "keyframes"
keyframes = [{ origin = [0, 0, 4], target = [0, 0, 0] }, { origin = [1, 0, 4], target = [1, 0, 0] }]"""


@pytest.mark.mitsuba
def test_motion_next_over_a_translating_camera_is_the_analytic_opposite(variant: str) -> None:
    """The camera moves right by 0.5 per frame over a plane at depth 4: ``motion`` is
    ``+shift`` (points came from the right), ``motion_next`` is ``-shift``; the last frame
    has no next frame."""
    w, h = 32, 24
    g = geometry(plane_spec(ORBIT_KEYS), 3, w, h)
    shift = film_scale(40, w) * 0.5 / 4
    nxt, valid = sq.next_motion_vectors(g[1], g[2])
    torch.testing.assert_close(nxt[0], torch.full((h, w), -shift), atol=2e-3, rtol=0)
    torch.testing.assert_close(nxt[1], torch.zeros(h, w), atol=2e-3, rtol=0)
    inside = torch.from_numpy(np.arange(w) + 0.5 - shift >= 0).expand(h, w)
    assert torch.equal(valid[0] > 0, inside)  # valid unless the point leaves the next film
    last, none = sq.next_motion_vectors(g[2], None)
    assert not last.any() and not none.any()


@pytest.mark.mitsuba
@pytest.mark.parametrize("scene", ["orbit", "moving"])
def test_motion_next_of_a_frame_is_minus_the_motion_of_the_next(variant: str, scene: str) -> None:
    """At pixel p of frame t, ``motion_next_t(p) = -motion_{t+1}(q)``, ``q = p +
    motion_next_t(p)``: frame t+1's vectors (bilinearly sampled at q) bring the point back.
    Checked where both masks hold (every tap of q valid in frame t+1), on an orbiting camera
    over a textured floor and a ball, and on a ball moving under a static camera (the ball's
    own displacement is needed: without it, its vectors are wrong)."""
    spec = spec_of(WARP, name="w") if scene == "orbit" else spec_of(MOVING)
    w, h = 32, 24
    g = geometry(spec, 3, w, h)
    disp = sq.object_offsets(spec, 1.0) - sq.object_offsets(spec, 0.5)
    nxt, next_valid = sq.next_motion_vectors(g[1], g[2], disp)
    motion, valid = sq.motion_vectors(g[2], g[1], disp)
    back = sq.warp_previous(motion[None].double(), nxt[None].double())[0]
    taps_valid = sq.warp_previous(valid[None], nxt[None])[0]
    both = (next_valid[0] > 0) & (taps_valid[0] > 0.999)
    assert int(both.sum()) > 0.5 * w * h
    assert float(nxt.norm(dim=0)[both].mean()) > 0.1  # something really moves
    err = (back + nxt.double()).abs().amax(dim=0)[both]
    # Exact up to bilinear interpolation of a smooth field between pixel centres: tiny on the
    # ball, a little more where the floor's perspective bends the field most.
    assert float(err.median()) < 5e-3 and float(err.quantile(0.9)) < 1e-2, err.max()
    if scene == "moving":
        ball = torch.from_numpy(g[1].object == 1) & both
        assert float(err[ball[both]].max()) < 1e-2 and int(ball.sum()) >= 8
        wrong, _ = sq.next_motion_vectors(g[1], g[2])  # the ball's motion left out
        assert float((wrong - nxt)[:, ball].abs().max()) > 1.0
    # Frame t+1 sees part of what frame t saw: some pixels leave or get covered.
    assert 0.3 < float(next_valid.mean()) < 1.0


@pytest.mark.mitsuba
def test_warping_the_previous_reference_reproduces_the_current_one(
    tmp_path: Path, variant: str
) -> None:
    """Frame t−1's reference warped by frame t's vectors matches frame t's reference within
    its Monte Carlo noise on valid pixels (2 px from the border); zeroed vectors do not."""
    spec = spec_of(WARP, name="warp")
    out = tmp_path / "w"
    cfg = config(out, width=32, height=32, spp=(1,), ref_spp=512)
    generate(jobs_from_specs([spec]), cfg)
    for f in (1, 2):
        cur = load_buffers(out / frame_reference_file("warp", f))
        prev = load_buffers(out / frame_reference_file("warp", f - 1))
        mask = torch.from_numpy(
            read_exr(out / frame_reference_file("warp", f)).pixels[sq.VALID_CHANNEL]
        )[None]
        assert 0.5 < float(mask.mean()) < 0.95  # disocclusions and edges are left out
        motion = cur["motion"][None]
        assert float(motion.norm(dim=1).mean()) > 2.0  # pixels really move
        warped = sq.warp_previous(prev["color"][None], motion)[0]
        err = sq.masked_error(warped, cur["color"], mask, border=2)
        zero = sq.masked_error(
            sq.warp_previous(prev["color"][None], torch.zeros_like(motion))[0],
            cur["color"],
            mask,
            border=2,
        )
        # Noise floor: E|a - b| for independent Gaussian means = sqrt(2/pi) * sd(a - b).
        sd = (cur["color_var"] + sq.warp_previous(prev["color_var"][None], motion)[0]).sqrt()
        floor = math.sqrt(2 / math.pi) * sq.masked_error(sd, torch.zeros_like(sd), mask, border=2)
        assert err < 1.5 * floor, (err, floor)
        assert zero > 3 * err, (zero, err)
        assert err < 0.02 * float(cur["color"].mean())


# --- files, manifest, resume, shards, CLI -----------------------------------------------------
@pytest.mark.mitsuba
def test_sequence_files_load_with_motion_and_the_manifest_records_frames(
    tmp_path: Path, variant: str
) -> None:
    spec = spec_of(BALL, name="ball", radius=0.5)
    out = tmp_path / "out"
    result = generate(jobs_from_specs([spec]), config(out))
    assert result.rendered == ["ball"]
    folder = out / "ball"
    assert sorted(p.name for p in folder.glob("*.exr")) == [f"frame_000{f}.exr" for f in range(3)]
    assert sorted(p.name for p in (folder / "ref").glob("*.exr")) == [
        f"frame_000{f}.exr" for f in range(3)
    ]
    from mcdenoise.denoise_files import collect_inputs

    assert [p.name for p in collect_inputs([folder])] == [f"frame_000{f}.exr" for f in range(3)]
    cams = sq.frame_cameras(spec, 3)
    m = load_manifest(out)
    assert m["settings"]["frames"] == 3 and m["image_count"] == 1
    (rec,) = m["images"]
    assert (
        rec["complete"] and rec["sequence"]["frames"] == 3 and rec["sequence"]["default_animation"]
    )
    assert rec["sequence"]["animation"] == {"camera_path": "orbit", "angle": 2.0}
    assert rec["sequence"]["moving_objects"] == [1]
    assert [fr["frame"] for fr in rec["frames"]] == [0, 1, 2]
    assert len({fr["seed"] for fr in rec["frames"]}) == 3  # independent noise per frame
    total = 0.0
    for f, fr in enumerate(rec["frames"]):
        assert fr["files"] == {
            "noisy": frame_file("ball", f),
            "reference": frame_reference_file("ball", f),
        }
        assert fr["camera"]["origin"] == pytest.approx(list(cams[f].origin))
        assert fr["object_offsets"][1] == pytest.approx([0.1 * f, 0, 0])
        assert fr["levels"][-1]["render_seconds"] > 0 and fr["geometry_seconds"] > 0
        total += fr["levels"][-1]["render_seconds"] + fr["reference"]["render_seconds"]
        noisy = out / fr["files"]["noisy"]
        assert [p.name for p in probe_exr(noisy)] == ["spp1", "spp4"]
        parts = [load_buffers(noisy, part=p) for p in ("spp1", "spp4")]
        parts.append(load_buffers(out / fr["files"]["reference"]))
        motions = {"motion", "motion_valid", "motion_next", "motion_next_valid"}
        for fb in parts:  # the canonical profile reads every motion buffer back by name
            assert {"color", "color_var", "albedo", "normal", "depth", "position"} | motions <= set(
                fb.names()
            )
            for name in motions:
                torch.testing.assert_close(fb[name], parts[0][name], rtol=0, atol=0)
            assert (
                fb.attributes["mcdenoise:frame"] == f
                and fb.attributes["mcdenoise:sequence"] == "ball"
            )
            torch.testing.assert_close(fb["motion"], parts[0]["motion"], rtol=0, atol=0)
        masks = [read_exr(noisy, part=p).pixels[sq.VALID_CHANNEL] for p in ("spp1", "spp4")]
        masks.append(read_exr(out / fr["files"]["reference"]).pixels[sq.VALID_CHANNEL])
        assert all(np.array_equal(mk, masks[0]) for mk in masks)
        assert set(np.unique(masks[0])) <= {0.0, 1.0}
        assert float(masks[0].mean()) == pytest.approx(fr["valid_fraction"], abs=1e-6)
        assert (masks[0].mean() == 0) == (f == 0)
        if f == 0:
            assert not parts[0]["motion"].any()
        else:
            assert float(parts[0]["motion"].abs().max()) > 0.1
        nxt = parts[0]["motion_next_valid"]
        assert float(nxt.mean()) == pytest.approx(fr["next_valid_fraction"], abs=1e-6)
        if f == 2:  # the last frame: no next frame
            assert not parts[0]["motion_next"].any() and not nxt.any()
        else:
            assert float(parts[0]["motion_next"].abs().max()) > 0.1 and float(nxt.mean()) > 0.3
    assert rec["render_seconds"] == pytest.approx(total, abs=1e-4)
    assert m["render_seconds"] == pytest.approx(total, abs=2e-3)
    # The folder is one sequence for a temporal method (ref/ is not read): svgf, frame by frame.
    from mcdenoise.batch import denoise_paths
    from mcdenoise.denoise_files import ReadOptions

    done = list(
        denoise_paths(
            [folder], tmp_path / "den", "svgf", device="cpu", progress=False,
            read=ReadOptions(part="spp4"),
        )
    )  # fmt: skip
    assert [o.job.output.name for o in done] == [f"frame_000{f}_spp4_svgf.exr" for f in range(3)]
    for f, o in enumerate(done):
        got = load_buffers(o.job.output)
        assert got.attributes["mcdenoise:frame"] == f and bool(torch.isfinite(got["color"]).all())


@pytest.mark.mitsuba
def test_sequences_are_deterministic_and_resume_frame_by_frame(
    tmp_path: Path, variant: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    spec = spec_of(BALL, name="ball", radius=0.5)
    jobs = jobs_from_specs([spec])
    generate(jobs, config(tmp_path / "a"))
    real = gen.write_frame

    def killed_at_frame_2(rendered, motion, cfg, seq, frame):
        if frame == 2:
            raise KeyboardInterrupt
        return real(rendered, motion, cfg, seq, frame)

    out = tmp_path / "b"
    monkeypatch.setattr(gen, "write_frame", killed_at_frame_2)
    with pytest.raises(KeyboardInterrupt):
        generate(jobs, config(out))
    (partial,) = load_manifest(out)["images"]
    assert not partial["complete"] and [f["frame"] for f in partial["frames"]] == [0, 1]
    stamps = [(out / frame_file("ball", f)).stat().st_mtime_ns for f in (0, 1)]
    rendered: list[int] = []

    def counting(rendered_image, motion, cfg, seq, frame):
        rendered.append(frame)
        return real(rendered_image, motion, cfg, seq, frame)

    monkeypatch.setattr(gen, "write_frame", counting)
    assert generate(jobs, config(out)).rendered == ["ball"]
    assert rendered == [2]  # only the missing frame
    assert [(out / frame_file("ball", f)).stat().st_mtime_ns for f in (0, 1)] == stamps
    assert load_manifest(out)["images"][0]["complete"]
    # The resumed run equals the uninterrupted one bit for bit (motion of frame 2 included).
    for f in range(3):
        for name, part in ((frame_file("ball", f), "spp4"), (frame_reference_file("ball", f), 0)):
            a, b = (read_exr(d / name, part=part).pixels for d in (tmp_path / "a", out))
            assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a), name
    again = generate(jobs, config(out))
    assert again.skipped == ["ball"] and again.rendered == []
    # A stills folder is not a sequence folder (and the other way round).
    with pytest.raises(RenderError, match=r"--frames 3.*\(stills\)"):
        generate(jobs, config(out, frames=None))


@pytest.mark.mitsuba
def test_shards_split_whole_sequences(tmp_path: Path, variant: str) -> None:
    specs = [spec_of(BALL, name=f"s{i}", radius=0.3 + 0.1 * i) for i in range(3)]
    jobs = jobs_from_specs(specs)
    out = tmp_path / "shared"
    first = generate(jobs, config(out, shard=(1, 2), frames=2))
    second = generate(jobs, config(out, shard=(2, 2), frames=2))
    assert first.rendered == ["s0", "s2"] and second.rendered == ["s1"]
    m = load_manifest(out)
    assert [r["id"] for r in m["images"]] == ["s0", "s1", "s2"]
    assert all(r["complete"] and len(r["frames"]) == 2 for r in m["images"])
    # The samples layout (data/samples) holds stills only.
    with pytest.raises(RenderError, match="s0 is a sequence"):
        export_samples(out, tmp_path / "samples")


@pytest.mark.mitsuba
def test_a_scene_mitsuba_cannot_load_is_one_clear_error(tmp_path: Path, variant: str) -> None:
    (tmp_path / "bad.obj").write_text("garbage\nf 1 2 3\n")
    text = BALL.format(name="bad", radius=0.5).replace(
        'shape = "rectangle"\ntransform = { rotate = [-90, 0, 0], scale = [3, 3, 1] }',
        'shape = "mesh"\nfile = "bad.obj"',
    )
    spec = parse_spec(tomllib.loads(text), source=str(tmp_path / "bad.toml"), base=tmp_path)
    with pytest.raises(InputError) as info:
        generate(jobs_from_specs([spec]), config(tmp_path / "o"))
    msg = str(info.value)
    assert "bad.toml: Mitsuba cannot load the geometry pass" in msg and "\n" not in msg


def test_bad_frame_counts_are_refused(tmp_path: Path) -> None:
    for bad in (1, 0, True, 2.5):
        with pytest.raises(RenderError, match="frames must be an integer >= 2"):
            config(tmp_path, frames=bad)


@pytest.mark.mitsuba
def test_cli_renders_a_sequence_and_refuses_one_frame(tmp_path: Path, variant: str) -> None:
    from click.testing import CliRunner
    from mcdenoise_cli.main import main

    path = tmp_path / "ball.toml"
    path.write_text(BALL.format(name="ball", radius=0.5), encoding="utf-8")
    tiny = ["--res", "16", "--spp", "1,4", "--ref-spp", "8", "--variant", VARIANT]
    runner = CliRunner()
    r = runner.invoke(
        main, ["render", str(path), "-o", str(tmp_path / "o"), "--frames", "2", *tiny]
    )
    assert r.exit_code == 0, r.output + r.stderr
    assert "rendered 1" in r.output and "sequence(s) of 2 frames" in r.output
    assert load_buffers(tmp_path / "o" / "ball" / "frame_0001.exr", part="spp4").spp == 4
    assert json.loads((tmp_path / "o" / "manifest.json").read_text())["settings"]["frames"] == 2
    bad = runner.invoke(
        main, ["render", str(path), "-o", str(tmp_path / "x"), "--frames", "1", *tiny]
    )
    assert bad.exit_code not in (0, None)
    err = bad.stderr.strip()
    assert len(err.splitlines()) == 1 and "frames must be an integer >= 2" in err
    assert "Traceback" not in bad.output + err


def test_docstring_examples() -> None:
    import doctest

    failed, attempted = doctest.testmod(sq, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0
