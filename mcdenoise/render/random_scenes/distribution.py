"""The distribution of the random scenes, as data: :data:`DISTRIBUTION`.

Every documented number of the generator lives here, once; the generator reads it from here
and :func:`describe_distribution` renders it as text (this module's docstring is that text, so
``help()`` and the API docs show the distribution the code draws from). The text template
holds no number of its own (a test checks this, and that every parameter appears in the text).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from mcdenoise.render.random_scenes.reflow import _reflow

# --------------------------------------------------------------------------------- draws


def _num(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class U:
    """Uniform on ``[lo, hi]``, written ``U(lo, hi)``."""

    lo: float
    hi: float

    def draw(self, rng: np.random.Generator, size: int | None = None) -> float | np.ndarray:
        if size is None:
            return rng.uniform(self.lo, self.hi)
        return rng.uniform(self.lo, self.hi, size)

    def __str__(self) -> str:
        return f"``U({_num(self.lo)}, {_num(self.hi)})``"


@dataclass(frozen=True)
class LogU(U):
    """Log-uniform on ``[lo, hi]``, written ``logU(lo, hi)``."""

    def draw(self, rng: np.random.Generator, size: int | None = None) -> float | np.ndarray:
        assert size is None
        return float(math.exp(rng.uniform(math.log(self.lo), math.log(self.hi))))

    def __str__(self) -> str:
        return f"``logU({_num(self.lo)}, {_num(self.hi)})``"


@dataclass(frozen=True)
class Count:
    """An integer uniform on ``lo..hi`` (both included), written ``lo–hi``."""

    lo: int
    hi: int

    def draw(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.lo, self.hi + 1))

    def __str__(self) -> str:
        return f"{self.lo}–{self.hi}"


def _weights(**w: float) -> Mapping[str, float]:
    return field(default_factory=lambda: dict(w))  # type: ignore[return-value]


# --------------------------------------------------------------------------------- parts


@dataclass(frozen=True)
class Interior:
    """Closed rooms (archetype ``interior``; AO rooms use the geometry)."""

    size: U = U(4, 7)  # width W and depth D, each
    height: U = U(2.6, 3.4)
    wall_value: U = U(0.4, 0.85)
    wall_image_prob: float = 0.15
    ceiling_grey: U = U(0.6, 0.85)
    opening_prob: float = 0.35  # variant window/door, else ceiling
    panel_half: U = U(0.2, 0.6)
    panel_irradiance: U = U(3, 6)
    door_prob: float = 0.3
    door_half_width: U = U(0.4, 0.6)
    door_height: U = U(1.9, 2.2)
    window_half_width: U = U(0.4, 0.9)
    window_sill: U = U(0.6, 1.0)
    window_top: U = U(1.6, 2.3)
    outside_panel_prob: float = 0.6  # else a sun
    outside_panel_size: U = U(1.3, 2.5)  # times the opening
    outside_panel_behind: U = U(0.2, 1.0)
    outside_panel_irradiance: U = U(6, 14)
    sun_elevation: U = U(15, 45)
    sun_turn: float = 35.0  # degrees either side of the wall's normal
    sun_inside_irradiance: U = U(1, 3)
    sky_per_sun: U = U(0.05, 0.15)  # environment radiance / the sun's irradiance
    point_prob: float = 0.2
    point_irradiance: U = U(1, 3)
    spot_prob: float = 0.15
    spot_irradiance: U = U(1, 4)
    bulb_prob: float = 0.25
    bulbs: Count = Count(1, 3)

    @property
    def ceiling_prob(self) -> float:
        return 1 - self.opening_prob

    @property
    def window_prob(self) -> float:
        return 1 - self.door_prob

    @property
    def outside_sun_prob(self) -> float:
        return 1 - self.outside_panel_prob


@dataclass(frozen=True)
class Outdoor:
    ground_rect_prob: float = 0.6  # else a disk
    ground_half: U = U(15, 40)
    spread: U = U(1.2, 2.5)  # radius of the disk the subjects stand in (also AO grounds)
    studio_prob: float = 0.25  # environment: the studio envmap file
    overcast_gain: float = 1.6  # environment brightness without a sun
    sun_prob: float = 0.7
    sun_elevation: U = U(15, 70)
    sun_irradiance: U = U(1.5, 4)
    bulb_prob: float = 0.15
    bulbs: Count = Count(1, 2)


@dataclass(frozen=True)
class Tabletop:
    size: U = U(0.15, 0.42)  # subject size s
    table_half_width: U = U(1.4, 2.4)
    table_half_depth: U = U(1.0, 1.8)
    floor_prob: float = 0.75
    floor_below: float = 0.75
    floor_value: U = U(0.1, 0.6)
    backdrop_prob: float = 0.5
    backdrop_value: U = U(0.2, 0.8)
    key_elevation: U = U(35, 75)
    key_azimuth: float = 120.0  # degrees either side of the camera's azimuth
    key_distance: U = U(1.8, 3.5)
    key_irradiance: U = U(2, 6)
    spot_prob: float = 0.55  # key light: spot, else point
    fill_constant_prob: float = 0.75
    fill_constant: U = U(0.05, 0.3)
    fill_point_prob: float = 0.25
    fill_point_irradiance: U = U(0.3, 1.0)
    bulb_prob: float = 0.2
    bulbs: Count = Count(1, 2)

    @property
    def point_prob(self) -> float:
        return 1 - self.spot_prob


@dataclass(frozen=True)
class SH:
    """SH-lit scenes and their random environments (:func:`random_sh_coefficients`)."""

    plane_rect_prob: float = 0.5  # else a disk
    plane_half: U = U(3, 8)
    spread: U = U(1.0, 2.2)  # radius of the disk the subjects stand in
    mean_radiance: U = U(0.3, 0.9)
    top_value: U = U(0.4, 1.0)  # colour value of the sky's zenith
    bottom_value: U = U(0.05, 0.4)  # and of its nadir
    gradient_exponent: U = U(0.5, 2.0)  # of max(y, 0) towards the zenith
    ambient: float = 0.05  # radiance added everywhere
    lobes: Count = Count(1, 3)
    lobe_sharpness: U = U(3, 25)  # exponent k of exp(k (cos θ - 1))
    lobe_strength: U = U(1, 6)
    lobe_below: float = 0.3  # half of the lobes: y of the direction mirrored and scaled by this
    sun_prob: float = 0.5
    sun_min_height: float = 0.15  # y of the sun's direction (sine of its elevation)
    sun_irradiance: U = U(0.5, 2)

    @property
    def sun_min_elevation(self) -> float:
        return math.degrees(math.asin(self.sun_min_height))


@dataclass(frozen=True)
class AO:
    radius: U = U(0.3, 2.0)
    reflectance: float = 0.8
    room_prob: float = 0.4  # else subjects on an open ground

    @property
    def ground_prob(self) -> float:
        return 1 - self.room_prob


@dataclass(frozen=True)
class Lights:
    """Conventions shared by every archetype's lights."""

    warm: tuple[float, float, float] = (1.0, 0.78, 0.55)
    cool: tuple[float, float, float] = (0.8, 0.9, 1.0)
    sun_disk_prob: float = 0.85  # else a delta directional light
    sun_angular_diameter: U = U(0.5, 3.0)
    sky_prob: float = 0.45  # environment: the procedural sky
    sky_scale: U = U(0.5, 1.3)
    studio_scale: U = U(0.2, 0.6)
    constant_radiance: U = U(0.2, 0.7)
    bulb_radius: U = U(0.02, 0.06)
    bulb_irradiance: U = U(0.3, 1.5)
    bulb_distance: float = 1.5  # where bulb_irradiance is reached
    spot_margin: U = U(5, 15)  # cutoff beyond the subjects' angular radius, degrees
    spot_min_cutoff: float = 12.0
    spot_max_cutoff: float = 60.0
    spot_beam: U = U(0.5, 0.9)  # beam width / cutoff

    @property
    def sun_delta_prob(self) -> float:
        return 1 - self.sun_disk_prob


@dataclass(frozen=True)
class Subjects:
    count_weights: tuple[float, ...] = (0.08, 0.14, 0.17, 0.17, 0.15, 0.12, 0.09, 0.08)
    tries: int = 40
    size: U = U(0.25, 0.7)  # s (tabletop: Tabletop.size)
    shapes: Mapping[str, float] = _weights(
        sphere=0.20, cube=0.17, cylinder=0.15, rectangle=0.09, disk=0.09, mesh=0.30
    )
    sphere_float_prob: float = 0.15
    sphere_float: U = U(0.1, 0.8)
    cube_half: U = U(0.5, 1.0)  # times s
    cube_yaw: U = U(0, 90)
    cylinder_radius: U = U(0.4, 0.9)
    cylinder_height: U = U(0.8, 2.5)
    rectangle_width: U = U(0.6, 1.2)
    rectangle_height: U = U(0.6, 1.4)
    disk_radius: U = U(0.6, 1.2)
    disk_lying_prob: float = 0.5
    mesh_scale: U = U(0.8, 1.3)
    facing: float = 40.0  # flat subjects face the camera within this many degrees
    hide_fraction: float = 0.7  # of the bounding radius, to another subject's line of sight

    @property
    def max_count(self) -> int:
        return len(self.count_weights)

    @property
    def count_percents(self) -> str:
        return ", ".join(_num(round(100 * w, 6)) for w in self.count_weights)


@dataclass(frozen=True)
class Materials:
    types: Mapping[str, float] = _weights(
        diffuse=0.25,
        plastic=0.12,
        roughplastic=0.18,
        conductor=0.12,
        roughconductor=0.18,
        dielectric=0.15,
    )
    roughness: LogU = LogU(0.03, 0.5)
    rough_dielectric_prob: float = 0.3
    dielectric_roughness: LogU = LogU(0.02, 0.3)
    ior: U = U(1.3, 1.8)
    conductor_preset_prob: float = 0.8
    #: Mitsuba conductor presets drawn from (all metallic; Mitsuba ships more).
    conductors: tuple[str, ...] = (
        "Ag", "Al", "Au", "Be", "Cr", "Cu", "Hg", "Ir", "Li", "Mo", "Nb", "Rh", "Ta", "TiN", "VN",
        "W",
    )  # fmt: skip
    eta: U = U(0.05, 1.5)
    k: U = U(1.5, 5.0)
    white_specular_prob: float = 0.75
    specular_tint: U = U(0.6, 1.0)
    grey_prob: float = 0.25
    grey_saturation: U = U(0.0, 0.1)
    saturation: U = U(0.2, 0.9)
    value: U = U(0.05, 0.85)
    dark_value: U = U(0.05, 0.5)  # first colour of two-colour textures
    light_value: U = U(0.3, 0.85)  # second colour
    textures: Mapping[str, float] = _weights(
        constant=0.50, checkerboard=0.20, noise=0.20, image=0.10
    )
    checker_periods: U = U(1, 6)  # per uv unit
    noise_cells: U = U(4, 16)  # per uv unit
    image_repeats: U = U(1, 3)

    @property
    def conductor_list(self) -> str:
        return ", ".join(self.conductors)


@dataclass(frozen=True)
class Floors:
    """Floors, grounds, tables and support planes."""

    diffuse_prob: float = 0.6  # else roughplastic
    textures: Mapping[str, float] = _weights(
        constant=0.25, checkerboard=0.35, noise=0.25, image=0.15
    )
    checker_size: U = U(0.6, 2.5)  # world units
    noise_size: U = U(0.3, 1.2)
    image_size: U = U(1.0, 3.0)

    @property
    def roughplastic_prob(self) -> float:
        return 1 - self.diffuse_prob


@dataclass(frozen=True)
class Camera:
    azimuth: U = U(0, 360)
    elevation: U = U(5, 45)
    tabletop_elevation: U = U(15, 55)
    sh_elevation: U = U(10, 40)
    fov: U = U(30, 60)
    distance: U = U(1.0, 1.3)  # times the distance at which the subjects just fit
    aim: float = 0.1  # target jitter, times the subjects' bounding radius
    room_setback: U = U(0.3, 0.7)  # from the front wall
    room_height: U = U(0.9, 1.9)
    room_fov: U = U(40, 65)
    room_max_fov: float = 85.0
    thinlens_prob: float = 0.2
    aperture: U = U(0.01, 0.04)  # radius, times the focus distance


@dataclass(frozen=True)
class Effects:
    indirect_prob: Mapping[str, float] = _weights(interior=1.0, outdoor=0.8, tabletop=0.8, sh=0.7)
    caustics_prob: float = 0.6
    max_depths: tuple[tuple[int, float], ...] = ((6, 0.15), (8, 0.50), (10, 0.20), (12, 0.15))
    dielectric_min_depth: int = 8
    rr_depth: int = 5

    @property
    def caustics_cut_prob(self) -> float:
        return 1 - self.caustics_prob

    @property
    def depth_values(self) -> str:
        return ", ".join(str(d) for d, _ in self.max_depths)

    @property
    def depth_percents(self) -> str:
        return ", ".join(_num(round(100 * p, 6)) for _, p in self.max_depths)


@dataclass(frozen=True)
class Distribution:
    """Everything :func:`~mcdenoise.render.random_scenes.random_scene` draws from."""

    archetypes: Mapping[str, float] = _weights(
        interior=0.30, outdoor=0.25, tabletop=0.20, sh=0.15, ao=0.10
    )
    interior: Interior = Interior()
    outdoor: Outdoor = Outdoor()
    tabletop: Tabletop = Tabletop()
    sh: SH = SH()
    ao: AO = AO()
    lights: Lights = Lights()
    subjects: Subjects = Subjects()
    materials: Materials = Materials()
    floors: Floors = Floors()
    camera: Camera = Camera()
    effects: Effects = Effects()

    @property
    def outdoor_constant_prob(self) -> float:
        return 1 - self.lights.sky_prob - self.outdoor.studio_prob

    @property
    def window_constant_prob(self) -> float:
        return 1 - self.lights.sky_prob


#: The distribution the generator draws from.
DISTRIBUTION = Distribution()

#: A wider distribution for training beyond :data:`DISTRIBUTION` (issue 21: depth of field,
#: glossy and metal): thin lenses in 60 % of the lit scenes with apertures up to 8 % of the
#: focus distance (the default: 20 %, up to 4 %), twice the share of conductors, no AO
#: scenes (they have no albedo, which the kpcn trainer needs). Draw from it with
#: ``random_scene(seed, index, distribution=WIDE)``; ``mcdenoise render --random`` always
#: uses :data:`DISTRIBUTION`.
WIDE = Distribution(
    archetypes={"interior": 0.35, "outdoor": 0.25, "tabletop": 0.25, "sh": 0.15},
    camera=Camera(thinlens_prob=0.6, aperture=U(0.01, 0.08)),
    materials=Materials(
        types={
            "diffuse": 0.15,
            "plastic": 0.08,
            "roughplastic": 0.12,
            "conductor": 0.2,
            "roughconductor": 0.3,
            "dielectric": 0.15,
        }
    ),
)

#: The named distributions (``benchmarks/render_random.py --distribution NAME``).
DISTRIBUTIONS: Mapping[str, Distribution] = {"default": DISTRIBUTION, "wide": WIDE}


# --------------------------------------------------------------------------------- text

#: The text of :func:`describe_distribution`: every number is a ``{d....}`` field of a
#: :class:`Distribution` (``:.0%`` formats a probability); the only digits outside fields
#: are in :data:`FORMULAS`.
TEMPLATE = """\
Distribution
============
Scene units ≈ metres, angles in degrees, colours linear RGB; ``U(a, b)`` uniform,
``logU`` log-uniform, percentages are probabilities. Light powers are derived from a target
irradiance ``E`` at the subjects (point/spot intensity ``E·d²``, emitter radiance ``E·d²/A``),
so exposure does not depend on a light's distance or size; in rooms, ``E`` is multiplied by
``1 − ρ`` (``ρ`` the area-weighted reflectance of floor, walls and ceiling) because
interreflection adds about ``1 / (1 − ρ)``.

**Archetypes** (probability):

interior ({d.archetypes[interior]:.0%})
    Closed room: W, D {d.interior.size}, H {d.interior.height}; camera inside (below).
    Floor: see "floors"; walls: constant value {d.interior.wall_value} ({d.interior.wall_image_prob:.0%}:
    brick or wood image); ceiling: grey {d.interior.ceiling_grey}. Light (variant):
    ``ceiling`` {d.interior.ceiling_prob:.0%}: emissive panel under the ceiling, half sizes
    {d.interior.panel_half}, ``E`` {d.interior.panel_irradiance} at the floor.
    ``window``/``door`` {d.interior.opening_prob:.0%}: an opening in the back or a side wall (door
    {d.interior.door_prob:.0%}, half width {d.interior.door_half_width}, height {d.interior.door_height};
    window {d.interior.window_prob:.0%}, half width {d.interior.window_half_width}, sill
    {d.interior.window_sill}, top {d.interior.window_top}) with outside either ``+panel``
    ({d.interior.outside_panel_prob:.0%}: emissive panel {d.interior.outside_panel_size}× the opening,
    {d.interior.outside_panel_behind} behind it, ``E`` {d.interior.outside_panel_irradiance} at the
    room's centre) or ``+sun`` ({d.interior.outside_sun_prob:.0%}: a sun at elevation
    {d.interior.sun_elevation} within ±{d.interior.sun_turn:g}° of the wall's normal, bright enough
    that the light entering gives an average ``E`` {d.interior.sun_inside_irradiance} inside, plus
    an environment as outdoors but without the studio envmap (sky {d.lights.sky_prob:.0%}, constant
    {d.window_constant_prob:.0%}) of radiance about {d.interior.sky_per_sun}× the sun's
    irradiance): nearly all light indirect. Extras: point light ({d.interior.point_prob:.0%}, ``E``
    {d.interior.point_irradiance}), spot ({d.interior.spot_prob:.0%}, ``E`` {d.interior.spot_irradiance}),
    {d.interior.bulbs} bulbs ({d.interior.bulb_prob:.0%}). Always ``indirect``.

outdoor ({d.archetypes[outdoor]:.0%})
    Subjects within a disk of radius {d.outdoor.spread}. Ground: rectangle
    ({d.outdoor.ground_rect_prob:.0%}) or disk of half size {d.outdoor.ground_half}; one environment: procedural sky envmap {d.lights.sky_prob:.0%} (scale
    {d.lights.sky_scale}), studio envmap file {d.outdoor.studio_prob:.0%} (scale
    {d.lights.studio_scale}), constant {d.outdoor_constant_prob:.0%} ({d.lights.constant_radiance}),
    × {d.outdoor.overcast_gain:g} when there is no sun; sun {d.outdoor.sun_prob:.0%} (elevation
    {d.outdoor.sun_elevation}, azimuth uniform, irradiance {d.outdoor.sun_irradiance});
    {d.outdoor.bulbs} bulbs ({d.outdoor.bulb_prob:.0%}).

tabletop ({d.archetypes[tabletop]:.0%})
    Subjects of size {d.tabletop.size} on a table slab (half {d.tabletop.table_half_width} ×
    {d.tabletop.table_half_depth}, floor-like material), a floor {d.tabletop.floor_below:g} below
    ({d.tabletop.floor_prob:.0%}, diffuse, value {d.tabletop.floor_value}), a backdrop facing the
    camera ({d.tabletop.backdrop_prob:.0%}, diffuse, value {d.tabletop.backdrop_value}). Key light
    at elevation {d.tabletop.key_elevation}, azimuth within ±{d.tabletop.key_azimuth:g}° of the
    camera's, {d.tabletop.key_distance} away, ``E`` {d.tabletop.key_irradiance}: spot
    {d.tabletop.spot_prob:.0%} (see "spots") or point {d.tabletop.point_prob:.0%}. Fill: constant
    {d.tabletop.fill_constant} ({d.tabletop.fill_constant_prob:.0%}) and/or a second point light
    opposite the key (``E`` {d.tabletop.fill_point_irradiance}, {d.tabletop.fill_point_prob:.0%});
    {d.tabletop.bulbs} bulbs ({d.tabletop.bulb_prob:.0%}).

sh ({d.archetypes[sh]:.0%})
    Subjects within a disk of radius {d.sh.spread} on a support plane (rectangle
    {d.sh.plane_rect_prob:.0%}, else a disk; half {d.sh.plane_half}) lit by an SH environment of the AR-lighting paper's order
    (:func:`random_sh_coefficients`, mean radiance {d.sh.mean_radiance}): a gradient sky
    (colours of value {d.sh.top_value} at the zenith and {d.sh.bottom_value} at the nadir,
    exponent {d.sh.gradient_exponent}, plus {d.sh.ambient:g} everywhere) and {d.sh.lobes}
    coloured lobes ``exp(k (cos θ − 1))`` of sharpness ``k`` {d.sh.lobe_sharpness} and strength
    {d.sh.lobe_strength}, mostly from above (half of them mirrored below the horizon, at
    {d.sh.lobe_below:g} of their height), projected on SH and lifted to be non-negative
    everywhere. Plus, in {d.sh.sun_prob:.0%}, a main directional light (a sun along the SH sky's
    brightest direction above {d.sh.sun_min_elevation:.1f}° elevation, irradiance
    {d.sh.sun_irradiance}).

ao ({d.archetypes[ao]:.0%})
    Effects ``["ao"]``, ``ao_radius`` {d.ao.radius}, white diffuse geometry (reflectance
    {d.ao.reflectance:g}): {d.ao.ground_prob:.0%} subjects on an open ground (as outdoors), {d.ao.room_prob:.0%} in
    a closed room (as interiors); no lights; always a pinhole.

**Lights**: bulbs (fireflies) are emissive spheres of radius {d.lights.bulb_radius} and radiance
giving ``E`` {d.lights.bulb_irradiance} at {d.lights.bulb_distance:g} units, away from subjects and
camera. Suns have angular diameter {d.lights.sun_angular_diameter} ({d.lights.sun_disk_prob:.0%})
or none (a delta ``directional`` light, {d.lights.sun_delta_prob:.0%}). Spots: cutoff = the
subjects' angular radius + {d.lights.spot_margin}, kept in [{d.lights.spot_min_cutoff:g},
{d.lights.spot_max_cutoff:g}]; beam width {d.lights.spot_beam}× the cutoff. Every sun and light
colour is a white between warm {d.lights.warm} and cool {d.lights.cool}, of unit luminance.

**Subjects**: count one to {d.subjects.max_count} with weights {d.subjects.count_percents} %,
placed on the floor, ground or table with non-overlapping footprints (a subject that does not
fit in {d.subjects.tries} tries is left out); size ``s`` {d.subjects.size}. Shapes: sphere
{d.subjects.shapes[sphere]:.0%} (radius ``s``; {d.subjects.sphere_float_prob:.0%} float
{d.subjects.sphere_float} above the ground), cube {d.subjects.shapes[cube]:.0%} (half extents
{d.subjects.cube_half}·s, yaw {d.subjects.cube_yaw}), cylinder {d.subjects.shapes[cylinder]:.0%}
(upright, radius {d.subjects.cylinder_radius}·s, height {d.subjects.cylinder_height}·s), rectangle
{d.subjects.shapes[rectangle]:.0%} (standing panel, half sizes {d.subjects.rectangle_width}·s ×
{d.subjects.rectangle_height}·s), disk {d.subjects.shapes[disk]:.0%} (radius
{d.subjects.disk_radius}·s, lying on the ground {d.subjects.disk_lying_prob:.0%}, else standing),
mesh {d.subjects.shapes[mesh]:.0%} (one of the packaged meshes, uniform scale
{d.subjects.mesh_scale}·s, yaw uniform). Standing panels, disks and the star mesh face the camera
±{d.subjects.facing:g}°. A scene whose subjects all lie flat is redrawn, and a subject standing
in front of another one's centre (closer than {d.subjects.hide_fraction:g} of its bounding radius
to the line of sight) is removed, so no standing subject is hidden.

**Materials** of the subjects: diffuse {d.materials.types[diffuse]:.0%}, plastic
{d.materials.types[plastic]:.0%}, roughplastic {d.materials.types[roughplastic]:.0%}, conductor
{d.materials.types[conductor]:.0%}, roughconductor {d.materials.types[roughconductor]:.0%},
dielectric {d.materials.types[dielectric]:.0%}. GGX roughness {d.materials.roughness} (rough
plastic, rough conductor); {d.materials.rough_dielectric_prob:.0%} of dielectrics are rough,
{d.materials.dielectric_roughness}; IOR {d.materials.ior} (plastics, dielectric). Conductors:
{d.materials.conductor_preset_prob:.0%} a Mitsuba preset ({d.materials.conductor_list}), else RGB
``eta`` {d.materials.eta}, ``k`` {d.materials.k}; specular tint white
({d.materials.white_specular_prob:.0%}) or {d.materials.specular_tint} per channel. Colours:
uniform hue, saturation {d.materials.saturation} ({d.materials.grey_prob:.0%}: grey,
{d.materials.grey_saturation}), value {d.materials.value}; two-colour textures use values
{d.materials.dark_value} and {d.materials.light_value}. Base-colour texture of diffuse and
plastic non-mesh subjects: constant {d.materials.textures[constant]:.0%}, checkerboard
{d.materials.textures[checkerboard]:.0%} ({d.materials.checker_periods} periods per uv unit),
noise {d.materials.textures[noise]:.0%} ({d.materials.noise_cells} cells per uv unit), image
{d.materials.textures[image]:.0%} (bricks or wood, {d.materials.image_repeats} repeats); meshes
carry no UVs and get constant colours. **Floors**, grounds, tables: diffuse
{d.floors.diffuse_prob:.0%} / roughplastic {d.floors.roughplastic_prob:.0%}, texture constant
{d.floors.textures[constant]:.0%}, checkerboard {d.floors.textures[checkerboard]:.0%}, noise
{d.floors.textures[noise]:.0%}, image {d.floors.textures[image]:.0%}, with world-size periods
{d.floors.checker_size} (checks), {d.floors.noise_size} (noise cells), {d.floors.image_size}
(image tiles).

**Camera** (square images; ``fov`` horizontal = vertical): open scenes orbit the subjects'
bounding sphere at azimuth {d.camera.azimuth}, elevation {d.camera.elevation} (tabletop
{d.camera.tabletop_elevation}, sh {d.camera.sh_elevation}), fov {d.camera.fov}, at
{d.camera.distance}× the distance at which the sphere just fits, aimed at its centre ±
{d.camera.aim:g} of its radius. Interiors: at {d.camera.room_setback} from the front wall, x
within the middle half of the room's width, height {d.camera.room_height}, aimed at the
subjects' centroid, fov the larger of {d.camera.room_fov} and what frames every subject (at
most {d.camera.room_max_fov:g}). Every subject's centre is in frame and the camera is outside
every object. Thin lens (``dof``) in {d.camera.thinlens_prob:.0%} of lit scenes: focused on a
random subject (``focus_distance`` = its depth along the view axis), ``aperture_radius``
{d.camera.aperture}× the focus distance.

**Effects**: lit scenes declare ``direct``; ``indirect`` in {d.effects.indirect_prob[interior]:.0%}
of interiors, {d.effects.indirect_prob[outdoor]:.0%} of outdoor, {d.effects.indirect_prob[tabletop]:.0%}
of tabletop and {d.effects.indirect_prob[sh]:.0%} of sh scenes; ``glossy`` iff a glossy material is
present; ``caustics`` in {d.effects.caustics_prob:.0%} of the scenes with ``indirect`` and a smooth
specular material (plastic, conductor, smooth dielectric), so {d.effects.caustics_cut_prob:.0%}
exercise the integrator that cuts those paths; ``dof`` iff thin lens. ``render.max_depth`` (with
``indirect``): {d.effects.depth_values} with probabilities {d.effects.depth_percents} % (at least
{d.effects.dielectric_min_depth} with a dielectric); ``rr_depth`` {d.effects.rr_depth}.
"""

#: Formulas of :data:`TEMPLATE` whose digits are not parameters.
FORMULAS: tuple[str, ...] = (
    "E·d²/A",
    "E·d²",
    "``1 − ρ``",
    "``1 / (1 − ρ)``",
    "``exp(k (cos θ − 1))``",
)


def describe_distribution(distribution: Distribution = DISTRIBUTION) -> str:
    """The distribution as reStructuredText (this module's docstring is the default's)."""
    return _reflow(TEMPLATE.format(d=distribution))


def template_numbers() -> list[str]:
    """Numbers written in :data:`TEMPLATE` itself, outside its fields and formulas (none)."""
    text = re.sub(r"\{[^{}]*\}", "", TEMPLATE)
    for formula in FORMULAS:
        text = text.replace(formula, "")
    return re.findall(r"[0-9]+", text)


__doc__ = f"{__doc__}\n{describe_distribution()}"
