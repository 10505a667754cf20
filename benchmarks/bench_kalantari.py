"""What learning the filter parameters buys (Kalantari 2015), on held-out renders.

For every image of a held-out data set (``mcdenoise render`` layout; default
``data/generated/heldout``: the 11 curated specs of ``data/scenes`` and 24 random scenes of
seed 2000, none used for training or tuning) at each spp level (4, 16, 64) it measures the
relMSE of:

* ``noisy``;
* ``xbf-default`` / ``nlm-default``: the fixed filters with the package defaults;
* ``xbf-best`` / ``nlm-best``: the fixed filters with the best parameters of a grid search on
  the **training** set, per spp level (:mod:`mcdenoise.train.grid`; cached in
  ``benchmarks/results/kalantari_grid_<kind>.json``, ``--regrid`` recomputes);
* ``kalantari-xbf`` / ``kalantari-nlm``: the learned models (default: the shipped weights);
* ``oidn`` when pyoidn is installed.

and prints per spp the geometric mean (and mean) over images, the ratio learned / best fixed
(the issue's target: <= 0.7 for the cross-bilateral filter at 4 and 16 spp) and each method's
seconds per megapixel (whole method: preparation, features, filter; median over images).
Images without albedo (AO scenes) are skipped by every method, since the shipped models need
it; they are counted in the header.

    python benchmarks/bench_kalantari.py [--heldout DIR] [--train DIR] [--xbf-model RUN]
        [--nlm-model RUN] [--grid-images 24] [--regrid] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

from mcdenoise.denoise import denoise
from mcdenoise.eval.metrics import relmse
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.models.kalantari import settings_class
from mcdenoise.prep.kalantari import prepare_item
from mcdenoise.registry import get_method
from mcdenoise.train.grid import GridResult, grid_search
from mcdenoise.train.patches import load_items, scan_dataset, split_images

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
GUIDES = ["albedo", "normal", "depth", "position"]


def best_fixed(kind: str, train_dir: Path, n_images: int, regrid: bool, seed: int) -> GridResult:
    """The grid search on (the training split of) the training set, cached."""
    cache = RESULTS / f"kalantari_grid_{kind}.json"
    if cache.is_file() and not regrid:
        res = GridResult.from_dict(json.loads(cache.read_text()))
        print(f"{kind}: grid result from {cache.relative_to(REPO)} (--regrid to recompute)")
        return res
    entries = scan_dataset(train_dir)
    train, _ = split_images(entries, 0.15, seed)  # the models' training split (seed 0)
    images = sorted({e.image for e in train})[:n_images]
    chosen = [e for e in train if e.image in images]
    filt = "xbf" if kind == "xbf2" else kind
    settings = settings_class(filt)()
    items, report = load_items(chosen, lambda b, r: prepare_item(b, filt, settings, GUIDES, r))
    t0 = time.perf_counter()
    res = grid_search(kind, items, progress=True)
    print(
        f"{kind}: grid of {len(res.trials) // max(1, len(res.best))} points on "
        f"{report.used} training levels in {time.perf_counter() - t0:.0f} s"
    )
    RESULTS.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps(res.to_dict(), indent=1))
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--heldout", type=Path, default=REPO / "data" / "generated" / "heldout")
    ap.add_argument("--train", type=Path, default=REPO / "data" / "generated" / "kal-train")
    ap.add_argument("--xbf-model", default="shipped")
    ap.add_argument("--nlm-model", default="shipped")
    ap.add_argument("--grid-images", type=int, default=24)
    ap.add_argument("--regrid", action="store_true")
    ap.add_argument("--grid-only", action="store_true", help="run/cache the grid search and stop")
    ap.add_argument("--seed", type=int, default=0, help="the training split's seed")
    ap.add_argument("--json", type=Path, default=None, help="write every number here")
    args = ap.parse_args(argv)

    grids = {
        k: best_fixed(k, args.train, args.grid_images, args.regrid, args.seed)
        for k in ("xbf", "xbf2", "nlm")
    }
    # the best fixed cross-bilateral filter of either grid (one or two passes), per level
    one, two = grids.pop("xbf"), grids.pop("xbf2")
    for spp, err in two.best_error.items():
        if err < one.best_error.get(spp, float("inf")):
            one.best[spp], one.best_error[spp] = two.best[spp], err
    grids["xbf"] = one
    for k, g in grids.items():
        for spp, s in sorted(g.best.items()):
            print(
                f"  best fixed {k} at {spp} spp: {s} (training geo-mean relMSE {g.best_error[spp]:.5f})"
            )

    if args.grid_only:
        return 0
    oidn = get_method("oidn")
    methods: list[tuple[str, str, dict]] = [
        ("xbf-default", "cross-bilateral", {}),
        ("xbf-best", "cross-bilateral", {"grid": "xbf"}),
        ("kalantari-xbf", "kalantari-xbf", {"model": args.xbf_model}),
        ("nlm-default", "nlm", {}),
        ("nlm-best", "nlm", {"grid": "nlm"}),
        ("kalantari-nlm", "kalantari-nlm", {"model": args.nlm_model}),
    ]
    if oidn.unavailable() is None:
        methods.append(("oidn", "oidn", {}))
    entries = scan_dataset(args.heldout)
    errs: dict[tuple[int, str], list[float]] = {}
    names: dict[int, list[str]] = {}  # image of each entry of errs[(spp, ...)], in order
    secs: dict[str, list[float]] = {}
    skipped = set()
    print(
        f"\nheld-out: {args.heldout} ({len({e.image for e in entries})} images); "
        f"torch threads {torch.get_num_threads()}"
    )
    for e in entries:
        b = load_buffers(e.path, part=e.part)
        if "albedo" not in b:
            skipped.add(e.image)
            continue
        ref = load_buffers(e.reference)["color"]
        spp = e.spp or 0
        errs.setdefault((spp, "noisy"), []).append(relmse(b["color"], ref))
        names.setdefault(spp, []).append(e.image)
        mp = b.shape[0] * b.shape[1] / 1e6
        for label, name, params in methods:
            p = dict(params)
            if "grid" in p:
                p = dict(grids[p.pop("grid")].best[spp])
            res = denoise(b, name, params=p, device="cpu")
            errs.setdefault((spp, label), []).append(relmse(res.image, ref))
            secs.setdefault(label, []).append(res.seconds / mp)
    print(
        f"skipped {len(skipped)} image(s) without albedo (AO scenes): {', '.join(sorted(skipped))}"
    )
    labels = ["noisy"] + [m[0] for m in methods]
    spps = sorted({k[0] for k in errs})
    out = {"spp": {}, "seconds_per_mp": {}}
    head = (
        f"{'method':<15}"
        + "".join(f"{f'{s} spp geo':>13}{'mean':>10}" for s in spps)
        + f"{'s/MP':>8}"
    )
    print(
        "\nrelMSE over "
        + f"{len(errs[(spps[0], 'noisy')])} images per level (geometric mean, mean)"
    )
    print(head)
    print("-" * len(head))
    for label in labels:
        row = f"{label:<15}"
        for s in spps:
            v = errs[(s, label)]
            row += f"{geometric_mean(v):>13.5f}{statistics.fmean(v):>10.5f}"
            out["spp"].setdefault(str(s), {})[label] = {
                "geomean": geometric_mean(v),
                "mean": statistics.fmean(v),
            }
        sp = statistics.median(secs[label]) if label in secs else 0.0
        out["seconds_per_mp"][label] = sp
        print(row + (f"{sp:>8.1f}" if label in secs else f"{'-':>8}"))
    print("\nratios (geometric mean over images of the per-image ratio):")
    for kind in ("xbf", "nlm"):
        for s in spps:
            learned, best, default = (
                errs[(s, f"kalantari-{kind}")],
                errs[(s, f"{kind}-best")],
                errs[(s, f"{kind}-default")],
            )
            ratios = [a / b for a, b in zip(learned, best, strict=True)]
            r_best = geometric_mean(ratios)
            r_def = geometric_mean([a / b for a, b in zip(learned, default, strict=True)])
            wins = sum(r < 1 for r in ratios)
            line = f"  kalantari-{kind} / {kind}-best at {s:>3} spp: {r_best:.3f} (vs default {r_def:.3f}; better on {wins}/{len(best)}"
            # the curated specs (data/scenes) are unlike the random training scenes
            rand = [r for r, n in zip(ratios, names[s], strict=True) if n.startswith("random_")]
            cur = [r for r, n in zip(ratios, names[s], strict=True) if not n.startswith("random_")]
            if rand and cur:
                line += f"; curated specs {geometric_mean(cur):.3f}, random scenes {geometric_mean(rand):.3f}"
            line += ")"
            if "oidn" in labels:
                line += f"; / oidn {geometric_mean([a / b for a, b in zip(learned, errs[(s, 'oidn')], strict=True)]):.3f}"
            print(line)
            if kind == "xbf" and "oidn" in labels:
                # what the issue's target (<= 0.7x the best fixed filter) asks against OIDN
                oidn_ = errs[(s, "oidn")]
                r_need = 0.7 * geometric_mean([a / b for a, b in zip(best, oidn_, strict=True)])
                print(f"    (0.7x {kind}-best would be {r_need:.3f}x OIDN's relMSE at {s} spp)")
            out.setdefault("ratios", {})[f"{kind}@{s}"] = {
                "vs_best": r_best,
                "vs_default": r_def,
                "wins": wins,
            }
    out["images"] = {
        f"{n}@{s}": {label: errs[(s, label)][i] for label in labels}
        for s in spps
        for i, n in enumerate(names[s])
    }
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
