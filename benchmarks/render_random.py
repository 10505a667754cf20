"""Render procedural scenes of a named random-scene distribution (``default`` or ``wide``).

``mcdenoise render --random N --seed S`` always draws from the default distribution
(:data:`mcdenoise.render.random_scenes.distribution.DISTRIBUTION`); this script renders scenes
of any of :data:`~mcdenoise.render.random_scenes.distribution.DISTRIBUTIONS` (``wide``: more
and stronger depth of field, more metal, no AO; issue 21) into the same layout, so that
``mcdenoise train`` reads them like any render. Image ids are ``random_<name>_s<seed>_<k>``,
the scenes ``random_scene(seed, k, distribution=...)`` for ``k = start .. start + count - 1``;
re-running skips finished images (as ``mcdenoise render`` does).

    python benchmarks/render_random.py --distribution wide --count 60 --seed 3000 \\
        --res 128 --spp 4,16,64 --ref-spp 1024 -o data/generated/kpcn-wide --threads 1
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from mcdenoise.errors import InputError
from mcdenoise.render.config import RenderConfig, RenderError
from mcdenoise.render.generate import generate
from mcdenoise.render.jobs import jobs_from_specs
from mcdenoise.render.random_scenes import random_scene
from mcdenoise.render.random_scenes.distribution import DISTRIBUTIONS
from mcdenoise.threads import set_render_threads


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--distribution", choices=sorted(DISTRIBUTIONS), default="wide")
    ap.add_argument("--count", type=int, required=True)
    ap.add_argument("--seed", type=int, default=3000)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", default="4,16,64")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("-o", "--out", type=Path, required=True)
    args = ap.parse_args(argv)
    try:
        spp = tuple(int(x) for x in args.spp.split(","))
        dist = DISTRIBUTIONS[args.distribution]
        specs = []
        for k in range(args.start, args.start + args.count):
            spec = random_scene(args.seed, k, distribution=dist).spec
            name = f"random_{args.distribution}_s{args.seed}_{k:05d}"
            specs.append(dataclasses.replace(spec, name=name))
        jobs = jobs_from_specs(specs, seed=args.seed, start=args.start)
        set_render_threads(args.threads)
        config = RenderConfig(
            out=args.out,
            width=args.res,
            height=args.res,
            spp=spp,
            ref_spp=args.ref_spp,
            seed=args.seed,
            progress="lines",
        )
        result = generate(jobs, config)
    except (InputError, RenderError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(
        f"rendered {len(result.rendered)}, skipped {len(result.skipped)} of {len(jobs)} "
        f"({args.distribution}, seed {args.seed}) in {result.seconds:.1f} s; "
        f"manifest: {result.manifest}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
