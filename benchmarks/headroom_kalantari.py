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
half and judged by the other half). Its rows: ``halves-block`` (chosen per block, the chosen
candidate on the full buffer, the halves judged after the preparation's firefly clamp),
``halves-mean-block`` (the mean of the chosen candidate on the two halves, NFOR's output, for
which the estimate is unbiased) and ``halves-image`` (one candidate per image).

``--variants`` adds a row ``SET:RULE`` per candidate set and weighting rule
(:func:`~mcdenoise.methods.selection.weights`: ``argmin``, ``smooth``, ``soft0.3``,
``soft1``, ``soft-smooth0.3``) and ``SET:oracle``: sets ``M`` (the 9 shifts, each half
filtered with the bandwidths the model predicts on it), ``Mabs`` (the 9 shifts, each half
filtered with the full buffer's), ``X`` (5 fixed cross-bilateral filters,
:func:`~mcdenoise.methods.selection.fixed_neighbours` of ``xbf-best``) and the unions
``M+X``, ``Mabs+X``. ``Mabs+X:soft-smooth0.3`` is what ``kalantari-xbf`` does on an input
with halves. ``--cache DIR`` keeps each image's candidate outputs there
(``<image>@<spp>.pt``, a few MB) and reads them back on the next run, so the rows of a new
rule cost seconds (the files do not record ``--shift`` or ``--model``: one folder per
setting).

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
        [--variants] [--cache DIR] [--images A,B,...] [--threads N]
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
from mcdenoise.geomean import geometric_mean
from mcdenoise.io import load_buffers
from mcdenoise.io.buffers import has_halves
from mcdenoise.losses import relative_squared_error, relmse_map
from mcdenoise.methods.selection import (
    blend,
    choose,
    fixed_neighbours,
    half_buffers,
    pick,
    shifted_offsets,
    weights,
)
from mcdenoise.models.kalantari import KalantariModel
from mcdenoise.models.weights import SHIPPED, shipped_model_path
from mcdenoise.prep.kalantari import prepare_for_model
from mcdenoise.train.grid import GridResult
from mcdenoise.train.patches import scan_dataset

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
    model: KalantariModel, b, s: float, o_full: Tensor
) -> tuple[dict[str, Tensor], tuple[Tensor, Tensor, Tensor, Tensor]]:
    """Every candidate's output ``(1, K, 3, H, W)`` on half A and on half B, with each half's
    own predicted bandwidths shifted (``a``, ``b``: what :func:`select_kalantari` runs) and
    with the full buffer's (``a-abs``, ``b-abs``: the bandwidths that will be applied, judged
    at half the samples), and the halves' colour and variance after the preparation's
    firefly clamp (the judges :func:`select_kalantari` uses)."""
    outs: dict[str, Tensor] = {}
    judges = []
    for h in ("a", "b"):
        half = half_buffers(b, h)
        batch = {k: v[None] for k, v in prepare_for_model(model.card, half).items()}
        o = model.offsets(batch["features"])
        outs[h] = torch.stack([model.filter(batch, oc) for oc in candidates(model, o, s)], 1)
        outs[f"{h}-abs"] = torch.stack(
            [model.filter(batch, oc) for oc in candidates(model, o_full, s)], 1
        )
        f = batch["factor"]
        judges += [batch["irr"] * f, batch["irr_var"] * f.square()]
    ca, cva, cb, cvb = judges
    return outs, (ca, cb, cva, cvb)


def fixed_outputs(b, sets: list[dict]) -> dict[str, Tensor]:
    """The fixed filters' outputs ``(1, F, 3, H, W)`` on the full buffer and on each half."""
    res = {}
    for name, buf in (("full", b), ("a", half_buffers(b, "a")), ("b", half_buffers(b, "b"))):
        res[name] = torch.stack(
            [denoise(buf, "cross-bilateral", params=p, device="cpu").image[None] for p in sets], 1
        )
    return res


#: Candidate sets of the variant rows: model shifts judged with the halves' own bandwidths
#: (``M``) or with the full buffer's (``Mabs``), the fixed filters (``X``), and unions.
SETS = ("M", "Mabs", "X", "M+X", "Mabs+X")
#: Weighting rules of the variant rows: (name, rule, tau).
VARIANT_RULES = (
    ("argmin", "argmin", 0.0),
    ("smooth", "smooth", 0.0),
    ("soft0.3", "soft", 0.3),
    ("soft1", "soft", 1.0),
    ("soft-smooth0.3", "soft-smooth", 0.3),
)


def variant_rows(c: dict[str, Tensor], radius: int) -> dict[str, float]:
    """relMSE of every (candidate set, rule) pair of one image from its cached candidate
    outputs ``c`` (see :func:`image_cache`), and of each set's oracle (block argmin of the
    true error)."""
    ref, den = c["ref"], c["pilot"].square() + 0.01
    judges = (c["judge_a"], c["judge_b"], c["judge_va"], c["judge_vb"])
    parts = {
        "M": (c["M_full"], c["M_a"], c["M_b"]),
        "Mabs": (c["M_full"], c["M_a-abs"], c["M_b-abs"]),
        "X": (c["X_full"], c["X_a"], c["X_b"]),
    }
    rows: dict[str, float] = {}
    for name in SETS:
        full, oa, ob = (torch.cat(t, 1) for t in zip(*(parts[p] for p in name.split("+"))))
        est = (cross_error(oa, ob, *judges[:2], *judges[2:]) / den[:, None]).mean(2)
        true = relmse_map(full[0], ref[None]).mean(1)[None]
        rows[f"{name}:oracle"] = relmse(pick(full, choose(true, radius))[0], ref)
        for label, rule, tau in VARIANT_RULES:
            out = blend(full, weights(est, radius, rule, tau))[0]
            rows[f"{name}:{label}"] = relmse(out, ref)
    return rows


def halves_rows(c: dict[str, Tensor], true: Tensor, radius: int) -> dict[str, float]:
    """The two-buffer rows of one image (see the module docstring)."""
    ref, den = c["ref"], c["pilot"].square() + 0.01
    est = (
        cross_error(c["M_a"], c["M_b"], c["judge_a"], c["judge_b"], c["judge_va"], c["judge_vb"])
        / den[:, None]
    ).mean(2)
    index = choose(est, radius)
    means = (c["M_a"] + c["M_b"]) * 0.5
    whole = int(est.mean((2, 3)).argmin(1))
    return {
        "halves-block": relmse(pick(c["M_full"], index)[0], ref),
        "halves-mean-block": relmse(pick(means, index)[0], ref),
        "halves-image": float(true[:, whole].mean()),
    }


def image_cache(model: KalantariModel, b, ref: Tensor, grids: dict, spp: int, args) -> dict:
    """Every candidate output, true-error and SURE map of one image that the rows need."""
    c: dict[str, Tensor] = {"ref": ref}
    with torch.no_grad():
        batch = {k: v[None] for k, v in prepare_for_model(model.card, b).items()}
        o = model.offsets(batch["features"])
        pilot = box_mean(model.filter(batch, o), PILOT_RADIUS)
        maps = [
            error_maps(model, batch, oc, ref[None], pilot)
            for oc in candidates(model, o, args.shift)
        ]
        c["pilot"] = pilot
        c["M_full"] = torch.stack([m[0] for m in maps], 1)
        c["true"] = torch.cat([m[1] for m in maps], 1)
        c["sure"] = torch.cat([m[2] for m in maps], 1)
        if has_halves(b):
            outs, judges = half_outputs(model, b, args.shift, o)
            c |= {f"M_{k}": v for k, v in outs.items()}
            c |= dict(zip(("judge_a", "judge_b", "judge_va", "judge_vb"), judges, strict=True))
            if spp in grids and args.variants:
                c |= {
                    f"X_{k}": v for k, v in fixed_outputs(b, fixed_neighbours(grids[spp])).items()
                }
    best = xbf_best(grids, b, spp, ref)
    if best:
        c["xbf-best"] = torch.tensor(best)
    return c


def image_rows(c: dict[str, Tensor], radius: int) -> dict[str, float]:
    """The rows of one image from its :func:`image_cache`."""
    outs, true, sure, ref = c["M_full"], c["true"], c["sure"], c["ref"]
    row = {"base": float(true[:, true.shape[1] // 2].mean())}
    for name, score in (("oracle", true), ("sure", sure)):
        out, whole = select(outs, score, radius)
        row[f"{name}-block"] = relmse(out[0], ref)
        row[f"{name}-image"] = float(true[:, whole].mean())
    if "M_a" in c:
        row.update(halves_rows(c, true, radius))
    if "X_full" in c:
        row.update(variant_rows(c, radius))
    if "xbf-best" in c:
        row["xbf-best"] = float(c["xbf-best"])
    return row


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


def print_summary(rows: dict[str, dict[str, float]], spps: set[int], keys: list[str], args) -> None:
    """Per spp, one line per selection: the geometric mean over images of its relMSE over the
    model's (``/ base``) and over the best fixed filter's (``/ xbf-best``)."""
    print(
        f"\nrelMSE ratios, geometric mean over images (block radius {args.radius}, "
        f"shift {args.shift}):"
    )
    for s in sorted(spps):
        sel = [r for k, r in rows.items() if k.endswith(f"@{s}")]
        shown = [k for k in keys if sel and all(k in r for r in sel)]
        shown += [k for k in (sel[0] if sel else {}) if ":" in k and all(k in r for r in sel)]
        best = [r for r in sel if "xbf-best" in r]
        print(f"{s} spp, {len(sel)} images ({len(best)} with xbf-best):")
        print(f"{'selection':>24}{'/ base':>10}{'/ xbf-best':>12}")
        for k in ("base", *shown):
            line = f"{k:>24}{geometric_mean([r[k] / r['base'] for r in sel]):>10.3f}"
            if len(best) == len(sel):
                line += f"{geometric_mean([r[k] / r['xbf-best'] for r in sel]):>12.3f}"
            print(line)


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
    ap.add_argument("--variants", action="store_true", help="the candidate-set x rule rows")
    ap.add_argument("--cache", type=Path, default=None, help="keep each image's outputs here")
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
    half_keys = ["halves-block", "halves-mean-block", "halves-image"]
    wanted = {i for i in args.images.split(",") if i}
    for e in scan_dataset(args.heldout):
        if e.spp not in spps or (wanted and e.image not in wanted):
            continue
        reference = args.ref_dir / e.reference.name if args.ref_dir else e.reference
        if not reference.is_file():
            print(f"{e.image}: no reference {reference}, skipped")
            continue
        key = f"{e.image}@{e.spp}"
        cached = args.cache / f"{key}.pt" if args.cache else None
        t0 = time.perf_counter()
        if cached is not None and cached.is_file():
            c = torch.load(cached)
        else:
            b, ref = load_pair(e.path, e.part, reference)
            if "albedo" not in b:  # as bench_kalantari: the shipped model needs it
                continue
            c = image_cache(model, b, ref, grids, e.spp or 0, args)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                torch.save(c, cached)
        row = image_rows(c, args.radius)
        rows[key] = row
        print(
            f"{e.image:<22}{e.spp:>4} spp  base {row['base']:.5f}  "
            + "  ".join(f"{k} {row[k] / row['base']:.3f}" for k in keys + half_keys if k in row)
            + f"  ({time.perf_counter() - t0:.1f} s)",
            flush=True,
        )
    print_summary(rows, spps, keys + half_keys, args)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
