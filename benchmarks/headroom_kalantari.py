"""How much a learned cross-bilateral model leaves on the table, and whether SURE can take it.

For every image of a held-out data set at the chosen spp levels, the model's predicted
log-bandwidths are shifted globally (spatial bandwidths of both passes by -s, 0, +s; colour
bandwidths of both passes by -s, 0, +s: 9 candidate filters), and one candidate is chosen

* per pixel, by the lowest error averaged over a (2R+1)² block around it, or
* per image, by the lowest error over the image,

where the error is either the **true** per-pixel relMSE against the reference (an oracle: the
headroom a better bandwidth predictor could reach, in-sample, so a little optimistic),
**SURE** (Stein's unbiased risk estimate: ``(f - y)² + 2 σ² ∂f/∂y``, with the render's
variance buffer as σ² and a Monte Carlo estimate of the divergence from one random ±1 probe),
which needs no reference and could run at inference (Li, Wu, Chuang 2012 select filter
scales this way), or, on renders with half buffers (``mcdenoise render --halves``), the
**two-buffer** estimate of :mod:`mcdenoise.methods.selection` (every candidate run on each
half and judged by the other half; what ``kalantari-xbf`` does with halves). Its rows:
``halves-block`` (chosen per block, the chosen candidate on the full buffer: the method's
output; the halves judged after the preparation's firefly clamp), ``halves-raw-block`` (the
same judged by the raw halves), ``halves-mean-block`` (the mean of the chosen candidate on the
two halves, NFOR's output, for which the estimate is unbiased) and ``halves-image`` (one
candidate per image).

It prints the geometric mean over images of each selection's relMSE divided by the model's own
(``base``) and by the best fixed cross-bilateral filter's (``xbf-best``: the parameters of
``bench_kalantari.py``'s grid search on the training set, per spp, from
``benchmarks/results/kalantari_grid_xbf*.json``, run on the same noisy image).
``--ref-dir`` reads the references from another folder (same image ids): a set re-rendered
with halves can reuse the 2048-spp references of ``data/generated/heldout``. ``--gaussian-check`` first replaces
the noise of one image by Gaussian noise of the buffer's variance, where SURE is exact in
expectation, and prints SURE against the true error per candidate: it tells a wrong estimator
from noise that breaks SURE's assumptions.

    python benchmarks/headroom_kalantari.py [--heldout DIR] [--ref-dir DIR] [--model shipped|RUN]
        [--spp 4,16] [--radius 8] [--shift 0.7] [--gaussian-check IMAGE] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch
from torch import Tensor

from mcdenoise.denoise import denoise
from mcdenoise.eval.metrics import relmse
from mcdenoise.filters.box import box_mean
from mcdenoise.filters.two_buffer import cross_error
from mcdenoise.io import load_buffers
from mcdenoise.losses import relative_squared_error, relmse_map
from mcdenoise.methods.selection import (
    choose,
    half_buffers,
    has_halves,
    pick,
    shifted_offsets,
)
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.models.weights import SHIPPED, shipped_model_path
from mcdenoise.prep.kalantari import prepare_for_model
from mcdenoise.stats import geometric_mean
from mcdenoise.train.dataset import scan_dataset
from mcdenoise.train.grid import GridResult

REPO = Path(__file__).resolve().parents[1]
GRIDS = [REPO / "benchmarks" / "results" / f"kalantari_grid_{k}.json" for k in ("xbf", "xbf2")]
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
    return shifted_offsets(model, o, s)


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


def half_outputs(
    model: KalantariModel, b, s: float
) -> tuple[list[list[Tensor]], list[tuple[Tensor, Tensor]]]:
    """Every candidate's output ``(1, 3, H, W)`` on half A and on half B (each half's own
    features and predicted bandwidths, shifted), and each half's colour and variance after
    the preparation's firefly clamp (the judges :func:`select_kalantari` uses)."""
    outs, clamped = [], []
    for h in ("a", "b"):
        half = half_buffers(b, h)
        batch = {k: v[None] for k, v in prepare_for_model(model.card, half).items()}
        o = model.offsets(batch["features"])
        outs.append([model.filter(batch, oc) for oc in candidates(model, o, s)])
        f = batch["factor"]
        clamped.append((batch["irr"] * f, batch["irr_var"] * f.square()))
    return outs, clamped


def halves_rows(
    model: KalantariModel, b, outs: Tensor, true: Tensor, pilot: Tensor, ref: Tensor, args
) -> dict[str, float]:
    """The two-buffer rows of one image (see the module docstring): judged by the clamped
    halves (``halves-*``, what the method does) and by the raw halves (``halves-raw-block``)."""
    (outs_a, outs_b), ((ca, cva), (cb, cvb)) = half_outputs(model, b, args.shift)
    ha, hb = half_buffers(b, "a"), half_buffers(b, "b")
    raw = (ha["color"][None], hb["color"][None], ha["color_var"][None], hb["color_var"][None])
    den = pilot.square() + 0.01

    def estimate(a: Tensor, bb: Tensor, va: Tensor, vb: Tensor) -> Tensor:
        return torch.cat(
            [
                (cross_error(oa, ob, a, bb, va, vb) / den).mean(1, keepdim=True)
                for oa, ob in zip(outs_a, outs_b, strict=True)
            ],
            1,
        )

    est = estimate(ca, cb, cva, cvb)
    index = choose(est, args.radius)
    means = torch.stack([(oa + ob) * 0.5 for oa, ob in zip(outs_a, outs_b, strict=True)], 1)
    whole = int(est.mean((2, 3)).argmin(1))
    return {
        "halves-block": relmse(pick(outs, index)[0], ref),
        "halves-raw-block": relmse(pick(outs, choose(estimate(*raw), args.radius))[0], ref),
        "halves-mean-block": relmse(pick(means, index)[0], ref),
        "halves-image": float(true[:, whole].mean()),
    }


def xbf_best(grids: dict[int, dict], b, spp: int, ref: Tensor) -> float | None:
    """relMSE of the best fixed cross-bilateral filter of the training grid at ``spp``."""
    if spp not in grids:
        return None
    res = denoise(b, "cross-bilateral", params=dict(grids[spp]), device="cpu")
    return relmse(res.image, ref)


def best_grid() -> dict[int, dict]:
    """Per spp, the better of the one- and two-pass grids' best settings (as bench_kalantari)."""
    best: dict[int, dict] = {}
    err: dict[int, float] = {}
    for path in GRIDS:
        if not path.is_file():
            continue
        g = GridResult.from_dict(json.loads(path.read_text()))
        for spp, e in g.best_error.items():
            if e < err.get(spp, float("inf")):
                best[spp], err[spp] = g.best[spp], e
    return best


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
    ap.add_argument("--ref-dir", type=Path, default=None, help="read references from here")
    ap.add_argument("--images", default="", help="comma-separated image names (default: all)")
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
    grids = best_grid()
    rows: dict[str, dict[str, float]] = {}
    keys = ["oracle-block", "oracle-image", "sure-block", "sure-image"]
    half_keys = ["halves-block", "halves-raw-block", "halves-mean-block", "halves-image"]
    wanted = {i for i in args.images.split(",") if i}
    for e in scan_dataset(args.heldout):
        if e.spp not in spps or (wanted and e.image not in wanted):
            continue
        reference = args.ref_dir / e.reference.name if args.ref_dir else e.reference
        if not reference.is_file():
            print(f"{e.image}: no reference {reference}, skipped")
            continue
        b, ref = load_pair(e.path, e.part, reference)
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
        if has_halves(b):
            with torch.no_grad():
                row.update(halves_rows(model, b, outs, true, pilot, ref, args))
        best = xbf_best(grids, b, e.spp or 0, ref)
        if best:
            row["xbf-best"] = best
        rows[f"{e.image}@{e.spp}"] = row
        print(
            f"{e.image:<22}{e.spp:>4} spp  base {row['base']:.5f}  "
            + "  ".join(f"{k} {row[k] / row['base']:.3f}" for k in keys + half_keys if k in row)
            + f"  ({time.perf_counter() - t0:.1f} s)",
            flush=True,
        )
    print(
        f"\nrelMSE ratios, geometric mean over images (block radius {args.radius}, shift {args.shift}):"
    )
    shown = keys + [k for k in half_keys if any(k in r for r in rows.values())]
    print(
        f"{'spp':>4}{'images':>8}"
        + "".join(f"{k:>19}" for k in ("base", *shown))
        + "   (/ base; / xbf-best)"
    )
    for s in sorted(spps):
        sel = [r for k, r in rows.items() if k.endswith(f"@{s}") and all(h in r for h in shown)]
        line = f"{s:>4}{len(sel):>8}" + f"{'1':>19}"
        line += "".join(f"{geometric_mean([r[k] / r['base'] for r in sel]):>19.3f}" for k in shown)
        withbest = [r for r in sel if "xbf-best" in r]
        if withbest:
            line += (
                "\n"
                + " " * 12
                + "".join(
                    f"{geometric_mean([r[k] / r['xbf-best'] for r in withbest]):>19.3f}"
                    for k in ("base", *shown)
                )
            )
        print(line)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
