"""Screen-space AO against the ray-traced reference: SSIM, relMSE and milliseconds per method.

Reads a render folder of AO scenes (``mcdenoise render <ao specs> -o DIR``), runs ``ssao``,
``hbao``, ``alchemy``, ``gtao`` and ``nnao`` (``--nnao-model``: default the shipped one) on the lowest spp level's G-buffer (they ignore the
colour, so the level does not matter) and prints, per image and method, SSIM and relMSE
against ``DIR/ref/<id>.exr`` and the wall time; the noisy ray-traced levels are listed as the
peer in the same run. Renders made before the camera was recorded in the header get it from
the manifest (the spec's camera and ``render.ao_radius``).

    python benchmarks/bench_ao.py DIR [--threads 1] [--repeat 2]
    python benchmarks/bench_ao.py --speed 512 [--threads 1]
    python benchmarks/bench_ao.py DIR --random-ao 6 --seed 3000   # render them first
    python benchmarks/bench_ao.py DIR --val-of RUN --nnao-param blur=false

``--random-ao N`` first renders (into DIR, 128×96, 4/16/64 spp, 1024-spp references) the
first N scenes of the random generator with ``--seed`` whose archetype is ``ao``: a held-out
set no AO parameter was chosen on; with ``--render-only`` it stops there (the nnao training
set of ``data/recipes/nnao.md``).

``--val-of RUN`` keeps only the validation images of the nnao training run ``RUN`` (its model
card's ``val_images``: choices about nnao are made there, never on the held-out sets); given
again (``--val-of A --val-of B``), the validation images of A that B did not train on (to
compare two runs on images neither saw);
``--nnao-param KEY=VALUE`` (repeatable) sets nnao's parameters (e.g. ``blur=false``). The
last lines give each method's mean SSIM and relMSE over the images.

``--speed N`` times the five methods alone on a synthetic N×N G-buffer (a floor and two
walls seen from a camera pitched 25° down) and prints CPU ms per frame and per megapixel.

Times are for the image size rendered; ``ms/MP`` scales them to one megapixel (the
methods are linear in the pixel count). For the screen-space methods ``cpu ms`` is the
process CPU time of the best run: with one thread it is what an idle core would take, and it
stays meaningful when other jobs share the cores (wall time then grows with the load).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from mcdenoise.ao import ESTIMATORS
from mcdenoise.ao.geometry import ViewGBuffer, ray_directions, view_gbuffer
from mcdenoise.eval.metrics import relmse, ssim
from mcdenoise.io import load_buffers
from mcdenoise.io.camera import CAMERA_ATTR
from mcdenoise.methods.ao import METHODS
from mcdenoise.methods.nnao import METHOD as NNAO
from mcdenoise.methods.nnao import load_nnao, nnao
from mcdenoise.models.weights import SHIPPED
from mcdenoise.render.scene_spec import Camera
from mcdenoise.render.scenes import camera_metadata


def _camera_from_manifest(record: dict) -> str:
    cam = record["spec"]["camera"]
    camera = Camera(
        type=cam.get("type", "pinhole"),
        origin=tuple(cam["origin"]),
        target=tuple(cam["target"]),
        up=tuple(cam.get("up", (0.0, 1.0, 0.0))),
        fov=float(cam["fov"]),
    )
    radius = record["spec"]["render"]["ao_radius"]
    return json.dumps(camera_metadata(camera, ao_radius=radius))


def synthetic_gbuffer(size: int) -> ViewGBuffer:
    """A floor (y = 1, view frame y down) and two walls (z = 3, x = 1.5), camera pitched
    25° down, horizontal fov 60°: every pixel sees a surface, corners included."""
    f = size / (2.0 * math.tan(math.radians(30.0)))
    d = ray_directions(size, size, f, torch.device("cpu"))
    a = math.radians(25.0)
    rot = torch.tensor(
        [[1, 0, 0], [0, math.cos(a), math.sin(a)], [0, -math.sin(a), math.cos(a)]],
        dtype=torch.float32,
    )
    dw = torch.einsum("ij,jhw->ihw", rot, d)
    best = torch.full((size, size), math.inf)
    normal = torch.zeros(3, size, size)
    for n, c in (((0.0, 1.0, 0.0), 1.0), ((0.0, 0.0, 1.0), 3.0), ((1.0, 0.0, 0.0), 1.5)):
        nt = torch.tensor(n)
        den = (dw * nt[:, None, None]).sum(0)
        t = c / torch.where(den.abs() > 1e-9, den, torch.full_like(den, 1e-9))
        hit = (t > 0) & (t < best)
        best = torch.where(hit, t, best)
        normal = torch.where(hit[None], nt[:, None, None].expand(3, size, size), normal)
    depth = torch.where(torch.isfinite(best), best, torch.zeros_like(best))
    return view_gbuffer(depth, f, normal=normal, world_to_view=rot.T)


def speed(size: int, repeat: int, nnao_model: str = SHIPPED) -> None:
    g = synthetic_gbuffer(size)
    mp = size * size / 1e6
    print(
        f"synthetic {size}x{size}, {torch.get_num_threads()} thread(s), CPU time best of {repeat}"
    )
    model = load_nnao(nnao_model)
    estimators = {**ESTIMATORS, "nnao": lambda g, r: nnao(model, g, r)}
    for name, estimator in estimators.items():
        estimator(g, 0.5)  # untimed
        best = float("inf")
        for _ in range(max(1, repeat)):
            c0 = time.process_time()
            estimator(g, 0.5)
            best = min(best, time.process_time() - c0)
        print(f"{name:<8} {1000 * best:8.0f} ms  {1000 * best / mp:8.0f} ms/MP")


def render_random_ao(folder: Path, count: int, seed: int) -> None:
    """Render the first ``count`` random scenes of data set ``seed`` with archetype ``ao``."""
    from mcdenoise.render.config import RenderConfig
    from mcdenoise.render.generate import generate
    from mcdenoise.render.jobs import jobs_from_specs
    from mcdenoise.render.random_scenes import random_scene

    specs = []
    index = 0
    while len(specs) < count and index < 100 * count:
        scene = random_scene(seed, index)
        if scene.archetype == "ao":
            specs.append(scene.spec)
        index += 1
    config = RenderConfig(
        out=folder, width=128, height=96, spp=(4, 16, 64), ref_spp=1024, progress=False
    )
    generate(jobs_from_specs(specs), config)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, nargs="?")
    ap.add_argument("--speed", type=int, metavar="N", help="time on a synthetic NxN G-buffer")
    ap.add_argument("--random-ao", type=int, metavar="N", help="render N random AO scenes first")
    ap.add_argument("--seed", type=int, default=3000, help="data set seed of --random-ao")
    ap.add_argument(
        "--render-only", action="store_true", help="stop after --random-ao (training sets)"
    )
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=2, help="timed runs per method (best kept)")
    ap.add_argument("--nnao-model", default=SHIPPED, help="nnao model file or run folder")
    ap.add_argument(
        "--nnao-param", action="append", default=[], metavar="KEY=VALUE", help="nnao parameter"
    )
    ap.add_argument(
        "--val-of",
        action="append",
        default=[],
        metavar="RUN",
        help="only the validation images of nnao run RUN (again: minus that run's training images)",
    )
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.speed:
        speed(args.speed, args.repeat, args.nnao_model)
        return
    if args.folder is None:
        ap.error("give a render folder or --speed N")
    if args.random_ao:
        render_random_ao(args.folder, args.random_ao, args.seed)
        if args.render_only:
            return
    manifest = json.loads((args.folder / "manifest.json").read_text())
    nnao_params: dict[str, str] = {"model": args.nnao_model}
    for item in args.nnao_param:
        key, eq, value = item.partition("=")
        if not eq:
            ap.error(f"--nnao-param wants KEY=VALUE, got {item!r}")
        nnao_params[key] = value
    keep = None
    if args.val_of:
        keep = set(load_nnao(args.val_of[0]).card.training.get("val_images", []))
        if not keep:
            ap.error(f"{args.val_of[0]}: the model card lists no validation images")
        for other in args.val_of[1:]:
            keep -= set(load_nnao(other).card.training.get("train_images", []))
    sums: dict[str, list[float]] = {}
    print(
        f"threads {args.threads}; SSIM and relMSE against the reference; ms best of {args.repeat}"
    )
    print(
        f"{'image':<22} {'method':<14} {'ssim':>6} {'relmse':>8} {'ms':>8} {'ms/MP':>9} "
        f"{'cpu ms':>8} {'cpu ms/MP':>10}"
    )
    for record in manifest["images"]:
        if "ao" not in record.get("effects", []):
            continue
        image = record["id"]
        if keep is not None and image not in keep:
            continue
        ref = load_buffers(args.folder / record["files"]["reference"])["color"].numpy()
        for level in record["levels"]:
            fb = load_buffers(args.folder / record["files"]["noisy"], part=level["part"])
            x = fb["color"].numpy()
            ms = 1000.0 * float(level["render_seconds"])
            mp = fb.width * fb.height / 1e6
            name = f"mcd_ao {level['spp']} spp"
            print(
                f"{image:<22} {name:<14} {ssim(x, ref):6.3f} {relmse(x, ref):8.4f} "
                f"{ms:8.0f} {ms / mp:9.0f}"
            )
        fb = load_buffers(args.folder / record["files"]["noisy"], part=record["levels"][0]["part"])
        if CAMERA_ATTR not in fb.attributes:
            fb.attributes[CAMERA_ATTR] = _camera_from_manifest(record)
        mp = fb.width * fb.height / 1e6
        for method in (*METHODS, NNAO):
            params = method.resolve_params(nnao_params if method is NNAO else None)
            best, best_cpu = float("inf"), float("inf")
            for _ in range(max(1, args.repeat)):
                t0, c0 = time.perf_counter(), time.process_time()
                out = method.run(fb, params, torch.device("cpu"))
                best = min(best, time.perf_counter() - t0)
                best_cpu = min(best_cpu, time.process_time() - c0)
            x = out.numpy()
            acc = sums.setdefault(method.name, [0.0, 0.0, 0.0])
            acc[0] += ssim(x, ref)
            acc[1] += relmse(x, ref)
            acc[2] += 1
            print(
                f"{image:<22} {method.name:<14} {ssim(x, ref):6.3f} {relmse(x, ref):8.4f} "
                f"{1000 * best:8.0f} {1000 * best / mp:9.0f} "
                f"{1000 * best_cpu:8.0f} {1000 * best_cpu / mp:10.0f}"
            )
    for name, (s_ssim, s_rel, n) in sums.items():
        print(f"mean of {int(n)} images {name:<8} {s_ssim / n:6.3f} {s_rel / n:8.4f}")


if __name__ == "__main__":
    main()
