"""Make the procedural assets of :mod:`mcdenoise.render.random_scenes` (meshes, textures, an
environment map). Every file in this folder except this script is its output.

Usage (the shipped files were made with exactly this; the output is deterministic, and
``tests/render/test_random_scenes.py`` checks that it reproduces the shipped files)::

    python mcdenoise/render/assets/make_assets.py [--out FOLDER]

Meshes (``meshes/``, y up, closed and consistently oriented with outward normals, no normals
or UVs stored, so Mitsuba computes smooth vertex normals; "faceted" meshes repeat each vertex
per face so they shade flat). Each is centred on its bounding box and scaled so its largest
half-extent is 1; ``meshes/index.json`` records per file the half-extents ``[hx, hy, hz]``
and ``radius`` (largest distance of a vertex from the origin), which the scene generator uses
to rest meshes on the ground and to keep the camera outside them.

=============  ======  ==================================================================
file           format  shape
=============  ======  ==================================================================
torus.obj      OBJ     torus lying flat, tube radius 0.35 of the ring radius (smooth)
knot.ply       PLY     (2, 3) torus knot tube (smooth; self-occluding, good for AO)
blob.ply       PLY     icosphere with smooth random radial bumps (smooth)
vase.obj       OBJ     closed solid of revolution with a neck (smooth)
bowl.ply       PLY     open bowl with a wall thickness (smooth; concave: AO, caustics)
rock.obj       OBJ     low-poly random rock (faceted)
star.ply       PLY     five-pointed star prism standing upright (faceted)
=============  ======  ==================================================================

Textures (``textures/``, 8-bit sRGB PNG, 128×128, tileable): ``bricks.png``, ``wood.png``.
Environment (``envmaps/studio.exr``, 128×64 half-float lat-long, linear Rec.709): a dim
gradient with two soft boxes and one tiny very bright spot (fireflies).
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
from contextlib import AbstractContextManager
from pathlib import Path

import numpy as np

from mcdenoise.io.atomic import atomic_path

ROOT = Path(__file__).resolve().parent
SEED = 20240611


# --------------------------------------------------------------------------------- writers


def _atomic(path: Path) -> AbstractContextManager[Path]:
    """The library's atomic writer (a temporary next to ``path``, then ``os.replace``)."""

    return atomic_path(path)


def write_obj(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    """Write a triangle mesh as Wavefront OBJ (positions and faces only)."""
    lines = [f"# {path.name}: made by make_assets.py"]
    lines += [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    with _atomic(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="ascii")


def write_ply(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    """Write a triangle mesh as binary little-endian PLY (float positions, int indices)."""
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment made by make_assets.py\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = v.astype("<f4").tobytes()
    faces = b"".join(struct.pack("<B3i", 3, *map(int, tri)) for tri in f)
    with _atomic(path) as tmp:
        tmp.write_bytes(header.encode("ascii") + body + faces)


# --------------------------------------------------------------------------------- geometry


def signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """Signed volume of a closed triangle mesh (positive: outward-facing triangles)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def orient_outward(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Flip every triangle when the mesh's signed volume is negative."""
    return f[:, ::-1].copy() if signed_volume(v, f) < 0 else f


def normalise(v: np.ndarray) -> np.ndarray:
    """Centre on the bounding box and scale the largest half-extent to 1."""
    lo, hi = v.min(0), v.max(0)
    return (v - (lo + hi) / 2) / ((hi - lo).max() / 2)


def grid_faces(rows: int, cols: int, wrap_cols: bool = True) -> np.ndarray:
    """Triangles of a ``rows × cols`` vertex grid (columns wrap around, rows do not)."""
    faces = []
    for i in range(rows - 1):
        for j in range(cols if wrap_cols else cols - 1):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = a + cols, b + cols
            faces += [(a, c, b), (b, c, d)]
    return np.array(faces, dtype=np.int64)


def torus_grid(rows: int, cols: int) -> np.ndarray:
    """Triangles of a grid that wraps in both directions."""
    faces = []
    for i in range(rows):
        for j in range(cols):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = ((i + 1) % rows) * cols + j, ((i + 1) % rows) * cols + (j + 1) % cols
            faces += [(a, c, b), (b, c, d)]
    return np.array(faces, dtype=np.int64)


def torus(n_major: int = 40, n_minor: int = 16, ratio: float = 0.35) -> tuple:
    u = np.linspace(0, 2 * np.pi, n_major, endpoint=False)[:, None]
    w = np.linspace(0, 2 * np.pi, n_minor, endpoint=False)[None, :]
    ring = 1 + ratio * np.cos(w)
    v = np.stack([ring * np.cos(u), ratio * np.sin(w) + 0 * u, ring * np.sin(u)], -1).reshape(-1, 3)
    return v, torus_grid(n_major, n_minor)


def torus_knot(p: int = 2, q: int = 3, n: int = 160, m: int = 10, tube: float = 0.3) -> tuple:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)

    def curve(t: np.ndarray) -> np.ndarray:
        r = 2 + np.cos(q * t)
        return np.stack([r * np.cos(p * t), np.sin(q * t), r * np.sin(p * t)], -1)

    h = 1e-4
    c = curve(t)
    d1 = (curve(t + h) - curve(t - h)) / (2 * h)
    d2 = (curve(t + h) - 2 * c + curve(t - h)) / (h * h)
    tan = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    bi = np.cross(d1, d2)
    bi /= np.linalg.norm(bi, axis=1, keepdims=True)
    nor = np.cross(bi, tan)
    a = np.linspace(0, 2 * np.pi, m, endpoint=False)
    v = (
        c[:, None, :]
        + tube * (np.cos(a)[None, :, None] * nor[:, None, :])
        + tube * (np.sin(a)[None, :, None] * bi[:, None, :])
    ).reshape(-1, 3)
    return v, torus_grid(n, m)


def icosphere(level: int) -> tuple:
    g = (1 + 5**0.5) / 2
    v = [
        (-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g),
        (0, -1, -g), (0, 1, -g), (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1),
    ]  # fmt: skip
    f = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
        (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
        (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = list(f)
    for _ in range(level):
        cache: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int, cache: dict[tuple[int, int], int] = cache) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts), np.array(faces, dtype=np.int64)


def blob(rng: np.random.Generator) -> tuple:
    v, f = icosphere(3)
    bump = np.zeros(len(v))
    for _ in range(6):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        bump += np.cos(rng.uniform(2, 4) * (v @ axis) + rng.uniform(0, 2 * np.pi))
    return v * (1 + 0.08 * bump)[:, None], f


def lathe(profile: list[tuple[float, float]], n: int = 32) -> tuple:
    """Revolve ``(radius, height)`` points about y; first and last points lie on the axis."""
    inner = profile[1:-1]
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.array([[r * np.cos(t), y, r * np.sin(t)] for r, y in inner for t in a]).reshape(-1, 3)
    bottom = len(ring)
    v = np.vstack([ring, [[0, profile[0][1], 0]], [[0, profile[-1][1], 0]]])
    f = list(grid_faces(len(inner), n))
    for j in range(n):
        f.append((bottom, j, (j + 1) % n))
        last = (len(inner) - 1) * n
        f.append((bottom + 1, last + (j + 1) % n, last + j))
    return v, np.array(f, dtype=np.int64)


def vase() -> tuple:
    hs = np.linspace(0, 1, 26)
    radius = 0.33 + 0.22 * np.sin(np.pi * (hs * 1.25 + 0.05)) ** 2 * (1 - hs) + 0.08 * hs**3
    prof = [(0.0, 0.0)] + [(float(r), float(h) * 1.7) for r, h in zip(radius, hs)]
    prof.append((0.0, 1.7))
    return lathe(prof, 32)


def bowl() -> tuple:
    outer = [(0.45 * s, -0.8) for s in np.linspace(0.1, 1, 4)]
    outer += [
        (0.45 + 0.55 * math.sin(t), -0.8 + 0.8 * (1 - math.cos(t)))
        for t in np.linspace(0.15, math.pi / 2, 12)
    ]
    inner = [
        (0.9 * math.sin(t), -0.7 + 0.7 * (1 - math.cos(t)))
        for t in np.linspace(math.pi / 2, 0.12, 12)
    ]
    # the inner surface ends at y = 0 too; the rim is the step between radius 1 and 0.9
    prof = [(0.0, -0.8), *outer, *inner, (0.0, -0.7)]
    return lathe(prof, 40)


def facet(v: np.ndarray, f: np.ndarray) -> tuple:
    """Repeat every vertex per face, so computed vertex normals are face normals."""
    return v[f.reshape(-1)], np.arange(f.size, dtype=np.int64).reshape(-1, 3)


def rock(rng: np.random.Generator) -> tuple:
    v, f = icosphere(1)
    v = v * rng.uniform(0.8, 1.1, size=(len(v), 1)) * np.array([1.2, 0.8, 1.0])
    v[:, 1] = np.maximum(v[:, 1], -0.55)  # a flat-ish base to rest on
    return facet(v, f)


def star(points: int = 5, outer: float = 1.0, inner: float = 0.45, depth: float = 0.35) -> tuple:
    ang = np.pi / 2 + np.arange(2 * points) * np.pi / points
    rad = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    xy = np.stack([rad * np.cos(ang), rad * np.sin(ang)], -1)
    k = len(xy)
    front = np.hstack([xy, np.full((k, 1), depth / 2)])
    back = np.hstack([xy, np.full((k, 1), -depth / 2)])
    v = np.vstack([front, back, [[0, 0, depth / 2]], [[0, 0, -depth / 2]]])
    cf, cb = 2 * k, 2 * k + 1
    f = []
    for i in range(k):
        j = (i + 1) % k
        f += [(cf, i, j), (cb, k + j, k + i), (i, k + i, j), (j, k + i, k + j)]
    return facet(v, np.array(f, dtype=np.int64))


# --------------------------------------------------------------------------------- images


def _to_srgb8(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0, 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return (s * 255 + 0.5).astype(np.uint8)


def _value_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Tileable smooth value noise in [0, 1] of shape (size, size)."""
    grid = rng.uniform(0, 1, (cells, cells))
    t = np.arange(size) * cells / size
    i0 = np.floor(t).astype(int)
    fr = t - i0
    fr = fr * fr * (3 - 2 * fr)
    i1 = (i0 + 1) % cells
    rows0 = grid[i0][:, i0] * (1 - fr)[None, :] + grid[i0][:, i1] * fr[None, :]
    rows1 = grid[i1][:, i0] * (1 - fr)[None, :] + grid[i1][:, i1] * fr[None, :]
    return rows0 * (1 - fr)[:, None] + rows1 * fr[:, None]


def bricks(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    rows, cols = 8, 4
    y, x = np.mgrid[0:size, 0:size] / size
    row = np.floor(y * rows).astype(int)
    xs = x * cols + 0.5 * (row % 2)
    col = np.floor(xs).astype(int) % cols
    fx, fy = xs % 1, (y * rows) % 1
    mortar = (fx < 0.04) | (fx > 0.96) | (fy < 0.08) | (fy > 0.92)
    tint = rng.uniform(0.75, 1.15, (rows, cols))[row, col]
    base = np.array([0.42, 0.16, 0.09])
    grain = 0.85 + 0.3 * _value_noise(rng, size, 32)
    img = base[None, None, :] * (tint * grain)[..., None]
    img[mortar] = np.array([0.45, 0.43, 0.40])
    return img


def wood(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    x = np.mgrid[0:size, 0:size][1] / size
    warp = _value_noise(rng, size, 4) * 2.0 + _value_noise(rng, size, 16) * 0.3
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (6 * x + warp))
    light, dark = np.array([0.55, 0.33, 0.16]), np.array([0.25, 0.12, 0.05])
    return light * (1 - rings[..., None] ** 3) + dark * rings[..., None] ** 3


def studio_envmap(width: int = 128, height: int = 64) -> np.ndarray:
    v, u = (np.mgrid[0:height, 0:width] + 0.5) / np.array([height, width])[:, None, None]
    theta = v * np.pi  # 0 at the zenith (Mitsuba's lat-long: +y up, top row)
    up = np.clip(np.cos(theta), 0, 1)[..., None]
    img = (
        0.08 + 0.5 * up * np.array([0.55, 0.62, 0.75]) + 0.12 * (1 - up) * np.array([0.6, 0.5, 0.4])
    )
    for cu, cv, hu, hv, lum, col in (
        (0.20, 0.30, 0.06, 0.07, 12.0, (1.0, 0.95, 0.9)),
        (0.62, 0.22, 0.09, 0.05, 8.0, (0.9, 0.95, 1.0)),
    ):
        box = np.exp(-(((u - cu) / hu) ** 8) - (((v - cv) / hv) ** 8))
        img = img + lum * box[..., None] * np.array(col)
    img[14:16, 100:102] += 400.0  # a tiny, very bright spot: fireflies
    return img.astype(np.float32)


def write_png(path: Path, img: np.ndarray) -> None:
    import OpenImageIO as oiio  # lazy: OpenImageIO only where an image is written

    with _atomic(path) as tmp:
        buf = oiio.ImageBuf(_to_srgb8(img))
        if not buf.write(str(tmp)):
            raise OSError(f"{path}: {buf.geterror()}")


def write_exr(path: Path, img: np.ndarray) -> None:
    import OpenImageIO as oiio  # lazy: OpenImageIO only where an image is written

    spec = oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.HALF)
    spec.attribute("compression", "zip")
    with _atomic(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise OSError(f"{path}: {oiio.geterror()}")
        out.write_image(img)
        out.close()


# --------------------------------------------------------------------------------- main


def make_assets(out: Path = ROOT) -> list[Path]:
    """Write every asset under ``out`` (``meshes/``, ``textures/``, ``envmaps/``); return the
    files written. Deterministic: the same bytes on every run."""
    rng = np.random.default_rng(SEED)
    meshes = {
        "torus.obj": torus(),
        "knot.ply": torus_knot(),
        "blob.ply": blob(rng),
        "vase.obj": vase(),
        "bowl.ply": bowl(),
        "rock.obj": rock(rng),
        "star.ply": star(),
    }
    for sub in ("meshes", "textures", "envmaps"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    written = []
    index = {}
    for name, (v, f) in meshes.items():
        v = normalise(np.asarray(v, float))
        f = orient_outward(v, np.asarray(f))
        (write_obj if name.endswith(".obj") else write_ply)(out / "meshes" / name, v, f)
        written.append(out / "meshes" / name)
        index[name] = {
            "half_extents": [round(float(x), 5) for x in np.abs(v).max(0)],
            "radius": round(float(np.linalg.norm(v, axis=1).max()), 5),
            "vertices": len(v),
            "triangles": len(f),
        }
    with _atomic(out / "meshes" / "index.json") as tmp:
        tmp.write_text(json.dumps(index, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    write_png(out / "textures" / "bricks.png", bricks(rng))
    write_png(out / "textures" / "wood.png", wood(rng))
    write_exr(out / "envmaps" / "studio.exr", studio_envmap())
    written += [
        out / "meshes" / "index.json",
        out / "textures" / "bricks.png",
        out / "textures" / "wood.png",
        out / "envmaps" / "studio.exr",
    ]
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT, help="output folder (default: here)")
    args = parser.parse_args(argv)
    for path in make_assets(args.out):
        print(f"{path}  {path.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
