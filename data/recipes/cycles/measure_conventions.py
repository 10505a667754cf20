"""Measure what Blender's passes hold on a render_cycles.py file, against the scene itself
(``scene.json``): the numbers behind the ``cycles`` profile (docs/results/io-notes.md). Run
with the project's venv::

    .venv/bin/python data/recipes/cycles/measure_conventions.py DIR/cycles_spp4.exr DIR/scene.json

Reads the channels as stored (no profile), layer ``ViewLayer``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_erosion

from mcdenoise.io.exr import probe_exr, read_exr

L = "ViewLayer"


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.split("\n\n")[1].strip(), file=sys.stderr)
        return 2
    path, facts = Path(argv[0]), json.loads(Path(argv[1]).read_text())
    px: dict[str, np.ndarray] = {}
    for p in probe_exr(path):
        px.update(read_exr(path, part=p.index).pixels)

    def stack(name: str, suffixes: str) -> np.ndarray:
        return np.stack([px[f"{L}.{name}.{c}"] for c in suffixes]).astype(np.float64)

    m = np.array(facts["camera_matrix_world"])
    rot, cam = m[:3, :3], m[:3, 3]
    w, h = facts["resolution"]
    f = facts["camera_focal_px"]

    def project(points: np.ndarray) -> np.ndarray:
        c = np.einsum("ji,j...->i...", rot, points - cam.reshape(3, *([1] * (points.ndim - 1))))
        return np.stack([w / 2 + f * c[0] / -c[2], h / 2 - f * c[1] / -c[2]])

    pos, z, dd = stack("Position", "XYZ"), px[f"{L}.Depth.Z"], px[f"{L}.Denoising Depth.Z"]
    hit = z < 1e9
    floor = hit & (np.abs(pos[2]) < 1e-4)
    floor[: 2 * h // 3] = False
    print(f"{path}: {hit.size - hit.sum()} background pixels (Depth.Z >= 1e9), {floor.sum()} floor")
    print("  Depth.Z on the background:", np.unique(z[~hit])[:3])
    print(
        "  Denoising Depth / Position / Normal on the background: max |.| =",
        f"{np.abs(dd[~hit]).max():.3g} / {np.abs(pos[:, ~hit]).max():.3g} /",
        f"{np.abs(stack('Normal', 'XYZ')[:, ~hit]).max():.3g}",
        "(edge pixels: other samples hit)",
    )
    n, dn = stack("Normal", "XYZ"), stack("Denoising Normal", "XYZ")
    cam_axes = (rot.T @ np.array([0.0, 0.0, 1.0])) * np.array([1.0, 1.0, -1.0])
    print("  floor Normal mean", np.round(n[:, floor].mean(1), 4), "(world +Z: (0, 0, 1))")
    print(
        "  floor Denoising Normal mean",
        np.round(dn[:, floor].mean(1), 4),
        "; world +Z in Cycles camera space (x right, y up, z forward):",
        np.round(cam_axes, 4),
    )
    ray = np.linalg.norm(pos - cam[:, None, None], axis=0)
    planar = np.einsum("i,ihw->hw", -rot[:, 2], pos - cam[:, None, None])
    print(f"  Depth.Z - planar z of Position: max |.| = {np.abs(z - planar)[hit].max():.2g}")
    print(
        f"  Denoising Depth vs |Position - camera|: median rel. diff. "
        f"{np.median(np.abs(dd - ray)[floor] / ray[floor]):.4f}; vs planar z: "
        f"{np.median(np.abs(dd - planar)[floor] / planar[floor]):.4f} (floor pixels)"
    )
    alb = stack("Denoising Albedo", "RGB")
    above = (alb > 1).any(0)
    print(f"  Denoising Albedo: {above.sum()} pixel(s) above 1, max {alb.max():.4g}")
    loc = np.array(facts["mover_location"])
    dist = np.abs(np.linalg.norm(pos - loc[1][:, None, None], axis=0) - facts["mover_radius"])
    inner = binary_erosion(dist < 0.01, iterations=2)  # no floor sample in the pixel
    vec = stack("Vector", "XYZW")
    cur = project(pos)
    prev = project(pos - (loc[1] - loc[0])[:, None, None]) - cur
    nxt = project(pos + (loc[2] - loc[1])[:, None, None]) - cur
    print(f"  Vector on {inner.sum()} pixels inside the moving sphere (pixel units, y down):")
    for label, got, want in (
        ("X - (prev - cur).x", vec[0], prev[0]),
        ("Y + (prev - cur).y", vec[1], -prev[1]),
        ("Z + (next - cur).x", vec[2], -nxt[0]),
        ("W - (next - cur).y", vec[3], nxt[1]),
    ):
        print(
            f"    max |{label}| = {np.abs(got - want)[inner].max():.3f}  "
            f"(|{label.split()[0]}| up to {np.abs(got[inner]).max():.2f})"
        )
    static = binary_erosion(hit & (dist > 0.05), iterations=2)
    print(
        f"  Vector elsewhere (static, {static.sum()} px): max |.| = {np.abs(vec[:, static]).max()}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
