"""Would four quarter buffers make the reference-free estimate better? (issue 36; measured
negative, see docs/results/estimate.md.)

Two independent ``mcdenoise render --halves`` renders of the same scenes at half the spp
(``--seed 10`` and ``--seed 11``, recipe in ``data/recipes/heldout-halves.md``) give, per
image and level ``L``, four quarters of ``L/2`` samples each; their mean is a ``2L``-spp input
and its reference the mean of the two renders' references. Per method (run on the full
input, on each of the six half inputs of the three pairings of the quarters, and on each
quarter), the relMSE estimates (normalised by the output's matched normaliser, as
``--estimate-error``):

* ``est_p1``: one pairing, the estimate ``mcdenoise`` makes today (of the mean of the
  filtered halves);
* ``est_p3``: the mean over the three pairings (less noise, if the pairings' noise were not
  shared);
* ``extrap``: the error of one filtered input extrapolated from the quarter and the half
  levels to the full count, ``M(2L) = M(L)² / M(L/2)`` (each ``M`` the two-buffer estimate of
  one filtered input's error, ``½[(D_A − B)² + (D_B − A)²] − ½(A − B)²``);

* ``loo``: leave one quarter out (4-fold cross-validation): the method on three quarters
  judged by the fourth, ``(D(x₋ₖ) − qₖ)² − ½(qₖ − qⱼ)²`` (``j`` another quarter: an unbiased
  estimate of ``Var qₖ`` without a variance buffer), averaged over ``k``: the error of one
  filtered input of ``3L/2`` samples, nearer the full count than a half;
* ``loo_extrap``: extrapolated from the half level and ``loo`` to the full count (the power
  law through ``L`` and ``3L/2`` samples);

against the true relMSE of the method's full output (the reference's noise removed), and
prints per level the share within 1.5× and the mean Spearman ρ of the methods per image.

    python benchmarks/estimate_quarters.py RUN_A RUN_B [RUN_A RUN_B ...] [--methods ...]
        [--json OUT] [--from-json OUT ...]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import torch

ESTIMATES = ("est_p1", "est_p3", "extrap", "loo", "loo_extrap")
PAIRINGS = (((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2)))


def combine(parts):
    """The mean input of ``parts`` (independent inputs of one image): means, and variances
    of the mean divided by the count squared."""
    from mcdenoise.io import FeatureBuffers

    k = len(parts)
    bufs = {}
    for n in parts[0].names():
        if all(n in p for p in parts):
            t = sum(p[n].double() for p in parts)
            bufs[n] = (t / (k * k) if n.endswith("_var") else t / k).float()
    return FeatureBuffers(bufs, spp=sum(p.spp for p in parts))


def records(run_a: Path, run_b: Path, methods: list[str]) -> list[dict]:
    from mcdenoise.denoise import denoise
    from mcdenoise.errors import McdenoiseError
    from mcdenoise.eval.estimate import matched_normaliser, squared_error
    from mcdenoise.io import load_buffers
    from mcdenoise.io.buffers import half_inputs, sanitize
    from mcdenoise.losses import RELMSE_EPS

    def rel(sq, norm):
        return float((sq / (norm.square() + RELMSE_EPS)).mean())

    def one(da, db, a, b):  # the error of one filtered input (not of the mean of two)
        return 0.5 * ((da - b).square() + (db - a).square()) - 0.5 * (a - b).square()

    out = []
    for path in sorted(run_a.glob("*.exr")):
        img = path.stem
        refs = [load_buffers(d / "ref" / f"{img}.exr") for d in (run_a, run_b)]
        ref = sum(r["color"].double() for r in refs) / 2
        ref_var = sum(r["color_var"].double() for r in refs) / 4
        for level in (2, 8):
            runs = [
                sanitize(load_buffers(d / f"{img}.exr", part=f"spp{level}"))[0]
                for d in (run_a, run_b)
            ]
            q = [h for fb in runs for h in half_inputs(fb)]
            full = combine(q)
            x = full["color"].double()
            halves = {pr: combine([q[i] for i in pr]) for pg in PAIRINGS for pr in pg}
            three = [combine([q[i] for i in range(4) if i != k]) for k in range(4)]
            for m in methods:
                try:
                    df = denoise(full, m, device="cpu").image.double()
                    dh = {
                        pr: denoise(h, m, device="cpu").image.double() for pr, h in halves.items()
                    }
                    dq = [denoise(h, m, device="cpu").image.double() for h in q]
                    d3 = [denoise(h, m, device="cpu").image.double() for h in three]
                except McdenoiseError as err:
                    print(f"{img}/{2 * level}/{m}: skipped: {err}", file=sys.stderr)
                    continue
                norm = matched_normaliser(df, x)
                pair_est, half_level = [], []
                for p1, p2 in PAIRINGS:
                    a, b = halves[p1]["color"].double(), halves[p2]["color"].double()
                    pair_est.append(rel(squared_error(dh[p1], dh[p2], a, b), norm))
                    half_level.append(rel(one(dh[p1], dh[p2], a, b), norm))
                quarter_level = [
                    rel(one(dq[i], dq[j], q[i]["color"].double(), q[j]["color"].double()), norm)
                    for i, j in itertools.combinations(range(4), 2)
                ]
                mh, mq = sum(half_level) / 3, sum(quarter_level) / 6
                qc = [h["color"].double() for h in q]
                loo = (
                    sum(
                        rel(
                            (d3[k] - qc[k]).square() - 0.5 * (qc[k] - qc[(k + 1) % 4]).square(),
                            norm,
                        )
                        for k in range(4)
                    )
                    / 4
                )
                # M(n) ∝ n^-α through (L, mh) and (3L/2, loo), taken to 2L
                alpha = math.log(mh / loo) / math.log(1.5) if mh > 0 and loo > 0 else float("nan")
                rec = {
                    "image": img,
                    "spp": 2 * level,
                    "method": m,
                    "true": rel((df - ref).square() - ref_var, ref),
                    "est_p1": pair_est[0],
                    "est_p3": sum(pair_est) / 3,
                    "extrap": mh * mh / mq if mq > 0 and mh > 0 else float("nan"),
                    "loo": loo,
                    "loo_extrap": loo * (4 / 3) ** -alpha if math.isfinite(alpha) else float("nan"),
                }
                out.append(rec)
                print(json.dumps(rec), file=sys.stderr)
    return out


def analyse(recs: list[dict]) -> None:
    from scipy.stats import spearmanr

    for est in ESTIMATES:
        cells = []
        for spp in sorted({r["spp"] for r in recs}):
            rs = [r for r in recs if r["spp"] == spp]
            ok = [r["true"] > 0 and 1 / 1.5 <= r[est] / r["true"] <= 1.5 for r in rs]
            per = defaultdict(list)
            for r in rs:
                per[r["image"]].append(r)
            rho = [
                spearmanr([r[est] for r in v], [r["true"] for r in v]).statistic
                for v in per.values()
                if len(v) > 2
            ]
            rho = [x for x in rho if not math.isnan(x)]
            cells.append(
                f"{spp} spp: within 1.5x {sum(ok) / len(ok):.3f} of {len(ok)}, "
                f"rho {sum(rho) / len(rho):.3f}"
            )
        print(f"{est:8s} " + "; ".join(cells))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="*", type=Path, help="pairs of render folders")
    ap.add_argument("--methods", default="kpcn,nlm,cross-bilateral,kalantari-xbf,oidn")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--from-json", nargs="+", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.from_json:
        recs = [r for f in args.from_json for r in json.loads(f.read_text())]
    else:
        if not args.runs or len(args.runs) % 2:
            ap.error("give the render folders in pairs (two seeds of the same scenes)")
        torch.set_num_threads(args.threads)
        recs = []
        for a, b in zip(args.runs[::2], args.runs[1::2]):
            recs += records(a, b, args.methods.split(","))
        if args.json:
            args.json.write_text(json.dumps(recs, indent=1))
    analyse(recs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
