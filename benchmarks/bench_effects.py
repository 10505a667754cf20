"""What the declared effects cost: the same geometry rendered as AO, direct only and full paths.

Loads one scene spec (default: the curated Cornell-style box) and renders the SAME geometry,
materials, camera, resolution and spp under three effect lists:

* ``ao``: ``["ao"]``, the ``mcd_ao`` integrator (one occlusion ray per sample);
* ``direct``: ``["direct"]`` (plus ``glossy`` when a glossy material is present, which is a
  declaration, not a switch): path depth 2;
* ``full``: every transport effect the geometry allows (``direct``, ``indirect``, ``glossy``
  if glossy materials, ``caustics`` if specular ones), ``max_depth`` 8, Russian roulette
  from depth 5.

(``dof`` is kept in all three when the camera is a thin lens.) For each it prints the median
of ``--repeats`` timed renders after one warm-up render (which also pays the LLVM/CUDA
kernel compilation), the throughput in samples per second, and the ratio of the full render's
time to it. Target: AO and direct each >= 3x cheaper than full paths (``--check`` exits 1
when missed). By default only the radiance integrator is timed, so the ratios are those of
the light transport; ``--buffers`` times what ``mcdenoise render`` runs (``moment`` -> ``aov``
with the plan's feature buffers -> radiance), whose fixed per-sample cost narrows them.

The target holds for closed scenes such as the Cornell box, where depth-8 paths do bounce
about 8 times. In open scenes most paths escape after a bounce or two, so full paths cost
only 2-2.5x direct lighting there (e.g. ``--spec data/scenes/glossy_env.toml``): that is
what the light does, not overhead.

    python benchmarks/bench_effects.py [--spec data/scenes/cornell.toml] [--res 256]
        [--spp 64] [--repeats 5] [--variant auto] [--ao-radius R] [--buffers] [--check]
        [--json out.json]
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
from mcdenoise.render.mitsuba_setup import ensure_variant
from mcdenoise.render.scene_spec import SceneSpec, load_spec, parse_spec
from mcdenoise.render.scenes import scene_dict

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SPEC = ROOT / "data" / "scenes" / "cornell.toml"
TARGET = 3.0  # full / cheap time ratio the issue asks for


def effect_variants(spec: SceneSpec, ao_radius: float | None) -> dict[str, SceneSpec]:
    """The spec with effects ``ao``, ``direct`` and ``full`` (same everything else)."""
    mats = [o.material for o in spec.objects]
    glossy = ["glossy"] if any(m.glossy for m in mats) else []
    caustics = ["caustics"] if any(m.specular_lobe for m in mats) else []
    dof = ["dof"] if spec.camera.type == "thinlens" else []
    base = spec.to_dict()
    base.pop("source", None)
    radius = ao_radius or spec.render.ao_radius or 0.5 * _size(spec)
    lists = {
        "ao": (["ao", *dof], {"ao_radius": radius}),
        "direct": (["direct", *glossy, *dof], {}),
        "full": (["direct", "indirect", *glossy, *caustics, *dof], {"max_depth": 8, "rr_depth": 5}),
    }
    out = {}
    for key, (effects, render) in lists.items():
        d = {**base, "effects": effects, "render": {**base["render"], **render}}
        d["name"] = f"{spec.name}-{key}"
        out[key] = parse_spec(d, base=Path(spec.source).parent if spec.source else None)
    return out


def _size(spec: SceneSpec) -> float:
    from mcdenoise.render.scenes import scene_bounds

    return scene_bounds(spec)[1]


def time_renders(scenes: dict[str, Any], spp: int, repeats: int) -> dict[str, list[float]]:
    """Seconds of ``repeats`` renders of each scene after one warm-up render each (kernel
    compilation). The scenes take turns in every round, so a load change on the shared
    machine hits all of them alike; the image is copied to numpy, so the JIT variants' lazy
    evaluation is included."""
    import mitsuba as mi
    import numpy as np

    for scene in scenes.values():
        np.asarray(mi.render(scene, spp=spp, seed=0))
    times: dict[str, list[float]] = {k: [] for k in scenes}
    for i in range(repeats):
        for key, scene in scenes.items():
            t0 = time.perf_counter()
            np.asarray(mi.render(scene, spp=spp, seed=i + 1))
            times[key].append(time.perf_counter() - t0)
    return times


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", type=Path, default=DEFAULT_SPEC)
    ap.add_argument("--res", type=int, default=256, help="image width = height")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--variant", default="auto")
    ap.add_argument(
        "--ao-radius", type=float, default=None, help="default: the spec's or 0.5 × scene radius"
    )
    ap.add_argument("--buffers", action="store_true", help="time the moment/aov stack too")
    ap.add_argument("--check", action="store_true", help="exit 1 when the target is missed")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args(argv)

    import mitsuba as mi

    variant = ensure_variant(args.variant)
    spec = load_spec(args.spec)
    loaded, plans = {}, {}
    for key, s in effect_variants(spec, args.ao_radius).items():
        plan = plans[key] = plan_effects(s)
        integrator = plan.integrator_dict()
        if args.buffers:
            from mcdenoise.render.moments import moment_integrator

            integrator = moment_integrator(integrator, plan.features)
        loaded[key] = mi.load_dict(
            scene_dict(s, plan, width=args.res, height=args.res, integrator=integrator)
        )
    times = time_renders(loaded, args.spp, args.repeats)
    rows = [
        {
            "effects": key,
            "plan": plans[key].describe(),
            "seconds": statistics.median(times[key]),
            "all_seconds": times[key],
        }
        for key in loaded
    ]
    full = next(r for r in rows if r["effects"] == "full")["seconds"]
    samples = args.res * args.res * args.spp
    print(
        f"{spec.name}: {args.res}x{args.res}, {args.spp} spp, Mitsuba {mi.__version__} {variant}, "
        f"median of {args.repeats} after a warm-up"
        + (", moment/aov buffers included" if args.buffers else ", radiance only")
    )
    print(f"{'effects':8} {'seconds':>8} {'Msamples/s':>11} {'full/this':>10}  plan")
    ok = True
    for r in rows:
        r["samples_per_second"] = samples / r["seconds"]
        r["speedup_vs_full"] = full / r["seconds"]
        if r["effects"] != "full":
            ok &= r["speedup_vs_full"] >= TARGET
        print(
            f"{r['effects']:8} {r['seconds']:8.3f} {r['samples_per_second'] / 1e6:11.2f} "
            f"{r['speedup_vs_full']:9.1f}x  {r['plan']}"
        )
    print(f"target: ao and direct >= {TARGET:g}x cheaper than full: {'met' if ok else 'NOT met'}")
    if args.json:
        from mcdenoise.io.atomic import write_text_atomic

        write_text_atomic(
            args.json,
            json.dumps(
                {
                    "spec": str(args.spec),
                    "variant": variant,
                    "res": args.res,
                    "spp": args.spp,
                    "rows": rows,
                },
                indent=2,
            ),
        )
    return 1 if args.check and not ok else 0


if __name__ == "__main__":
    sys.exit(main())
