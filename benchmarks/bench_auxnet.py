"""The auxiliary prefilters alone: how close each brings the noisy albedo and normal to the
reference's, and what it costs.

For every image and level of the out-of-distribution set (``data/generated/ood``, rendered by
``python benchmarks/render_ood.py``; never used for training or tuning) the albedo and normal
as ``kpcn`` would see them with ``prefilter=off`` (as written), ``adaptive`` (the hand-tuned
NLM of ``prep/aux_prefilter.py``, the default), ``net`` (the shipped ``auxnet``, or
``--model``, on every pixel) and ``learned`` (``kpcn -p prefilter=learned``: the net where the
pixel mixes surfaces, ``adaptive`` elsewhere) are compared with the canonical reference's
(2048 spp):

* albedo relMSE (ε = 0.01) and the same over the 1 % of pixels where the noisy albedo is
  farthest from the reference (the mixing pixels: defocused edges, silhouettes);
* normal mean squared error.

Printed: the geometric mean over scenes per set, level and mode, and with ``--speed`` the
seconds per megapixel of each prefilter on a 1024² tile of the first image (median of 3,
``--threads`` torch threads).

    python benchmarks/bench_auxnet.py [--sets aov256,r256] [--levels 4,16,64] [--model RUN]
        [--speed] [--threads 2] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_ood

from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.io.buffers import FeatureBuffers
from mcdenoise.models.weights import load_auxnet, shipped_model_path
from mcdenoise.prep.aux_prefilter import prefilter_aux
from mcdenoise.prep.inputs import prepare_inputs
from mcdenoise.prep.learned_prefilter import learned_aux, learned_prefilter

MODES = ("off", "adaptive", "net", "learned")
EPS = 0.01


def read(item: bench_ood.Item) -> FeatureBuffers:
    return load_buffers(item.path, part=item.part)


def features(b: FeatureBuffers, mode: str, net) -> dict[str, torch.Tensor]:
    """The albedo and normal ``(1, 3, H, W)`` of ``b`` as ``kpcn`` prepares them in ``mode``."""
    inp = prepare_inputs(b, features=("albedo", "normal"), prefilter=False)
    f = dict(inp.features)
    if mode == "adaptive":
        f.update(prefilter_aux(f, inp.feature_vars, inp.color, inp.color_var))
    elif mode == "learned":
        f.update(learned_aux(f, inp.feature_vars, inp.color, inp.color_var, net))
    elif mode == "net":
        f.update(learned_prefilter(f, inp.feature_vars, inp.color, inp.color_var, net))
    return f


def measure(item: bench_ood.Item, net) -> dict[str, float]:
    b = read(item)
    ref = load_buffers(item.reference)
    ra, rn = ref["albedo"][None], ref["normal"][None]
    noisy = b["albedo"][None]
    far = (noisy - ra).abs().mean(1).flatten()
    worst = far >= torch.quantile(far, 0.99)
    out = {}
    for mode in MODES:
        f = features(b, mode, net)
        rel = ((f["albedo"] - ra).square() / (ra.square() + EPS)).mean(1).flatten()
        out[f"{mode}.albedo"] = float(rel.mean())
        out[f"{mode}.albedo_worst1"] = float(rel[worst].mean())
        out[f"{mode}.normal"] = float((f["normal"] - rn).square().mean())
    return out


def speed(item: bench_ood.Item, net, reps: int = 3) -> dict[str, float]:
    b = read(item)
    tiles = {k: v.repeat(1, 4, 4)[:, :1024, :1024] for k, v in b.buffers.items() if v.ndim == 3}
    big = FeatureBuffers(buffers=tiles, spp=b.spp)
    inp = prepare_inputs(big, features=("albedo", "normal"), prefilter=False)
    runs = {
        "adaptive": lambda: prefilter_aux(inp.features, {}, inp.color, inp.color_var),
        "net": lambda: learned_prefilter(inp.features, {}, inp.color, inp.color_var, net),
        "learned": lambda: learned_aux(inp.features, {}, inp.color, inp.color_var, net),
    }
    out = {}
    for name, fn in runs.items():
        fn()
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        out[name] = statistics.median(ts) * 1e6 / (1024 * 1024)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=bench_ood.DATA)
    ap.add_argument("--sets", default="aov256,r256")
    ap.add_argument("--levels", default="4,16,64")
    ap.add_argument("--model", default=None, help="auxnet weights (default: the shipped ones)")
    ap.add_argument("--speed", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    net = load_auxnet(args.model or shipped_model_path("auxnet"))
    levels = [int(x) for x in args.levels.split(",")]
    rows = []
    for name in args.sets.split(","):
        for item in bench_ood.items_of(args.data, name, levels, []):
            try:
                m = measure(item, net)
            except Exception as err:  # a scene without albedo (AO) is skipped, named
                print(f"skip {item.image}: {err}", file=sys.stderr)
                continue
            rows.append({"set": name, "image": item.image, "spp": item.spp, **m})
    print(
        f"{'set':8} {'spp':>4} {'mode':9} {'albedo relMSE':>14} {'worst 1 %':>10} {'normal MSE':>11}"
    )
    for name in args.sets.split(","):
        for spp in levels:
            sel = [r for r in rows if r["set"] == name and r["spp"] == spp]
            for mode in MODES:
                a = geometric_mean([r[f"{mode}.albedo"] for r in sel])
                w = geometric_mean([r[f"{mode}.albedo_worst1"] for r in sel])
                n = geometric_mean([r[f"{mode}.normal"] for r in sel])
                print(f"{name:8} {spp:4d} {mode:9} {a:14.5f} {w:10.4f} {n:11.5f}")
    result = {"rows": rows}
    if args.speed:
        first = bench_ood.items_of(args.data, args.sets.split(",")[0], [4], [])[0]
        s = speed(first, net)
        result["speed_s_per_mp"] = s
        print(f"seconds per megapixel ({args.threads} threads): " + ", ".join(
            f"{k} {v:.2f}" for k, v in s.items()))  # fmt: skip
    if args.json:
        write_text_atomic(args.json, json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
