"""Half buffers and the reference-free error estimate (issue 24): what halves cost to render,
and how well the estimate matches the true error on held-out renders.

``python benchmarks/bench_estimate.py render-cost [--scenes ...] [--reps 3]``
    The extra render time of ``--halves``: every scene is loaded once (``llvm_ad_rgb``, 128²,
    4/16/64 spp, one thread), rendered once per mode to compile the kernels, then ``--reps``
    times per mode, alternating, so load on a shared machine hits both alike; the time is the
    noisy levels' render seconds without Dr.Jit's kernel compilation (``jit_seconds``).
    Prints per scene the median seconds with and without halves and the ratio, and the ratio
    of the sums.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CURATED = ("cornell", "dof_row", "textured_floors", "glossy_env", "sun_outdoor")


def _level_seconds(rendered) -> float:
    return sum(r["increment_seconds"] - r.get("jit_seconds", 0.0) for r in rendered.level_records)


def render_cost(args: argparse.Namespace) -> int:
    import tempfile

    from mcdenoise.render.config import RenderConfig
    from mcdenoise.render.jobs import jobs_from_specs
    from mcdenoise.render.passes import render_image
    from mcdenoise.render.scenes import ensure_variant
    from mcdenoise.render.spec import load_spec
    from mcdenoise.threads import set_render_threads

    variant = ensure_variant(args.variant)
    set_render_threads(args.threads)
    specs = [load_spec(ROOT / "data" / "scenes" / f"{s}.toml") for s in args.scenes]
    spp = tuple(int(v) for v in args.spp.split(","))
    totals = {False: 0.0, True: 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        cfgs = {
            h: RenderConfig(
                out=Path(tmp),
                width=args.res,
                height=args.res,
                spp=spp,
                ref_spp=1,
                variant=variant,
                halves=h,
            )
            for h in (False, True)
        }
        print(f"{'scene':18s} {'plain s':>8s} {'halves s':>8s} {'ratio':>6s}")
        for job in jobs_from_specs(specs, seed=args.seed):
            times: dict[bool, list[float]] = {False: [], True: []}
            for rep in range(args.reps + 1):
                for h in (False, True) if rep % 2 == 0 else (True, False):
                    t = _level_seconds(render_image(job, cfgs[h], variant))
                    if rep:  # the first round compiles the kernels of both modes
                        times[h].append(t)
            med = {h: statistics.median(v) for h, v in times.items()}
            for h in med:
                totals[h] += med[h]
            print(f"{job.id:18s} {med[False]:8.3f} {med[True]:8.3f} {med[True] / med[False]:6.3f}")
    print(
        f"{'all':18s} {totals[False]:8.3f} {totals[True]:8.3f} {totals[True] / totals[False]:6.3f}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    rc = sub.add_parser("render-cost", help="extra render time of --halves")
    rc.add_argument("--scenes", nargs="+", default=list(CURATED))
    rc.add_argument("--reps", type=int, default=3)
    rc.add_argument("--res", type=int, default=128)
    rc.add_argument("--spp", default="4,16,64")
    rc.add_argument("--seed", type=int, default=0)
    rc.add_argument("--threads", type=int, default=1)
    rc.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args(argv)
    return render_cost(args)


if __name__ == "__main__":
    sys.exit(main())
