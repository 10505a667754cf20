"""What each method buys on the shipped sample renders: relMSE vs the reference, per scene.

Prints, for every scene and spp in ``data/samples`` (or ``--samples DIR``), the relMSE of the
noisy input and of each available method, the reduction factor (noisy / method) and the
seconds the method took; then the geometric mean of the reduction factor over scenes per spp.
OIDN (pyoidn) is printed beside the classical filters when installed, as the industry peer.

Target of the foundation issue: at 16 spp, NLM and cross-bilateral each cut relMSE by >= 3x.

    python benchmarks/bench_quality.py [--spp 16] [--methods nlm,cross-bilateral,oidn]
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import torch

from mcdenoise.denoise import denoise
from mcdenoise.eval.metrics import relmse
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.registry import available_methods, get_method

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=Path, default=REPO / "data" / "samples")
    ap.add_argument("--spp", default="4,16", help="comma-separated spp levels (default 4,16)")
    ap.add_argument("--methods", default=None, help="comma-separated (default: all available)")
    args = ap.parse_args(argv)

    methods = (
        [get_method(m) for m in args.methods.split(",")] if args.methods else available_methods()
    )
    spps = [int(s) for s in args.spp.split(",")]
    print(f"torch threads: {torch.get_num_threads()}; samples: {args.samples}")
    header = f"{'scene':<11}{'spp':>5}  {'method':<16}{'relMSE':>10}{'noisy/method':>14}{'sec':>8}"
    print(header)
    print("-" * len(header))
    factors: dict[tuple[int, str], list[float]] = {}
    for noisy_path in sorted(args.samples.glob("*_spp*.exr")):
        m = re.fullmatch(r"(.+)_spp(\d+)", noisy_path.stem)
        if not m or int(m.group(2)) not in spps:
            continue
        scene, spp = m.group(1), int(m.group(2))
        ref = load_buffers(args.samples / "ref" / f"{scene}.exr").color
        buf = load_buffers(noisy_path)
        base = relmse(buf.color, ref)
        print(f"{scene:<11}{spp:>5}  {'noisy':<16}{base:>10.5f}{1.0:>14.2f}{'':>8}")
        for method in methods:
            res = denoise(buf, method, device="cpu")
            err = relmse(res.image, ref)
            f = base / err if err > 0 else math.inf
            factors.setdefault((spp, method.name), []).append(f)
            print(f"{'':<11}{'':>5}  {method.name:<16}{err:>10.5f}{f:>14.2f}{res.seconds:>8.2f}")
    print()
    print("geometric mean over scenes of the relMSE reduction (noisy / method):")
    for (spp, name), fs in sorted(factors.items()):
        g = geometric_mean(fs)
        worst = min(fs)
        print(f"  {spp:>3} spp  {name:<16} {g:6.2f}x  (worst scene {worst:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
