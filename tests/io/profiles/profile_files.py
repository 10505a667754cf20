"""Synthetic EXR files with each renderer's exact channel names, for the profile tests.

Imported by the tests of this folder (``from profile_files import ...``; pytest puts the folder
on ``sys.path``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mcdenoise.io.exr_write import write_exr

H, W = 6, 9
# linear sRGB <- CIE XYZ (D65), as Mitsuba's film converts moment colours
SRGB_FROM_XYZ = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)


def planes(rng: np.random.Generator, names, lo=0.0, hi=1.0) -> dict[str, np.ndarray]:
    return {n: rng.uniform(lo, hi, (H, W)).astype(np.float32) for n in names}


def write(path: Path, channels: dict[str, np.ndarray], attributes=None) -> Path:
    # Shuffle the insertion order: nothing may depend on it.
    names = list(channels)[::-1]
    write_exr(path, {n: channels[n] for n in names}, attributes=attributes or {})
    return path


def stack(ch: dict[str, np.ndarray], names) -> np.ndarray:
    return np.stack([ch[n] for n in names])


def mitsuba_channels(rng, spp_var_y):
    """Channels as Mitsuba's aov integrator nesting a moment integrator writes them."""
    xyz = rng.uniform(0.1, 2.0, (3, H, W))
    rgb = np.einsum("ij,jhw->ihw", SRGB_FROM_XYZ, xyz)
    ch = {c: rgb[i].astype(np.float32) for i, c in enumerate("RGB")}
    ch["A"] = np.ones((H, W), np.float32)
    for i, s in enumerate("XYZ"):
        ch[f"img.path.{s}"] = xyz[i].astype(np.float32)
        ch[f"img.m2_path.{s}"] = (xyz[i] ** 2 + spp_var_y[i]).astype(np.float32)
    ch.update({f"img.{c}": ch[c] for c in "RGB"})
    ch["img.A"] = ch["A"]
    ch.update(planes(rng, ["albedo.R", "albedo.G", "albedo.B"]))
    ch.update(planes(rng, ["nn.X", "nn.Y", "nn.Z"], -1, 1))
    ch.update(planes(rng, ["dd.T"], 1, 5))
    ch.update(planes(rng, ["pp.X", "pp.Y", "pp.Z"], -3, 3))
    # A decoy moment pair whose first moment is not the colour.
    ch.update(planes(rng, ["decoy.X", "decoy.Y", "decoy.Z"]))
    ch.update(planes(rng, ["m2_decoy.X", "m2_decoy.Y", "m2_decoy.Z"], 2, 3))
    return ch


def blender_file(path: Path, layers: dict, attributes: dict | None = None) -> Path:
    """A multilayer EXR laid out as Blender 5 writes it: one part ``<Layer>.<Pass>`` per pass,
    channels ``<Layer>.<Pass>.<ch>``, the file-wide attributes (``BlenderMultiChannel``,
    ``cycles.<Layer>.samples``...) in part 0 only.

    ``layers``: layer -> pass -> channel suffix -> ``(H, W)`` array, in file order.
    """
    from mcdenoise.io.exr_write import ExrPartData, write_exr_parts

    parts = []
    for layer, passes in layers.items():
        for pass_name, chans in passes.items():
            parts.append(
                ExrPartData(
                    name=f"{layer}.{pass_name}",
                    channels={f"{layer}.{pass_name}.{c}": a for c, a in chans.items()},
                    attributes=None if parts else dict(attributes or {}),
                )
            )
    write_exr_parts(path, parts)
    return path


def blender_layer(rng: np.random.Generator, *, denoising: bool, position: bool = True) -> dict:
    """Passes of one view layer, with values in the ranges Cycles writes (see cycles.py)."""

    def p(suffixes, lo=0.0, hi=1.0):
        return {c: rng.uniform(lo, hi, (H, W)).astype(np.float32) for c in suffixes}

    depth = rng.uniform(1, 9, (H, W)).astype(np.float32)
    depth[0, :3] = 1e10  # Blender's "no hit"
    passes = {
        "Combined": p("RGBA"),
        "Depth": {"Z": depth},
        "Normal": p("XYZ", -1, 1),
        "Vector": p("XYZW", -3, 3),
    }
    if position:
        passes["Position"] = p("XYZ", -5, 5)
    if denoising:
        passes["Denoising Normal"] = p("XYZ", -1, 1)
        passes["Denoising Albedo"] = p("RGB")
        passes["Denoising Depth"] = p("Z", 1, 9)
    return passes


BLENDER_ATTRS = {
    "BlenderMultiChannel": "Blender V2.55.1 and newer",
    "Software": "Blender 5.0.1",
    "cycles.ViewLayer.samples": "16",
    "cycles.Layer2.samples": "16",
}
