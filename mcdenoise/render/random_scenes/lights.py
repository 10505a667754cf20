"""Lights of the random scenes: point, spot, sun, environment, emissive bulbs, and random
order-5 SH environments. Powers are set from a target irradiance at the subjects (see the
distribution's text)."""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mcdenoise.render.random_scenes.assets import envmap_file
from mcdenoise.render.random_scenes.distribution import DISTRIBUTION, Distribution, Lights
from mcdenoise.render.random_scenes.placement import Solid, outside
from mcdenoise.render.random_scenes.sampling import (
    LUMINANCE,
    colour,
    rounded,
    rounded_vec,
    tint,
)
from mcdenoise.render.sh import (
    PAPER_ORDER,
    latlong_directions,
    latlong_solid_angles,
    sh_basis,
    world_to_sh_frame,
)


def bulbs(
    rng: np.random.Generator,
    lights: Lights,
    count: int,
    region: Callable[[], np.ndarray],
    avoid: Sequence[Solid],
    camera_origin: np.ndarray,
) -> list[dict[str, Any]]:
    """Small very bright emissive spheres (fireflies) at ``region()`` positions."""
    out = []
    for _ in range(count):
        r = lights.bulb_radius.draw(rng)
        for _attempt in range(20):
            p = region()
            if (
                p[1] > r + 0.1  # above the ground or table
                and outside(p, avoid, r + 0.1)
                and np.linalg.norm(p - camera_origin) > r + 0.5
            ):
                e = lights.bulb_irradiance.draw(rng)
                radiance = e * lights.bulb_distance**2 / (math.pi * r * r) * tint(rng, lights)
                out.append(
                    {
                        "shape": "sphere",
                        "center": rounded_vec(p),
                        "radius": rounded(r, 5),
                        "material": {"type": "diffuse", "reflectance": [0.8, 0.8, 0.8]},
                        "emission": rounded_vec(radiance, 2),
                    }
                )
                break
    return out


def point(position: np.ndarray, target: np.ndarray, irradiance: float, rgb: np.ndarray) -> dict:
    """A point light giving ``irradiance`` × ``rgb`` at ``target``."""
    d2 = float(np.sum((position - target) ** 2))
    return {
        "type": "point",
        "position": rounded_vec(position),
        "intensity": rounded_vec(irradiance * d2 * rgb, 3),
    }


def spot(
    rng: np.random.Generator,
    lights: Lights,
    position: np.ndarray,
    target: np.ndarray,
    radius: float,
    irradiance: float,
    rgb: np.ndarray,
) -> dict:
    """A spot light aimed at ``target`` whose cone covers a sphere of ``radius`` there."""
    dist = float(np.linalg.norm(position - target))
    angular = math.degrees(math.atan(1.3 * radius / dist)) + lights.spot_margin.draw(rng)
    cutoff = min(max(angular, lights.spot_min_cutoff), lights.spot_max_cutoff)
    return {
        "type": "spot",
        "position": rounded_vec(position),
        "target": rounded_vec(target),
        "intensity": rounded_vec(irradiance * dist * dist * rgb, 3),
        "cutoff": rounded(cutoff, 2),
        "beam_width": rounded(cutoff * lights.spot_beam.draw(rng), 2),
    }


#: Offsets in units in the last place tried by :func:`_unit`, smallest first.
_ULP_STEPS = sorted(itertools.product(range(-4, 5), repeat=3), key=lambda t: (sum(map(abs, t)), t))


def _unit(direction: Sequence[float]) -> list[float]:
    """A unit vector whose float norm is exactly 1.0, so :func:`~mcdenoise.render.scene_spec.parse_spec`
    (which divides by the norm again) keeps it bit for bit and specs round-trip exactly: the
    normalised ``direction`` moved by at most a few ulps per component."""
    norm = math.sqrt(sum(float(c) ** 2 for c in direction))
    d = [float(c) / norm for c in direction]
    for steps in _ULP_STEPS:
        e = list(d)
        for i, n in enumerate(steps):
            for _ in range(abs(n)):
                e[i] = float(np.nextafter(e[i], math.copysign(math.inf, n)))
        if math.sqrt(sum(c * c for c in e)) == 1.0:
            return e
    raise AssertionError(f"no unit vector of norm exactly 1.0 near {direction}")


def sun(
    rng: np.random.Generator, lights: Lights, direction: np.ndarray, irradiance: float
) -> dict[str, Any]:
    """A sun shining from ``direction`` (a disk or, sometimes, a delta light)."""
    return {
        "type": "sun",
        "direction": _unit(rounded_vec(direction / np.linalg.norm(direction))),
        "irradiance": rounded_vec(irradiance * tint(rng, lights), 3),
        "angular_diameter": rounded(
            lights.sun_angular_diameter.draw(rng) if rng.random() < lights.sun_disk_prob else 0.0,
            3,
        ),
    }


def environment(
    rng: np.random.Generator, lights: Lights, *, studio: float, gain: float = 1.0
) -> dict[str, Any]:
    """One environment light: procedural sky (``lights.sky_prob``), the studio envmap
    (probability ``studio``) or a constant, its brightness times ``gain``."""
    u = rng.random()
    if u < lights.sky_prob:
        return {
            "type": "envmap",
            "procedural": "sky",
            "scale": rounded(gain * lights.sky_scale.draw(rng)),
            "rotate": [0.0, rounded(rng.uniform(0, 360), 2), 0.0],
        }
    if u < lights.sky_prob + studio:
        return {
            "type": "envmap",
            "file": envmap_file(),
            "scale": rounded(gain * lights.studio_scale.draw(rng)),
            "rotate": [0.0, rounded(rng.uniform(0, 360), 2), 0.0],
        }
    radiance = gain * lights.constant_radiance.draw(rng) * tint(rng, lights)
    return {"type": "constant", "radiance": rounded_vec(radiance)}


@functools.cache
def sh_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World directions ``(N, 3)``, solid angles ``(N,)`` and order-5 SH basis ``(N, 36)``
    of Mitsuba's lat-long texel samples (read-only arrays)."""
    dirs = latlong_directions(width, height).reshape(-1, 3)
    weights = latlong_solid_angles(width, height).reshape(-1)
    basis = sh_basis(PAPER_ORDER, world_to_sh_frame(dirs))
    for a in (dirs, weights, basis):
        a.flags.writeable = False
    return dirs, weights, basis


def random_sh_coefficients(
    rng: np.random.Generator,
    mean_radiance: float = 0.8,
    *,
    distribution: Distribution = DISTRIBUTION,
) -> np.ndarray:
    """Order-5 SH radiance ``(36, 3)`` (module :mod:`mcdenoise.render.sh` convention) of a
    random environment drawn from ``distribution.sh``: a gradient sky (brighter above) plus
    coloured lobes, projected on SH; then the constant term is raised until the radiance is
    ≥ 0 at every texel of the lat-long :func:`~mcdenoise.render.sh.sh_envmap_dict` bakes (so
    nothing is clamped), and everything is scaled to ``mean_radiance`` (luminance averaged
    over the sphere)."""
    m, lights, sh = distribution.materials, distribution.lights, distribution.sh
    dirs, weights, basis = sh_grid(64, 33)
    up = dirs[:, 1:2]
    top = np.array(colour(rng, m, sh.top_value))
    bottom = np.array(colour(rng, m, sh.bottom_value))
    gradient = np.clip(up, 0, 1) ** sh.gradient_exponent.draw(rng)
    radiance = top * gradient + bottom * np.clip(-up, 0, 1)
    radiance = radiance + sh.ambient
    for _ in range(sh.lobes.draw(rng)):
        mu = rng.normal(size=3)
        mu[1] = abs(mu[1]) * rng.choice([1.0, -sh.lobe_below])  # mostly from above
        mu /= np.linalg.norm(mu)
        lobe = np.exp(sh.lobe_sharpness.draw(rng) * (dirs @ mu - 1))[:, None]
        radiance = radiance + sh.lobe_strength.draw(rng) * lobe * tint(rng, lights)
    coeffs = basis.T @ (radiance * weights[:, None])  # (36, 3): ∫ L Y_i dω by quadrature
    y00 = 0.5 / math.sqrt(math.pi)
    lowest = (sh_grid(128, 65)[2] @ coeffs).min(axis=0)  # the texels sh_envmap_dict bakes
    coeffs[0] += np.maximum(0.0, -lowest) / y00
    mean = coeffs[0] * y00  # mean radiance per channel
    coeffs *= mean_radiance / float(mean @ LUMINANCE)
    coeffs[0] += 2e-4 / y00  # keeps the coefficients non-negative after rounding
    return coeffs
