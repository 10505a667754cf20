"""`FeatureBuffers`: the in-memory form of one rendered image and its auxiliary buffers.

Every buffer is a float32 ``torch.Tensor`` of layout ``(C, H, W)`` on the CPU (move it with
:meth:`FeatureBuffers.to`). Buffers are addressed by *feature name*, never by channel position;
the names and channel counts are fixed here and nowhere else:

=================  ==  ====================================================================
name               C   meaning
=================  ==  ====================================================================
color              3   noisy radiance, linear HDR RGB, the mean of ``spp`` samples
albedo             3   first-hit reflectance ("texture"), linear RGB, usually in [0, 1]
normal             3   first-hit shading normal, world space, components in [-1, 1]
depth              1   distance from the camera to the first hit along the ray (scene units;
                       Mitsuba's ``T``; not the planar camera z)
position           3   first-hit world position (scene units)
diffuse            3   diffuse part of ``color`` (optional extra)
specular           3   specular part of ``color`` (optional extra)
visibility         1   direct-light visibility in [0, 1] (optional extra)
motion             2   screen-space motion to the previous frame, pixels (x right, y down):
                       the surface seen at pixel p was at ``p + motion`` in frame t - 1
motion_valid       1   1 where ``motion`` can be trusted (no disocclusion/edge), else 0
motion_next        2   screen-space motion to the next frame, pixels (x right, y down): the
                       surface seen at pixel p will be at ``p + motion_next`` in frame t + 1
                       (0 in the last frame of a sequence)
motion_next_valid  1   1 where ``motion_next`` can be trusted: sampling frame t + 1 at
                       ``p + motion_next`` finds the surface seen at p (its own mask: frame
                       t + 1's ``motion_valid`` is on t + 1's pixels); 0 in the last frame
=================  ==  ====================================================================

``motion_next`` of frame t and ``motion`` of frame t + 1 are opposite where both are valid:
``motion_next_t(p) = -motion_{t+1}(p + motion_next_t(p))``. ``mcdenoise render --frames``
writes all four motion buffers (:mod:`mcdenoise.render.animation`); Blender Cycles' ``Vector``
pass gives ``motion`` and ``motion_next`` but no masks (:mod:`mcdenoise.io.profiles.cycles`).

Where the camera ray escapes (background), ``depth``, ``position`` and ``normal`` are 0.

For every name ``f`` above, ``f + "_var"`` holds the per-pixel **variance of the mean** of that
buffer (same channel count, or 1 channel for a luminance variance), i.e. the sample variance
divided by the sample count. A renderer that writes the per-sample variance (pbrt-v4's
``Variance``) is converted on load by the profile, which divides by ``spp``.

Half buffers (two independent halves of the samples, Rousselle et al. 2012, Bitterli et al.
2016): for a name ``f`` of :data:`HALVABLE`, ``f + "_a"`` and ``f + "_b"`` are the means of
two disjoint halves of the pixel's samples (``spp / 2`` each, from disjoint sample streams), so
``f == (f_a + f_b) / 2`` where a renderer writes all three; ``f_a + "_var"`` is the variance
of the mean of that half (``color_a_var``). Halves come in pairs: an image with only one of
``f_a``/``f_b`` is refused by :func:`check_halves` (which :func:`mcdenoise.io.load_buffers`
runs), naming the half that is missing.

Missing buffers are simply absent: code that needs one calls :meth:`FeatureBuffers.require`,
which raises :class:`MissingFeatureError` naming what is missing and what the file has.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from mcdenoise.errors import InputError, McdenoiseError

#: Feature name -> channel count. The order is the canonical order used when writing.
FEATURES: dict[str, int] = {
    "color": 3,
    "albedo": 3,
    "normal": 3,
    "depth": 1,
    "position": 3,
    "diffuse": 3,
    "specular": 3,
    "visibility": 1,
    "motion": 2,
    "motion_valid": 1,
    "motion_next": 2,
    "motion_next_valid": 1,
}
#: Suffix of variance buffers: ``color_var`` is the variance of the mean of ``color``.
VAR_SUFFIX = "_var"

#: Buffers that may come as two independent halves ``<name>_a`` / ``<name>_b`` (see the module
#: docstring); motion vectors and their masks are geometry, never halved.
HALVABLE: tuple[str, ...] = (
    "color",
    "albedo",
    "normal",
    "depth",
    "position",
    "diffuse",
    "specular",
    "visibility",
)
#: Suffixes of the two halves.
HALF_SUFFIXES: tuple[str, str] = ("_a", "_b")
#: ``color_a, color_b, albedo_a, ...``: every half buffer name (without variances).
HALF_NAMES: tuple[str, ...] = tuple(f + h for f in HALVABLE for h in HALF_SUFFIXES)

#: Every buffer name a FeatureBuffers may hold.
BUFFER_NAMES: tuple[str, ...] = (
    tuple(FEATURES)
    + tuple(f + VAR_SUFFIX for f in FEATURES)
    + HALF_NAMES
    + tuple(f + VAR_SUFFIX for f in HALF_NAMES)
)


def base_feature(name: str) -> str:
    """The feature a buffer name belongs to: ``color_a_var`` -> ``color``, ``depth`` -> ``depth``.

    >>> base_feature("color_a_var"), base_feature("albedo_b"), base_feature("normal_var")
    ('color', 'albedo', 'normal')
    """
    base = name[: -len(VAR_SUFFIX)] if name.endswith(VAR_SUFFIX) else name
    if base not in FEATURES and base[-2:] in HALF_SUFFIXES and base[:-2] in HALVABLE:
        return base[:-2]
    return base


class MissingFeatureError(McdenoiseError, ValueError):
    """A method needs buffers the input does not have.

    The message names the missing buffers and lists the buffers (and, when known, the raw
    file channels) that *are* present, so the user can fix the profile or mapping.
    """

    def __init__(
        self,
        missing: Iterable[str],
        present: Iterable[str],
        *,
        source: str | None = None,
        channels: Iterable[str] | None = None,
        needed_by: str | None = None,
    ) -> None:
        self.missing = list(missing)
        self.present = list(present)
        self.source = source
        self.channels = list(channels) if channels is not None else None
        who = f"{needed_by} needs" if needed_by else "missing"
        where = f"{source}: " if source else ""
        msg = f"{where}{who} {', '.join(self.missing)}; the input has {', '.join(self.present) or 'nothing'}"
        if self.channels is not None:
            shown = self.channels[:40]
            more = f", ... ({len(self.channels) - 40} more)" if len(self.channels) > 40 else ""
            msg += f" (file channels: {', '.join(shown)}{more})"
        super().__init__(msg)


def expected_channels(name: str) -> int:
    """Channel count of buffer ``name`` (variance buffers may also have 1 channel)."""
    base = base_feature(name)
    if base not in FEATURES:
        raise KeyError(f"unknown buffer name {name!r}; known: {', '.join(BUFFER_NAMES)}")
    return FEATURES[base]


@dataclass
class FeatureBuffers:
    """Named float32 buffers ``(C, H, W)`` of one image, plus where they came from.

    Attributes:
        buffers: name -> tensor ``(C, H, W)``, float32 (see the module docstring for names).
        spp: samples per pixel of ``color`` when known.
        source: path of the file the buffers were read from, if any.
        profile: name of the renderer profile that mapped the file's channels.
        channels: for each buffer, the file channel names it was read from (same order).
        attributes: header attributes of the source file (string/number values only).
        data_window: ``(xmin, ymin, xmax, ymax)`` inclusive, of the pixels held.
        display_window: ``(xmin, ymin, xmax, ymax)`` inclusive, of the source file.
    """

    buffers: dict[str, torch.Tensor] = field(default_factory=dict)
    spp: int | None = None
    source: str | None = None
    profile: str | None = None
    channels: dict[str, list[str]] = field(default_factory=dict)
    attributes: dict[str, Any] = field(default_factory=dict)
    data_window: tuple[int, int, int, int] | None = None
    display_window: tuple[int, int, int, int] | None = None

    def __post_init__(self) -> None:
        items = dict(self.buffers)
        self.buffers = {}
        for name, value in items.items():
            self[name] = value

    # --- mapping-like access -------------------------------------------------------------
    def __setitem__(self, name: str, value: torch.Tensor | np.ndarray) -> None:
        want = expected_channels(name)
        t = torch.as_tensor(value)
        if t.ndim == 2:
            t = t.unsqueeze(0)
        if t.ndim != 3:
            raise InputError(f"buffer {name!r} must be (C, H, W), got shape {tuple(t.shape)}")
        ok = t.shape[0] == want or (name.endswith(VAR_SUFFIX) and t.shape[0] == 1)
        if not ok:
            raise InputError(
                f"buffer {name!r} must have {want} channel(s), got {t.shape[0]} "
                f"(shape {tuple(t.shape)})"
            )
        if self.buffers:
            h, w = self.shape
            if t.shape[1:] != (h, w):
                raise InputError(
                    f"buffer {name!r} is {t.shape[2]}x{t.shape[1]} but the image is {w}x{h}: "
                    "all buffers of an image must have the same resolution"
                )
        if t.dtype != torch.float32:
            t = t.to(torch.float32)
        self.buffers[name] = t

    def __getitem__(self, name: str) -> torch.Tensor:
        try:
            return self.buffers[name]
        except KeyError:
            raise self._missing([name]) from None

    def __contains__(self, name: object) -> bool:
        return name in self.buffers

    def __iter__(self) -> Iterator[str]:
        return iter(self.buffers)

    def __len__(self) -> int:
        return len(self.buffers)

    def get(self, name: str, default: torch.Tensor | None = None) -> torch.Tensor | None:
        return self.buffers.get(name, default)

    def names(self) -> list[str]:
        """Buffer names present, in canonical order."""
        return [n for n in BUFFER_NAMES if n in self.buffers]

    # --- convenience ---------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the image."""
        if not self.buffers:
            raise ValueError("FeatureBuffers is empty")
        first = next(iter(self.buffers.values()))
        return int(first.shape[1]), int(first.shape[2])

    @property
    def height(self) -> int:
        return self.shape[0]

    @property
    def width(self) -> int:
        return self.shape[1]

    @property
    def color(self) -> torch.Tensor:
        return self["color"]

    def require(self, names: Iterable[str], *, needed_by: str | None = None) -> None:
        """Raise :class:`MissingFeatureError` unless every buffer in ``names`` is present."""
        missing = [n for n in names if n not in self.buffers]
        if missing:
            raise self._missing(missing, needed_by=needed_by)

    def _missing(self, missing: list[str], needed_by: str | None = None) -> MissingFeatureError:
        raw = sorted({c for cs in self.channels.values() for c in cs}) or None
        if self.attributes.get("_file_channels"):
            raw = list(self.attributes["_file_channels"])
        return MissingFeatureError(
            missing, self.names(), source=self.source, channels=raw, needed_by=needed_by
        )

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> FeatureBuffers:
        """A copy with every buffer moved to ``device`` / cast to ``dtype`` (metadata shared)."""
        out = FeatureBuffers(
            spp=self.spp,
            source=self.source,
            profile=self.profile,
            channels=dict(self.channels),
            attributes=dict(self.attributes),
            data_window=self.data_window,
            display_window=self.display_window,
        )
        out.buffers = {k: v.to(device=device, dtype=dtype) for k, v in self.buffers.items()}
        return out

    def subset(self, names: Iterable[str]) -> FeatureBuffers:
        """A view holding only ``names`` (those present); metadata is kept."""
        keep = set(names)
        out = self.to()
        out.buffers = {k: v for k, v in self.buffers.items() if k in keep}
        return out

    def crop(self, y0: int, x0: int, h: int, w: int) -> FeatureBuffers:
        """The window ``[y0:y0+h, x0:x0+w]`` of every buffer (views, no copy).

        ``data_window`` moves with the crop (the display window is kept), so saving the
        crop writes it at its place in the image.
        """
        out = self.to()
        out.buffers = {k: v[:, y0 : y0 + h, x0 : x0 + w] for k, v in self.buffers.items()}
        if self.data_window is not None and out.buffers:
            ch, cw = out.shape
            dx, dy = self.data_window[0] + max(x0, 0), self.data_window[1] + max(y0, 0)
            out.data_window = (dx, dy, dx + cw - 1, dy + ch - 1)
        return out

    def tiled(self, height: int, width: int) -> FeatureBuffers:
        """Every buffer repeated to ``height`` × ``width`` (cropped at the far edges, contiguous
        copies): a large frame of the same content, for timing and memory benchmarks.
        Metadata is kept, the data and display windows are not (the image is a new size)."""
        ry, rx = -(-height // self.height), -(-width // self.width)
        out = self.to()
        out.buffers = {
            k: v.repeat(1, ry, rx)[:, :height, :width].contiguous() for k, v in self.buffers.items()
        }
        out.data_window = out.display_window = None
        return out

    def nonfinite_counts(self) -> dict[str, dict[str, int]]:
        """Per buffer: counts of NaN, +/-Inf and negative values (for reports and ``info``)."""
        out: dict[str, dict[str, int]] = {}
        for name in self.names():
            t = self.buffers[name]
            out[name] = {
                "nan": int(torch.isnan(t).sum()),
                "inf": int(torch.isinf(t).sum()),
                "negative": int((t < 0).sum()),
            }
        return out


def halves_problem(buffers: FeatureBuffers) -> str | None:
    """What is wrong with the half buffers of ``buffers`` (one line), or ``None``.

    A feature with only one of its halves (``color_a`` without ``color_b``), or a half
    variance without its half, is a problem; sizes are checked by :class:`FeatureBuffers`
    itself (every buffer of an image has the image's size).
    """
    for f in HALVABLE:
        a, b = f + HALF_SUFFIXES[0], f + HALF_SUFFIXES[1]
        if (a in buffers) != (b in buffers):
            have, lack = (a, b) if a in buffers else (b, a)
            return (
                f"{have} without {lack}: half buffers come in pairs (two independent halves "
                "of the samples); give both or neither"
            )
        for h in (a, b):
            if h + VAR_SUFFIX in buffers and h not in buffers:
                return f"{h}{VAR_SUFFIX} without {h}"
    return None


def check_halves(buffers: FeatureBuffers) -> None:
    """Raise :class:`~mcdenoise.errors.InputError` (one line, prefixed with the source) if
    :func:`halves_problem` finds something."""
    problem = halves_problem(buffers)
    if problem:
        where = f"{buffers.source}: " if buffers.source else ""
        raise InputError(where + problem)


def has_halves(buffers: FeatureBuffers, name: str = "color") -> bool:
    """``True`` when both halves of ``name`` are present (:func:`check_halves` first)."""
    return all(name + h in buffers for h in HALF_SUFFIXES)


def shared_guides(buffers: FeatureBuffers, reads: Sequence[str] | None = None) -> list[str]:
    """The noisy features of ``buffers`` that both halves would share: present, not halved
    (no ``albedo_a``/``albedo_b``) while the colour is, and not known to be noise-free (a
    ``<feature>_var`` of zeros everywhere). ``reads``: only these features (what a method
    reads); ``None``: every feature.

    A guide shared by both halves holds the samples of both, so a filter run on half A and
    guided by it follows half B's noise too, and the two-buffer error estimate of that filter
    comes out low (:mod:`mcdenoise.eval.estimate`). Empty when the colour is not halved.
    """
    if not has_halves(buffers):
        return []
    out = []
    for f in HALVABLE[1:]:
        if f not in buffers or has_halves(buffers, f) or (reads is not None and f not in reads):
            continue
        var = buffers.get(f + VAR_SUFFIX)
        if var is None or bool((var > 0).any()):
            out.append(f)
    return out


def half_inputs(buffers: FeatureBuffers) -> tuple[FeatureBuffers, FeatureBuffers]:
    """The two half-sample inputs of ``buffers``: in each, ``color`` is one half
    (``color_a`` or ``color_b``), ``color_var`` its variance (else twice the full one, the
    variance of a mean of half the samples), each halved feature its half (``albedo_a``...,
    likewise), the other buffers as they are, metadata kept and ``spp`` half the count; no half
    buffers remain in them (so a method that uses halves does not recurse on a half).

    Features that are not halved are shared by both halves. They hold the samples of both
    halves, so a filter guided by them sees the other half's noise (:func:`shared_guides`);
    the renderer halves every feature for this reason (:mod:`mcdenoise.render.passes`). Used by the reference-free estimate
    (:mod:`mcdenoise.eval.estimate`) and the per-region selection
    (:mod:`mcdenoise.methods.selection`), which say what a missing half means for them.

    Raises:
        InputError: halves of another size, one half only (:func:`check_halves`), or none.
    """
    check_halves(buffers)
    if not has_halves(buffers):
        where = f"{buffers.source}: " if buffers.source else ""
        raise InputError(f"{where}no half buffers (color_a, color_b)")
    base = {n: t for n, t in buffers.buffers.items() if n not in _ALL_HALVES}
    out = []
    for suffix in HALF_SUFFIXES:
        half = buffers.to()
        half.buffers = dict(base)
        for n in HALF_NAMES:
            if n.endswith(suffix) and n in buffers:
                feat = n[: -len(suffix)]
                half.buffers[feat] = buffers[n]
                var = buffers.get(n + VAR_SUFFIX)
                if var is not None:
                    half.buffers[feat + VAR_SUFFIX] = var
                elif feat + VAR_SUFFIX in half.buffers:  # no half variance: twice the full one
                    half.buffers[feat + VAR_SUFFIX] = 2 * half.buffers[feat + VAR_SUFFIX]
        half.spp = max(1, buffers.spp // 2) if buffers.spp else None
        out.append(half)
    return out[0], out[1]


_ALL_HALVES = frozenset(HALF_NAMES) | {n + VAR_SUFFIX for n in HALF_NAMES}


#: Finite values beyond this magnitude are treated like +/-Inf by :func:`sanitize`: no render
#: produces them (they come from damaged pixel data) and the filters' float32 arithmetic
#: overflows on them (squares, sums of squares) into NaN/Inf mid-method.
MAX_MAGNITUDE = 1e18


def out_of_range_counts(t: torch.Tensor) -> tuple[int, int, int]:
    """(NaN, +/-Inf, finite beyond +/-:data:`MAX_MAGNITUDE`) counts of ``t``."""
    nan = int(torch.isnan(t).sum())
    inf = int(torch.isinf(t).sum())
    huge = int((torch.isfinite(t) & (t.abs() > MAX_MAGNITUDE)).sum())
    return nan, inf, huge


def sanitize(
    buffers: FeatureBuffers, *, clamp_negative: Mapping[str, bool] | None = None
) -> tuple[FeatureBuffers, dict[str, int]]:
    """Replace NaN/Inf so filters never see them; return the repaired copy and repair counts.

    Policy (documented in the README): NaN -> 0; +Inf -> the largest finite value of that
    buffer (0 if none); -Inf -> 0 for ``color``-like and variance buffers, the smallest finite
    value otherwise. Finite values beyond +/-:data:`MAX_MAGNITUDE` (damaged pixel data) count
    as +/-Inf, and "finite" above means within that range. Colour, albedo, diffuse/specular
    and every variance are clamped at 0 (a negative variance or radiance is not physical);
    normals, positions and motion keep their sign. ``clamp_negative`` overrides the clamp per buffer name.
    """
    nonneg = {"color", "albedo", "diffuse", "specular", "visibility", "depth"}
    out = buffers.to()
    repaired: dict[str, int] = {}
    for name in buffers.names():
        t = buffers.buffers[name]
        base = base_feature(name)
        clamp = name.endswith(VAR_SUFFIX) or base in nonneg
        if clamp_negative is not None and name in clamp_negative:
            clamp = clamp_negative[name]
        bad = ~torch.isfinite(t) | (t.abs() > MAX_MAGNITUDE)
        n_bad = int(bad.sum())
        n_neg = int((t < 0).sum()) if clamp else 0
        if n_bad == 0 and n_neg == 0:
            continue
        fixed = t.clone()
        if n_bad:
            finite = t[~bad]
            hi = float(finite.max()) if finite.numel() else 0.0
            lo = float(finite.min()) if finite.numel() else 0.0
            fixed = torch.where(torch.isnan(fixed), torch.zeros_like(fixed), fixed)
            fixed = torch.where(fixed > MAX_MAGNITUDE, torch.full_like(fixed, hi), fixed)
            fixed = torch.where(
                fixed < -MAX_MAGNITUDE, torch.full_like(fixed, 0.0 if clamp else lo), fixed
            )
        if clamp:
            fixed = fixed.clamp_min(0.0)
        out.buffers[name] = fixed
        repaired[name] = n_bad + n_neg
    return out, repaired
