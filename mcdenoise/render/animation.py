"""Sequences for temporal denoising: camera paths, moving objects and screen-space motion.

A sequence is a scene spec sampled at ``N`` frames, at sequence times ``s = f / (N - 1)``
(``f = 0 .. N-1``; ``s = 0`` for a single frame). Each frame is rendered like a still image
(every spp level and the reference) with the frame's camera and object positions, plus the
``motion`` (to the previous frame) and ``motion_next`` (to the next frame) buffers and their
reprojection validity masks, computed here.

Camera paths (``[animation]`` of the spec, :class:`mcdenoise.render.scene_spec.Animation`)
    ``orbit``: the origin turns about the axis through the target along the camera's ``up``,
    by ``angle · s`` degrees (positive: counter-clockwise seen from the ``up`` side);
    ``dolly``: ``origin + fraction · s · (target - origin)``; ``keyframes``: origin and target
    interpolated linearly between keys at ``s = k / (K - 1)``; ``static``: no camera motion.
    ``up``, ``fov`` and the lens stay; a thin lens keeps its focus offset from the target
    (``focus_distance - |target - origin|``), so a dolly towards a focused subject stays in
    focus. Without ``[animation]`` a sequence uses :func:`default_animation`: an orbit of
    :data:`DEFAULT_ORBIT_DEGREES_PER_FRAME` (1°) per frame, i.e. ``N - 1`` degrees in all.
Moving objects
    ``objects[i].motion = { translate = [dx, dy, dz] }``: the object is translated by
    ``s · (dx, dy, dz)`` (world space, after its own transform). Lights do not move.
Motion vectors (buffer ``motion``, channels ``motion.X``/``motion.Y``, pixels, x right, y down)
    ``motion(p) = q - p``: ``q`` is where the surface point seen through the **centre** of
    pixel ``p`` in frame ``t`` was on the film of frame ``t - 1`` (continuous coordinates,
    pixel ``(i, j)`` covers ``[j, j+1] × [i, i+1]``), so ``prev_pixel = p + motion``. Frame 0
    has motion 0. The point comes from a **geometry pass** (:func:`render_geometry`): one
    un-jittered ray through each pixel centre (Mitsuba's ``stratified`` sampler with
    ``jitter = false``, 1 spp; the lens centre for a thin lens), recording the world position
    of the first hit and which spec object it belongs to. Not the ``position`` buffer of a
    level or of the reference: those are averages over the pixel's footprint, and where a
    pixel straddles a silhouette the average is a point on neither surface (against the sky
    it is pulled towards the world origin, since Mitsuba's position AOV is 0 where a ray
    escapes), so its projection is meaningless exactly where motion matters. The centre ray
    gives an exact surface point, identical for every spp level, as a rasteriser's motion
    vectors are. The point ``X`` hit in frame ``t`` on object ``i`` was at
    ``X - (s_t - s_{t-1}) · translate_i`` in frame ``t - 1``; it is projected with frame
    ``t - 1``'s camera (Mitsuba's perspective convention: horizontal ``fov``, square pixels,
    camera +X to the image's left; a thin lens projects through its centre, where its blur
    is centred). A pixel whose centre ray escapes (sky, environment) gets the motion of the
    direction at infinity (pure camera rotation), which is exact for environment maps.
    Refraction and reflection are not followed: through glass or in a mirror the motion is
    that of the glass's or mirror's own surface, as with a rasteriser's vectors.
Motion to the next frame (buffer ``motion_next``, channels ``motion_next.X/Y``)
    The same from frame ``t`` to frame ``t + 1`` (:func:`next_motion_vectors`): the point
    seen at pixel ``p`` in frame ``t`` will be at ``p + motion_next`` in frame ``t + 1``;
    0 in the last frame. Its own mask ``motion_next_valid`` (channel ``motion_next_valid.Y``)
    is built like ``motion_valid`` below against frame ``t + 1``'s geometry pass (all 0 in
    the last frame): frame ``t + 1``'s ``motion_valid`` lives on that frame's pixels and
    cannot say which pixels of frame ``t`` are seen again. Where both are valid,
    ``motion_next_t(p) = -motion_{t+1}(p + motion_next_t(p))``.
Validity mask (channel ``motion_valid.Y`` next to ``motion``, 1 = valid, 0 = not)
    1 where bilinearly sampling frame ``t - 1`` at ``q`` gives back what pixel ``p`` shows:
    ``q`` lies on the film, the point is in front of the previous camera, every bilinear tap
    of ``q`` (weight > 1e-4) in frame ``t - 1``'s geometry pass hit the same object as ``p``
    (or, for the sky, nothing), the bilinearly interpolated distance from the previous camera
    there agrees with the point's own distance within :data:`DEPTH_TOLERANCE` (1 %), and no
    silhouette crosses ``p`` or a tap (their 3×3 neighbourhoods see one object: a pixel on an
    edge averages two surfaces that move differently, and no single vector moves it). So 0 at
    disocclusions, where the point left the film, in a one-pixel band along every boundary
    between objects (or object and sky), and everywhere in frame 0. A silhouette of an object
    over itself (a mesh folding over) is caught only by the distance test. It is geometric:
    moving shadows, highlights and reflections are not detected.

Arrays: world positions and directions are float64 ``(H, W, 3)`` numpy arrays while
computing; :func:`motion_vectors` returns float32 tensors ``(2, H, W)`` and ``(1, H, W)``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from mcdenoise.errors import InputError
from mcdenoise.render.effects import EffectPlan
from mcdenoise.render.scene_spec import Animation, Camera, SceneSpec, SpecError
from mcdenoise.render.scenes import camera_to_world, scene_dict

#: Default camera path of a sequence whose spec has no ``[animation]``: an orbit of this many
#: degrees per frame about the target (``N - 1`` degrees over ``N`` frames).
DEFAULT_ORBIT_DEGREES_PER_FRAME = 1.0
#: Relative distance tolerance of the validity mask's depth test.
DEPTH_TOLERANCE = 0.01
#: EXR channel of the validity mask, written next to ``motion.X``/``motion.Y``.
VALID_CHANNEL = "motion_valid.Y"
#: EXR channel of the next frame's validity mask, next to ``motion_next.X``/``motion_next.Y``.
NEXT_VALID_CHANNEL = "motion_next_valid.Y"
#: Object ``i`` of the geometry pass is a diffuse BSDF of reflectance ``(i + 1) / ID_SCALE``,
#: read back through the ``albedo`` AOV (exact in float32 for fewer than 2**16 objects).
ID_SCALE = 2.0**16
#: Bilinear taps lighter than this do not count in the validity test.
_TAP_EPS = 1e-4


# --------------------------------------------------------------------------------------------
# Camera paths and object motion
# --------------------------------------------------------------------------------------------
def check_frames(frames: int) -> int:
    """Raise :class:`InputError` unless ``frames`` is an integer >= 2."""
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 2:
        raise InputError(f"frames must be an integer >= 2 (a sequence), got {frames!r}")
    return frames


def frame_times(frames: int) -> list[float]:
    """Sequence time of each frame: ``f / (frames - 1)``.

    >>> frame_times(3)
    [0.0, 0.5, 1.0]
    """
    check_frames(frames)
    return [f / (frames - 1) for f in range(frames)]


def default_animation(frames: int) -> Animation:
    """The camera path of a sequence whose spec has no ``[animation]``: a gentle orbit of
    :data:`DEFAULT_ORBIT_DEGREES_PER_FRAME` per frame.

    >>> default_animation(5).angle
    4.0
    """
    return Animation("orbit", angle=DEFAULT_ORBIT_DEGREES_PER_FRAME * (check_frames(frames) - 1))


def sequence_animation(spec: SceneSpec, frames: int) -> Animation:
    """The spec's ``[animation]``, else :func:`default_animation`."""
    return spec.animation if spec.animation is not None else default_animation(frames)


def _rotate(v: np.ndarray, axis: np.ndarray, degrees: float) -> np.ndarray:
    """Rodrigues' rotation of ``v`` about the unit ``axis`` (right-handed)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return v * c + np.cross(axis, v) * s + axis * float(axis @ v) * (1.0 - c)


def camera_at(spec: SceneSpec, animation: Animation, s: float) -> Camera:
    """The camera at sequence time ``s`` in [0, 1] (see the module doc).

    Raises:
        SpecError: the path makes the camera degenerate (origin on the target, ``up`` along
            the view direction, a thin lens focused behind itself).
    """
    cam = spec.camera
    o0, t0 = np.asarray(cam.origin, dtype=np.float64), np.asarray(cam.target, dtype=np.float64)
    path = animation.camera_path
    if path == "static":
        origin, target = o0, t0
    elif path == "orbit":
        up = np.asarray(cam.up, dtype=np.float64)
        n = float(np.linalg.norm(up))
        if n == 0:
            raise SpecError(f"{spec.source or spec.name}: camera.up must not be zero")
        origin, target = t0 + _rotate(o0 - t0, up / n, animation.angle * s), t0
    elif path == "dolly":
        origin, target = o0 + animation.fraction * s * (t0 - o0), t0
    elif path == "keyframes":
        keys = animation.keyframes
        x = min(max(s, 0.0), 1.0) * (len(keys) - 1)
        k = min(math.floor(x), len(keys) - 2)
        w = x - k
        a, b = keys[k], keys[k + 1]
        origin = (1 - w) * np.asarray(a.origin) + w * np.asarray(b.origin)
        target = (1 - w) * np.asarray(a.target) + w * np.asarray(b.target)
    else:
        raise SpecError(f"{spec.source or spec.name}: animation: unknown camera path {path!r}")
    where = f"{spec.source or spec.name}: animation ({path}) at s = {s:.4g}"
    dist = float(np.linalg.norm(target - origin))
    if dist < 1e-9:
        raise SpecError(f"{where}: the camera origin reaches its target")
    view = (target - origin) / dist
    up = np.asarray(cam.up, dtype=np.float64)
    if np.linalg.norm(np.cross(up, view)) < 1e-6 * max(float(np.linalg.norm(up)), 1e-300):
        raise SpecError(f"{where}: camera.up is parallel to the view direction")
    focus = cam.focus_distance
    if cam.type == "thinlens" and focus is not None:
        focus = dist + (focus - math.dist(cam.origin, cam.target))
        if focus <= 0:
            raise SpecError(f"{where}: the thin lens would focus behind the camera")
    return dataclasses.replace(
        cam,
        origin=tuple(float(v) for v in origin),
        target=tuple(float(v) for v in target),
        focus_distance=focus,
    )


def frame_cameras(spec: SceneSpec, frames: int) -> list[Camera]:
    """The camera of each of ``frames`` frames (:func:`sequence_animation`)."""
    anim = sequence_animation(spec, frames)
    return [camera_at(spec, anim, s) for s in frame_times(frames)]


def object_offsets(spec: SceneSpec, s: float) -> np.ndarray:
    """World translation of every spec object at sequence time ``s``: ``(n_objects, 3)``."""
    return np.array(
        [np.asarray(o.motion or (0.0, 0.0, 0.0), dtype=np.float64) * s for o in spec.objects],
        dtype=np.float64,
    ).reshape(len(spec.objects), 3)


def spec_at(spec: SceneSpec, s: float) -> SceneSpec:
    """``spec`` with every moving object where it is at sequence time ``s`` (camera as is)."""
    if not any(o.motion for o in spec.objects):
        return spec
    objects = []
    for o, d in zip(spec.objects, object_offsets(spec, s)):
        if o.motion is not None:
            t = o.transform
            if o.shape == "sphere" and t == type(t)():
                c = np.asarray(o.center or (0.0, 0.0, 0.0)) + d
                o = dataclasses.replace(o, center=tuple(float(v) for v in c))
            else:  # translate is applied last: a world-space shift
                moved = np.asarray(t.translate) + d
                o = dataclasses.replace(
                    o, transform=dataclasses.replace(t, translate=tuple(float(v) for v in moved))
                )
        objects.append(o)
    return dataclasses.replace(spec, objects=tuple(objects))


# --------------------------------------------------------------------------------------------
# Projection
# --------------------------------------------------------------------------------------------
def _world_to_camera(camera: Camera) -> np.ndarray:

    return np.linalg.inv(camera_to_world(camera))


def _film_scale(camera: Camera, width: int) -> float:
    """Pixels per unit of ``x / z`` in camera space (horizontal fov, square pixels)."""
    return 0.5 * width / math.tan(math.radians(camera.fov) / 2.0)


def project_points(
    points: np.ndarray, camera: Camera, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Film position of world ``points`` ``(..., 3)`` seen by ``camera``.

    Returns ``(pixels (..., 2), z (...))``: continuous film coordinates (x right, y down,
    pixel ``(i, j)`` spans ``[j, j+1] × [i, i+1]``) and the camera-space depth along the view
    axis (``<= 0``: behind the camera; its pixels are then meaningless).
    """
    m = _world_to_camera(camera)
    local = np.asarray(points, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]
    return _film(local, camera, width, height)


def project_directions(
    directions: np.ndarray, camera: Camera, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Film position of points at infinity along world ``directions`` ``(..., 3)``: as
    :func:`project_points`, rotation only."""
    m = _world_to_camera(camera)
    local = np.asarray(directions, dtype=np.float64) @ m[:3, :3].T
    return _film(local, camera, width, height)


def _film(local: np.ndarray, camera: Camera, width: int, height: int) -> tuple[Any, Any]:
    z = local[..., 2]
    f = _film_scale(camera, width)
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(z > 0, z, 1.0)
        u = 0.5 * width - f * local[..., 0] / safe
        v = 0.5 * height - f * local[..., 1] / safe
    return np.stack([u, v], axis=-1), z


def pixel_directions(camera: Camera, width: int, height: int) -> np.ndarray:
    """World direction (unit) of the ray through each pixel centre: ``(H, W, 3)``."""

    f = _film_scale(camera, width)
    u = np.arange(width, dtype=np.float64) + 0.5
    v = np.arange(height, dtype=np.float64) + 0.5
    uu, vv = np.meshgrid(u, v)
    local = np.stack([(0.5 * width - uu) / f, (0.5 * height - vv) / f, np.ones_like(uu)], -1)
    local /= np.linalg.norm(local, axis=-1, keepdims=True)
    return local @ camera_to_world(camera)[:3, :3].T


# --------------------------------------------------------------------------------------------
# Geometry pass
# --------------------------------------------------------------------------------------------
@dataclass
class GeometryBuffer:
    """First hits of the pixel-centre rays of one frame.

    Attributes:
        position: ``(H, W, 3)`` float64 world position (0 where nothing was hit).
        object: ``(H, W)`` int64 index of the spec object hit, -1 where the ray escaped.
        camera: the frame's camera.
    """

    position: np.ndarray
    object: np.ndarray
    camera: Camera

    @property
    def hit(self) -> np.ndarray:
        return self.object >= 0

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.object.shape[0]), int(self.object.shape[1])


def geometry_scene_dict(
    spec: SceneSpec, plan: EffectPlan, camera: Camera, width: int, height: int
) -> dict[str, Any]:
    """The ``mi.load_dict`` dict of the geometry pass: the spec's objects only (no lights,
    no emitters), object ``i`` with a diffuse BSDF of reflectance ``(i + 1) / ID_SCALE``, an
    ``aov`` integrator (``position``, ``albedo``) and an un-jittered 1-spp ``stratified``
    sampler, so each pixel holds exactly its centre ray's hit."""

    if len(spec.objects) >= ID_SCALE - 1:
        raise InputError(f"the geometry pass supports < {int(ID_SCALE) - 1} objects")
    aov = {"type": "aov", "aovs": "pp:position,id:albedo"}
    full = scene_dict(spec, plan, width=width, height=height, integrator=aov, camera=camera)
    d: dict[str, Any] = {"type": "scene", "integrator": aov}
    for key, value in full.items():
        if not key.startswith("obj_"):
            continue
        index = int(key.split("_")[1])
        shape = {k: v for k, v in value.items() if k not in ("bsdf", "emitter")}
        shape["bsdf"] = {
            "type": "twosided",
            "bsdf": {
                "type": "diffuse",
                "reflectance": {"type": "rgb", "value": [(index + 1) / ID_SCALE, 0.0, 0.0]},
            },
        }
        d[key] = shape
    sensor = dict(full["sensor"])
    sensor["sampler"] = {"type": "stratified", "jitter": False, "sample_count": 1}
    d["sensor"] = sensor
    return d


def render_geometry(
    spec: SceneSpec, plan: EffectPlan, camera: Camera, width: int, height: int
) -> GeometryBuffer:
    """Trace one ray through each pixel centre of ``camera`` (Mitsuba variant already set,
    see :func:`mcdenoise.render.mitsuba_setup.ensure_variant`); ``spec`` with objects where they are
    in this frame (:func:`spec_at`)."""
    import mitsuba as mi  # lazy: Mitsuba is optional and slow to import

    try:
        scene = mi.load_dict(geometry_scene_dict(spec, plan, camera, width, height))
    except RuntimeError as err:  # Mitsuba reports every load failure as a long RuntimeError
        first = next((ln.strip() for ln in str(err).splitlines() if ln.strip()), repr(err))
        raise InputError(
            f"{spec.source or spec.name}: Mitsuba cannot load the geometry pass: {first}"
        ) from None
    mi.render(scene, spp=1, seed=0)
    bitmap = scene.sensors()[0].film().bitmap(raw=False)
    struct = bitmap.struct_()
    index = {struct[i].name: i for i in range(bitmap.channel_count())}
    pixels = np.array(bitmap, dtype=np.float32, copy=True)
    try:
        pos = np.stack([pixels[..., index[f"pp.{c}"]] for c in "XYZ"], axis=-1)
        ident = pixels[..., index["id.R"]]
    except KeyError as err:
        raise InputError(f"geometry pass: the film has no channel {err}") from None
    obj = np.rint(ident.astype(np.float64) * ID_SCALE).astype(np.int64) - 1
    obj[(obj < 0) | (obj >= len(spec.objects))] = -1
    pos = np.where(obj[..., None] >= 0, pos.astype(np.float64), 0.0)
    return GeometryBuffer(position=pos, object=obj, camera=camera)


# --------------------------------------------------------------------------------------------
# Motion vectors and the validity mask
# --------------------------------------------------------------------------------------------
def _bilinear_taps(
    q: np.ndarray, width: int, height: int
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The four ``(row, col, weight)`` taps of bilinear sampling at film positions ``q``
    ``(H, W, 2)``, border-clamped (as ``grid_sample`` with ``padding_mode="border"``)."""
    x = np.clip(q[..., 0] - 0.5, 0.0, width - 1.0)
    y = np.clip(q[..., 1] - 0.5, 0.0, height - 1.0)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, width - 1), np.minimum(y0 + 1, height - 1)
    return [
        (y0, x0, (1 - fx) * (1 - fy)),
        (y0, x1, fx * (1 - fy)),
        (y1, x0, (1 - fx) * fy),
        (y1, x1, fx * fy),
    ]


def _pure(objects: np.ndarray) -> np.ndarray:
    """True where the 3×3 neighbourhood (border-clamped) of a pixel sees one object (or only
    sky): no silhouette crosses the pixel's box-filter footprint."""
    padded = np.pad(objects, 1, mode="edge")
    h, w = objects.shape
    out = np.ones((h, w), dtype=bool)
    for dy in range(3):
        for dx in range(3):
            out &= padded[dy : dy + h, dx : dx + w] == objects
    return out


def motion_vectors(
    current: GeometryBuffer,
    previous: GeometryBuffer | None,
    displacement: np.ndarray | None = None,
    *,
    depth_tolerance: float = DEPTH_TOLERANCE,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Screen-space motion of frame ``t`` to frame ``t - 1`` and its validity mask.

    Args:
        current: geometry pass of frame ``t``.
        previous: geometry pass of frame ``t - 1`` (its camera projects); ``None`` for the
            first frame (motion 0, nothing valid).
        displacement: ``(n_objects, 3)`` world translation of each object from frame
            ``t - 1`` to frame ``t`` (default: nothing moves).
        depth_tolerance: relative tolerance of the distance test of the mask.

    Returns:
        ``motion`` float32 ``(2, H, W)`` in pixels (x right, y down; ``prev = p + motion``)
        and ``valid`` float32 ``(1, H, W)`` in {0, 1} (see the module doc).
    """
    h, w = current.shape
    if previous is None:
        return torch.zeros(2, h, w), torch.zeros(1, h, w)
    if previous.shape != (h, w):
        raise InputError(f"geometry passes of different sizes: {previous.shape} vs {(h, w)}")
    cam = previous.camera
    hit = current.hit
    pts = current.position.copy()
    if displacement is not None and hit.any():
        disp = np.asarray(displacement, dtype=np.float64).reshape(-1, 3)
        if int(current.object.max()) >= len(disp):
            raise InputError(
                f"displacement has {len(disp)} rows, object {int(current.object.max())} was hit"
            )
        pts[hit] -= disp[current.object[hit]]
    q_hit, z_hit = project_points(pts, cam, w, h)
    q_sky, z_sky = project_directions(pixel_directions(current.camera, w, h), cam, w, h)
    q = np.where(hit[..., None], q_hit, q_sky)
    z = np.where(hit, z_hit, z_sky)
    front = z > 0
    centre = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), axis=-1)
    motion = np.where(front[..., None], q - centre, 0.0)

    inside = front & (q[..., 0] >= 0) & (q[..., 0] <= w) & (q[..., 1] >= 0) & (q[..., 1] <= h)
    origin = np.asarray(cam.origin, dtype=np.float64)
    prev_dist = np.linalg.norm(previous.position - origin, axis=-1)
    want = np.linalg.norm(pts - origin, axis=-1)
    prev_pure = _pure(previous.object)
    same = _pure(current.object)
    dist = np.zeros((h, w))
    for r, c, wt in _bilinear_taps(q, w, h):
        counts = wt > _TAP_EPS
        same &= ~counts | ((previous.object[r, c] == current.object) & prev_pure[r, c])
        dist += wt * prev_dist[r, c]
    close = np.abs(dist - want) <= depth_tolerance * want
    valid = inside & same & np.where(hit, close, True)
    return (
        torch.from_numpy(np.moveaxis(motion, -1, 0).astype(np.float32)),
        torch.from_numpy(valid[None].astype(np.float32)),
    )


def next_motion_vectors(
    current: GeometryBuffer,
    following: GeometryBuffer | None,
    displacement: np.ndarray | None = None,
    *,
    depth_tolerance: float = DEPTH_TOLERANCE,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Screen-space motion of frame ``t`` to frame ``t + 1`` (``motion_next``) and its
    validity mask (``motion_next_valid``).

    The same construction as :func:`motion_vectors` with the next frame in the role of the
    previous one: the point seen through the centre of pixel ``p`` in frame ``t`` is moved
    with its object to frame ``t + 1`` and projected with frame ``t + 1``'s camera, so
    ``next_pixel = p + motion_next``; the mask is 1 where bilinearly sampling frame ``t + 1``
    there finds that same surface (same object under every tap, no silhouette, distance
    within ``depth_tolerance``). Where frame ``t + 1``'s ``motion`` is valid at ``q``, the two
    vectors are opposite: ``motion_next(p) = -motion_{t+1}(q)`` with ``q = p +
    motion_next(p)`` (up to float32 rounding of the positions), since both map one surface
    point between the same two cameras.

    Args:
        current: geometry pass of frame ``t``.
        following: geometry pass of frame ``t + 1``; ``None`` for the last frame (motion 0,
            nothing valid).
        displacement: ``(n_objects, 3)`` world translation of each object from frame ``t``
            to frame ``t + 1`` (default: nothing moves).
        depth_tolerance: relative tolerance of the distance test of the mask.

    Returns:
        ``motion_next`` float32 ``(2, H, W)`` in pixels (x right, y down) and ``valid``
        float32 ``(1, H, W)`` in {0, 1}.
    """
    back = None if displacement is None else -np.asarray(displacement, dtype=np.float64)
    return motion_vectors(current, following, back, depth_tolerance=depth_tolerance)


def warp_previous(previous: torch.Tensor, motion: torch.Tensor) -> torch.Tensor:
    """Backward-warp frame ``t - 1`` into frame ``t``: ``out[p] = previous[p + motion[p]]``.

    Bilinear, border-clamped (``grid_sample``, ``align_corners=False``: pixel ``j`` is
    centred at ``j + 0.5``, as the motion's coordinates).

    Args:
        previous: ``(B, C, H, W)`` any float data (e.g. linear HDR RGB colour).
        motion: ``(B, 2, H, W)`` pixels, x right, y down (the ``motion`` buffer of frame t).

    Returns:
        ``(B, C, H, W)`` in ``previous``'s dtype.
    """
    if previous.ndim != 4 or motion.ndim != 4 or motion.shape[1] != 2:
        raise InputError(
            f"warp_previous needs (B, C, H, W) and (B, 2, H, W), got {tuple(previous.shape)} "
            f"and {tuple(motion.shape)}"
        )
    b, _, h, w = previous.shape
    if motion.shape[0] != b or motion.shape[2:] != (h, w):
        raise InputError(f"motion {tuple(motion.shape)} does not fit image {tuple(previous.shape)}")
    m = motion.to(previous.dtype)
    xs = torch.arange(w, dtype=previous.dtype, device=previous.device) + 0.5
    ys = torch.arange(h, dtype=previous.dtype, device=previous.device) + 0.5
    gx = (xs.view(1, 1, w) + m[:, 0]) * (2.0 / w) - 1.0  # (B, H, W)
    gy = (ys.view(1, h, 1) + m[:, 1]) * (2.0 / h) - 1.0
    grid = torch.stack([gx, gy], dim=-1)  # (B, H, W, 2)
    return F.grid_sample(
        previous, grid, mode="bilinear", padding_mode="border", align_corners=False
    )


def masked_error(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor, *, border: int = 0) -> float:
    """Mean absolute difference of ``a`` and ``b`` ``(C, H, W)`` over pixels where ``mask``
    ``(1, H, W)`` is > 0.5 and at least ``border`` pixels from the image edge (NaN if none)."""
    m = mask[0] > 0.5
    if border > 0:
        keep = torch.zeros_like(m)
        keep[border:-border, border:-border] = True
        m = m & keep
    if not bool(m.any()):
        return float("nan")
    return float((a - b).abs().mean(dim=0)[m].mean())
