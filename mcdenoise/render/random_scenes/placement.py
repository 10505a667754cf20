"""Geometry of the random scenes: the subjects (built at the origin, then placed without
overlap), the cameras that frame them, and the culling of hidden subjects."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mcdenoise.render.random_scenes.assets import mesh_assets
from mcdenoise.render.random_scenes.distribution import Distribution, U
from mcdenoise.render.random_scenes.materials import subject_material
from mcdenoise.render.random_scenes.sampling import UP, choose, rounded, rounded_vec

# --------------------------------------------------------------------------------- subjects


@dataclass
class Solid:
    """A subject built at the origin (x = z = 0, resting on y = 0), then moved."""

    obj: dict[str, Any]
    centre: np.ndarray  # of the bounding sphere
    radius: float  # of the bounding sphere
    foot: float  # footprint radius in the xz plane
    can_hide: bool = True  # False: lies flat on the ground, hides nothing

    def moved(self, x: float, y: float, z: float) -> Solid:
        obj = json.loads(json.dumps(self.obj))  # a deep copy
        shift = np.array([x, y, z])
        if obj["shape"] == "sphere":
            obj["center"] = rounded_vec(np.asarray(obj["center"]) + shift)
        else:
            translate = np.asarray(obj["transform"]["translate"]) + shift
            obj["transform"]["translate"] = rounded_vec(translate)
        return Solid(obj, self.centre + shift, self.radius, self.foot, self.can_hide)


def xform(translate: Sequence[float], rotate: Sequence[float], scale: Sequence[float]) -> dict:
    """A spec transform (rounded)."""
    return {"translate": rounded_vec(translate), "rotate": rounded_vec(rotate, 3),
            "scale": rounded_vec(scale)}  # fmt: skip


def _solid(
    rng: np.random.Generator,
    d: Distribution,
    shape: str,
    s: float,
    face_yaw: float,
    material: dict[str, Any],
) -> Solid:
    """One subject of ``shape`` and size ``s`` at the origin; flat ones face ``face_yaw``."""
    sub = d.subjects
    o: dict[str, Any] = {"shape": shape, "material": material}
    facing = face_yaw + rng.uniform(-sub.facing, sub.facing)
    if shape == "sphere":
        lift = sub.sphere_float.draw(rng) if rng.random() < sub.sphere_float_prob else 0.0
        o["center"], o["radius"] = [0.0, rounded(s + lift), 0.0], rounded(s)
        return Solid(o, np.array([0.0, s + lift, 0.0]), s, s)
    if shape == "cube":
        h = s * sub.cube_half.draw(rng, 3)
        o["transform"] = xform([0, h[1], 0], [0, sub.cube_yaw.draw(rng), 0], h)
        return Solid(
            o, np.array([0.0, h[1], 0.0]), float(np.linalg.norm(h)), math.hypot(h[0], h[2])
        )
    if shape == "cylinder":
        rad, height = s * sub.cylinder_radius.draw(rng), s * sub.cylinder_height.draw(rng)
        o["transform"] = xform([0, 0, 0], [-90, rng.uniform(0, 360), 0], [rad, rad, height])
        return Solid(o, np.array([0.0, height / 2, 0.0]), math.hypot(rad, height / 2), rad)
    if shape == "rectangle":
        w, h = s * sub.rectangle_width.draw(rng), s * sub.rectangle_height.draw(rng)
        o["transform"] = xform([0, h, 0], [0, facing, 0], [w, h, 1])
        return Solid(o, np.array([0.0, h, 0.0]), math.hypot(w, h), w)
    if shape == "disk":
        rad = s * sub.disk_radius.draw(rng)
        if rng.random() < sub.disk_lying_prob:  # lying on the ground, facing up
            o["transform"] = xform([0, 0.003, 0], [-90, 0, 0], [rad, rad, 1])
            return Solid(o, np.array([0.0, 0.003, 0.0]), rad, rad, can_hide=False)
        o["transform"] = xform([0, rad, 0], [0, facing, 0], [rad, rad, 1])
        return Solid(o, np.array([0.0, rad, 0.0]), rad, rad)
    if shape == "mesh":
        meshes = mesh_assets()
        mesh = meshes[int(rng.integers(len(meshes)))]
        k = s * sub.mesh_scale.draw(rng)
        yaw = facing if mesh.name.startswith("star") else rng.uniform(0, 360)
        hx, hy, hz = mesh.half_extents
        o["file"] = mesh.file
        o["transform"] = xform([0, k * hy, 0], [0, yaw, 0], [k, k, k])
        return Solid(o, np.array([0.0, k * hy, 0.0]), k * mesh.radius, k * math.hypot(hx, hz))
    raise ValueError(f"unknown shape {shape!r}")


def place_subjects(
    rng: np.random.Generator,
    d: Distribution,
    count: int,
    sample_xz: Callable[[float], tuple[float, float] | None],
    size: U,
    face_yaw: float,
    *,
    textured: bool = True,
    material: Callable[[], dict[str, Any]] | None = None,
) -> list[Solid]:
    """``count`` subjects with non-overlapping footprints; ``sample_xz(foot)`` draws a
    position whose footprint of radius ``foot`` fits the region (``None``: cannot fit)."""
    placed: list[Solid] = []
    for _ in range(count):
        shape = choose(rng, d.subjects.shapes)
        mat = material() if material else subject_material(rng, d, textured=shape != "mesh")
        s = size.draw(rng)
        for _attempt in range(d.subjects.tries):
            solid = _solid(rng, d, shape, s, face_yaw, mat)
            xz = sample_xz(solid.foot)
            if xz is not None and all(
                math.dist(xz, (p.centre[0], p.centre[2])) > solid.foot + p.foot + 0.05
                for p in placed
            ):
                placed.append(solid.moved(xz[0], 0.0, xz[1]))
                break
            s *= 0.95
    # a scene whose only subjects lie flat on the ground shows nothing: the caller retries
    return placed if any(p.can_hide for p in placed) else []


def subject_count(rng: np.random.Generator, d: Distribution) -> int:
    """The number of subjects to place (1 .. ``len(count_weights)``)."""
    w = d.subjects.count_weights
    return 1 + int(rng.choice(len(w), p=np.asarray(w) / sum(w)))


def in_box(
    rng: np.random.Generator, x: tuple[float, float], z: tuple[float, float]
) -> Callable[[float], tuple[float, float] | None]:
    """Positions in the box ``x`` × ``z`` that keep a footprint inside it."""

    def sample(foot: float) -> tuple[float, float] | None:
        lo_x, hi_x, lo_z, hi_z = x[0] + foot, x[1] - foot, z[0] + foot, z[1] - foot
        if lo_x > hi_x or lo_z > hi_z:
            return None
        return float(rng.uniform(lo_x, hi_x)), float(rng.uniform(lo_z, hi_z))

    return sample


def in_disk(
    rng: np.random.Generator, radius: float
) -> Callable[[float], tuple[float, float] | None]:
    """Positions in the disk of ``radius`` around the origin that keep a footprint inside it."""

    def sample(foot: float) -> tuple[float, float] | None:
        r = radius - foot
        if r <= 0:
            return None
        rr, a = r * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        return rr * math.cos(a), rr * math.sin(a)

    return sample


def outside(point: np.ndarray, solids: Sequence[Solid], margin: float) -> bool:
    """True if ``point`` is farther than ``margin`` from every solid's bounding sphere."""
    return all(np.linalg.norm(point - s.centre) > s.radius + margin for s in solids)


def bounding(solids: Sequence[Solid]) -> tuple[np.ndarray, float]:
    """Centre and radius of a sphere around every solid's bounding sphere."""
    lo = np.min([s.centre - s.radius for s in solids], axis=0)
    hi = np.max([s.centre + s.radius for s in solids], axis=0)
    c = (lo + hi) / 2
    return c, max(float(np.linalg.norm(s.centre - c)) + s.radius for s in solids)


# --------------------------------------------------------------------------------- camera


def _basis(origin: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f = target - origin
    f = f / np.linalg.norm(f)
    right = np.cross(f, UP)
    right /= np.linalg.norm(right)
    return f, right, np.cross(right, f)


def _needed_tan(origin: np.ndarray, target: np.ndarray, solids: Sequence[Solid]) -> float:
    """tan of the half field of view that holds every subject's centre (plus half its
    bounding radius) in a square image; inf when a subject is behind or around the camera."""
    f, right, up = _basis(origin, target)
    worst = 0.0
    for sld in solids:
        dv = sld.centre - origin
        depth = float(dv @ f)
        if depth <= sld.radius:
            return math.inf
        pad = 0.5 * sld.radius / depth
        worst = max(worst, abs(float(dv @ right)) / depth + pad, abs(float(dv @ up)) / depth + pad)
    return worst


def orbit_camera(
    rng: np.random.Generator, d: Distribution, solids: Sequence[Solid], azimuth: float, elevation: U
) -> dict[str, Any]:
    """A camera on a sphere around the subjects that frames all of them."""
    cam = d.camera
    c, radius = bounding(solids)
    fov = cam.fov.draw(rng)
    e, a = math.radians(elevation.draw(rng)), math.radians(azimuth)
    direction = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    target = c + rng.uniform(-cam.aim, cam.aim, 3) * radius
    dist = radius / math.sin(math.radians(fov) / 2) * cam.distance.draw(rng)
    half_tan = math.tan(math.radians(fov) / 2)
    for _ in range(50):
        origin = target + dist * direction
        origin[1] = max(origin[1], 0.2)
        if _needed_tan(origin, target, solids) < 0.95 * half_tan and outside(origin, solids, 0.1):
            break
        dist *= 1.1
    return {"origin": rounded_vec(origin), "target": rounded_vec(target), "fov": rounded(fov, 2)}


def room_camera(
    rng: np.random.Generator, d: Distribution, solids: list[Solid], w: float, dz: float, h: float
) -> dict[str, Any] | None:
    """A camera inside a room (x in ±w/2, z up to dz/2, y below h) that frames ``solids``."""
    cam = d.camera
    for _ in range(60):
        origin = np.array(
            [
                rng.uniform(-w / 4, w / 4),
                rng.uniform(cam.room_height.lo, min(cam.room_height.hi, h - 0.5)),
                dz / 2 - cam.room_setback.draw(rng),
            ]
        )
        target = np.mean([s.centre for s in solids], axis=0) + rng.uniform(-0.2, 0.2, 3)
        target[1] = max(target[1], 0.3)
        if not outside(origin, solids, 0.1):
            continue
        need = math.degrees(2 * math.atan(1.08 * _needed_tan(origin, target, solids)))
        fov = max(need, cam.room_fov.draw(rng))
        if fov <= cam.room_max_fov:
            return {
                "origin": rounded_vec(origin),
                "target": rounded_vec(target),
                "fov": rounded(fov, 2),
            }
    return None


def _seg_dist(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> float:
    """Distance from ``p`` to the segment ``a``–``b``."""
    ab = b - a
    t = float(np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0))
    return float(np.linalg.norm(a + t * ab - p))


def unhidden(d: Distribution, origin: Sequence[float], solids: Sequence[Solid]) -> list[Solid]:
    """Drop subjects that stand in front of another standing subject's centre (within
    ``hide_fraction`` of their bounding radius of the line of sight), nearest first, so no kept
    standing subject is hidden behind another (objects lying flat on the ground hide nothing)."""
    o = np.asarray(origin, dtype=np.float64)
    keep = sorted(solids, key=lambda s: float(np.linalg.norm(s.centre - o)))
    i = 0
    while i < len(keep):
        a = keep[i]
        da = float(np.linalg.norm(a.centre - o))
        hides = a.can_hide and any(
            c.can_hide
            and float(np.linalg.norm(c.centre - o)) > da
            and _seg_dist(o, c.centre, a.centre) < d.subjects.hide_fraction * a.radius
            for c in keep[i + 1 :]
        )
        if hides:
            del keep[i]
        else:
            i += 1
    return keep


def make_thinlens(
    rng: np.random.Generator, d: Distribution, cam: dict[str, Any], solids: Sequence[Solid]
) -> None:
    """Make ``cam`` a thin lens focused on a random subject."""
    origin, target = np.asarray(cam["origin"]), np.asarray(cam["target"])
    f = (target - origin) / np.linalg.norm(target - origin)
    focus = float((solids[int(rng.integers(len(solids)))].centre - origin) @ f)
    cam.update(
        type="thinlens",
        focus_distance=rounded(focus),
        aperture_radius=rounded(focus * d.camera.aperture.draw(rng), 5),
    )
