#!/bin/sh
# Equal-budget training runs for the kpcn ablations printed by bench_kpcn.py.
# Every run: the shipped model's recipe (data/recipes/kpcn.md) with ONE change, trained for
# STEPS steps (default 3000, ~16 min per run on 2 idle CPU cores for k <= 11). Keep the recipe's
# 200 warm-up steps: with 100, the k = 11 run collapsed (validation relMSE stuck at 0.476 from
# step 400 to 800, 8x worse than the noisy input; the CLI now warns when that happens).
# Run folders go to runs/abl-*; then:
#   python benchmarks/bench_kpcn.py --ablation base=runs/abl-base --ablation k5=runs/abl-k5 ...
set -e
STEPS=${STEPS:-3000}
DATA=${DATA:-data/generated/kal-train}
common="--data $DATA -s patch=48 -s margin=8 -s batch=8 -s steps=$STEPS -s epoch_steps=500 \
  -s lr=1e-3 -s warmup=200 -s threads=${THREADS:-2} --quiet"
run() { name=$1; shift; [ -f runs/abl-$name/model.pt ] || mcdenoise train --model kpcn --out runs/abl-$name $common "$@"; }
run base -s kernel=11                       # 3 scales, source-aware, SMAPE, k = 11
run k5 -s kernel=5
run k21 -s kernel=21
run scales1 -s kernel=11 -s scales=1
run shared -s kernel=11 -s encoder=shared
run asym -s kernel=11 -s loss=asymmetric -s asym_slope=2
