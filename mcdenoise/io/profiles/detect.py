"""The table of renderer profiles: look one up by name, or guess it from a file's header.

Each renderer's detection rule is its profile's :meth:`~mcdenoise.io.profiles.base.Profile.detect`
(in its own module); this module only fixes the order in which the rules are tried.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.io.buffers import FEATURES
from mcdenoise.io.profiles.base import RGB, Profile, ProfileError, shorten
from mcdenoise.io.profiles.cycles import CyclesProfile
from mcdenoise.io.profiles.mcdenoise import McdenoiseProfile, canonical_channels
from mcdenoise.io.profiles.mitsuba import MitsubaProfile
from mcdenoise.io.profiles.pbrt import PbrtProfile
from mcdenoise.io.profiles.tungsten import TungstenProfile

_PROFILES: dict[str, type[Profile]] = {
    "mcdenoise": McdenoiseProfile,
    "mitsuba": MitsubaProfile,
    "cycles": CyclesProfile,
    "pbrt": PbrtProfile,
    "tungsten": TungstenProfile,
}
#: Profile names accepted by :func:`get_profile` (``cycles`` also as ``cycles:<Layer>``).
PROFILE_NAMES: tuple[str, ...] = tuple(_PROFILES)
#: Order in which :func:`detect_profile` tries the profiles' rules: the most specific marks
#: (a header attribute, Blender's ``<Layer>.<Pass>`` names) before generic AOV names.
DETECTION_ORDER: tuple[type[Profile], ...] = (
    McdenoiseProfile,
    CyclesProfile,
    PbrtProfile,
    TungstenProfile,
    MitsubaProfile,
)


def get_profile(name: str | Profile) -> Profile:
    """The profile called ``name`` (``"mcdenoise"``, ``"mitsuba"``, ``"cycles"``,
    ``"cycles:<Layer>"``, ``"pbrt"``, ``"tungsten"``); a Profile instance is returned as is."""
    if isinstance(name, Profile):
        return name
    if not isinstance(name, str):
        raise ProfileError(f"profile must be a name, got {name!r}")
    key, _, option = name.partition(":")
    cls = _PROFILES.get(key.strip().lower())
    if cls is None:
        raise ProfileError(
            f"unknown profile {name!r}; use 'auto' or one of {', '.join(PROFILE_NAMES)}"
        )
    if cls is CyclesProfile:
        return CyclesProfile(option or None)
    if option:
        raise ProfileError(f"profile {key!r} takes no option (got {name!r})")
    return cls()


def detect_with_reason(
    channels: Sequence[str], attributes: Mapping[str, Any]
) -> tuple[Profile, str]:
    """:func:`detect_profile` plus the reason (which rule matched), for reports."""
    for cls in DETECTION_ORDER:
        prof = cls()
        why = prof.detect(channels, attributes)
        if why:
            return prof, why
    generic = set(RGB) | {c for f in FEATURES for c in canonical_channels(f)}
    if generic & set(channels):
        return McdenoiseProfile(), "only generic channel names (R,G,B ...): mcdenoise layout"
    raise ProfileError(
        "cannot tell which renderer wrote this file (channels: "
        f"{shorten(list(channels))}); pass profile= one of {', '.join(PROFILE_NAMES)} "
        "or a mapping file"
    )


def detect_profile(channel_names: Sequence[str], attributes: Mapping[str, Any]) -> Profile:
    """Guess the renderer profile from channel names and header attributes.

    The profiles' own :meth:`~mcdenoise.io.profiles.base.Profile.detect` rules are tried in
    :data:`DETECTION_ORDER`, first match wins; otherwise a file with canonical names (plain
    ``R,G,B`` ...) is read as the mcdenoise layout.

    Raises:
        ProfileError: nothing recognisable (the message lists the channels).
    """
    return detect_with_reason(channel_names, attributes)[0]
