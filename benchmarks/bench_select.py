"""The per-region selection of ``kalantari-xbf`` (``-p select=on``) against the fixed
cross-bilateral filter, on renders with halves, with every guide halved and with the guides
shared by both halves (issue 36).

For every image of each data set (``mcdenoise render`` layout with halves) at each spp
level: the relMSE against the reference of ``cross-bilateral`` (the package defaults),
``xbf-best`` (the best fixed parameters of the grid search on the training set,
``benchmarks/results/kalantari_grid_xbf*.json``, as ``bench_kalantari.py``), ``kalantari-xbf``
alone (``select=off``) and with the selection (``select=on``); then ``select=on`` again with
the feature halves dropped (``shared``: the guides of the full buffer in both halves, as
renders before issue 36 had them). Prints per set and level the geometric means over images
of ``select=on`` over ``cross-bilateral`` and over ``xbf-best`` (the issue's target: 0.7).

    python benchmarks/bench_select.py DATA [DATA ...] [--spp 4,16] [--threads 2] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_kalantari import best_fixed

from mcdenoise.denoise import denoise
from mcdenoise.eval.metrics import relmse
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.train.patches import scan_dataset

REPO = Path(__file__).resolve().parents[1]


def drop_feature_halves(b):
    """``b`` without the halves of its features (the colour's kept)."""
    out = b.to()
    out.buffers = {
        n: t
        for n, t in b.buffers.items()
        if n.startswith("color") or not n.endswith(("_a", "_b", "_a_var", "_b_var"))
    }
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", nargs="+", type=Path)
    ap.add_argument("--spp", default="4,16")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    train = REPO / "data" / "generated" / "kal-train"
    one, two = best_fixed("xbf", train, 24, False, 0), best_fixed("xbf2", train, 24, False, 0)
    for spp, err in two.best_error.items():
        if err < one.best_error.get(spp, float("inf")):
            one.best[spp], one.best_error[spp] = two.best[spp], err
    spps = {int(s) for s in args.spp.split(",")}
    rows = []
    for data in args.data:
        for e in scan_dataset(data):
            if e.spp not in spps:
                continue
            b = load_buffers(e.path, part=e.part)
            if "albedo" not in b or "color_a" not in b:
                continue
            ref = load_buffers(e.reference)["color"]
            t0 = time.perf_counter()
            row = {"set": data.name, "image": e.image, "spp": e.spp}
            runs = {
                "cross-bilateral": ("cross-bilateral", {}, b),
                "xbf-best": ("cross-bilateral", dict(one.best[e.spp]), b),
                "kalantari-xbf": ("kalantari-xbf", {"select": "off"}, b),
                "select": ("kalantari-xbf", {"select": "on"}, b),
                "select-shared": ("kalantari-xbf", {"select": "on"}, drop_feature_halves(b)),
            }
            for label, (name, params, inp) in runs.items():
                row[label] = relmse(denoise(inp, name, params=params, device="cpu").image, ref)
            rows.append(row)
            print(
                f"{data.name:18s} {e.image:22s} {e.spp:3d} spp  "
                + "  ".join(f"{k} {row[k]:.5f}" for k in runs)
                + f"  ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    for data in args.data:
        for spp in sorted(spps):
            rs = [r for r in rows if r["set"] == data.name and r["spp"] == spp]
            if not rs:
                continue
            cells = []
            for k in ("kalantari-xbf", "select", "select-shared"):
                for base in ("cross-bilateral", "xbf-best"):
                    g = geometric_mean([r[k] / r[base] for r in rs])
                    cells.append(f"{k}/{base} {g:.3f}")
            print(f"{data.name:18s} {spp:3d} spp ({len(rs)} images): " + "  ".join(cells))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
