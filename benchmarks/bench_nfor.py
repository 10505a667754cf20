"""NFOR (Bitterli et al. 2016) beside OIDN, kpcn and kalantari-xbf on held-out renders with halves.

For every image of a held-out set rendered with half buffers (``mcdenoise render --halves``,
the default; recipe: ``data/recipes/nfor.md``) at each spp level it measures the relMSE
(ε = 0.01, linear HDR RGB) against the reference and the seconds per megapixel of

* ``noisy``; ``nfor`` (:func:`mcdenoise.methods.nfor.denoise_nfor`, Tungsten's settings);
* ``oidn`` (when pyoidn is installed), ``kpcn`` and ``kalantari-xbf`` through
  :func:`mcdenoise.denoise.denoise` (their defaults; they read the full buffer only);

and prints per spp the geometric mean over images and each method's ratio to OIDN's
(geometric mean of the per-image ratios), then the median s/MP (whole method, one thread
unless ``--threads``). Images without albedo are skipped (kpcn and the shipped Kalantari
models need it). ``--ref-dir`` reads the references from another folder with the same image
ids (a set re-rendered with halves can reuse the 2048-spp references of
``data/generated/heldout``); ``--images`` picks images by name, ``--limit`` caps their count. ``--from-log LOG ...`` prints
the summary of the per-image lines of earlier runs' output (runs cut short, or split over
processes) without running anything.

    python benchmarks/bench_nfor.py [--heldout DIR] [--ref-dir DIR] [--spp 4,16,64]
        [--images a,b] [--limit N] [--threads 1] [--json OUT]
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
from mcdenoise.methods.nfor import denoise_nfor
from mcdenoise.registry import get_method
from mcdenoise.train.patches import scan_dataset

REPO = Path(__file__).resolve().parents[1]
PEERS = ("oidn", "kpcn", "kalantari-xbf")


def run_nfor(b) -> tuple[torch.Tensor, float]:
    t0 = time.perf_counter()
    out = denoise_nfor(b)
    return out, time.perf_counter() - t0


def parse_logs(paths: list[Path]) -> dict[str, dict[str, float]]:
    """The per-image rows printed by earlier runs: ``IMAGE SPP spp  name value ...``."""
    rows: dict[str, dict[str, float]] = {}
    for path in paths:
        for line in path.read_text().splitlines():
            parts = line.split("(")[0].split()
            if len(parts) < 5 or parts[2] != "spp":
                continue
            vals = parts[3:]
            rows[f"{parts[0]}@{parts[1]}"] = {
                vals[i]: float(vals[i + 1]) for i in range(0, len(vals) - 1, 2)
            }
    return rows


def summary(rows: dict[str, dict[str, float]], spps: list[int], n_images: int) -> None:
    """Geometric means per spp and ratios to OIDN (per image, then the geometric mean)."""
    labels = [k for k in ("noisy", "nfor", *PEERS) if all(k in r for r in rows.values())]
    print(f"\nrelMSE (eps 0.01, linear RGB), geometric mean over {n_images} images; / oidn:")
    print(f"{'spp':>4}{'images':>7}" + "".join(f"{k:>15}" for k in labels))
    for s in spps:
        sel = [r for k, r in rows.items() if k.endswith(f"@{s}")]
        if not sel:
            continue
        print(
            f"{s:>4}{len(sel):>7}"
            + "".join(f"{geometric_mean([r[k] for r in sel]):>15.5f}" for k in labels)
        )
        if "oidn" in labels:
            print(
                " " * 11
                + "".join(
                    f"{geometric_mean([r[k] / r['oidn'] for r in sel]):>15.3f}" for k in labels
                )
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--heldout", type=Path, default=REPO / "data/generated/heldout-halves")
    ap.add_argument("--ref-dir", type=Path, default=None)
    ap.add_argument("--spp", default="4,16,64")
    ap.add_argument("--images", default="", help="comma-separated image names (default: all)")
    ap.add_argument("--limit", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--from-log", type=Path, nargs="+", default=None)
    args = ap.parse_args(argv)
    if args.from_log:
        rows = parse_logs(args.from_log)
        summary(
            rows, sorted({int(k.split("@")[1]) for k in rows}), len({k.split("@")[0] for k in rows})
        )
        return 0
    torch.set_num_threads(args.threads)
    spps = {int(s) for s in args.spp.split(",")}
    peers = [p for p in PEERS if get_method(p).unavailable() is None]
    entries = [e for e in scan_dataset(args.heldout) if e.spp in spps]
    wanted = [s for s in args.images.split(",") if s]
    images = sorted({e.image for e in entries if not wanted or e.image in wanted})
    rows: dict[str, dict[str, float]] = {}
    secs: dict[str, list[float]] = {}
    kept: list[str] = []
    for image in images:
        if args.limit and len(kept) >= args.limit:
            break
        mine = sorted((e for e in entries if e.image == image), key=lambda e: e.spp or 0)
        reference = args.ref_dir / mine[0].reference.name if args.ref_dir else mine[0].reference
        if not reference.is_file():
            print(f"{image}: no reference {reference}, skipped")
            continue
        ref = load_buffers(reference)["color"]
        for e in mine:
            b = load_buffers(e.path, part=e.part)
            if "albedo" not in b or "color_a" not in b:
                print(f"{image}: no albedo or no halves, skipped")
                break
            if image not in kept:
                kept.append(image)
            mp = b.shape[0] * b.shape[1] / 1e6
            row = {"noisy": relmse(b["color"], ref)}
            out, sec = run_nfor(b)
            row["nfor"] = relmse(out, ref)
            secs.setdefault("nfor", []).append(sec / mp)
            for p in peers:
                res = denoise(b, p, device="cpu")
                row[p] = relmse(res.image, ref)
                secs.setdefault(p, []).append(res.seconds / mp)
            rows[f"{image}@{e.spp}"] = row
            print(
                f"{image:<22}{e.spp:>4} spp  "
                + "  ".join(f"{k} {v:.5f}" for k, v in row.items())
                + f"  (nfor {sec:.1f} s)",
                flush=True,
            )
    summary(rows, sorted(spps), len(kept))
    print(
        f"\nseconds per megapixel (median, {args.threads} thread(s)): "
        + ", ".join(f"{k} {statistics.median(v):.1f}" for k, v in secs.items())
    )
    if args.json:
        args.json.write_text(json.dumps({"images": rows, "seconds_per_mp": secs}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
