"""Renderer profiles: which EXR channels hold which feature buffer, looked up by NAME.

A profile turns the channel names (and header attributes) of a file into a
:class:`ChannelMap`: for every buffer of :mod:`mcdenoise.io.buffers` (``color``, ``albedo``,
``normal``, ``depth``, ``position``, ``diffuse``, ``specular``, ``visibility``, ``motion`` and
their ``<name>_var`` variances *of the mean*) the file channels it comes from and how they are
converted. Channel positions and the order inside the file never matter.

Each renderer's conventions are declared once, in its own module (checked against the
renderer's source or output):

=============  ======================================  ==========================================
profile        module                                  files
=============  ======================================  ==========================================
``mcdenoise``  :mod:`~mcdenoise.io.profiles.mcdenoise`  the canonical layout ``save_buffers`` writes
``mitsuba``    :mod:`~mcdenoise.io.profiles.mitsuba`    Mitsuba 3 ``aov`` (+ ``moment``) integrator
``cycles``     :mod:`~mcdenoise.io.profiles.cycles`     Blender multilayer EXR
``pbrt``       :mod:`~mcdenoise.io.profiles.pbrt`       pbrt-v4 ``gbuffer`` film
``tungsten``   :mod:`~mcdenoise.io.profiles.tungsten`   Tungsten as packaged for KPCN
``mapping``    :mod:`~mcdenoise.io.profiles.mapping`    a user mapping file (TOML or JSON)
=============  ======================================  ==========================================

The rest: :mod:`~mcdenoise.io.profiles.base` (the :class:`Profile` base class, the records and
errors), :mod:`~mcdenoise.io.profiles.detect` (the table of profiles, :func:`get_profile`,
:func:`detect_profile`) and :mod:`~mcdenoise.io.profiles.resolve` (:func:`resolve_channels`,
the sample count, completeness checks and :func:`assemble`).
"""

from __future__ import annotations

from mcdenoise.io.profiles.base import (
    Alternatives,
    AssembledBuffers,
    BufferSource,
    ChannelMap,
    IncompleteFeatureError,
    Profile,
    ProfileError,
)
from mcdenoise.io.profiles.cycles import BLENDER_ATTR, CyclesProfile, cycles_layers
from mcdenoise.io.profiles.detect import (
    DETECTION_ORDER,
    PROFILE_NAMES,
    detect_profile,
    get_profile,
)
from mcdenoise.io.profiles.mapping import ChannelMapping, MappingProfile, load_mapping
from mcdenoise.io.profiles.mcdenoise import (
    LAYOUT_ATTR,
    LAYOUT_VERSION,
    SPP_ATTR,
    SUFFIXES,
    McdenoiseProfile,
    canonical_channels,
)
from mcdenoise.io.profiles.mitsuba import MitsubaProfile
from mcdenoise.io.profiles.pbrt import PbrtProfile
from mcdenoise.io.profiles.resolve import assemble, resolve_channels, resolve_spp
from mcdenoise.io.profiles.tungsten import TungstenProfile

__all__ = [
    "BLENDER_ATTR",
    "DETECTION_ORDER",
    "LAYOUT_ATTR",
    "LAYOUT_VERSION",
    "PROFILE_NAMES",
    "SPP_ATTR",
    "SUFFIXES",
    "Alternatives",
    "AssembledBuffers",
    "BufferSource",
    "ChannelMap",
    "ChannelMapping",
    "CyclesProfile",
    "IncompleteFeatureError",
    "MappingProfile",
    "McdenoiseProfile",
    "MitsubaProfile",
    "PbrtProfile",
    "Profile",
    "ProfileError",
    "TungstenProfile",
    "assemble",
    "canonical_channels",
    "cycles_layers",
    "detect_profile",
    "get_profile",
    "load_mapping",
    "resolve_channels",
    "resolve_spp",
]
