"""The ``mcdenoise`` canonical layout: what :func:`mcdenoise.io.save_buffers` writes, and the
profile that reads it back.

==============  ==========================================  =====================================
buffer          EXR channels                                contents
==============  ==========================================  =====================================
color           ``R``, ``G``, ``B``                         noisy radiance, linear HDR RGB
albedo          ``albedo.R``, ``albedo.G``, ``albedo.B``    first-hit reflectance, linear RGB
normal          ``normal.X``, ``normal.Y``, ``normal.Z``    shading normal, world space
depth           ``depth.Z``                                 distance camera -> first hit
position        ``position.X``, ``.Y``, ``.Z``              first-hit world position
diffuse         ``diffuse.R``, ``.G``, ``.B``               diffuse part of color
specular        ``specular.R``, ``.G``, ``.B``              specular part of color
visibility      ``visibility.Y``                            direct-light visibility in [0, 1]
motion          ``motion.X``, ``motion.Y``                  motion to the previous frame (pixels)
motion_valid    ``motion_valid.Y``                          1 where the motion is trustworthy
motion_next     ``motion_next.X``, ``motion_next.Y``        motion to the next frame (pixels)
motion_next_    ``motion_next_valid.Y``                     1 where ``motion_next`` is
 valid                                                      trustworthy
<buffer>_var    ``<buffer>_var.<same suffixes>``            variance of the mean of <buffer>
<buffer>_var    ``<buffer>_var.Y`` (1 channel)              luminance variance of the mean
color_a,        ``color_a.R/G/B``, ``color_b.R/G/B``         the two independent half-sample
 color_b                                                    colour buffers (``mcdenoise render
                                                            --halves``); ``color = (a + b) / 2``
<feature>_a/_b  ``albedo_a.R/G/B``, ``depth_b.Z``, ...      halves of a feature (same suffixes)
<half>_var      ``color_a_var.R/G/B``, ...                  variance of the mean of that half
==============  ==========================================  =====================================

e.g. ``color_var.R/G/B`` or ``color_var.Y``, ``depth_var.Z``, ``normal_var.X/Y/Z``. Header
attributes: ``mcdenoise:layout`` = ``"1"`` (marks the layout; detection relies on it) and
``mcdenoise:spp`` (int, samples per pixel of ``color``; read for files of every profile).
Other ``mcdenoise:*`` attributes (method, params JSON, source, seconds) are written by callers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.errors import InputError
from mcdenoise.io.buffers import (
    FEATURES,
    HALF_NAMES,
    VAR_SUFFIX,
    base_feature,
    expected_channels,
)
from mcdenoise.io.profiles.base import RGB, Alternatives, BufferSource, Profile

#: Canonical channel suffixes of each feature (``color`` has no layer prefix).
SUFFIXES: dict[str, tuple[str, ...]] = {
    "color": ("R", "G", "B"),
    "albedo": ("R", "G", "B"),
    "normal": ("X", "Y", "Z"),
    "depth": ("Z",),
    "position": ("X", "Y", "Z"),
    "diffuse": ("R", "G", "B"),
    "specular": ("R", "G", "B"),
    "visibility": ("Y",),
    "motion": ("X", "Y"),
    "motion_valid": ("Y",),
    "motion_next": ("X", "Y"),
    "motion_next_valid": ("Y",),
}
#: Value of the ``mcdenoise:layout`` attribute written by :func:`mcdenoise.io.save_buffers`.
LAYOUT_VERSION = "1"
LAYOUT_ATTR = "mcdenoise:layout"
SPP_ATTR = "mcdenoise:spp"


def canonical_channels(buffer: str, n_channels: int | None = None) -> tuple[str, ...]:
    """EXR channel names of ``buffer`` in the ``mcdenoise`` layout.

    >>> canonical_channels("color"), canonical_channels("depth_var")
    (('R', 'G', 'B'), ('depth_var.Z',))
    >>> canonical_channels("color_var", 1), canonical_channels("color_a")
    (('color_var.Y',), ('color_a.R', 'color_a.G', 'color_a.B'))
    """
    want = expected_channels(buffer)
    n = want if n_channels is None else n_channels
    is_var = buffer.endswith(VAR_SUFFIX)
    base = base_feature(buffer)
    if n != want and not (is_var and n == 1):
        raise InputError(f"buffer {buffer!r} cannot have {n} channel(s)")
    if buffer == "color":
        return RGB
    suffixes = SUFFIXES[base] if n == want else ("Y",)
    return tuple(f"{buffer}.{s}" for s in suffixes)


class McdenoiseProfile(Profile):
    """The canonical layout, detected by its ``mcdenoise:layout`` header attribute."""

    name = "mcdenoise"
    description = "mcdenoise canonical layout (R,G,B; albedo.R/G/B; normal.X/Y/Z; depth.Z; ...)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        if LAYOUT_ATTR in attributes:
            return f"header attribute {LAYOUT_ATTR}={attributes[LAYOUT_ATTR]!r}"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        alts: Alternatives = {}
        for feat in (*FEATURES, *HALF_NAMES):
            n = expected_channels(feat)
            alts[feat] = [BufferSource(canonical_channels(feat))]
            var = feat + VAR_SUFFIX
            alts[var] = [BufferSource(canonical_channels(var))]
            if n > 1:
                alts[var].append(BufferSource(canonical_channels(var, 1)))
        return alts

    def header_spp(self, attributes: Mapping[str, Any]) -> tuple[int, str] | None:
        return None  # mcdenoise:spp is read for every profile (resolve.resolve_spp)
