#!/usr/bin/env bash
# Train kpcn from a packed training set on a GPU, from the source tree (nothing installed).
#
#   data/recipes/kpcn_gpu.sh PACK.npz [-s key=value ...]
#
# PACK.npz: made here by `mcdenoise train --model kpcn --data DIR --pack PACK.npz` (see
# data/recipes/kpcn.md, "On a GPU"). The machine needs python3 with torch, numpy, click and tqdm
# (scikit-image for the filters' imports); no OpenImageIO, OpenEXR or Mitsuba: a pack is read
# with numpy. The shipped recipe's first command is the default; extra -s flags come after it
# and win (e.g. -s steps=4000 -s batch=32, or --from RUN for the fine-tuning).
#
# Environment: DEVICE (cuda), AMP (bf16; ignored on cpu), PYTHON (python3), OUT (default
# runs/kpcn-gpu; the device tool sets it), TIME_LIMIT (seconds: then training is interrupted
# like Ctrl-C, exit status 124, and the summary still written; the run folder keeps its last
# checkpoint, at a multiple of epoch_steps, for --resume). Written: $OUT/summary.txt (torch, GPU, steps/s),
# $OUT/train.log and the run folder $OUT/run (config.json, latest, metrics.jsonl, model.pt =
# weights + card, checkpoints/ with the last checkpoint: 7 files in all, within what the
# device tool brings back; `mcdenoise train --out $OUT/run --resume` continues it).
set -euo pipefail

PACK=${1:?usage: data/recipes/kpcn_gpu.sh PACK.npz [-s key=value ...]}
shift
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
PYTHON=${PYTHON:-python3}
DEVICE=${DEVICE:-cuda}
AMP=${AMP:-bf16}
OUT=${OUT:-$REPO/runs/kpcn-gpu}
RUN=$OUT/run
mkdir -p "$OUT"

# mcdenoise_cli is the cli/ folder (pyproject's package-dir): a link to it, outside the tree
SHIM=$(mktemp -d)
ln -s "$REPO/cli" "$SHIM/mcdenoise_cli"
export PYTHONPATH="$REPO:$SHIM${PYTHONPATH:+:$PYTHONPATH}"
export PYTHONUNBUFFERED=1
# deterministic = true (the default) asks cuBLAS for reproducible results: it needs this
export CUBLAS_WORKSPACE_CONFIG=${CUBLAS_WORKSPACE_CONFIG:-:4096:8}

"$PYTHON" - <<'EOF' | tee "$OUT/summary.txt"
import platform, torch
dev = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no CUDA device"
print(f"python {platform.python_version()}, torch {torch.__version__}, {dev}, "
      f"{torch.get_num_threads()} CPU threads")
EOF

# The shipped recipe's first command (data/recipes/kpcn.md); -s threads: the sampler's CPU work.
set +e
limit=()
[ -n "${TIME_LIMIT:-}" ] && limit=(timeout --signal=INT --kill-after=30 "$TIME_LIMIT")
"${limit[@]}" "$PYTHON" -m mcdenoise_cli.main train --model kpcn --data "$PACK" --out "$RUN" \
    -s kernel=5 -s patch=48 -s margin=8 -s batch=8 -s steps=16000 -s epoch_steps=1000 \
    -s lr=1e-3 -s warmup=200 -s threads=4 -s checkpoints_kept=1 \
    -s device="$DEVICE" -s amp="$AMP" "$@" 2>&1 | tee "$OUT/train.log"
rc=${PIPESTATUS[0]}
set -e

"$PYTHON" - "$RUN/metrics.jsonl" <<'EOF' | tee -a "$OUT/summary.txt"
import json, sys
try:
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
except OSError:
    rows = []
if rows:
    last = rows[-1]
    print(f"{last['step']} steps in {last['seconds']:.1f} s of training: "
          f"{last['step'] / max(last['seconds'], 1e-9):.2f} steps/s (validations included); "
          f"best validation relMSE {min(r['val_loss'] for r in rows):.5g}, "
          f"{last['skipped_steps']} skipped")
else:
    print("no metrics written")
EOF
exit "$rc"
