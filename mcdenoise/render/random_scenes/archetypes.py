"""The five scene archetypes (interior, outdoor, tabletop, sh, ao): each builder fills a
:class:`Build` with geometry, subjects, camera and lights drawn from the distribution."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mcdenoise.render.random_scenes.distribution import Distribution, U
from mcdenoise.render.random_scenes.lights import (
    bulbs,
    environment,
    point,
    random_sh_coefficients,
    sh_grid,
    spot,
    sun,
)
from mcdenoise.render.random_scenes.materials import albedo, floor_material, texture
from mcdenoise.render.random_scenes.placement import (
    Solid,
    bounding,
    in_box,
    in_disk,
    orbit_camera,
    place_subjects,
    room_camera,
    subject_count,
    xform,
)
from mcdenoise.render.random_scenes.sampling import (
    LUMINANCE,
    UP,
    colour,
    rounded,
    rounded_vec,
    tint,
)

#: Brightness of an environment at gain 1, the reference of ``Interior.sky_per_sun``.
_NOMINAL_ENVIRONMENT = 0.5


@dataclass
class Build:
    """The scene being assembled, in the user-facing schema."""

    rng: np.random.Generator
    dist: Distribution
    archetype: str
    variant: str = ""
    objects: list[dict[str, Any]] = field(default_factory=list)
    subjects: list[Solid] = field(default_factory=list)
    materials: dict[str, dict[str, Any]] = field(default_factory=dict)
    lights: list[dict[str, Any]] = field(default_factory=list)
    camera: dict[str, Any] = field(default_factory=dict)
    indirect: bool = True
    ao_radius: float | None = None
    room_albedo: float = 0.5  # mean reflectance of a room's floor, walls and ceiling

    def all_materials(self) -> list[dict[str, Any]]:
        out = []
        for o in self.objects + [s.obj for s in self.subjects]:
            m = o.get("material")
            out.append(self.materials[m] if isinstance(m, str) else m)
        return [m for m in out if m is not None]


def _rect(translate: Sequence[float], rotate: Sequence[float], half: Sequence[float]) -> dict:
    return {"shape": "rectangle", "transform": xform(translate, rotate, [half[0], half[1], 1])}


def _white(reflectance: float) -> dict[str, Any]:
    return {"type": "diffuse", "reflectance": [reflectance] * 3}


def _room(b: Build, w: float, d: float, h: float, *, ao: bool) -> None:
    """Floor, ceiling and four walls; with variant ``window`` one of the back and side walls
    gets an opening (window or door) with a light outside (:func:`_opening_light`)."""
    rng, room = b.rng, b.dist.interior
    if ao:
        white = _white(b.dist.ao.reflectance)
        b.materials.update(floor=white, wall=white, ceiling=white)
    else:
        b.materials["floor"] = floor_material(rng, b.dist, max(w, d))
        wall_tex = (
            texture(rng, b.dist, "image", extent=max(w, d))
            if rng.random() < room.wall_image_prob
            else None
        )
        b.materials["wall"] = {
            "type": "diffuse",
            "reflectance": wall_tex or colour(rng, b.dist.materials, room.wall_value),
        }
        b.materials["ceiling"] = {
            "type": "diffuse",
            "reflectance": rounded_vec([room.ceiling_grey.draw(rng)] * 3),
        }
    floor, wall, ceiling = (
        albedo(b.materials[k].get("reflectance", b.materials[k].get("diffuse")))
        for k in ("floor", "wall", "ceiling")
    )
    b.room_albedo = (w * d * (floor + ceiling) + 2 * (w + d) * h * wall) / (
        2 * w * d + 2 * (w + d) * h
    )
    b.objects.append({**_rect([0, 0, 0], [-90, 0, 0], [w / 2, d / 2]), "material": "floor"})
    b.objects.append({**_rect([0, h, 0], [90, 0, 0], [w / 2, d / 2]), "material": "ceiling"})
    # wall: (centre of its base line, yaw so the rectangle's +z faces inward, half width)
    walls = {
        "back": (np.array([0.0, 0.0, -d / 2]), 0.0, w / 2),
        "left": (np.array([-w / 2, 0.0, 0.0]), 90.0, d / 2),
        "right": (np.array([w / 2, 0.0, 0.0]), -90.0, d / 2),
        "front": (np.array([0.0, 0.0, d / 2]), 180.0, w / 2),
    }
    opening = ""
    if b.variant == "window":
        opening = ("back", "left", "right")[int(rng.integers(3))]
    for name, (base, yaw, half_w) in walls.items():
        u = np.array([math.cos(math.radians(yaw)), 0.0, -math.sin(math.radians(yaw))])
        if name != opening:
            b.objects.append(
                {
                    **_rect(base + np.array([0, h / 2, 0]), [0, yaw, 0], [half_w, h / 2]),
                    "material": "wall",
                }
            )
            continue
        door = rng.random() < room.door_prob
        half_width = room.door_half_width if door else room.window_half_width
        hw = min(half_width.draw(rng), half_w - 0.3)
        if door:
            v0, v1 = 0.0, min(room.door_height.draw(rng), h - 0.3)
        else:
            v0, v1 = room.window_sill.draw(rng), min(room.window_top.draw(rng), h - 0.3)
        c = rng.uniform(-half_w + hw + 0.3, half_w - hw - 0.3)
        pieces = [(-half_w, c - hw, 0.0, h), (c + hw, half_w, 0.0, h), (c - hw, c + hw, v1, h)]
        if v0 > 0:
            pieces.append((c - hw, c + hw, 0.0, v0))
        for a0, a1, b0, b1 in pieces:
            centre = base + u * (a0 + a1) / 2 + np.array([0, (b0 + b1) / 2, 0])
            b.objects.append(
                {**_rect(centre, [0, yaw, 0], [(a1 - a0) / 2, (b1 - b0) / 2]), "material": "wall"}
            )
        hole_centre = base + u * c + np.array([0, (v0 + v1) / 2, 0])
        hole_half = np.array([hw, (v1 - v0) / 2])
        b.variant = "door" if door else "window"
        inward = np.array([math.sin(math.radians(yaw)), 0.0, math.cos(math.radians(yaw))])
        _opening_light(b, hole_centre, hole_half, inward, yaw, (w, d, h))


def _opening_light(
    b: Build,
    centre: np.ndarray,
    half: np.ndarray,
    inward: np.ndarray,
    yaw: float,
    size: tuple[float, float, float],
) -> None:
    """Light outside an opening: an emissive panel facing in, or a sun shining in + a sky.

    The sun's irradiance is set so that the power entering through the opening, spread over
    the room's surfaces and multiplied by interreflection (≈ 1 / (1 − albedo)), gives the
    average irradiance ``Interior.sun_inside_irradiance`` inside: the sunlit patch is then
    tens of times brighter than the rest, as in real rooms. The environment's brightness is
    ``Interior.sky_per_sun`` × the sun's irradiance.
    """
    rng, room, lights = b.rng, b.dist.interior, b.dist.lights
    w, d, h = size
    reach = (w if abs(inward[0]) > 0.5 else d) / 2  # opening -> room centre
    if rng.random() < room.outside_panel_prob:
        area = 4 * half[0] * half[1]
        # the room multiplies light by about 1 / (1 - albedo) through interreflection
        e = room.outside_panel_irradiance.draw(rng)
        radiance = e * (1 - b.room_albedo) * reach**2 / area * tint(rng, lights)
        grow = room.outside_panel_size.draw(rng)
        behind = room.outside_panel_behind.draw(rng)
        panel = _rect(centre - inward * behind, [0, yaw, 0], half * grow)
        panel["material"] = {"type": "diffuse", "reflectance": [0.5, 0.5, 0.5]}
        panel["emission"] = rounded_vec(radiance, 3)
        b.objects.append(panel)
        b.variant += "+panel"
        return
    elev = math.radians(room.sun_elevation.draw(rng))
    turn = math.radians(rng.uniform(-room.sun_turn, room.sun_turn))
    out = -inward
    horiz = np.array(
        [
            out[0] * math.cos(turn) + out[2] * math.sin(turn),
            0.0,
            -out[0] * math.sin(turn) + out[2] * math.cos(turn),
        ]
    )
    room_area = 2 * w * d + 2 * (w + d) * h
    hole_area = 4 * half[0] * half[1]
    irradiance = room.sun_inside_irradiance.draw(rng) * room_area * (1 - b.room_albedo) / hole_area
    b.lights.append(sun(rng, lights, horiz * math.cos(elev) + UP * math.sin(elev), irradiance))
    gain = irradiance * room.sky_per_sun.draw(rng) / _NOMINAL_ENVIRONMENT
    b.lights.append(environment(rng, lights, studio=0.0, gain=gain))
    b.variant += "+sun"


def _interior(b: Build, ao: bool = False) -> None:
    rng, d = b.rng, b.dist
    room = d.interior
    w, dz, h = room.size.draw(rng), room.size.draw(rng), room.height.draw(rng)
    if not ao:
        b.variant = "window" if rng.random() < room.opening_prob else "ceiling"
    subjects: list[Solid] = []
    cam = None
    count = subject_count(rng, d)
    white = _white(d.ao.reflectance)
    while cam is None:
        subjects = place_subjects(
            rng,
            d,
            count,
            in_box(rng, (-w / 2 + 0.4, w / 2 - 0.4), (-dz / 2 + 0.4, dz / 2 - 1.8)),
            d.subjects.size,
            rng.uniform(-30, 30),
            material=(lambda: dict(white)) if ao else None,
        )
        cam = room_camera(rng, d, subjects, w, dz, h) if subjects else None
        count = max(1, count - 1)
    b.subjects = subjects
    b.camera = cam
    _room(b, w, dz, h, ao=ao)
    if ao:
        return
    lights = d.lights
    centre = np.mean([s.centre for s in subjects], axis=0)
    if b.variant == "ceiling":
        half = room.panel_half.draw(rng, 2)
        x = rng.uniform(-w / 4, w / 4)
        z = rng.uniform(-dz / 4, dz / 4)
        # interreflection adds ~ 1 / (1 - albedo)
        e = room.panel_irradiance.draw(rng) * (1 - b.room_albedo)
        radiance = e * h * h / (4 * half[0] * half[1]) * tint(rng, lights)
        panel = _rect([x, h - 0.005, z], [90, 0, 0], half)
        panel["material"] = {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]}
        panel["emission"] = rounded_vec(radiance, 3)
        b.objects.append(panel)
    origin = np.asarray(cam["origin"])
    if rng.random() < room.point_prob:
        pos = np.array(
            [rng.uniform(-w / 3, w / 3), h - rng.uniform(0.3, 0.6), rng.uniform(-dz / 3, dz / 3)]
        )
        e = room.point_irradiance.draw(rng) * (1 - b.room_albedo)
        b.lights.append(point(pos, centre, e, tint(rng, lights)))
    if rng.random() < room.spot_prob:
        pos = np.array([rng.uniform(-w / 3, w / 3), h - 0.3, rng.uniform(-dz / 3, dz / 3)])
        _, rad = bounding(subjects)
        e = room.spot_irradiance.draw(rng) * (1 - b.room_albedo)
        b.lights.append(spot(rng, lights, pos, centre, rad, e, tint(rng, lights)))
    if rng.random() < room.bulb_prob:

        def region() -> np.ndarray:
            return np.array(
                [
                    rng.uniform(-w / 2 + 0.2, w / 2 - 0.2),
                    rng.uniform(h / 2, h - 0.2),
                    rng.uniform(-dz / 2 + 0.2, dz / 2 - 0.2),
                ]
            )

        b.objects += bulbs(rng, lights, room.bulbs.draw(rng), region, subjects, origin)


def _ground(b: Build, white: bool = False) -> None:
    rng, out = b.rng, b.dist.outdoor
    g = out.ground_half.draw(rng)
    mat = _white(b.dist.ao.reflectance) if white else floor_material(rng, b.dist, 2 * g)
    if rng.random() < out.ground_rect_prob:
        ground = _rect([0, 0, 0], [-90, 0, 0], [g, g])
    else:
        ground = {"shape": "disk", "transform": xform([0, 0, 0], [-90, 0, 0], [g, g, 1])}
    b.objects.append({**ground, "material": mat})


def _open_subjects(b: Build, size: U, region: float, azimuth: float, **kw: Any) -> None:
    rng = b.rng
    count = subject_count(rng, b.dist)
    subjects: list[Solid] = []
    while not subjects:
        subjects = place_subjects(rng, b.dist, count, in_disk(rng, region), size, azimuth, **kw)
    b.subjects = subjects


def _outdoor(b: Build) -> None:
    rng, d = b.rng, b.dist
    out, lights = d.outdoor, d.lights
    azimuth = d.camera.azimuth.draw(rng)
    _open_subjects(b, d.subjects.size, d.outdoor.spread.draw(rng), azimuth)
    b.camera = orbit_camera(rng, d, b.subjects, azimuth, d.camera.elevation)
    _ground(b)
    has_sun = rng.random() < out.sun_prob
    gain = 1.0 if has_sun else out.overcast_gain  # overcast: a brighter sky
    b.lights.append(environment(rng, lights, studio=out.studio_prob, gain=gain))
    b.variant = b.lights[-1].get("procedural") or (
        "studio" if "file" in b.lights[-1] else "constant"
    )
    if has_sun:
        e = math.radians(out.sun_elevation.draw(rng))
        a = rng.uniform(0, 2 * math.pi)
        direction = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
        b.lights.append(sun(rng, lights, direction, out.sun_irradiance.draw(rng)))
        b.variant += "+sun"
    if rng.random() < out.bulb_prob:
        c, rad = bounding(b.subjects)

        def region() -> np.ndarray:
            return c + rng.uniform(-1, 1, 3) * (rad + 0.5) + np.array([0, rad, 0])

        origin = np.asarray(b.camera["origin"])
        b.objects += bulbs(rng, lights, out.bulbs.draw(rng), region, b.subjects, origin)


def _tabletop(b: Build) -> None:
    rng, d = b.rng, b.dist
    tab, lights = d.tabletop, d.lights
    azimuth = d.camera.azimuth.draw(rng)
    tw, td = tab.table_half_width.draw(rng), tab.table_half_depth.draw(rng)
    count = subject_count(rng, d)
    subjects: list[Solid] = []
    while not subjects:
        subjects = place_subjects(
            rng,
            d,
            count,
            in_box(rng, (-tw + 0.1, tw - 0.1), (-td + 0.1, td - 0.1)),
            tab.size,
            azimuth,
        )
    b.subjects = subjects
    b.camera = orbit_camera(rng, d, subjects, azimuth, d.camera.tabletop_elevation)
    b.objects.append(
        {
            "shape": "cube",
            "transform": xform([0, -0.04, 0], [0, 0, 0], [tw, 0.04, td]),
            "material": floor_material(rng, d, 2 * max(tw, td)),
        }
    )
    if rng.random() < tab.floor_prob:
        b.objects.append(
            {
                **_rect([0, -tab.floor_below, 0], [-90, 0, 0], [12, 12]),
                "material": {
                    "type": "diffuse",
                    "reflectance": colour(rng, d.materials, tab.floor_value),
                },
            }
        )
    if rng.random() < tab.backdrop_prob:
        a = math.radians(azimuth)
        back = -np.array([math.sin(a), 0.0, math.cos(a)]) * (math.hypot(tw, td) + 0.3)
        b.objects.append(
            {
                **_rect(back + np.array([0, 1.0, 0]), [0, azimuth, 0], [4.0, 1.8]),
                "material": {
                    "type": "diffuse",
                    "reflectance": colour(rng, d.materials, tab.backdrop_value),
                },
            }
        )
    c, rad = bounding(subjects)
    key_az = math.radians(azimuth + rng.uniform(-tab.key_azimuth, tab.key_azimuth))
    e = math.radians(tab.key_elevation.draw(rng))
    dist = tab.key_distance.draw(rng)
    pos = c + dist * np.array(
        [math.cos(e) * math.sin(key_az), math.sin(e), math.cos(e) * math.cos(key_az)]
    )
    if rng.random() < tab.spot_prob:
        key = tab.key_irradiance.draw(rng)
        b.lights.append(spot(rng, lights, pos, c, rad, key, tint(rng, lights)))
        b.variant = "spot"
    else:
        b.lights.append(point(pos, c, tab.key_irradiance.draw(rng), tint(rng, lights)))
        b.variant = "point"
    if rng.random() < tab.fill_constant_prob:
        radiance = tab.fill_constant.draw(rng) * tint(rng, lights)
        b.lights.append({"type": "constant", "radiance": rounded_vec(radiance)})
        b.variant += "+fill"
    if rng.random() < tab.fill_point_prob:
        fill_az = key_az + math.pi + rng.uniform(-0.8, 0.8)
        fpos = c + rng.uniform(2, 4) * np.array(
            [math.sin(fill_az), rng.uniform(0.3, 0.8), math.cos(fill_az)]
        )
        e_fill = tab.fill_point_irradiance.draw(rng)
        b.lights.append(point(fpos, c, e_fill, tint(rng, lights)))
        b.variant += "+point"
    if rng.random() < tab.bulb_prob:

        def region() -> np.ndarray:
            return c + rng.uniform(-1, 1, 3) * (rad + 0.6) + np.array([0, rad + 0.2, 0])

        origin = np.asarray(b.camera["origin"])
        b.objects += bulbs(rng, lights, tab.bulbs.draw(rng), region, subjects, origin)


def _sh_scene(b: Build) -> None:
    rng, d = b.rng, b.dist
    sh = d.sh
    azimuth = d.camera.azimuth.draw(rng)
    _open_subjects(b, d.subjects.size, d.sh.spread.draw(rng), azimuth)
    b.camera = orbit_camera(rng, d, b.subjects, azimuth, d.camera.sh_elevation)
    g = sh.plane_half.draw(rng)
    plane = (
        _rect([0, 0, 0], [-90, 0, 0], [g, g])
        if rng.random() < sh.plane_rect_prob
        else {"shape": "disk", "transform": xform([0, 0, 0], [-90, 0, 0], [g, g, 1])}
    )
    b.objects.append({**plane, "material": floor_material(rng, d, 2 * g)})
    coeffs = random_sh_coefficients(rng, sh.mean_radiance.draw(rng), distribution=d)
    b.lights.append(
        {"type": "sh", "coefficients": [rounded_vec(c, 5) for c in coeffs], "scale": 1.0}
    )
    b.variant = "sh"
    if rng.random() < sh.sun_prob:
        # the main directional light: the brightest direction of the (non-negative) SH sky
        dirs, _, basis = sh_grid(64, 33)
        lum = basis @ coeffs @ LUMINANCE
        best = dirs[int(np.argmax(np.where(dirs[:, 1] > sh.sun_min_height, lum, -np.inf)))]
        b.lights.append(sun(rng, d.lights, best, sh.sun_irradiance.draw(rng)))
        b.variant += "+sun"


def _ao(b: Build) -> None:
    rng, d = b.rng, b.dist
    b.ao_radius = rounded(d.ao.radius.draw(rng), 3)
    b.indirect = False
    white = _white(d.ao.reflectance)
    if rng.random() < d.ao.room_prob:
        b.variant = "room"
        _interior(b, ao=True)
        return
    b.variant = "ground"
    azimuth = d.camera.azimuth.draw(rng)
    spread = d.outdoor.spread.draw(rng)
    _open_subjects(b, d.subjects.size, spread, azimuth, material=lambda: dict(white))
    b.camera = orbit_camera(rng, d, b.subjects, azimuth, d.camera.elevation)
    _ground(b, white=True)


#: Archetype name -> builder.
BUILDERS: dict[str, Callable[[Build], None]] = {
    "interior": _interior,
    "outdoor": _outdoor,
    "tabletop": _tabletop,
    "sh": _sh_scene,
    "ao": _ao,
}
