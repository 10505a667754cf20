"""Make the small assets the curated scene specs in this folder use. Deterministic.

Usage (the shipped files were made with exactly this)::

    python data/scenes/make_assets.py

Writes, next to this script:

* ``meshes/twist.obj``: a square column (cross-section 1 × 1, height 2, centred on the
  origin, y up) twisted by 90° from bottom to top, closed by two square caps; 24 segments
  along the height. Each side has its own vertices, so Mitsuba's smooth vertex normals
  round the twisted sides but keep the edges sharp. UVs: each side maps to u in
  [k/4, (k+1)/4], v = height in [0, 1]; caps use their own square [0, 1]².
* ``textures/tiles.png``: 64 × 64, 8-bit sRGB, tileable: 4 × 4 tiles of seeded random
  warm colours separated by dark grout lines.
* ``envmaps/studio.exr``: 64 × 33 lat-long (Mitsuba's ``envmap`` layout: row ``i`` at polar
  angle ``π i / 32`` from +Y), half float, linear Rec.709 radiance: a dim grey-blue
  gradient with a large warm soft box on the upper left (+X side, seen from +Z) and a
  smaller cool one behind on the right (radiance 6 and 3).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SEED = 31


def twist_mesh(segments: int = 24, twist_deg: float = 90.0) -> tuple[list, list, list]:
    """Vertices ``(x, y, z)``, uvs ``(u, v)`` and triangles (0-based, shared v/vt index)."""
    verts: list[tuple[float, float, float]] = []
    uvs: list[tuple[float, float]] = []
    tris: list[tuple[int, int, int]] = []
    corners = [(0.5, 0.5), (-0.5, 0.5), (-0.5, -0.5), (0.5, -0.5)]  # (x, z), counter-clockwise
    # seen from +y, so the outward side normals come out of (a - b) x up ordering below

    def ring_point(k: int, i: int) -> tuple[float, float, float]:
        y = -1.0 + 2.0 * i / segments
        a = np.radians(twist_deg) * i / segments
        x, z = corners[k % 4]
        c, s = np.cos(a), np.sin(a)
        return (float(c * x - s * z), float(y), float(s * x + c * z))

    for side in range(4):
        base = len(verts)
        for i in range(segments + 1):
            for j in (0, 1):
                verts.append(ring_point(side + j, i))
                uvs.append(((side + j) / 4.0, i / segments))
        for i in range(segments):
            a, b = base + 2 * i, base + 2 * i + 1  # this ring: corner k, corner k+1
            c, d = a + 2, b + 2  # next ring up
            # outward winding (counter-clockwise seen from outside)
            tris.append((a, c, b))
            tris.append((b, c, d))
    for i, sign in ((0, -1), (segments, 1)):
        base = len(verts)
        for k in range(4):
            verts.append(ring_point(k, i))
            x, _, z = verts[-1]
            uvs.append((0.5 + x, 0.5 + z))
        if sign > 0:  # top cap faces +y
            tris += [(base, base + 2, base + 1), (base, base + 3, base + 2)]
        else:
            tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return verts, uvs, tris


def _check_outward(verts: list, tris: list) -> None:
    """Every triangle's normal points away from the column's axis (or along y for caps)."""
    v = np.asarray(verts)
    for t in tris:
        p = v[list(t)]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        centre = p.mean(axis=0)
        radial = centre * np.array([1.0, 0.0, 1.0])
        if abs(n[1]) > 0.9 * np.linalg.norm(n):  # cap
            ok = np.sign(n[1]) == np.sign(centre[1])
        else:
            ok = float(n @ radial) > 0
        if not ok:
            raise AssertionError(f"inward-facing triangle {t}")


def write_twist(path: Path) -> None:
    from mcdenoise.io.atomic import write_text_atomic

    verts, uvs, tris = twist_mesh()
    _check_outward(verts, tris)
    lines = [f"# {path.name}: twisted square column, made by data/scenes/make_assets.py"]
    lines += [f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in verts]
    lines += [f"vt {u:.4f} {v:.4f}" for u, v in uvs]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in tris]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, "\n".join(lines) + "\n")


def tiles_image(size: int = 64, tiles: int = 4) -> np.ndarray:
    """``(size, size, 3)`` uint8 sRGB tiles with dark grout."""
    rng = np.random.default_rng(SEED)
    colours = rng.uniform([0.45, 0.25, 0.15], [0.85, 0.6, 0.4], size=(tiles, tiles, 3))
    cell = size // tiles
    y, x = np.mgrid[0:size, 0:size]
    img = colours[y // cell, x // cell]
    grout = ((x % cell) < 2) | ((y % cell) < 2)
    img[grout] = (0.12, 0.11, 0.10)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def write_png(path: Path, pixels: np.ndarray) -> None:
    import OpenImageIO as oiio

    from mcdenoise.io.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    h, w, c = pixels.shape
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        out.open(str(tmp), oiio.ImageSpec(w, h, c, "uint8"))
        out.write_image(pixels)
        out.close()


def studio_image(width: int = 64, height: int = 33) -> np.ndarray:
    """``(height, width, 3)`` float32 linear radiance in Mitsuba's lat-long layout."""
    theta = np.pi * np.arange(height) / (height - 1)
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    st = np.sin(theta)[:, None]
    d = np.stack(
        np.broadcast_arrays(
            st * np.sin(phi)[None], np.cos(theta)[:, None], -st * np.cos(phi)[None]
        ),
        axis=-1,
    )
    up = d[..., 1:2]
    img = 0.08 + 0.1 * np.clip(up, 0, 1) * np.array([0.8, 0.9, 1.0])
    for direction, half_angle, radiance in (
        ((0.7, 0.6, 0.4), 0.35, (6.0, 5.2, 4.2)),
        ((-0.6, 0.4, -0.7), 0.25, (2.4, 2.8, 3.2)),
    ):
        dn = np.asarray(direction) / np.linalg.norm(direction)
        angle = np.arccos(np.clip(d @ dn, -1, 1))[..., None]
        img = img + np.where(angle < half_angle, np.asarray(radiance), 0.0)
    return img.astype(np.float32)


def write_studio(path: Path) -> None:
    from mcdenoise.io.exr_write import write_exr

    img = studio_image()
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, {c: img[..., i] for i, c in enumerate("RGB")}, pixel_type="half")


def main() -> int:
    write_twist(HERE / "meshes" / "twist.obj")
    write_png(HERE / "textures" / "tiles.png", tiles_image())
    write_studio(HERE / "envmaps" / "studio.exr")
    for p in ("meshes/twist.obj", "textures/tiles.png", "envmaps/studio.exr"):
        print(f"{p}: {(HERE / p).stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
