#!/bin/sh
# Short, equal-budget training runs for the kpcn ablations printed by bench_kpcn.py.
# Every run: the shipped model's recipe (data/recipes/kpcn.md) with ONE change, trained for
# STEPS steps (default 600: what two CPU cores afford; the ranking, not the absolute error, is
# what these runs show). Run folders go to runs/abl-*; then:
#   python benchmarks/bench_kpcn.py --ablation base=runs/abl-base --ablation k5=runs/abl-k5 ...
set -e
STEPS=${STEPS:-600}
DATA=${DATA:-data/generated/kal-train}
common="--data $DATA -s patch=48 -s margin=8 -s batch=8 -s steps=$STEPS -s epoch_steps=$STEPS \
  -s lr=1e-3 -s warmup=100 -s threads=${THREADS:-2} --quiet"
run() { name=$1; shift; [ -f runs/abl-$name/model.pt ] || mcdenoise train --model kpcn --out runs/abl-$name $common "$@"; }
run base -s kernel=11                       # 3 scales, source-aware, SMAPE, k = 11
run k5 -s kernel=5
run k21 -s kernel=21
run scales1 -s kernel=11 -s scales=1
run shared -s kernel=11 -s encoder=shared
run asym -s kernel=11 -s loss=asymmetric -s asym_slope=2
