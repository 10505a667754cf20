"""Render throughput of the data generator per Mitsuba variant (samples per second).

Renders one scene spec (default: the curated Cornell-style box, direct + indirect, depth 8)
through exactly the stack ``mcdenoise render`` uses (``moment`` -> ``aov`` with the plan's
features -> the plan's radiance integrator, box filter, reading the film back into moments)
for each variant that works here. Per variant: one warm-up pass (its seconds include the
LLVM/CUDA kernel compilation and are printed as ``first``), then the median of ``--repeats``
timed passes of ``--spp`` samples per pixel at ``--res``. Throughput = width * height * spp
/ median seconds; the last column is the ratio to ``scalar_rgb`` measured in the same run.

    python benchmarks/bench_render.py [--spec data/scenes/cornell.toml] [--res 128]
        [--spp 64] [--repeats 3] [--variants scalar_rgb,llvm_ad_rgb] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from mcdenoise.render.effects import plan_effects
from mcdenoise.render.mitsuba_setup import ensure_variant, variant_works
from mcdenoise.render.moments import moment_integrator, render_moments
from mcdenoise.render.scene_spec import load_spec
from mcdenoise.render.scenes import scene_dict

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SPEC = ROOT / "data" / "scenes" / "cornell.toml"


def bench_variant(
    variant: str, spec_path: Path, res: int, spp: int, repeats: int
) -> dict[str, Any]:
    """Seconds of the first (compiling) and of ``repeats`` warm passes of one variant."""
    import mitsuba as mi

    ensure_variant(variant)
    spec = load_spec(spec_path)
    plan = plan_effects(spec)
    scene = mi.load_dict(
        scene_dict(
            spec,
            plan,
            width=res,
            height=res,
            integrator=moment_integrator(plan.integrator_dict(), plan.features),
        )
    )
    t0 = time.perf_counter()
    render_moments(scene, spp, 1, plan.features)
    first = time.perf_counter() - t0
    times = []
    for k in range(repeats):
        t0 = time.perf_counter()
        render_moments(scene, spp, 2 + k, plan.features)
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    return {
        "variant": variant,
        "plan": plan.describe(),
        "first_seconds": first,
        "seconds": times,
        "median_seconds": median,
        "samples_per_second": res * res * spp / median,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", type=Path, default=DEFAULT_SPEC)
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--variants", default="scalar_rgb,llvm_ad_rgb,cuda_ad_rgb")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    rows = []
    for v in [s.strip() for s in args.variants.split(",") if s.strip()]:
        if not v.startswith("scalar") and not variant_works(v):
            print(f"{v:<12} does not work here, skipped")
            continue
        rows.append(bench_variant(v, args.spec, args.res, args.spp, args.repeats))
    base = next((r for r in rows if r["variant"] == "scalar_rgb"), None)
    print(
        f"{args.spec.name}: {args.res}x{args.res}, {args.spp} spp per pass, "
        f"median of {args.repeats}; {rows[0]['plan'] if rows else ''}"
    )
    print(f"{'variant':<12} {'first s':>8} {'median s':>9} {'Msamples/s':>11} {'x scalar':>9}")
    for r in rows:
        ratio = r["samples_per_second"] / base["samples_per_second"] if base else float("nan")
        print(
            f"{r['variant']:<12} {r['first_seconds']:8.3f} {r['median_seconds']:9.3f} "
            f"{r['samples_per_second'] / 1e6:11.3f} {ratio:9.2f}"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
