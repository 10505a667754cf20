"""Spec -> Mitsuba scene (mcdenoise/render/scenes.py): every spec feature checked by tiny renders.

Renders run in ``scalar_rgb`` (no JIT compilation, so each takes milliseconds); one test
renders in the variant ``ensure_variant("auto")`` picks. Images are float32 ``(H, W, C)``
linear RGB as Mitsuba returns them; values are compared with closed-form radiance where
one exists (point light, sun, constant environment, emitters seen directly).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mcdenoise.errors import InputError
from mcdenoise.render.effects import plan_effects
from mcdenoise.render.scene_spec import Camera, SpecError, load_spec, parse_spec

mi = pytest.importorskip("mitsuba")
from mcdenoise.render import mitsuba_setup, scenes  # noqa: E402  (after the importorskip)

pytestmark = pytest.mark.mitsuba

ROOT = Path(__file__).resolve().parents[2]
CURATED = sorted((ROOT / "data" / "scenes").glob("*.toml"))
WHITE = {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]}
FLOOR = {"shape": "rectangle", "transform": {"rotate": [-90, 0, 0], "scale": 10}, "material": WHITE}
DOWN = {"up": [0, 0, -1]}  # for cameras looking straight down


@pytest.fixture(autouse=True)
def _scalar() -> None:
    mitsuba_setup.ensure_variant("scalar_rgb")


def spec_of(effects: list[str], objects: list[dict], lights: list[dict] = (), **top: Any):
    d = {"name": "t", "effects": effects, "objects": objects, "lights": list(lights)}
    d.setdefault("camera", {"origin": [0, 1, 4], "target": [0, 1, 0]})
    d.update(copy.deepcopy(top))
    return parse_spec(copy.deepcopy(d), base=ROOT / "data" / "scenes")


def render(spec, *, size=(16, 16), spp=4, seed=0) -> np.ndarray:
    d = scenes.scene_dict(spec, plan_effects(spec), width=size[0], height=size[1])
    return np.array(mi.render(mi.load_dict(d), spp=spp, seed=seed), dtype=np.float64)


def render_aov(spec, aov: str, *, size=(32, 32), spp=4) -> np.ndarray:
    """One AOV (``albedo``, ``depth``, ...) through Mitsuba's ``aov`` integrator, by name."""
    d = scenes.scene_dict(
        spec,
        plan_effects(spec),
        width=size[0],
        height=size[1],
        integrator={"type": "aov", "aovs": f"a:{aov}"},
    )
    scene = mi.load_dict(d)
    mi.render(scene, spp=spp)
    bitmap = scene.sensors()[0].film().bitmap()
    names = [bitmap.struct_()[i].name for i in range(bitmap.channel_count())]
    pixels = np.array(bitmap, dtype=np.float64)
    return pixels[..., [i for i, n in enumerate(names) if n.startswith("a.")]]


# ------------------------------------------------------------------------------- variant


def test_ensure_variant_auto_picks_a_working_variant_and_registers_integrators():
    v = mitsuba_setup.ensure_variant("auto")
    assert v in mitsuba_setup.VARIANTS and mi.variant() == v
    # auto takes the first that works of cuda, llvm, scalar
    for better in mitsuba_setup.VARIANTS[: mitsuba_setup.VARIANTS.index(v)]:
        assert better not in mi.variants() or not mitsuba_setup.variant_works(better)
    # the project's integrators load in it
    mi.load_dict({"type": "mcd_ao", "radius": 1.0})
    spec = load_spec(ROOT / "data" / "scenes" / "sun_outdoor.toml")
    img = render(spec, size=(8, 8), spp=2)  # bitmaps, sun disk, mcd_path in the JIT variant
    assert img.shape == (8, 8, 3) and np.isfinite(img).all() and img.mean() > 0


@pytest.mark.parametrize("bad", ["cuda", "scalar_spectral", ""])
def test_ensure_variant_rejects_unknown_names(bad):
    with pytest.raises(InputError, match="variant"):
        mitsuba_setup.ensure_variant(bad)


# -------------------------------------------------------------------------------- camera


def test_camera_to_world_is_mitsubas_look_at():
    rng = np.random.default_rng(1)
    for _ in range(5):
        o, t = rng.normal(size=3) * 3, rng.normal(size=3)
        cam = Camera(origin=tuple(o), target=tuple(t))
        ours = scenes.camera_to_world(cam)
        theirs = np.array(mi.ScalarTransform4f().look_at(origin=o, target=t, up=[0, 1, 0]).matrix)
        np.testing.assert_allclose(ours, theirs, atol=1e-5)
        forward = (t - o) / np.linalg.norm(t - o)
        np.testing.assert_allclose(ours[:3, 2], forward, atol=1e-12)  # looks along local +z


def test_up_parallel_to_the_view_is_an_error():
    with pytest.raises(InputError, match="parallel"):
        scenes.camera_to_world(Camera(origin=(0, 3, 0), target=(0, 0, 0)))
    spec = spec_of(
        ["direct"],
        [FLOOR],
        [{"type": "constant", "radiance": 1}],
        camera={"origin": [0, 3, 0], "target": [0, 0, 0]},
    )
    with pytest.raises(SpecError, match="camera"):
        scenes.scene_dict(spec, plan_effects(spec), width=4, height=4)


def test_pinhole_never_samples_a_lens_and_dof_uses_thinlens():
    lit = [{"type": "constant", "radiance": 1}]
    pin = spec_of(["direct"], [FLOOR], lit)
    d = scenes.scene_dict(pin, plan_effects(pin), width=8, height=4)
    s = d["sensor"]
    assert s["type"] == "perspective" and "aperture_radius" not in s
    assert s["fov_axis"] == "x" and s["film"]["rfilter"] == {"type": "box"}
    assert s["sampler"]["type"] == "independent"
    assert (s["film"]["width"], s["film"]["height"]) == (8, 4)
    thin = spec_of(
        ["direct", "dof"],
        [FLOOR],
        lit,
        camera={
            "type": "thinlens",
            "origin": [0, 1, 4],
            "target": [0, 1, 0],
            "aperture_radius": 0.2,
            "focus_distance": 3.0,
        },
    )
    s = scenes.scene_dict(thin, plan_effects(thin), width=8, height=4)["sensor"]
    assert (s["type"], s["aperture_radius"], s["focus_distance"]) == ("thinlens", 0.2, 3.0)
    # a camera override must match the plan
    with pytest.raises(SpecError, match="pinhole"):
        scenes.scene_dict(pin, plan_effects(pin), width=4, height=4, camera=thin.camera)


def test_fov_is_horizontal_whatever_the_aspect():
    # fov 90 at distance 1: the visible half-width is 1 (the rectangle's), half-height 0.5.
    panel = {
        "shape": "rectangle",
        "transform": {"scale": [1, 0.25, 1]},
        "material": WHITE,
        "emission": [1, 1, 1],
    }
    spec = spec_of(
        ["direct"], [panel], camera={"origin": [0, 0, 1], "target": [0, 0, 0], "fov": 90}
    )
    img = render(spec, size=(32, 16), spp=4).mean(-1)
    lit = img > 0.5
    assert lit[8].all()  # every column of the middle row: the full width
    assert lit[:, 16].sum() == 8  # half of the 16 rows: 0.25 of the 0.5 half-height


def test_thin_lens_blurs_away_from_the_focus_distance():
    def contrast(dist: float, thin: bool) -> float:
        # A checker panel at ``dist`` spanning the same angle whatever the distance.
        panel = {
            "shape": "rectangle",
            "transform": {"translate": [0, 0, -dist], "scale": [dist, dist, 1]},
            "material": {
                "type": "diffuse",
                "reflectance": {
                    "checkerboard": {"color0": [0, 0, 0], "color1": [1, 1, 1], "scale": 4}
                },
            },
        }
        cam = {"origin": [0, 0, 0], "target": [0, 0, -1], "fov": 60}
        if thin:
            cam.update(type="thinlens", aperture_radius=0.3, focus_distance=2.0)
        spec = spec_of(
            ["direct", "dof"] if thin else ["direct"],
            [panel],
            [{"type": "constant", "radiance": 1}],
            camera=cam,
        )
        return float(render_aov(spec, "albedo", size=(16, 16), spp=128)[..., 0].std())

    # blur circle on the near panel: 0.3 * (2 - 0.8) / 2 = 0.18 in radius, about a square
    in_focus, near, pinhole = contrast(2.0, True), contrast(0.8, True), contrast(0.8, False)
    assert near < 0.5 * in_focus  # out of focus: blurred
    assert near < 0.5 * pinhole  # the pinhole does not blur it
    assert in_focus > 0.9 * contrast(2.0, False)  # at the focus distance: sharp


# ------------------------------------------------------------------------------ textures


def _checker_panel(texture: dict) -> Any:
    panel = {"shape": "rectangle", "material": {"type": "diffuse", "reflectance": texture}}
    return spec_of(
        ["direct"],
        [panel],
        [{"type": "constant", "radiance": 1}],
        camera={"origin": [0, 0, 1], "target": [0, 0, 0], "fov": 90},
    )


@pytest.mark.parametrize("scale", [1, 2, 4])
def test_checkerboard_has_scale_periods_per_uv_unit(scale):
    tex = {"checkerboard": {"color0": [0, 0, 0], "color1": [1, 1, 1], "scale": scale}}
    a = render_aov(_checker_panel(tex), "albedo")[..., 0]  # the panel fills the frame
    for line in (a[16], a[:, 16]):
        squares = 1 + np.count_nonzero(np.diff(line > 0.5))
        assert squares == 2 * scale


def test_noise_texture_is_seeded_bounded_and_spatially_varying():
    def albedo(seed: int) -> np.ndarray:
        tex = {
            "noise": {
                "color0": [0.1, 0.2, 0.3],
                "color1": [0.6, 0.4, 0.9],
                "scale": 4,
                "seed": seed,
            }
        }
        return render_aov(_checker_panel(tex), "albedo", spp=1)

    a, b, c = albedo(1), albedo(1), albedo(2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).mean() > 0.02
    lo, hi = np.array([0.1, 0.2, 0.3]), np.array([0.6, 0.4, 0.9])
    assert (a >= lo - 1e-4).all() and (a <= hi + 1e-4).all()
    assert a[..., 0].std() > 0.05  # not a constant


def test_image_texture_repeats_scale_times():
    def albedo(scale: float) -> np.ndarray:
        tex = {"image": {"file": "textures/tiles.png", "scale": scale}}
        return render_aov(_checker_panel(tex), "albedo", spp=8)

    one, two = albedo(1), albedo(2)
    assert one.std() > 0.05
    # twice per uv: the left half repeats in the right half (and the top in the bottom)
    assert np.abs(two[:, :16] - two[:, 16:]).mean() < 0.02
    assert np.abs(two[:16] - two[16:]).mean() < 0.02
    assert np.abs(one[:, :16] - one[:, 16:]).mean() > 0.05


# -------------------------------------------------------------------------------- lights


def _looking_down(height: float = 3.0, fov: float = 4.0, at=(0, 0, 0)) -> dict:
    return {"origin": [at[0], height, at[2]], "target": list(at), "fov": fov, **DOWN}


def test_point_light_falls_off_with_the_inverse_square():
    def centre(h: float) -> float:
        spec = spec_of(
            ["direct"],
            [FLOOR],
            [{"type": "point", "position": [0, h, 0], "intensity": [10, 10, 10]}],
            camera=_looking_down(5.0, 2.0),
        )
        return float(render(spec, size=(8, 8), spp=4)[3:5, 3:5].mean())

    # diffuse 0.5 right under the light: L = rho / pi * I / h^2
    assert centre(1.0) == pytest.approx(0.5 / math.pi * 10, rel=0.01)
    assert centre(1.0) / centre(2.0) == pytest.approx(4.0, rel=0.01)


def test_spot_light_lights_its_cone_only():
    spot = {
        "type": "spot",
        "position": [0, 2, 0],
        "target": [0, 0, 0],
        "intensity": [10, 10, 10],
        "cutoff": 20,
        "beam_width": 15,
    }
    spec = spec_of(["direct"], [FLOOR], [spot], camera=_looking_down(2.0, 80.0))
    img = render(spec, size=(33, 33), spp=4).mean(-1)
    # centre: full intensity, L = rho / pi * I / h^2; the floor at 30 deg off-axis: dark
    assert img[16, 16] == pytest.approx(0.5 / math.pi * 10 / 4, rel=0.01)
    yy, xx = np.mgrid[0:33, 0:33]
    r = np.hypot(xx - 16, yy - 16) / 16.5 * math.tan(math.radians(40))  # on the floor, h = 1
    angle = np.degrees(np.arctan(r))  # off the spot's axis; a pixel spans about 1.5 degrees
    assert (img[angle > 22] == 0).all() and (img[angle < 13] > 0.3).all()
    assert ((angle > 22) & (angle < 30)).sum() > 50


def test_constant_environment_lights_an_open_floor_with_rho_times_radiance():
    spec = spec_of(
        ["direct"], [FLOOR], [{"type": "constant", "radiance": [2, 2, 2]}], camera=_looking_down()
    )
    assert render(spec, size=(8, 8), spp=256).mean() == pytest.approx(0.5 * 2, rel=0.03)


def test_procedural_sky_is_brighter_above_than_below():
    ball = {"shape": "sphere", "radius": 1, "material": WHITE}
    spec = spec_of(
        ["direct"],
        [ball],
        [{"type": "envmap", "procedural": "sky"}],
        camera={"origin": [0, 0, 4], "target": [0, 0, 0], "fov": 35},
    )
    img = render(spec, size=(16, 16), spp=64).mean(-1)
    assert img[4:6, 6:10].mean() > 1.25 * img[10:12, 6:10].mean()  # sky above, ground below


def test_envmap_file_and_its_rotation(tmp_path):
    from mcdenoise.io.exr_write import write_exr

    # lat-long lit only where the direction has x > 0 (u in (0, 0.5) in Mitsuba's layout)
    w, h = 32, 17
    img = np.zeros((h, w), np.float32)
    img[:, : w // 2] = 2.0
    write_exr(tmp_path / "half.exr", {"R": img, "G": img, "B": img})

    def sides(rotate_y: float) -> tuple[float, float]:
        ball = {"shape": "sphere", "radius": 1, "material": WHITE}
        env = {"type": "envmap", "file": str(tmp_path / "half.exr"), "rotate": [0, rotate_y, 0]}
        spec = spec_of(
            ["direct"], [ball], [env], camera={"origin": [0, 0, 4], "target": [0, 0, 0], "fov": 35}
        )
        im = render(spec, size=(16, 16), spp=32).mean(-1)
        return float(im[6:10, 2:5].mean()), float(im[6:10, 11:14].mean())  # image left, right

    left, right = sides(0)
    assert right > 2 * left  # world +X is on the image's right
    left, right = sides(180)
    assert left > 2 * right


def test_sh_environment_with_only_a_y1_term_lights_one_side():
    coeffs = [[0.0, 0.0, 0.0]] * 36
    coeffs[3] = [1.0, 1.0, 1.0]  # Y_1^1 ∝ x: positive towards +X, clamped to 0 towards -X
    ball = {"shape": "sphere", "radius": 1, "material": WHITE}
    spec = spec_of(
        ["direct"],
        [ball],
        [{"type": "sh", "coefficients": coeffs}],
        camera={"origin": [0, 0, 4], "target": [0, 0, 0], "fov": 35},
    )
    img = render(spec, size=(16, 16), spp=32).mean(-1)
    left, right = img[6:10, 2:5].mean(), img[6:10, 11:14].mean()
    assert right > 0.05 and right > 3 * left


def test_emissive_object_is_seen_with_its_radiance():
    lamp = {"shape": "sphere", "radius": 1, "material": WHITE, "emission": [5, 2, 1]}
    spec = spec_of(["direct"], [lamp], camera={"origin": [0, 0, 4], "target": [0, 0, 0]})
    img = render(spec, size=(9, 9), spp=4)
    np.testing.assert_allclose(img[4, 4], [5, 2, 1], rtol=1e-5)
    assert (img[0, 0] == 0).all()


def test_cylinder_is_closed_by_caps_that_face_outwards():
    # an emitter only emits on its outward side: seen from above or below through an open
    # cylinder, the inside would be black
    can = {
        "shape": "cylinder",
        "transform": {"rotate": [-90, 0, 0], "scale": [0.5, 0.5, 1]},
        "material": WHITE,
        "emission": [3, 3, 3],
    }
    for y in (4.0, -3.0):
        spec = spec_of(
            ["direct"],
            [can],
            camera={"origin": [0, y, 0], "target": [0, 0.5, 0], "fov": 20, **DOWN},
        )
        np.testing.assert_allclose(render(spec, size=(5, 5), spp=2)[2, 2], [3, 3, 3], rtol=1e-5)


PLY_CUBE = """ply
format ascii 1.0
element vertex 8
property float x
property float y
property float z
element face 12
property list uchar int vertex_indices
end_header
-1 -1 -1
1 -1 -1
1 1 -1
-1 1 -1
-1 -1 1
1 -1 1
1 1 1
-1 1 1
3 0 3 2
3 0 2 1
3 4 5 6
3 4 6 7
3 0 1 5
3 0 5 4
3 2 3 7
3 2 7 6
3 1 2 6
3 1 6 5
3 0 4 7
3 0 7 3
"""


@pytest.mark.parametrize("kind", ["obj", "ply"])
def test_mesh_renders_where_its_bounding_box_projects(kind, tmp_path):
    file = "meshes/twist.obj"  # relative to data/scenes
    if kind == "ply":
        file = str(tmp_path / "cube.ply")
        Path(file).write_text(PLY_CUBE)
    mesh = {
        "shape": "mesh",
        "file": file,
        "material": WHITE,
        "emission": [1, 1, 1],
        "transform": {"translate": [0.6, 0.2, 0], "scale": [0.4, 0.6, 0.4]},
    }
    spec = spec_of(["direct"], [mesh], camera={"origin": [0, 0, 5], "target": [0, 0, 0], "fov": 40})
    img = render(spec, size=(32, 32), spp=4).mean(-1)
    # project the transformed box [-1, 1]^3 of the (unit-sized) mesh
    m = np.asarray(spec.objects[0].transform.matrix())
    corners = np.array([[x, y, z, 1] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) @ m.T
    cam = np.linalg.inv(scenes.camera_to_world(spec.camera)) @ corners.T
    t = math.tan(math.radians(20))
    # camera +x is the image's left; rows grow downwards
    cols = (0.5 - cam[0] / cam[2] / t / 2) * 32
    rows = (0.5 - cam[1] / cam[2] / t / 2) * 32
    lit_rows, lit_cols = np.nonzero(img > 0.5)
    assert lit_cols.size > 20
    assert lit_cols.min() >= math.floor(cols.min()) and lit_cols.max() <= math.ceil(cols.max())
    assert lit_rows.min() >= math.floor(rows.min()) and lit_rows.max() <= math.ceil(rows.max())
    assert img[:, :14].max() == 0  # the left half (world -x) is empty


def _sun(diameter: float, direction=(0, 1, 0), irradiance=math.pi) -> dict:
    return {
        "type": "sun",
        "direction": list(direction),
        "irradiance": [irradiance] * 3,
        "angular_diameter": diameter,
    }


@pytest.mark.parametrize("diameter", [0.0, 0.1, 0.53, 5.0])
def test_sun_gives_its_irradiance_and_a_hard_shadow(diameter):
    blocker = {
        "shape": "cube",
        "transform": {"translate": [0, 1, 0], "scale": [0.5, 0.1, 4]},
        "material": WHITE,
    }
    spec = spec_of(
        ["direct"],
        [FLOOR, blocker],
        [_sun(diameter)],
        camera={"origin": [0, 0.8, 0], "target": [0, 0, 0], "fov": 90, **DOWN},
    )
    d = scenes.scene_dict(spec, plan_effects(spec), width=32, height=8)
    assert d["light_000"]["type"] == ("directional" if diameter == 0 else "disk")
    img = render(spec, size=(32, 8), spp=8).mean(-1)
    # E = pi on a 0.5-albedo floor: L = 0.5 outside the shadow; the slab shades |x| < 0.5
    row = img[4]
    x = (np.arange(32) - 15.5) / 16 * 0.8  # floor x at each pixel centre; pixels are 0.05 wide
    lit, shade = np.abs(x) > 0.56, np.abs(x) < 0.44
    np.testing.assert_allclose(row[lit], 0.5, rtol=3e-3)
    assert (row[shade] == 0).all()
    penumbra = (row > 0.05) & (row < 0.45)
    assert penumbra.sum() <= 2 * (1 + (diameter >= 5))  # hard edges


def test_sun_geometry_reproduces_the_irradiance():
    pos, r, radiance = scenes.sun_geometry((0, 2, 0), (3, 2, 1), 0.53, (1, 1, 1), 1000.0)
    np.testing.assert_allclose(pos, [1, 1001, 1])
    alpha = math.radians(0.53) / 2
    assert r == pytest.approx(1000 * math.tan(alpha))
    # projected solid angle of the disk seen face-on from the centre: pi sin^2(alpha)
    np.testing.assert_allclose(radiance * math.pi * (r**2 / (r**2 + 1000**2)), [3, 2, 1])


def test_finite_sun_makes_caustic_fireflies_only_when_caustics_are_simulated():
    # Sunlight mirrored onto the floor reaches the camera only along floor -> mirror -> sun,
    # found by BSDF sampling alone: rare, very bright samples with a finite sun (and the
    # caustics effect), impossible with a delta sun or without the caustics effect.
    mirror = {
        "shape": "rectangle",
        "material": {"type": "conductor", "conductor": "none"},
        "transform": {"translate": [1, 1, 0], "rotate": [0, -90, 0], "scale": [2, 1, 1]},
    }
    sun_dir = (-1, 1, 0)

    def floor_image(diameter: float, effects: list[str]) -> np.ndarray:
        spec = spec_of(
            effects,
            [FLOOR, mirror],
            [_sun(diameter, sun_dir)],
            camera=_looking_down(3.0, 30.0, at=(-0.3, 0, 0)),
        )
        return render(spec, size=(16, 16), spp=32, seed=3).mean(-1)

    direct = 0.5 * math.cos(math.radians(45))  # rho E cos / pi with E = pi
    caustic = floor_image(5.0, ["direct", "indirect", "caustics"])
    no_caustic = floor_image(5.0, ["direct", "indirect"])
    delta = floor_image(0.0, ["direct", "indirect", "caustics"])
    assert caustic.max() > 10 * direct  # fireflies
    assert caustic.mean() > 1.3 * no_caustic.mean()  # the mirrored sunlight
    assert no_caustic.max() < 1.5 * direct and delta.max() < 1.5 * direct


# ----------------------------------------------------------------------- effect switches


def test_direct_only_leaves_bounce_lit_surfaces_black_and_indirect_lights_them():
    # A lamp under a ceiling faces up: the floor sees only light that bounced off the ceiling.
    ceiling = {
        "shape": "rectangle",
        "transform": {"translate": [0, 2, 0], "rotate": [90, 0, 0], "scale": 3},
        "material": WHITE,
    }
    lamp = {
        "shape": "disk",
        "transform": {"translate": [0, 1.5, 0], "rotate": [-90, 0, 0], "scale": 0.3},
        "material": WHITE,
        "emission": [20] * 3,
    }
    cam = _looking_down(1.0, 60.0, at=(1.5, 0, 0))
    direct = render(spec_of(["direct"], [FLOOR, ceiling, lamp], camera=cam), spp=16)
    full = render(spec_of(["direct", "indirect"], [FLOOR, ceiling, lamp], camera=cam), spp=16)
    assert direct.max() == 0
    assert full.mean() > 0.01 and (full > 0).mean() > 0.9


def test_ao_plan_renders_occlusion_within_its_radius_without_lights():
    column = {
        "shape": "cube",
        "transform": {"translate": [0, 1, 0], "scale": [0.25, 1, 0.25]},
        "material": WHITE,
    }
    point = {"type": "point", "position": [0, 3, 0], "intensity": [1, 1, 1]}

    def ao(radius: float) -> np.ndarray:
        spec = spec_of(
            ["ao"],
            [FLOOR, column],
            [point],
            render={"ao_radius": radius},
            camera=_looking_down(3.0, 60.0, at=(0.6, 0, 0)),
        )
        d = scenes.scene_dict(spec, plan_effects(spec), width=8, height=8)
        assert d["integrator"] == {"type": "mcd_ao", "radius": radius}
        assert not any(k.startswith("light_") for k in d)  # lights play no part
        return render(spec, size=(16, 16), spp=64).mean(-1)

    wide, narrow = ao(1.0), ao(0.05)
    assert 0 <= wide.min() and wide.max() <= 1
    assert wide.min() < 0.75  # the floor at the column's foot
    assert wide[:, 14:].mean() > 0.97  # open floor more than 1 away from the column
    assert narrow.mean() > wide.mean() + 0.02  # a shorter radius sees less occlusion


def test_given_integrator_replaces_the_plans():
    spec = spec_of(["direct"], [FLOOR], [{"type": "constant", "radiance": 1}])
    d = scenes.scene_dict(spec, plan_effects(spec), width=4, height=4, integrator={"type": "depth"})
    assert d["integrator"] == {"type": "depth"}
    d = scenes.scene_dict(spec, plan_effects(spec), width=4, height=4)
    assert d["integrator"] == plan_effects(spec).integrator_dict()


# -------------------------------------------------------------------- materials, errors


def test_materials_map_to_mitsuba_plugins():
    from mcdenoise.render.scene_spec import Material, Texture

    b = scenes.bsdf_dict(Material(type="roughplastic", roughness=0.2, ior=1.4))
    assert b["type"] == "twosided"
    assert (b["bsdf"]["type"], b["bsdf"]["distribution"], b["bsdf"]["alpha"]) == (
        "roughplastic",
        "ggx",
        0.2,
    )
    assert b["bsdf"]["int_ior"] == 1.4
    g = scenes.bsdf_dict(Material(type="dielectric", roughness=0.1))
    assert (g["type"], g["alpha"], g["int_ior"], g["ext_ior"]) == ("roughdielectric", 0.1, 1.5, 1)
    assert scenes.bsdf_dict(Material(type="dielectric"))["type"] == "dielectric"
    c = scenes.bsdf_dict(
        Material(
            type="conductor",
            eta=(0.2, 0.4, 1.4),
            k=(3, 2.5, 2),
            specular=Texture(color=(0.9, 0.9, 0.9)),
        )
    )["bsdf"]
    assert c["eta"]["value"] == [0.2, 0.4, 1.4] and "material" not in c
    assert c["specular_reflectance"]["value"] == [0.9, 0.9, 0.9]
    au = scenes.bsdf_dict(Material(type="roughconductor", conductor="Au", roughness=0.1))
    assert au["bsdf"]["material"] == "Au" and au["bsdf"]["alpha"] == 0.1
    for m in (b, g, c, au):  # each loads in Mitsuba
        mi.load_dict(m)


def test_every_material_renders_visibly_from_both_sides_when_opaque():
    # twosided: a rectangle seen from behind looks like from the front
    for material in (
        {"type": "diffuse"},
        {"type": "roughplastic", "roughness": 0.3},
        {"type": "roughconductor", "conductor": "Cu", "roughness": 0.3},
    ):
        values = []
        for z in (2.0, -2.0):
            panel = {"shape": "rectangle", "material": material}
            spec = spec_of(
                ["direct", "glossy"] if material["type"] != "diffuse" else ["direct"],
                [panel],
                [{"type": "constant", "radiance": 1}],
                camera={"origin": [0, 0, z], "target": [0, 0, 0], "fov": 20},
            )
            values.append(render(spec, size=(4, 4), spp=64).mean())
        assert values[1] == pytest.approx(values[0], rel=0.1) and values[0] > 0.05


@pytest.mark.parametrize(
    "objects,lights,fragment",
    [
        (
            [{"shape": "sphere", "material": {"type": "conductor", "conductor": "Unobtainium"}}],
            [{"type": "constant", "radiance": 1}],
            "unknown conductor",
        ),
        (
            [{"shape": "sphere", "transform": {"scale": [1, 2, 1]}}],
            [{"type": "constant", "radiance": 1}],
            "uniform scale",
        ),
        (
            [FLOOR],
            [{"type": "constant", "radiance": 1}, {"type": "envmap", "procedural": "sky"}],
            "at most one environment",
        ),
        (
            [FLOOR],
            [{"type": "spot", "position": [0, 1, 0], "target": [0, 1, 0], "intensity": [1, 1, 1]}],
            "must differ",
        ),
    ],
)
def test_what_mitsuba_would_reject_is_a_one_line_spec_error(objects, lights, fragment):
    spec = spec_of(["direct"], objects, lights)
    with pytest.raises(SpecError, match=fragment) as err:
        scenes.scene_dict(spec, plan_effects(spec), width=4, height=4)
    assert "\n" not in str(err.value)


def test_film_size_must_be_positive():
    spec = spec_of(["direct"], [FLOOR], [{"type": "constant", "radiance": 1}])
    with pytest.raises(InputError, match="film size"):
        scenes.scene_dict(spec, plan_effects(spec), width=0, height=4)


# ------------------------------------------------------------------------ curated specs


def test_there_are_curated_specs_covering_every_effect_light_shape_and_material():
    specs = [load_spec(p) for p in CURATED]
    assert len(specs) >= 10
    effects = {e for s in specs for e in s.effects}
    assert effects == {"direct", "indirect", "glossy", "caustics", "dof", "ao"}
    assert {lt.type for s in specs for lt in s.lights} == {
        "point",
        "spot",
        "constant",
        "envmap",
        "sun",
        "sh",
    }
    assert {o.shape for s in specs for o in s.objects} == {
        "sphere",
        "cube",
        "cylinder",
        "rectangle",
        "disk",
        "mesh",
    }
    assert {o.material.type for s in specs for o in s.objects} >= {
        "diffuse",
        "plastic",
        "roughplastic",
        "conductor",
        "roughconductor",
        "dielectric",
    }
    kinds = {
        t.kind
        for s in specs
        for o in s.objects
        for t in (o.material.reflectance, o.material.diffuse)
    }
    assert kinds >= {"constant", "checkerboard", "image", "noise"}
    assert any(o.emission for s in specs for o in s.objects)


@pytest.mark.parametrize("path", CURATED, ids=[p.stem for p in CURATED])
def test_curated_spec_parses_plans_and_renders(path):
    spec = load_spec(path)
    plan = plan_effects(spec)
    d = scenes.scene_dict(spec, plan, width=16, height=16)
    assert d["integrator"] == plan.integrator_dict()
    img = render(spec, size=(16, 16), spp=1)
    assert img.shape == (16, 16, 3) and np.isfinite(img).all() and img.max() > 0


def test_named_materials_are_defined_once_and_referenced():
    spec = load_spec(ROOT / "data" / "scenes" / "interior_door.toml")
    d = scenes.scene_dict(spec, plan_effects(spec), width=4, height=4)
    assert {k for k in d if k.startswith("mat_")} == {"mat_wall", "mat_wood"}
    refs = [v["bsdf"] for k, v in d.items() if k.startswith("obj_") and "id" in v["bsdf"]]
    assert {r["id"] for r in refs} == {"mat_wall", "mat_wood"}
    assert all(r["type"] == "ref" for r in refs)
    assert len(refs) == sum(o.material_name is not None for o in spec.objects) + 2  # + caps
