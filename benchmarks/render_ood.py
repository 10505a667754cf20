"""Render the out-of-distribution benchmark set (``data/scenes/ood``): one command.

Never used for training or tuning (see ``data/scenes/ood/README.md``). The recipe and the
times it took are in ``data/recipes/ood.md``; the benchmark that reads the result is
``benchmarks/bench_ood.py``.

What it writes under ``--out`` (default ``data/generated/ood``, git-ignored):

``r256/``
    every spec at 256×256 in the canonical ``mcdenoise render`` layout (``<id>.exr`` with
    parts ``spp4``, ``spp16``, ``spp64``: colour, albedo, normal, depth, position and their
    variances; ``ref/<id>.exr``; ``manifest.json``), rendered by ``mcdenoise render``.
``r512/``
    the subset :data:`SUBSET_512` at 512×512, the same way (fewer reference samples).
``aov256/``, ``aov512/``
    plain Mitsuba ``aov`` files of the same images: ``<id>_spp4.exr`` ... rendered by Mitsuba's
    own ``aov`` integrator (``aovs = "albedo:albedo,normal:sh_normal,depth:depth,
    position:position"``) around the scene's radiance integrator, one ``mi.render`` call per
    level (4, 16 and 64 spp, each its own sampler seed, independent of the canonical levels'
    samples), and written by Mitsuba itself (``film.bitmap().write``): channels ``R,G,B``,
    ``albedo.R/G/B``, ``normal.X/Y/Z``, ``depth.T``, ``position.X/Y/Z``, header
    ``generatedBy = "Mitsuba version 3.9.1"``, no variance, no sample count. The film is the
    canonical one (``hdrfilm``, box filter, float32, independent sampler) so the canonical
    reference ``r256/ref/<id>.exr`` is the reference of these files too.

Re-running renders only what is missing (``mcdenoise render`` resumes; an aov file that exists
is kept). ``--threads`` is the Dr.Jit thread count of every render (default 2: the recipe's
2 cores).

    python benchmarks/render_ood.py [--out data/generated/ood] [--ref-spp 2048]
        [--ref-spp-512 1024] [--threads 2] [--skip-512]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SPECS = REPO / "data" / "scenes" / "ood"
OUT = REPO / "data" / "generated" / "ood"
LEVELS = (4, 16, 64)
#: Scenes also rendered at 512×512 (where resolution, thin geometry and texture detail differ
#: most from the 128×128 training renders).
SUBSET_512 = ("dof_extreme", "thin_wires", "fine_texture", "metals_rough")
#: The ``aov`` integrator's outputs in the plain copies: name -> Mitsuba AOV type.
PLAIN_AOVS = (("albedo", "albedo"), ("normal", "sh_normal"), ("depth", "depth"),
              ("position", "position"))  # fmt: skip
#: Sampler seeds of the plain copies: image seed + this + level (the canonical noisy and
#: reference passes use image seed + 0 .. 2·passes, far below).
PLAIN_SEED_OFFSET = 1 << 20


def plain_file(image_id: str, spp: int) -> str:
    return f"{image_id}_spp{spp}.exr"


def render_canonical(specs: list[Path], out: Path, res: int, ref_spp: int, threads: int) -> None:
    """``mcdenoise render`` of ``specs`` into ``out`` (resumes; refuses other settings)."""
    cmd = [
        sys.executable, "-m", "mcdenoise_cli.main", "render", *map(str, specs), "-o", str(out),
        "--res", str(res), "--spp", ",".join(map(str, LEVELS)), "--ref-spp", str(ref_spp),
        "--threads", str(threads), "--no-progress",
    ]  # fmt: skip
    print("$", " ".join(cmd[2:]), flush=True)
    subprocess.run(cmd, check=True)


def plain_integrator(radiance: dict[str, Any]) -> dict[str, Any]:
    """Mitsuba's ``aov`` integrator around ``radiance`` (unnamed, so colour is ``R,G,B``)."""
    return {
        "type": "aov",
        "aovs": ",".join(f"{name}:{kind}" for name, kind in PLAIN_AOVS),
        "integrator": radiance,
    }


def render_plain(folder: Path, out: Path, threads: int) -> list[Path]:
    """The plain Mitsuba ``aov`` files of every image of the canonical ``folder``."""
    import drjit as dr
    import mitsuba as mi

    from mcdenoise.render.effects import plan_effects
    from mcdenoise.render.integrators import register_integrators
    from mcdenoise.render.mitsuba_setup import ensure_variant, load_scene
    from mcdenoise.render.scene_spec import parse_spec
    from mcdenoise.render.scenes import scene_dict

    manifest = json.loads((folder / "manifest.json").read_text())
    # the variant that rendered the canonical images (the same estimator as the reference)
    used = {i.get("variant") for i in manifest["images"]} - {None}
    variant = ensure_variant(used.pop() if len(used) == 1 else "auto")
    register_integrators()
    # at least 2: with one Dr.Jit thread, Mitsuba 3.9.1 never returns from Bitmap.write of an
    # EXR (nor from loading an envmap file: mcdenoise.render.mitsuba_setup.LOAD_THREADS)
    dr.set_thread_count(max(threads, 2))
    width, height = manifest["settings"]["width"], manifest["settings"]["height"]
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for image in manifest["images"]:
        todo = [s for s in LEVELS if not (out / plain_file(image["id"], s)).is_file()]
        if not todo:
            continue
        # the spec as it was rendered (the manifest's copy), not the file as it is now
        spec = parse_spec(image["spec"], source=image["source"], base=REPO)
        plan = plan_effects(spec)
        d = scene_dict(spec, plan, width=width, height=height,
                       integrator=plain_integrator(plan.integrator_dict()))  # fmt: skip
        scene = load_scene(d)
        for spp in todo:
            t0 = time.perf_counter()
            mi.render(scene, spp=spp, seed=int(image["seed"]) + PLAIN_SEED_OFFSET + spp)
            bitmap = scene.sensors()[0].film().bitmap(raw=False)
            final = out / plain_file(image["id"], spp)
            tmp = final.with_name(f".{final.stem}.{os.getpid()}.tmp.exr")
            bitmap.write(str(tmp))
            os.replace(tmp, final)
            written.append(final)
            print(f"  {final.relative_to(out.parent)} ({time.perf_counter() - t0:.1f} s, "
                  f"{variant})", flush=True)  # fmt: skip
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--ref-spp", type=int, default=2048, help="reference spp at 256x256")
    ap.add_argument("--ref-spp-512", type=int, default=1024, help="reference spp at 512x512")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-512", action="store_true", help="only the 256x256 set")
    args = ap.parse_args(argv)
    specs = sorted(SPECS.glob("*.toml"))
    t0 = time.perf_counter()
    render_canonical(specs, args.out / "r256", 256, args.ref_spp, args.threads)
    t1 = time.perf_counter()
    print(f"r256: {t1 - t0:.0f} s", flush=True)
    render_plain(args.out / "r256", args.out / "aov256", args.threads)
    t2 = time.perf_counter()
    print(f"aov256: {t2 - t1:.0f} s", flush=True)
    if not args.skip_512:
        subset = [SPECS / f"{name}.toml" for name in SUBSET_512]
        render_canonical(subset, args.out / "r512", 512, args.ref_spp_512, args.threads)
        t3 = time.perf_counter()
        print(f"r512: {t3 - t2:.0f} s", flush=True)
        render_plain(args.out / "r512", args.out / "aov512", args.threads)
        print(f"aov512: {time.perf_counter() - t3:.0f} s", flush=True)
    print(f"total: {time.perf_counter() - t0:.0f} s; data in {args.out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
