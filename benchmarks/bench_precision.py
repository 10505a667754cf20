"""What a faster ``kpcn`` costs in quality (issue 38): held-out relMSE of the shipped model in
float32 against the variants the speed work made, per data set, spp level and input source.

For every image of each data set (``mcdenoise render`` layout: ``manifest.json``, ``<id>.exr``
with one part per spp level, ``ref/<id>.exr``; AO renders without albedo are skipped) it
denoises each level with the shipped ``kpcn`` twice or more:

* ``fp32``: the trunk in float32 (``-p precision=fp32``), the reference;
* ``bf16``: the trunk under bfloat16 autocast (``-p precision=bf16``, what ``auto`` picks on a
  CPU with native bfloat16);

on the render as it is (``full`` source) and on a copy with only colour, albedo and normal
(``basic``: a plain Mitsuba ``aov`` or Cycles file). It prints the geometric-mean relMSE of
each variant, its ratio to ``fp32`` and the worst single-image ratio; the issue allows a move of
0.5 %.

The sets to pass: the held-out renders of ``data/recipes/kpcn.md`` (random scenes of seed 2000
and the curated specs, never trained on), the hand-written textured scenes
(``data/scenes/textured``) and the out-of-distribution specs (``data/scenes/ood``).

    python benchmarks/bench_precision.py DATA_DIR [DATA_DIR ...] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from mcdenoise.eval.metrics import relmse
from mcdenoise.io import load_buffers
from mcdenoise.methods.kpcn import denoise_kpcn
from mcdenoise.models.weights import load_kpcn, shipped_model_path
from mcdenoise.threads import apply_threads

VARIANTS = ("fp32", "bf16")
BASIC = ("color", "albedo", "normal")


def _gmean(xs: list[float]) -> float:
    return math.exp(sum(math.log(x) for x in xs) / len(xs))


def measure(data: Path, model) -> dict[tuple[int, str], list[list[float]]]:
    """``(spp, source) -> [[relMSE per variant] per image]``."""
    manifest = json.loads((data / "manifest.json").read_text())
    rows: dict[tuple[int, str], list[list[float]]] = {}
    for im in manifest["images"]:
        if "albedo" not in im.get("features", ["albedo"]):
            continue
        ref = load_buffers(data / im["files"]["reference"])["color"]
        for level in im["levels"]:
            b = load_buffers(data / im["files"]["noisy"], part=level["part"])
            for source, bufs in (("full", b), ("basic", b.subset([n for n in BASIC if n in b]))):
                errs = [relmse(denoise_kpcn(model, bufs, precision=v), ref) for v in VARIANTS]
                rows.setdefault((level["spp"], source), []).append(errs)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="+", type=Path)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    apply_threads(args.threads)
    model = load_kpcn(shipped_model_path("kpcn")).eval()
    print(
        f"{'set':22s} {'spp':>4s} {'source':6s} {'n':>3s}  "
        + "  ".join(f"{v:>9s}" for v in VARIANTS)
        + "  ratio  worst image"
    )
    for data in args.data:
        for (spp, source), errs in sorted(measure(data, model).items()):
            g = [_gmean([e[i] for e in errs]) for i in range(len(VARIANTS))]
            worst = max(e[1] / e[0] for e in errs)
            print(
                f"{data.name:22s} {spp:4d} {source:6s} {len(errs):3d}  "
                + "  ".join(f"{x:9.6f}" for x in g)
                + f"  {g[1] / g[0]:.4f}  {worst:.4f}"
            )


if __name__ == "__main__":
    main()
