"""Temporal models on the validation sequences of a training run, against their untrained start.

Reads the validation sequence names from a ``kpcn-temporal`` run's model card, loads them from
the run's data folders (as training does: the 4-spp part, the ``full`` source, the sequence's
exposure), and prints per model the geometric means of the per-frame and temporal relMSE as
ratios to the single-frame kpcn (``TemporalTask.validate``): the shipped model, the untrained
offline model around the shipped kpcn (the temporal module at its zero start), and every model
file given. Used in issue 37 to find that training on cached trunk features with flips and
rotations (the first shipped model) left the model worse than its untrained start.

    python benchmarks/bench_temporal_val.py runs/RUN [MODEL.pt ...] [--threads 2]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mcdenoise.modelfile import model_file, read_card
from mcdenoise.models.kpcn_temporal import TemporalKpcn, from_single_frame
from mcdenoise.models.weights import load_kpcn, shipped_model_path
from mcdenoise.threads import apply_threads
from mcdenoise.train.config import load_config
from mcdenoise.train.kpcn_temporal import TemporalTask, find_sequences, load_sequence


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a kpcn-temporal run folder or model file")
    ap.add_argument("models", nargs="*", type=Path)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    apply_threads(args.threads)
    training = read_card(model_file(args.run))["training"]
    names = set(training["val_sequences"])
    folders = [p for p in find_sequences(training["data"]) if p.name in names]
    models = {
        "shipped": TemporalKpcn.load(shipped_model_path("kpcn-temporal")),
        "untrained (offline, 5)": from_single_frame(load_kpcn(shipped_model_path("kpcn"))),
        **{str(p): TemporalKpcn.load(model_file(p)) for p in args.models},
    }
    print(f"{len(folders)} validation sequences of {args.run} ({training['data']})")
    cfg = load_config(None, {"model": "kpcn-temporal"})
    for name, model in models.items():
        seqs = [load_sequence(p, int(training["level"]), model.card.offsets) for p in folders]
        s = TemporalTask(model.eval(), cfg, seqs).validate()
        print(
            f"  {name:40s} relMSE {s['val_relmse_ratio_to_base']:.3f}x kpcn, "
            f"temporal {s['val_trelmse_ratio_to_base']:.3f}x"
        )


if __name__ == "__main__":
    main()
