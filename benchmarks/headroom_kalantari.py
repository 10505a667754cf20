"""How much a learned cross-bilateral model leaves on the table, and whether SURE can take it.

For every image of a held-out data set at the chosen spp levels, the model's predicted
log-bandwidths are shifted globally (spatial bandwidths of both passes by -s, 0, +s; colour
bandwidths of both passes by -s, 0, +s: 9 candidate filters), and one candidate is chosen

* per pixel, by the lowest error averaged over a (2R+1)² block around it, or
* per image, by the lowest error over the image,

where the error is either the **true** per-pixel relMSE against the reference (an oracle: the
headroom a better bandwidth predictor could reach, in-sample, so a little optimistic) or
**SURE** (Stein's unbiased risk estimate: ``(f - y)² + 2 σ² ∂f/∂y``, with the render's
variance buffer as σ² and a Monte Carlo estimate of the divergence from one random ±1 probe),
which needs no reference and could run at inference (Li, Wu, Chuang 2012 select filter
scales this way).

It prints the geometric mean over images of each selection's relMSE divided by the model's own
(``base``) and, where ``benchmarks/results/kalantari.json`` (``bench_kalantari.py --json``)
has the best fixed filter's relMSE of that image, by that. ``--gaussian-check`` first replaces
the noise of one image by Gaussian noise of the buffer's variance, where SURE is exact in
expectation, and prints SURE against the true error per candidate: it tells a wrong estimator
from noise that breaks SURE's assumptions.

    python benchmarks/headroom_kalantari.py [--heldout DIR] [--model shipped|RUN] [--spp 4,16]
        [--radius 8] [--shift 0.7] [--gaussian-check IMAGE] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch
from torch import Tensor

from mcdenoise.eval.metrics import relmse
from mcdenoise.filters.box import box_mean
from mcdenoise.io import load_buffers
from mcdenoise.losses import relative_squared_error, relmse_map
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.models.weights import SHIPPED, shipped_model_path
from mcdenoise.prep.kalantari import prepare_for_model
from mcdenoise.stats import geometric_mean
from mcdenoise.train.dataset import scan_dataset

REPO = Path(__file__).resolve().parents[1]
STORED = REPO / "benchmarks" / "results" / "kalantari.json"
#: Relative size of the probe perturbation (times the pixel's noise standard deviation).
PROBE = 0.05
#: Radius of the box filter over the model's output that gives SURE its relMSE weights (a
#: per-pixel pilot correlates with the noise and biases SURE between candidates).
PILOT_RADIUS = 3


def shifts(s: float) -> list[tuple[float, float]]:
    """The candidates' (spatial, colour) log-bandwidth shifts; the middle one is (0, 0)."""
    return [(ds, dc) for ds in (-s, 0.0, s) for dc in (-s, 0.0, s)]


def candidates(model: KalantariModel, o: Tensor, s: float) -> list[Tensor]:
    """The model's log-offsets with the spatial and colour bandwidths shifted by -s, 0, +s."""
    outs = model.card.outputs
    spatial = [outs.index(n) for n in ("spatial", "spatial2") if n in outs]
    color = [outs.index(n) for n in ("color", "color2") if n in outs]
    res = []
    for ds, dc in shifts(s):
        oc = o.clone()
        oc[:, spatial] += ds
        oc[:, color] += dc
        res.append(oc)
    return res


def error_maps(
    model: KalantariModel,
    batch: dict[str, Tensor],
    offsets: Tensor,
    ref: Tensor,
    pilot: Tensor,
    seed: int = 0,
) -> tuple[Tensor, Tensor, Tensor]:
    """``(output (1,3,H,W), true relMSE map (1,1,H,W), SURE map (1,1,H,W))`` of one candidate.

    Both maps are in relMSE units: the SURE of the demodulated irradiance times the
    remodulation factor², over ``(pilot² + ε)``; the pilot (the model's own output, box
    filtered) is the same for every candidate, so the weights do not favour one.
    """
    y, var, a = batch["irr"], batch["irr_var"], batch["factor"]
    sig = var.clamp_min(0).sqrt()
    gen = torch.Generator().manual_seed(seed)
    probe = torch.randint(0, 2, y.shape, generator=gen).to(y.dtype) * 2 - 1
    f = model.filter(batch, offsets)
    fp = model.filter({**batch, "irr": y + PROBE * sig * probe}, offsets)
    div = probe * (fp - f) / a / (PROBE * sig).clamp_min(1e-12)
    sure = relative_squared_error(((f / a - y) ** 2 - var + 2 * var * div) * a**2, pilot)
    true = relmse_map(f, ref)
    return f, true.mean(1, keepdim=True), sure.mean(1, keepdim=True)


def select(outputs: Tensor, score: Tensor, radius: int) -> tuple[Tensor, int]:
    """Per-pixel choice by the block-averaged score ``(1,K,H,W)``, and the per-image choice."""
    pick = box_mean(score, radius).argmin(1, keepdim=True)  # (1,1,H,W)
    idx = pick[:, :, None].expand(-1, -1, outputs.shape[2], -1, -1)
    return torch.gather(outputs, 1, idx)[:, 0], int(score.mean((2, 3)).argmin(1))


def load_pair(path: Path, part: str | None, reference: Path) -> tuple[object, Tensor]:
    b = load_buffers(path, part=part)
    ref = torch.as_tensor(load_buffers(reference)["color"]).float()
    return b, ref


def gaussian_check(model: KalantariModel, heldout: Path, image: str, s: float) -> None:
    entries = [e for e in scan_dataset(heldout) if e.image == image]
    if not entries:
        raise SystemExit(f"headroom_kalantari: no image {image!r} in {heldout}")
    e = sorted(entries, key=lambda e: e.spp or 0)[len(entries) // 2]
    b, ref = load_pair(e.path, e.part, e.reference)
    with torch.no_grad():
        batch = {k: v[None] for k, v in prepare_for_model(model.card, b).items()}
        a = batch["factor"]
        gen = torch.Generator().manual_seed(1)
        noise = batch["irr_var"].sqrt() * torch.randn(a.shape, generator=gen)
        batch["irr"] = ref[None] / a + noise
        o = model.offsets(batch["features"])
        pilot = box_mean(model.filter(batch, o), PILOT_RADIUS)
        print(f"Gaussian-noise check on {image} at {e.spp} spp (noise of the buffer's variance):")
        print(f"{'shift (spatial, colour)':>26}{'SURE':>12}{'true':>12}")
        for (ds, dc), oc in zip(shifts(s), candidates(model, o, s), strict=True):
            _, true, sure = error_maps(model, batch, oc, ref[None], pilot)
            print(f"{f'({ds:+.1f}, {dc:+.1f})':>26}{sure.mean():>12.6f}{true.mean():>12.6f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--heldout", type=Path, default=REPO / "data" / "generated" / "heldout")
    ap.add_argument("--model", default=SHIPPED, help="shipped, a model file or a run folder")
    ap.add_argument("--spp", default="4,16", help="spp levels, comma-separated")
    ap.add_argument("--radius", type=int, default=8, help="block radius R of the selection")
    ap.add_argument("--shift", type=float, default=0.7, help="log-bandwidth shift s")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--gaussian-check", metavar="IMAGE", default="")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    path = shipped_model_path("kalantari-xbf") if args.model == SHIPPED else Path(args.model)
    model = KalantariModel.load(path)
    if model.card.kind != "xbf":
        raise SystemExit("headroom_kalantari: a cross-bilateral (kalantari-xbf) model is needed")
    if args.gaussian_check:
        gaussian_check(model, args.heldout, args.gaussian_check, args.shift)
        print()
    spps = {int(s) for s in args.spp.split(",")}
    stored = json.loads(STORED.read_text())["images"] if STORED.is_file() else {}
    rows: dict[str, dict[str, float]] = {}
    keys = ("oracle-block", "oracle-image", "sure-block", "sure-image")
    for e in scan_dataset(args.heldout):
        if e.spp not in spps:
            continue
        b, ref = load_pair(e.path, e.part, e.reference)
        if "albedo" not in b:  # as bench_kalantari: the shipped model needs it
            continue
        t0 = time.perf_counter()
        with torch.no_grad():
            batch = {k: v[None] for k, v in prepare_for_model(model.card, b).items()}
            o = model.offsets(batch["features"])
            pilot = box_mean(model.filter(batch, o), PILOT_RADIUS)
            maps = [
                error_maps(model, batch, oc, ref[None], pilot)
                for oc in candidates(model, o, args.shift)
            ]
        outs = torch.stack([m[0] for m in maps], 1)
        true = torch.cat([m[1] for m in maps], 1)
        sure = torch.cat([m[2] for m in maps], 1)
        row = {"base": float(true[:, len(maps) // 2].mean())}
        for name, score in (("oracle", true), ("sure", sure)):
            out, whole = select(outs, score, args.radius)
            row[f"{name}-block"] = relmse(out[0], ref)
            row[f"{name}-image"] = float(true[:, whole].mean())
        best = stored.get(f"{e.image}@{e.spp}", {}).get("xbf-best")
        if best:
            row["xbf-best"] = best
        rows[f"{e.image}@{e.spp}"] = row
        print(
            f"{e.image:<22}{e.spp:>4} spp  base {row['base']:.5f}  "
            + "  ".join(f"{k} {row[k] / row['base']:.3f}" for k in keys)
            + f"  ({time.perf_counter() - t0:.1f} s)",
            flush=True,
        )
    print(
        f"\nrelMSE ratios, geometric mean over images (block radius {args.radius}, shift {args.shift}):"
    )
    print(
        f"{'spp':>4}{'images':>8}"
        + "".join(f"{k:>14}" for k in ("base", *keys))
        + "   (/ base; / xbf-best)"
    )
    for s in sorted(spps):
        sel = [r for k, r in rows.items() if k.endswith(f"@{s}")]
        line = f"{s:>4}{len(sel):>8}" + f"{'1':>14}"
        line += "".join(f"{geometric_mean([r[k] / r['base'] for r in sel]):>14.3f}" for k in keys)
        withbest = [r for r in sel if "xbf-best" in r]
        if withbest:
            line += (
                "\n"
                + " " * 12
                + "".join(
                    f"{geometric_mean([r[k] / r['xbf-best'] for r in withbest]):>14.3f}"
                    for k in ("base", *keys)
                )
            )
        print(line)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
