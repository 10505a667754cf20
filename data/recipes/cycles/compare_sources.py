"""Which Cycles passes make the better buffers: relMSE of each method, as a fraction of the noisy
input's, on a render_cycles.py folder, with the buffers read as the ``cycles`` profile reads
them and with one choice changed at a time (albedo clamped to [0, 1]; the camera-space
``Denoising Normal``; that normal rotated to world space with the camera of ``scene.json``;
the planar ``Depth`` pass). Run with the project's venv::

    OMP_NUM_THREADS=1 .venv/bin/python data/recipes/cycles/compare_sources.py DIR [--spp 4,16,64]

DIR holds ``cycles_spp<N>.exr``, ``cycles_ref.exr`` and ``scene.json`` (render_cycles.py).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np
import torch

from mcdenoise.denoise import denoise
from mcdenoise.io import FeatureBuffers, load_buffers
from mcdenoise.io.exr import probe_exr, read_exr
from mcdenoise.losses import relmse

METHODS = ("oidn", "kpcn", "cross-bilateral", "nlm")
LAYER = "ViewLayer"


def _raw(path: Path, names: set[str]) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for p in probe_exr(path):
        if names & set(p.channel_names):
            out.update(
                read_exr(path, part=p.index, channels=sorted(names & set(p.channel_names))).pixels
            )
    return out


def variants(path: Path, camera_rotation: np.ndarray) -> dict[str, FeatureBuffers]:
    """The profile's buffers, and copies with one source or conversion changed."""
    base = load_buffers(path)
    dn_names = [f"{LAYER}.Denoising Normal.{c}" for c in "XYZ"]
    raw = _raw(path, {*dn_names, f"{LAYER}.Depth.Z"})
    dn = np.stack([raw[n] for n in dn_names])
    z = raw[f"{LAYER}.Depth.Z"][None]
    # Cycles' camera space: x right, y up, z into the picture (Blender's camera looks along -z).
    world = np.einsum(
        "ij,jhw->ihw", camera_rotation, dn * np.array([1.0, 1.0, -1.0])[:, None, None]
    )
    out = {"as read (Normal, Denoising Depth, albedo kept)": base}
    changes = {
        "albedo clamped to [0, 1]": ("albedo", base["albedo"].clamp(0, 1)),
        "Denoising Normal (camera space)": ("normal", torch.from_numpy(dn)),
        "Denoising Normal rotated to world": ("normal", torch.from_numpy(world.astype(np.float32))),
        "Depth pass, planar (1e10 -> 0)": ("depth", torch.from_numpy(np.where(z >= 1e10, 0, z))),
    }
    for name, (buf, value) in changes.items():
        v = base.to()
        v[buf] = value
        out[name] = v
    return out


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path)
    p.add_argument("--spp", default="4,16,64")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    logging.disable(logging.WARNING)  # the profile's warnings are the point of other checks
    facts = json.loads((args.folder / "scene.json").read_text())
    rot = np.array(facts["camera_matrix_world"])[:3, :3]
    ref = load_buffers(args.folder / "cycles_ref.exr")["color"]
    print("spp | buffers | " + " | ".join(METHODS))
    for spp in (int(s) for s in args.spp.split(",")):
        path = args.folder / f"cycles_spp{spp}.exr"
        if not path.is_file():
            print(f"compare_sources: no {path}", file=sys.stderr)
            return 1
        for name, fb in variants(path, rot).items():
            noisy = float(relmse(fb["color"], ref))
            row = [float(relmse(denoise(fb, m, device="cpu").image, ref)) / noisy for m in METHODS]
            print(f"{spp} | {name} | " + " | ".join(f"{x:.3f}" for x in row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
