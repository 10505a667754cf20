"""Copy a trained kpcn-temporal run into the shipped weights, recording in its model card the
hardware and the stages of training that made it (the trainer of the runs shipped on
2026-11-29 recorded its own stage's config only).

    python data/recipes/ship_temporal.py RUN OUT.pt --stage "runs/a: ..." --stage "runs/b: ..."
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mcdenoise.modelfile import model_file
from mcdenoise.models.kpcn_temporal import TemporalKpcn
from mcdenoise.train.patches import training_hardware


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--stage", action="append", default=[], help="one line per training stage")
    ap.add_argument("--threads", type=int, default=1, help="torch threads the stages used")
    args = ap.parse_args()
    model = TemporalKpcn.load(model_file(args.run))
    training = dict(model.card.training)
    hw = training_hardware("cpu")
    hw["torch_threads"] = args.threads
    training.setdefault("hardware", hw)
    training["stages"] = list(args.stage)
    model.card.training = training
    model.save(args.out)
    print(f"{args.run} -> {args.out}")


if __name__ == "__main__":
    main()
