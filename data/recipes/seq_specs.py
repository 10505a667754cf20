"""Write animated random scene specs (JSON) for temporal training / held-out sequences.

The random scene generator (``mcdenoise render --random``) gives every sequence the default
1°-per-frame orbit and no moving object. Temporal denoisers must also see dollies, faster
orbits, static cameras and objects that move (disocclusions, moving silhouettes), so this
script takes the generator's specs (``random_specs(count, seed)``, the same scenes as
``--random N --seed S``) and adds, per scene, with its own RNG (seeded by ``seed`` and the
index):

* a camera path: orbit of ±4…14° (40 %), dolly of 5…20 % of the way to the target (30 %),
  static (15 %), or the default-like slow orbit of ±2…4° (15 %);
* 1–2 moving objects (non-emissive, not the room's large rectangles when others exist),
  translated over the sequence by 0.4…1.5× their size in a random horizontal direction
  (sometimes with a small vertical part);
* with ``--moving-lights P``: with probability ``P`` one emissive object (an area light) moves
  too, by 0.3…1.0× its size (lighting that changes over the sequence). These draws use their
  own RNG, so the camera paths and moving objects of a seed are the same with or without it
  (the held-out specs of seed 9000 did not change when the option was added).

Usage (the recipes in temporal_training.md)::

    python data/recipes/seq_specs.py --count 40 --seed 7000 -o data/generated/seq-specs-train

Then ``mcdenoise render data/generated/seq-specs-train/*.json --frames F ...``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import random
from pathlib import Path

from mcdenoise.render.random_scenes import random_specs
from mcdenoise.render.scene_spec_types import Animation, SceneSpec


def _size(o) -> float:
    if o.shape == "sphere" and o.radius is not None:
        return 2.0 * o.radius
    s = o.transform.scale
    return 2.0 * max(abs(v) for v in s)


def animate(spec: SceneSpec, rng: random.Random) -> SceneSpec:
    """``spec`` with a random camera path and 1–2 moving objects."""
    u = rng.random()
    if u < 0.40:
        anim = Animation("orbit", angle=rng.choice([-1, 1]) * rng.uniform(4.0, 14.0))
    elif u < 0.70:
        anim = Animation("dolly", fraction=rng.uniform(0.05, 0.20))
    elif u < 0.85:
        anim = Animation("static")
    else:
        anim = Animation("orbit", angle=rng.choice([-1, 1]) * rng.uniform(2.0, 4.0))
    objs = list(spec.objects)
    small = [
        i
        for i, o in enumerate(objs)
        if o.emission is None and not (o.shape == "rectangle" and _size(o) > 2.0)
    ]
    cand = small or [i for i, o in enumerate(objs) if o.emission is None]
    moving = rng.sample(cand, k=min(len(cand), rng.choice([1, 1, 2])))
    for i in moving:
        o = objs[i]
        size = min(_size(o), 2.0)
        a = rng.uniform(0.0, 2.0 * math.pi)
        d = rng.uniform(0.4, 1.5) * size
        dy = rng.uniform(-0.2, 0.3) * size if rng.random() < 0.3 else 0.0
        objs[i] = dataclasses.replace(
            o, motion=(round(d * math.cos(a), 4), round(dy, 4), round(d * math.sin(a), 4))
        )
    return dataclasses.replace(spec, animation=anim, objects=tuple(objs))


def move_light(spec: SceneSpec, rng: random.Random, p: float) -> SceneSpec:
    """``spec`` with, at probability ``p``, one of its emissive objects translated over the
    sequence by 0.3…1.0× its size (horizontal, random direction)."""
    lights = [i for i, o in enumerate(spec.objects) if o.emission is not None]
    if not lights or rng.random() >= p:
        return spec
    objs = list(spec.objects)
    i = rng.choice(lights)
    size = min(_size(objs[i]), 2.0)
    a = rng.uniform(0.0, 2.0 * math.pi)
    d = rng.uniform(0.3, 1.0) * size
    objs[i] = dataclasses.replace(
        objs[i], motion=(round(d * math.cos(a), 4), 0.0, round(d * math.sin(a), 4))
    )
    return dataclasses.replace(spec, objects=tuple(objs))


#: Hand-written motion for curated scenes (held-out sequences): the three of
#: data/experiments/temporal.toml plus three more, each with a camera path and a moving object
#: (object index -> world translation over the sequence).
CURATED: dict[str, tuple[Animation, dict[int, tuple[float, float, float]]]] = {
    "cornell": (Animation("orbit", angle=10.0), {6: (-0.3, 0.0, 0.15)}),
    "textured_floors": (Animation("dolly", fraction=0.15), {3: (0.8, 0.0, 0.0)}),
    "glossy_env": (Animation("orbit", angle=-12.0), {1: (0.0, 0.0, 0.5)}),
    "mesh_object": (Animation("orbit", angle=8.0), {3: (-0.7, 0.0, 0.3)}),
    "sun_outdoor": (Animation("dolly", fraction=0.1), {2: (0.6, 0.0, -0.4)}),
    "interior_door": (Animation("static"), {11: (0.5, 0.0, 0.2)}),
}


def curated(scenes_dir: Path, out: Path) -> None:
    from mcdenoise.render.scene_spec import load_spec

    for name, (anim, moves) in CURATED.items():
        spec = load_spec(scenes_dir / f"{name}.toml")
        objs = list(spec.objects)
        for i, t in moves.items():
            objs[i] = dataclasses.replace(objs[i], motion=t)
        d = dataclasses.replace(spec, animation=anim, objects=tuple(objs)).to_dict()
        d.pop("source", None)
        (out / f"{name}_anim.json").write_text(json.dumps(d, indent=1), encoding="utf-8")
    print(f"{len(CURATED)} curated specs -> {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--curated", type=Path, help="also write the CURATED scenes of this folder (data/scenes)"
    )
    ap.add_argument(
        "--moving-lights",
        type=float,
        default=0.0,
        metavar="P",
        help="probability that one emissive object of a scene moves (default 0)",
    )
    ap.add_argument("-o", "--out", type=Path, required=True)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.curated:
        curated(args.curated, args.out)
    for k, spec in enumerate(random_specs(args.count, args.seed)):
        rng = random.Random(args.seed * 100003 + k)
        spec = animate(spec, rng)
        if args.moving_lights > 0:
            spec = move_light(spec, random.Random(f"light/{args.seed}/{k}"), args.moving_lights)
        d = spec.to_dict()
        d.pop("source", None)
        (args.out / f"{spec.name}.json").write_text(json.dumps(d, indent=1), encoding="utf-8")
    if args.count:
        print(f"{args.count} specs -> {args.out}")


if __name__ == "__main__":
    main()
