"""Throughput of the custom integrators against Mitsuba's ``path`` on one scene.

Renders the Cornell box of ``mi.cornell_box()`` (optionally with its two boxes replaced by a
glass and a rough-metal sphere, ``--glass``, so that the ``caustics`` switch has something to
cut) with

* ``path d8``: Mitsuba's ``path``, ``max_depth = 8`` (the reference of the ratio column);
* ``path d2``: Mitsuba's ``path``, ``max_depth = 2`` (direct light only);
* ``mcd_path d8``: ours, caustics on (same estimator as ``path d8``);
* ``mcd_path d8 -c``: ours, caustics off;
* ``mcd_ao``: ours, one occlusion ray per sample, radius ``--ao-radius``;

in ``llvm_ad_rgb`` (``--res`` × ``--res``, ``--spp``) and ``scalar_rgb`` (a smaller image,
``--scalar-res``, ``--scalar-spp``: the Python integrators run per sample in the interpreter
there). Each cell is the median of ``--repeats`` timed renders after one warm-up render (which
pays the LLVM kernel compilation), the integrators taking turns so that load from other
processes hits them alike; the table gives samples per second and the throughput ratio to
``path d8`` in the same variant and run (these machines are noisy: compare ratios).

    python benchmarks/bench_integrators.py [--res 256] [--spp 16] [--scalar-res 32]
        [--scalar-spp 4] [--repeats 3] [--glass] [--variants llvm_ad_rgb,scalar_rgb]
        [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from typing import Any

import drjit as dr
import mitsuba as mi

from mcdenoise.io.atomic import write_text_atomic
from mcdenoise.render.integrators import ao_integrator, path_integrator, use_variant


def integrators(ao_radius: float) -> dict[str, dict[str, Any]]:
    """The benchmarked integrator dicts, the reference first."""
    return {
        "path d8": {"type": "path", "max_depth": 8},
        "path d2": {"type": "path", "max_depth": 2},
        "mcd_path d8": path_integrator(max_depth=8),
        "mcd_path d8 -c": path_integrator(max_depth=8, caustics=False),
        "mcd_ao": ao_integrator(radius=ao_radius),
    }


def cornell(res: int, glass: bool) -> Any:
    """``mi.cornell_box()`` at ``res`` × ``res`` (box filter), optionally with glass/metal spheres."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=res, height=res, rfilter={"type": "box"})
    if glass:
        del d["small-box"], d["large-box"]
        d["glass"] = {
            "type": "sphere",
            "center": [0.35, -0.65, 0.3],
            "radius": 0.3,
            "bsdf": {"type": "dielectric"},
        }
        d["metal"] = {
            "type": "sphere",
            "center": [-0.4, -0.7, -0.2],
            "radius": 0.25,
            "bsdf": {"type": "roughconductor", "alpha": 0.2},
        }
    return mi.load_dict(d)


def time_render(scene: Any, integrator: Any, spp: int, seed: int) -> float:
    """Wall seconds of one render, kernels finished (LLVM launches are asynchronous)."""
    start = time.perf_counter()
    img = mi.render(scene, integrator=integrator, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - start


def bench_variant(
    variant: str, res: int, spp: int, repeats: int, glass: bool, ao_radius: float
) -> list[dict[str, Any]]:
    """Time every integrator ``repeats`` times, round-robin (so load spikes hit all alike)."""
    use_variant(variant)
    scene = cornell(res, glass)
    loaded = {name: mi.load_dict(spec) for name, spec in integrators(ao_radius).items()}
    for integ in loaded.values():
        time_render(scene, integ, spp, seed=0)  # warm-up / kernel compilation
    times: dict[str, list[float]] = {name: [] for name in loaded}
    for k in range(repeats):
        for name, integ in loaded.items():
            times[name].append(time_render(scene, integ, spp, seed=1 + k))
    samples = res * res * spp
    rows = [
        {
            "variant": variant,
            "integrator": name,
            "res": res,
            "spp": spp,
            "seconds": statistics.median(ts),
            "samples_per_s": samples / statistics.median(ts),
        }
        for name, ts in times.items()
    ]
    ref = rows[0]["samples_per_s"]
    for row in rows:
        row["ratio_to_path_d8"] = row["samples_per_s"] / ref
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--scalar-res", type=int, default=32)
    parser.add_argument("--scalar-spp", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--glass", action="store_true", help="glass + metal spheres, no boxes")
    parser.add_argument("--ao-radius", type=float, default=0.5)
    parser.add_argument("--variants", default="llvm_ad_rgb,scalar_rgb")
    parser.add_argument("--json", help="also write the rows as JSON here")
    args = parser.parse_args(argv)

    rows: list[dict[str, Any]] = []
    for variant in args.variants.split(","):
        scalar = variant.startswith("scalar")
        res = args.scalar_res if scalar else args.res
        spp = args.scalar_spp if scalar else args.spp
        rows += bench_variant(variant, res, spp, args.repeats, args.glass, args.ao_radius)

    scene = "cornell + glass/metal spheres" if args.glass else "mi.cornell_box()"
    print(f"scene: {scene}; median of {args.repeats} renders after a warm-up")
    print(
        f"{'variant':12s} {'integrator':15s} {'size':>13s} {'s':>8s} {'Msamples/s':>11s} {'vs path d8':>10s}"
    )
    for r in rows:
        size = f"{r['res']}^2x{r['spp']}spp"
        print(
            f"{r['variant']:12s} {r['integrator']:15s} {size:>13s} {r['seconds']:8.3f} "
            f"{r['samples_per_s'] / 1e6:11.3f} {r['ratio_to_path_d8']:10.2f}"
        )
    if args.json:
        write_text_atomic(args.json, json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
