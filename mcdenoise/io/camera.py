"""The camera of an image, read back from its header: what screen-space methods need.

``mcdenoise render`` writes the ``mcdenoise:camera`` header attribute (JSON, built by
:func:`mcdenoise.render.scenes.camera_metadata`): the camera-to-world matrix ``to_world`` (4×4,
rows), the field of view ``fov`` in degrees along ``fov_axis`` (``"x"``: horizontal), the clip
planes ``near``/``far`` and, for an AO render, ``ao_radius`` (the ray-traced AO's occlusion
distance). Frames of older sequences carry only the spec's camera (``origin``, ``target``,
``up``, ``fov``); the matrix is then rebuilt with Mitsuba's look-at. Inputs from other
renderers give what they know with options (:meth:`CameraInfo.with_overrides`).

Conventions, declared once here:

* Mitsuba camera space (the ``to_world`` frame): the camera looks along +Z, +Y is up in the
  image and +X points to the image's *left* (:func:`mcdenoise.render.scenes.look_at`).
* **View space** (what :meth:`CameraInfo.world_to_view` maps to, and what
  :mod:`mcdenoise.ao` works in) is the computer-vision frame: +x to the image's right, +y
  down the image, +z forward (depth), right-handed; so ``view = diag(-1, -1, 1) · camera``.
* Pixel ``(i, j)`` (column, row) has its centre at ``(i + 0.5, j + 0.5)``; a view-space point
  ``(x, y, z)`` lands at ``u = f x / z + W / 2``, ``v = f y / z + H / 2`` with the focal
  length in pixels ``f = W / (2 tan(fov / 2))`` (``fov_axis = "x"``) or
  ``H / (2 tan(fov / 2))`` (``"y"``): square pixels, principal point at the image centre
  (Mitsuba's ``perspective`` sensor).
* ``depth`` buffers hold the distance along the ray (:mod:`mcdenoise.io.buffers`), so
  ``near``/``far`` are informational (no z-buffer to linearise).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from mcdenoise.errors import InputError

#: Header attribute holding the camera (JSON).
CAMERA_ATTR = "mcdenoise:camera"
#: Header attribute a render may use for the AO radius on its own (read when the camera
#: record has none).
AO_RADIUS_ATTR = "mcdenoise:ao_radius"
#: Mitsuba camera space -> view space (x right, y down, z forward).
MITSUBA_TO_VIEW = np.diag([-1.0, -1.0, 1.0])


@dataclass(frozen=True)
class CameraInfo:
    """A pinhole camera as screen-space methods use it.

    Attributes:
        fov: field of view in degrees along ``fov_axis``.
        fov_axis: ``"x"`` (horizontal, mcdenoise's renders) or ``"y"``.
        to_world: 4×4 camera-to-world matrix in Mitsuba's camera frame (float64), or
            ``None`` when unknown (then world-space normals cannot be used).
        near, far: clip distances (informational), ``None`` when unknown.
        ao_radius: the occlusion distance of the ray-traced AO (scene units), or ``None``.
    """

    fov: float
    fov_axis: str = "x"
    to_world: np.ndarray | None = None
    near: float | None = None
    far: float | None = None
    ao_radius: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.fov, (int, float)) and 0.0 < self.fov < 180.0):
            raise InputError(f"camera: fov must be in (0, 180) degrees, got {self.fov!r}")
        if self.fov_axis not in ("x", "y"):
            raise InputError(f"camera: fov_axis must be 'x' or 'y', got {self.fov_axis!r}")
        if self.to_world is not None:
            m = np.asarray(self.to_world, dtype=np.float64)
            if m.shape != (4, 4) or not np.all(np.isfinite(m)):
                raise InputError("camera: to_world must be a finite 4x4 matrix")
            if abs(abs(np.linalg.det(m[:3, :3])) - 1.0) > 1e-3:
                raise InputError("camera: to_world must be a rigid transform (rotation + origin)")
            object.__setattr__(self, "to_world", m)
        if self.ao_radius is not None and not (
            self.ao_radius > 0 and math.isfinite(self.ao_radius)
        ):
            raise InputError(f"camera: ao_radius must be finite and > 0, got {self.ao_radius!r}")

    def focal_pixels(self, width: int, height: int) -> float:
        """Focal length in pixels for a ``width`` × ``height`` image (square pixels).

        >>> round(CameraInfo(fov=90.0).focal_pixels(64, 32), 9)
        32.0
        """
        side = width if self.fov_axis == "x" else height
        return side / (2.0 * math.tan(math.radians(self.fov) / 2.0))

    def world_to_view(self) -> np.ndarray:
        """3×3 rotation from world directions to view space (x right, y down, z forward).

        Raises:
            InputError: the camera has no ``to_world``.
        """
        if self.to_world is None:
            raise InputError("camera: no camera-to-world matrix (world-space normals need one)")
        return MITSUBA_TO_VIEW @ self.to_world[:3, :3].T

    def with_overrides(self, **values: Any) -> CameraInfo:
        """A copy with the given fields replaced (``None`` values are ignored)."""
        return replace(self, **{k: v for k, v in values.items() if v is not None})


def look_at(origin: Any, target: Any, up: Any) -> np.ndarray:
    """Mitsuba's look-at camera-to-world matrix (as :func:`mcdenoise.render.scenes.look_at`,
    which tests hold equal; io may not import render)."""
    o = np.asarray(origin, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - o
    left = np.cross(np.asarray(up, dtype=np.float64), f)
    if np.linalg.norm(f) == 0 or np.linalg.norm(left) < 1e-9 * np.linalg.norm(f):
        raise InputError("camera: origin, target and up do not define a view")
    f /= np.linalg.norm(f)
    left /= np.linalg.norm(left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(f, left), f, o
    return m


def _number(record: Mapping[str, Any], key: str, where: str) -> float | None:
    value = record.get(key)
    if value is None:
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} is not a number: {value!r}") from None


def camera_from_record(record: Mapping[str, Any], where: str = "camera") -> CameraInfo:
    """A :class:`CameraInfo` from a camera record (the JSON of ``mcdenoise:camera``, or a
    manifest's ``camera``): ``to_world`` when present, else look-at from ``origin``,
    ``target`` and ``up``.

    >>> cam = camera_from_record({"fov": 40, "origin": [0, 0, 5], "target": [0, 0, 0]})
    >>> cam.to_world[:3, 2].tolist(), cam.fov_axis
    ([0.0, 0.0, -1.0], 'x')
    """
    if not isinstance(record, Mapping):
        raise InputError(f"{where}: expected a JSON object, got {type(record).__name__}")
    fov = _number(record, "fov", where)
    if fov is None:
        raise InputError(f"{where}: no fov")
    to_world = record.get("to_world")
    if to_world is None and "origin" in record and "target" in record:
        to_world = look_at(record["origin"], record["target"], record.get("up", (0.0, 1.0, 0.0)))
    if to_world is not None:
        try:
            to_world = np.asarray(to_world, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{where}: to_world is not a 4x4 matrix") from None
    return CameraInfo(
        fov=fov,
        fov_axis=str(record.get("fov_axis", "x")),
        to_world=to_world,
        near=_number(record, "near", where),
        far=_number(record, "far", where),
        ao_radius=_number(record, "ao_radius", where),
    )


def camera_from_attributes(
    attributes: Mapping[str, Any], where: str = "input"
) -> CameraInfo | None:
    """The camera recorded in header ``attributes`` (:data:`CAMERA_ATTR`, JSON), or ``None``
    when the file records none. :data:`AO_RADIUS_ATTR` fills a missing ``ao_radius``.

    Raises:
        InputError: the attribute is there but is not a valid camera record.
    """
    raw = attributes.get(CAMERA_ATTR)
    if raw is None:
        return None
    try:
        record = json.loads(raw) if isinstance(raw, str) else raw
    except json.JSONDecodeError:
        raise InputError(f"{where}: {CAMERA_ATTR} is not valid JSON") from None
    cam = camera_from_record(record, f"{where}: {CAMERA_ATTR}")
    if cam.ao_radius is None and attributes.get(AO_RADIUS_ATTR) is not None:
        cam = cam.with_overrides(ao_radius=_number(attributes, AO_RADIUS_ATTR, where))
    return cam


__all__ = [
    "AO_RADIUS_ATTR",
    "CAMERA_ATTR",
    "CameraInfo",
    "camera_from_attributes",
    "camera_from_record",
    "look_at",
]
