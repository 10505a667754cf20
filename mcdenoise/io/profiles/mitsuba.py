"""The ``mitsuba`` profile: Mitsuba 3's ``aov`` integrator, optionally nesting a ``moment``
integrator (channel names checked by rendering with Mitsuba 3.9.1 ``scalar_rgb`` and
``Bitmap.write``).

Colour: ``R,G,B`` (else a nested integrator's ``<name>.R/G/B``). AOVs are
``<aovname>.<suffix>``; the common names are recognised: albedo ``albedo.R/G/B``; normal
``normal|nn|sh_normal .X/Y/Z``; depth ``depth|dd .T`` (distance along the ray); position
``position|pp .X/Y/Z``. An AOV integrator nested in a ``moment`` integrator gets its
integrator name as prefix (``aov.albedo.R``), which is accepted. Alpha (``A``, ``<name>.A`` of
nested integrators) is ignored.

The ``moment`` integrator writes, for each nested integrator ``N``, first moments
``[M.]N.<ch>`` and second moments ``[M.]m2_N.<ch>`` (``M``: the moment integrator's name when
it is itself nested). Variance of the mean = ``(m2 - m1^2) / (spp - 1)``, the unbiased
estimate (``/spp`` would underestimate it by ``(spp-1)/spp``). Two facts that matter:

1. The moments of an integrator's colour are stored as CIE **XYZ** (``.X/.Y/.Z``; ``R,G,B`` =
   sRGB(XYZ)), so per-channel RGB variances cannot be derived: ``color_var`` is the 1-channel
   *luminance* variance from the ``Y`` moments, and the moment pair whose ``Y`` equals the
   luminance of ``R,G,B`` is chosen on load (none matching: no ``color_var``, with a note).
   AOV moments (``m2_aov.albedo.R``) are per channel and give per-channel variances.
2. Render with ``rfilter = box``: with the default gaussian filter samples are splatted over
   neighbours and the moments no longer give the variance of the pixel mean.

Mitsuba writes no sample count: ``spp`` comes from ``mcdenoise:spp`` if present, else the
caller's ``spp=``; without it no variance is produced and ``mcdenoise info`` says why.
``generatedBy = "Mitsuba version ..."`` identifies files.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from mcdenoise.io.buffers import VAR_SUFFIX
from mcdenoise.io.profiles.base import (
    RGB,
    XYZ,
    Alternatives,
    BufferSource,
    Profile,
    copied,
    layered,
)

_MITSUBA_AOVS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # feature: (recognised AOV names in order of preference, suffixes)
    "albedo": (("albedo",), RGB),
    "normal": (("normal", "nn", "sh_normal"), XYZ),
    "depth": (("depth", "dd"), ("T",)),
    "position": (("position", "pp"), XYZ),
}
_MITSUBA_AOV_NAMES = {n for names, _ in _MITSUBA_AOVS.values() for n in names} | {
    "geo_normal",
    "uv",
    "dp_du",
    "dp_dv",
    "duv_dx",
    "duv_dy",
    "prim_index",
    "shape_index",
}


def _stems(channels: Sequence[str], suffixes: Sequence[str]) -> list[str]:
    """Distinct ``stem`` such that some ``stem.<suffix>`` is a channel, in file order."""
    out: dict[str, None] = {}
    for c in channels:
        stem, dot, suffix = c.rpartition(".")
        if dot and suffix in suffixes:
            out[stem] = None
    return list(out)


def _m2_partner(channel: str, present: set[str]) -> str | None:
    """The second-moment channel of ``channel`` written by Mitsuba's ``moment`` integrator:
    ``m2_`` prefixed to one name segment (``img.path.X`` -> ``img.m2_path.X``,
    ``aov.albedo.R`` -> ``m2_aov.albedo.R``), if exactly one such channel exists."""
    segs = channel.split(".")
    found = []
    for i in range(len(segs) - 1):
        cand = ".".join([*segs[:i], "m2_" + segs[i], *segs[i + 1 :]])
        if cand in present:
            found.append(cand)
    return found[0] if len(found) == 1 else None


class MitsubaProfile(Profile):
    """Mitsuba 3 ``aov`` (+ ``moment``) integrator output (see the module docstring)."""

    name = "mitsuba"
    description = "Mitsuba 3 aov integrator (+ moment integrator for variances)"

    def detect(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> str | None:
        gen = str(attributes.get("generatedBy", ""))
        if gen.startswith("Mitsuba"):
            return f"header attribute generatedBy={gen!r}"
        for c in channels:
            segs = c.split(".")
            if any(s.startswith("m2_") for s in segs[:-1]):
                return f"moment-integrator channel {c!r}"
            if len(segs) >= 2 and segs[-1] == "T" and segs[-2] in ("depth", "dd"):
                return f"Mitsuba depth AOV channel {c!r}"
            if len(segs) >= 2 and segs[-2] in ("nn", "sh_normal", "pp"):
                return f"Mitsuba AOV channel {c!r}"
        return None

    def propose(self, channels: Sequence[str], attributes: Mapping[str, Any]) -> Alternatives:
        present = set(channels)
        alts: Alternatives = {}
        # Colour: the film's R,G,B, else a nested integrator's <name>.R/G/B.
        color = [copied(*RGB)]
        for stem in _stems(channels, RGB):
            if "." not in stem and stem not in _MITSUBA_AOV_NAMES and not stem.startswith("m2_"):
                color.append(BufferSource(layered(stem, RGB)))
        alts["color"] = color
        # Luminance variance of colour from XYZ moments of any integrator; matched on load.
        color_var = []
        for stem in _stems(channels, XYZ):
            last = stem.rpartition(".")[2]
            if last in _MITSUBA_AOV_NAMES or last.startswith("m2_"):
                continue
            m1 = f"{stem}.Y"
            m2 = _m2_partner(m1, present)
            if m1 in present and m2 is not None:
                color_var.append(BufferSource((m1,), "moments", (m2,), RGB))
        if color_var:
            alts["color_var"] = color_var
        # AOVs, unprefixed first (preference order of names), then prefixed ones.
        for feat, (names, suffixes) in _MITSUBA_AOVS.items():
            stems = _stems(channels, suffixes)
            ordered = [n for n in names if n in stems]
            ordered += [s for n in names for s in stems if s.endswith("." + n)]
            ordered = [s for s in ordered if not any(p.startswith("m2_") for p in s.split("."))]
            feat_alts = [BufferSource(layered(s, suffixes)) for s in ordered]
            if feat_alts:
                alts[feat] = feat_alts
            var_alts = []
            for src in feat_alts:
                partners = [_m2_partner(c, present) for c in src.channels]
                if all(partners) and all(c in present for c in src.channels):
                    var_alts.append(
                        BufferSource(src.channels, "moments", tuple(partners))  # type: ignore[arg-type]
                    )
            if var_alts:
                alts[feat + VAR_SUFFIX] = var_alts
        return alts
